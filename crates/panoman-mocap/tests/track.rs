//! Retargeted CMU motion tracked from the TC-133 keypoints of its generated meshes
//! (`panoman_mocap::track`), on the committed `01_01` excerpt with the small test model.

use std::path::Path;

use panoman_human::params::ShapeParams;
use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
use panoman_mocap::retarget::CmuRetarget;
use panoman_mocap::track::{TrackOptions, select_frames, track_retarget};

#[test]
fn frame_selection_rejects_empty_ranges() {
    assert_eq!(select_frames(10, (0, None, 4)).unwrap(), vec![0, 4, 8]);
    assert_eq!(select_frames(10, (2, Some(5), 1)).unwrap(), vec![2, 3, 4]);
    assert!(select_frames(10, (0, None, 0)).is_err());
    assert!(select_frames(10, (5, Some(5), 1)).is_err());
    assert!(select_frames(10, (12, None, 1)).is_err());
}

#[test]
fn excerpt_is_tracked_by_both_methods() {
    let model = panoman::Model::load(panoman::training::small_model(None).expect("small model"))
        .expect("loads");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&path).unwrap().scaled(CMU_UNIT_M);
    let rig = model
        .rig()
        .cloned()
        .expect("the small model carries its rig");
    let shape = ShapeParams::default();
    let identity = rig.generator.identity(&shape).unwrap();
    let rt = CmuRetarget::calibrate(&identity, &shape, &bvh, 0).unwrap();
    let n = bvh.n_frames();
    let mut heard = 0;
    let rep = track_retarget(
        &model,
        &rt,
        &bvh,
        (0, None, 3),
        TrackOptions::default(),
        &mut |done, total, row| {
            heard += 1;
            assert_eq!(done, heard);
            assert_eq!(total, n.div_ceil(3));
            assert!(row.panoman.all_mean.is_finite() && row.lbs.all_mean.is_finite());
        },
    )
    .unwrap();
    assert_eq!(rep.frames.len(), n.div_ceil(3));
    assert_eq!(heard, rep.frames.len());
    assert_eq!(rep.n_vertices, model.n_vertices());
    let frames: Vec<usize> = rep.frames.iter().map(|r| r.frame).collect();
    assert_eq!(frames, (0..n).step_by(3).collect::<Vec<_>>());
    for s in [&rep.panoman, &rep.lbs] {
        assert!(s.mean_mm.is_finite() && s.mean_mm >= 0.0, "{s:?}");
        assert!(
            s.median_mm <= s.max_mm && s.mean_mm <= s.max_mm + 1e-9,
            "{s:?}"
        );
        assert!(s.max_vertex_mm >= s.max_mm, "{s:?}");
        assert!(s.ms_per_frame > 0.0);
        assert!(frames.contains(&s.worst_frame));
    }
    // The worst frame's meshes come back on the model's topology.
    let w = rep.worst.as_ref().expect("worst frame kept");
    assert_eq!(w.truth.len(), model.n_vertices());
    // The shell stage starts from the same IK as the baseline and may only improve on it
    // where the keypoints say so: its error stays within the 3 % of the baseline's
    // (plus 0.1 mm for the small template's rounding of tiny errors).
    assert!(
        rep.panoman.mean_mm <= 1.03 * rep.lbs.mean_mm + 0.1,
        "PanoMan {:.2} mm vs LBS {:.2} mm",
        rep.panoman.mean_mm,
        rep.lbs.mean_mm
    );
    // The truth is the rig's own mesh and every keypoint is exact. Measured on this excerpt:
    // frames 15–21 mm (mean 16.2; the torso's spine flexion, which the keypoints hardly see,
    // is most of it — crates/panoman-mocap/README.md); 40 mm, about twice the worst frame,
    // means a frame lost the person.
    assert!(rep.panoman.max_mm < 40.0, "{:?}", rep.panoman);
}

/// The contact prior's sole points on the default identity's rest mesh (small model): big
/// toe, small toe and heel of each foot, left on +x, toes forward (−y) of the heel, the big
/// toe medial of the small toe, all on the sole; the excerpt tracked from TC-133 (the foot
/// keypoints among the targets) and from TC-127 (without them), each reporting its layout.
#[test]
fn sole_points_and_the_foot_keypoints_in_tracking() {
    use panoman::sole_points;
    let model = panoman::Model::load(panoman::training::small_model(None).expect("small model"))
        .expect("loads");
    let rig = model.rig().cloned().expect("rig");
    let topology = model.output_topology().unwrap();
    let id = rig.generator.identity(&ShapeParams::default()).unwrap();
    let rest = rig
        .map
        .map(topology, &id.pose(&Default::default()).vertices);
    let p = sole_points(&rest).unwrap();
    let low = rest.iter().map(|v| v[2]).fold(f64::INFINITY, f64::min);
    let v = |k: usize| rest[p[k] as usize];
    for side in 0..2 {
        let (big, small, heel) = (v(3 * side), v(3 * side + 1), v(3 * side + 2));
        let sign = if side == 0 { 1.0 } else { -1.0 };
        for q in [big, small, heel] {
            assert!(q[0] * sign > 0.0, "side {side}: {q:?}");
            assert!(q[2] < low + 0.03, "not on the sole: {q:?}");
        }
        assert!(
            big[1] < heel[1] - 0.1 && small[1] < heel[1] - 0.05,
            "{big:?} {small:?} {heel:?}"
        );
        assert!(
            big[0].abs() < small[0].abs(),
            "big toe not medial: {big:?} {small:?}"
        );
    }
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&path).unwrap().scaled(CMU_UNIT_M);
    let shape = ShapeParams::default();
    let rt = CmuRetarget::calibrate(&id, &shape, &bvh, 0).unwrap();
    let without = TrackOptions {
        without_feet: true,
        ..TrackOptions::default()
    };
    let rep = track_retarget(&model, &rt, &bvh, (0, None, 3), without, &mut |_, _, _| {}).unwrap();
    assert_eq!(rep.layout, "TC-127");
    assert!(rep.panoman.mean_mm.is_finite() && rep.lbs.mean_mm.is_finite());
    assert!(rep.calibration.is_none());
    // With a shape calibration from two of the tracked frames (the first and the middle one),
    // from the whole layout.
    let cal = TrackOptions {
        shape_frames: 2,
        ..TrackOptions::default()
    };
    let rep = track_retarget(&model, &rt, &bvh, (0, None, 3), cal, &mut |_, _, _| {}).unwrap();
    assert_eq!(rep.layout, "TC-133");
    let c = rep.calibration.expect("calibrated");
    let n = bvh.n_frames().div_ceil(3);
    assert_eq!(c.frames, vec![0, 3 * (n / 2)]);
    assert_eq!(c.knobs.len(), 9);
    assert!(c.knobs.iter().all(|(_, v)| v.abs() <= 1.0));
    assert!(c.before_mm.is_finite() && c.after_mm.is_finite());
    assert!(rep.panoman.mean_mm.is_finite() && rep.lbs.mean_mm.is_finite());
}

/// The foot–floor contact prior (`TrackOptions::contacts`) on the excerpt: the sole level
/// pairs sit on the foot points with their rest height differences, the excerpt's standing
/// frames are detected as planted, both trackers run with the prior, and bad uses are
/// errors (no frame rate; a level pair on one vertex).
#[test]
fn contact_prior_tracks_the_excerpt() {
    use panoman_mocap::track::{ContactOptions, track_generated};
    let model = panoman::Model::load(panoman::training::small_model(None).expect("small model"))
        .expect("loads");
    let feet = model.sole_points().unwrap();
    let soles = model.sole_levels().unwrap();
    for (s, pair) in soles.iter().enumerate() {
        for (k, l) in pair.iter().enumerate() {
            assert_eq!((l.a, l.b), (feet[3 * s + 2], feet[3 * s + k]));
            assert!(l.offset.abs() < 0.03, "both on the sole: {}", l.offset);
            assert_eq!((l.up, l.weight), ([0.0, 0.0, 1.0], 1.0));
        }
    }
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&path).unwrap().scaled(CMU_UNIT_M);
    let shape = ShapeParams::default();
    let rig = model.rig().cloned().unwrap();
    let id = rig.generator.identity(&shape).unwrap();
    let rt = CmuRetarget::calibrate(&id, &shape, &bvh, 0).unwrap();
    let opts = TrackOptions {
        contacts: Some(ContactOptions::default()),
        without_feet: true,
        ..TrackOptions::default()
    };
    let rep = track_retarget(&model, &rt, &bvh, (0, None, 3), opts, &mut |_, _, _| {}).unwrap();
    let c = rep.contacts.expect("contacts reported");
    let n = rep.frames.len();
    eprintln!(
        "contacts: {:?} of {n} frames down, PanoMan {:.2} mm, LBS {:.2} mm",
        c.frames_down, rep.panoman.mean_mm, rep.lbs.mean_mm
    );
    // The excerpt starts in a T-pose: the left foot stands (12 of 14 frames measured), the
    // right one shuffles (weight 0.3 on average).
    assert!(
        c.frames_down.iter().all(|&d| d <= n) && c.frames_down.iter().sum::<usize>() > 0,
        "{c:?}"
    );
    assert!(
        c.mean_weight.iter().all(|w| (0.0..=1.0).contains(w)),
        "{c:?}"
    );
    assert!(rep.panoman.mean_mm.is_finite() && rep.lbs.mean_mm.is_finite());
    // track_generated needs the frame rate for the ankle speeds.
    let frames = vec![(0, rt.params(&bvh, 0))];
    let no_rate = TrackOptions {
        contacts: Some(ContactOptions::default()),
        without_feet: true,
        ..TrackOptions::default()
    };
    let e = track_generated(&model, &frames, no_rate, &mut |_, _, _| {}).unwrap_err();
    assert!(e.to_string().contains("frame rate"), "{e}");
    // A level pair on one vertex is refused by the fit's constraint check.
    let mut fitter = panoman::Fitter::new(&model).unwrap();
    let truth_kp = {
        let p = rt.params(&bvh, 0);
        let v = rig.map.map(
            model.output_topology().unwrap(),
            &rig.generator
                .identity(&p.shape)
                .unwrap()
                .pose(&p.pose)
                .vertices,
        );
        model.keypoints(&v).unwrap()
    };
    // The prior on two frames: each apply adds the frame's level pairs (the truth's frame 0
    // stands: four), a third frame is an error, and a frame without an ankle is named.
    use panoman::feet::ContactPrior;
    let two = vec![panoman::Targets::from_keypoints(&truth_kp); 2];
    let mut prior =
        ContactPrior::from_targets(&model, &two, 30.0, &ContactOptions::default()).unwrap();
    let mesh = vec![[0.0; 3]; model.n_vertices()];
    for _ in 0..2 {
        assert_eq!(prior.apply(&two[0]).unwrap().levels.len(), 4);
        prior.advance(&mesh);
    }
    assert!(prior.apply(&two[0]).is_err());
    let mut missing = two.clone();
    let la = panoman::keypoint_names()
        .iter()
        .position(|n| n == "l_ankle")
        .unwrap();
    missing[1].keypoints.points.remove(&la);
    let e = ContactPrior::from_targets(&model, &missing, 30.0, &ContactOptions::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("frame 1 has no l_ankle"), "{e}");
    assert!(ContactPrior::from_targets(&model, &two, 0.0, &ContactOptions::default()).is_err());
    let mut t = panoman::Targets::from_keypoints(&truth_kp);
    t.levels = vec![panoman::LevelPair {
        b: soles[0][0].a,
        ..soles[0][0].clone()
    }];
    let e = fitter
        .fit(&t, &panoman::FitRequest::default())
        .unwrap_err()
        .to_string();
    assert!(e.contains("level 0"), "{e}");
}
