//! The foot–floor contact prior (`panoman::feet`): contact detection from ankle keypoints
//! and the anchors of planted feet. Model-free; the level pairs on a model and the tracking
//! with the prior are tested in `panoman-mocap`'s `tests/track.rs`.

use panoman::feet::{ContactOptions, FootAnchors, FootContacts};
use panoman::{LevelPair, V3};

/// A walk-like sequence at 30 Hz, Z up, floor at ankle height 0.08 m: the left foot stands
/// for frames 0–9, swings (0.15 m up, 1.5 m/s forward) for 10–14 and stands again 15–24;
/// the right foot stands throughout, 0.2 m to the side.
fn sequence() -> Vec<(f64, [V3; 2])> {
    (0..25)
        .map(|i| {
            let t = i as f64 / 30.0;
            let (y, z) = match i {
                0..=9 => (0.0, 0.08),
                10..=14 => (0.05 * (i - 9) as f64, 0.23),
                _ => (0.3, 0.08),
            };
            (t, [[0.1, y, z], [-0.1, 0.0, 0.08]])
        })
        .collect()
}

#[test]
fn contacts_are_down_when_low_and_still() {
    let c = FootContacts::detect(&sequence(), &ContactOptions::default()).unwrap();
    assert_eq!(c.weights.len(), 25);
    assert!((c.floor[0] - 0.08).abs() < 1e-12 && (c.floor[1] - 0.08).abs() < 1e-12);
    // The standing right foot: weight 1 everywhere.
    assert!(c.weights.iter().all(|w| w[1] == 1.0), "{:?}", c.weights);
    // The left foot: down before and after, up while swinging (15 cm above its floor level).
    for i in (0..9).chain(16..25) {
        assert_eq!(c.weights[i][0], 1.0, "frame {i}");
    }
    for i in 10..15 {
        assert_eq!(c.weights[i][0], 0.0, "frame {i}");
    }
    // Frame 9 is low but its central difference sees the lift (0.15 m up in 1/15 s).
    assert_eq!(c.weights[9][0], 0.0);
    // Between the band ends the weight is linear: an ankle 3.5 cm up (half of 2–5 cm), still.
    let mut s = sequence();
    s[3].1[1][2] = 0.08 + 0.035;
    s[2].1[1][2] = s[3].1[1][2];
    s[4].1[1][2] = s[3].1[1][2];
    let c = FootContacts::detect(&s, &ContactOptions::default()).unwrap();
    assert!((c.weights[3][1] - 0.5).abs() < 1e-9, "{:?}", c.weights[3]);
    // Another up axis: the same sequence rotated to Y up gives the same weights.
    let rotated: Vec<(f64, [V3; 2])> = sequence()
        .into_iter()
        .map(|(t, a)| (t, a.map(|p| [p[0], p[2], -p[1]])))
        .collect();
    let o = ContactOptions {
        up: [0.0, 3.0, 0.0],
        ..ContactOptions::default()
    };
    let r = FootContacts::detect(&rotated, &o).unwrap();
    let c = FootContacts::detect(&sequence(), &ContactOptions::default()).unwrap();
    assert_eq!(r.weights, c.weights);
}

#[test]
fn level_pairs_take_the_contact_weight() {
    let c = FootContacts::detect(&sequence(), &ContactOptions::default()).unwrap();
    let pair = |a: u32, b: u32| LevelPair {
        a,
        b,
        up: [0.0, 0.0, 1.0],
        offset: 0.01,
        weight: 1.0,
    };
    let soles = [[pair(1, 2), pair(1, 3)], [pair(4, 5), pair(4, 6)]];
    // Both feet down: four pairs at the options' weight.
    let l = c.levels(0, &soles);
    assert_eq!(l.len(), 4);
    assert!(
        l.iter()
            .all(|p| p.weight == ContactOptions::default().weight)
    );
    // Left foot swinging: only the right foot's two pairs.
    let l = c.levels(12, &soles);
    assert_eq!(l.iter().map(|p| p.a).collect::<Vec<_>>(), vec![4, 4]);
    assert!(c.levels(99, &soles).is_empty());
}

#[test]
fn anchors_hold_a_planted_foot_and_release_it() {
    let points = [10, 11, 12, 20, 21, 22];
    let mut mesh = vec![[0.0; 3]; 30];
    for (k, &v) in points.iter().enumerate() {
        mesh[v as usize] = [k as f64, 1.0, 0.0];
    }
    let mut a = FootAnchors::default();
    // Touchdown of the left foot only: anchored where this frame's fit put it.
    assert!(a.handles([1.0, 0.0], &points, 0.5).is_empty());
    a.update([1.0, 0.0], &points, &mesh);
    assert_eq!(
        a.anchors[0],
        Some([[0.0, 1.0, 0.0], [1.0, 1.0, 0.0], [2.0, 1.0, 0.0]])
    );
    assert_eq!(a.anchors[1], None);
    // The next frame's fit moved it: the anchor stays where it was.
    let moved: Vec<V3> = mesh.iter().map(|p| [p[0] + 0.1, p[1], p[2]]).collect();
    a.update([0.8, 0.0], &points, &moved);
    let h = a.handles([0.8, 0.0], &points, 0.5);
    assert_eq!(h.len(), 3);
    assert_eq!(
        h.iter().map(|h| h.vertex).collect::<Vec<_>>(),
        vec![10, 11, 12]
    );
    assert!(h.iter().all(|h| (h.weight - 0.4).abs() < 1e-12));
    assert_eq!(h[1].position, [1.0, 1.0, 0.0]);
    // Lifted: released, and a later touchdown anchors afresh.
    a.update([0.2, 0.0], &points, &moved);
    assert_eq!(a.anchors[0], None);
    assert!(a.handles([1.0, 0.0], &points, 0.5).is_empty());
    a.update([1.0, 0.0], &points, &moved);
    assert_eq!(a.anchors[0].unwrap()[0], [0.1, 1.0, 0.0]);
}

#[test]
fn bad_contact_input_is_an_error() {
    let o = ContactOptions::default();
    let err = |s: &[(f64, [V3; 2])], o: &ContactOptions| {
        FootContacts::detect(s, o).unwrap_err().to_string()
    };
    assert!(err(&[], &o).contains("no frames"));
    let mut s = sequence();
    s[5].0 = s[4].0;
    assert!(err(&s, &o).contains("frame 5"), "{}", err(&s, &o));
    let mut s = sequence();
    s[7].1[0][2] = f64::NAN;
    assert!(err(&s, &o).contains("frame 7"));
    for bad in [
        ContactOptions { up: [0.0; 3], ..o },
        ContactOptions {
            height: (0.05, 0.02),
            ..o
        },
        ContactOptions {
            speed: (f64::NAN, 1.0),
            ..o
        },
        ContactOptions {
            floor_percentile: 120.0,
            ..o
        },
        ContactOptions { weight: -1.0, ..o },
    ] {
        assert!(FootContacts::detect(&sequence(), &bad).is_err(), "{bad:?}");
    }
}
