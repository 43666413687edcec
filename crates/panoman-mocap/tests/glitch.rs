//! Capture glitches found from the markers alone: a marker that leaves its rigid neighbours
//! is flagged, its neighbours and the ordinary motion are not.
use panoman_mocap::glitch::{drop_glitches, find_glitches};
use panoman_mocap::markers::{MarkerSequence, UpSource};

/// Two rigid clusters of four markers (a "shank" and a "foot"), each cluster translating and
/// turning over 200 frames, the foot also rotating relative to the shank by up to 30°.
fn two_clusters() -> MarkerSequence {
    let shank = [
        [0.0, 0.0, 0.0],
        [0.06, 0.0, 0.0],
        [0.0, 0.07, 0.0],
        [0.0, 0.0, 0.2],
    ];
    let foot = [
        [0.0, 0.0, -0.05],
        [0.1, 0.0, -0.08],
        [0.0, 0.15, -0.08],
        [0.05, 0.2, -0.06],
    ];
    let n = 200;
    let mut positions = Vec::new();
    for f in 0..n {
        let t = f as f64 / n as f64;
        let (a, b) = (1.5 * t, 0.5 * (6.0 * t).sin());
        let rot = |p: [f64; 3], ang: f64| {
            [
                ang.cos() * p[0] - ang.sin() * p[1],
                ang.sin() * p[0] + ang.cos() * p[1],
                p[2],
            ]
        };
        let move_by = [0.8 * t, 0.1 * t, 0.3];
        for p in shank {
            let q = rot(p, a);
            positions.push([q[0] + move_by[0], q[1] + move_by[1], q[2] + move_by[2]]);
        }
        for p in foot {
            let q = rot(rot(p, b), a);
            positions.push([q[0] + move_by[0], q[1] + move_by[1], q[2] + move_by[2]]);
        }
    }
    MarkerSequence {
        names: (0..8).map(|i| format!("M{i}")).collect(),
        rate_hz: 100.0,
        first_frame: 1,
        positions,
        source_unit: "m".into(),
        metres_per_unit: 1.0,
        up_axis: None,
        up_source: UpSource::Unknown,
    }
}

#[test]
fn a_marker_that_leaves_its_neighbours_is_a_glitch() {
    let clean = two_clusters();
    assert!(
        find_glitches(&clean, 0.05, 0.05).iter().all(|g| !g),
        "rigid motion and the relative foot rotation are not glitches"
    );
    let mut seq = clean.clone();
    let nm = seq.n_markers();
    // A label swap for 20 frames (marker 5 takes a point 0.3 m away), one missing sample.
    for f in 100..120 {
        let p = &mut seq.positions[f * nm + 5];
        p[2] += 0.3;
    }
    seq.positions[50 * nm + 1] = [f64::NAN; 3];
    let flags = find_glitches(&seq, 0.05, 0.05);
    for f in 0..seq.n_frames() {
        for i in 0..nm {
            assert_eq!(
                flags[f * nm + i],
                i == 5 && (100..120).contains(&f),
                "frame {f} marker {i}"
            );
        }
    }
    let counts = drop_glitches(&mut seq, 0.05, 0.05);
    assert_eq!(counts, vec![0, 0, 0, 0, 0, 20, 0, 0]);
    assert!(seq.get(110, 5).is_none() && seq.get(99, 5).is_some());
    // Threshold 0 with no noise: still nothing flagged on the clean capture.
    assert!(find_glitches(&clean, 1e-9, 1e-9).iter().all(|g| !g));
}

/// A marker that slides away from its cluster and back (lifted by a ramp up to 0.3 m and down
/// again over frames 60–140) crosses the 5 cm threshold only in the middle of the slide. With
/// the lower threshold at 2.5 cm the run reaches further on both sides and has no holes (a
/// missing frame inside it is carried over, not flagged). A distance changes by at most the
/// marker's displacement (triangle inequality), so the frames lifted by less than 2.5 cm and a
/// separate 3 cm excursion, which never reaches the threshold, stay unflagged.
#[test]
fn a_glitch_run_goes_on_while_the_marker_stays_off() {
    let mut seq = two_clusters();
    let nm = seq.n_markers();
    let off = |f: usize| -> f64 {
        if (60..140).contains(&f) {
            0.3 * (1.0 - (f as f64 - 100.0).abs() / 40.0)
        } else {
            0.0
        }
    };
    for f in 0..seq.n_frames() {
        seq.positions[f * nm + 5][2] += off(f);
        if (170..180).contains(&f) {
            seq.positions[f * nm + 5][2] += 0.03;
        }
    }
    let missing = 80;
    seq.positions[missing * nm + 5] = [f64::NAN; 3];
    let single = find_glitches(&seq, 0.05, 0.05);
    let runs = find_glitches(&seq, 0.05, 0.025);
    let flagged = |flags: &[bool]| -> Vec<usize> {
        (0..seq.n_frames()).filter(|&f| flags[f * nm + 5]).collect()
    };
    let (a, b) = (flagged(&single), flagged(&runs));
    assert!(
        !a.is_empty() && a.iter().all(|f| b.contains(f)),
        "{a:?} {b:?}"
    );
    assert!(
        b[0] < a[0] && b[b.len() - 1] > a[a.len() - 1],
        "{a:?} {b:?}"
    );
    assert!(b[0] < missing && b[b.len() - 1] > missing, "{b:?}");
    let holes: Vec<usize> = (b[0]..=b[b.len() - 1]).filter(|f| !b.contains(f)).collect();
    assert_eq!(
        holes,
        vec![missing],
        "the run is one piece but for the missing frame"
    );
    for &f in &b {
        assert!(
            off(f) > 0.025,
            "frame {f} lifted {:.3} m is flagged",
            off(f)
        );
    }
    // The other markers, and the excursion that never crosses the threshold, stay clean.
    assert!((170..180).all(|f| !runs[f * nm + 5]));
    for i in (0..nm).filter(|&i| i != 5) {
        assert!((0..seq.n_frames()).all(|f| !runs[f * nm + i]), "marker {i}");
    }
}
