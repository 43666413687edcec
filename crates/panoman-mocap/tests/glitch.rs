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
        find_glitches(&clean, 0.05).iter().all(|g| !g),
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
    let flags = find_glitches(&seq, 0.05);
    for f in 0..seq.n_frames() {
        for i in 0..nm {
            assert_eq!(
                flags[f * nm + i],
                i == 5 && (100..120).contains(&f),
                "frame {f} marker {i}"
            );
        }
    }
    let counts = drop_glitches(&mut seq, 0.05);
    assert_eq!(counts, vec![0, 0, 0, 0, 0, 20, 0, 0]);
    assert!(seq.get(110, 5).is_none() && seq.get(99, 5).is_some());
    // Threshold 0 with no noise: still nothing flagged on the clean capture.
    assert!(find_glitches(&clean, 1e-9).iter().all(|g| !g));
}
