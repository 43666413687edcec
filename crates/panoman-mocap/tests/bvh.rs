//! BVH reader, writer and forward kinematics.

use std::path::{Path, PathBuf};

use panoman_mocap::MocapError;
use panoman_mocap::bvh::{Bvh, CMU_UNIT_M, Channel, axis_rotation, parse_bvh, read_bvh};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn assert_format_err<T: std::fmt::Debug>(r: Result<T, MocapError>, name: &str, needle: &str) {
    match r {
        Err(e @ MocapError::Format { .. }) => {
            let msg = e.to_string();
            assert!(
                msg.contains(name) && msg.contains(needle),
                "`{msg}` lacks {name} / {needle}"
            );
        }
        other => panic!("expected a format error, got {other:?}"),
    }
}

fn dist(a: [f64; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|k| (a[k] - b[k]).powi(2)).sum::<f64>().sqrt()
}

#[test]
fn cmu_excerpt_facts_and_fk() {
    let b = read_bvh(&data("01_01_head.bvh")).unwrap();
    assert_eq!((b.joints.len(), b.n_channels(), b.n_frames()), (31, 96, 40));
    assert_eq!(b.frame_time_s, 0.0083333);
    assert_eq!(b.joints[0].name, "Hips");
    assert_eq!(b.joints[0].channels.len(), 6);
    assert_eq!(
        b.joints[1].channels,
        [Channel::Zrotation, Channel::Yrotation, Channel::Xrotation]
    );
    let toe = b.joint_index("LeftToeBase").unwrap();
    assert_eq!(b.joints[toe].end_site, Some([0.0, -0.0, 1.18966]));
    assert_eq!(b.joints.iter().filter(|j| j.end_site.is_some()).count(), 7);
    // Frame 0 row: "9.3722 17.8693 -17.3198 0 0 0 | 0 0 0 | -17 0 0 | …".
    let p = b.joint_positions(0);
    let root = [9.3722, 17.8693, -17.3198];
    assert_eq!(p[0], root);
    let up = b.joint_index("LeftUpLeg").unwrap();
    assert_eq!(b.frame(0)[9], -17.0);
    let up_pos = [root[0] + 1.36306, root[1] - 1.79463, root[2] + 0.83929];
    assert!(dist(p[up], up_pos) < 1e-12);
    // LeftLeg = LeftUpLeg + Rz(−17°)·(2.44811, −6.72613, 0).
    let (s, c) = (-17f64).to_radians().sin_cos();
    let o = [2.44811, -6.72613];
    let leg = [
        up_pos[0] + c * o[0] - s * o[1],
        up_pos[1] + s * o[0] + c * o[1],
        up_pos[2],
    ];
    assert!(dist(p[b.joint_index("LeftLeg").unwrap()], leg) < 1e-12);
    // Metres: the CMU subject's head is ~1.6 m above the toes in the T-pose.
    let m = b.scaled(CMU_UNIT_M);
    let pm = m.joint_positions(0);
    let head = pm[m.joint_index("Head").unwrap()];
    let toe_y = pm[toe][1];
    assert!(
        (1.3..1.9).contains(&(head[1] - toe_y)),
        "{}",
        head[1] - toe_y
    );
}

#[test]
fn write_read_round_trip() {
    let b = read_bvh(&data("01_01_head.bvh"))
        .unwrap()
        .scaled(CMU_UNIT_M);
    let text = b.to_text();
    let c = parse_bvh(&text, Path::new("rt.bvh")).unwrap();
    assert_eq!(c, b, "values read back exactly");
    for f in 0..b.n_frames() {
        for (x, y) in b.joint_positions(f).into_iter().zip(c.joint_positions(f)) {
            assert!(dist(x, y) < 1e-9);
        }
    }
    let dir = std::env::temp_dir().join(format!("panoman-mocap-bvh-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("rt.bvh");
    b.write(&path).unwrap();
    assert_eq!(read_bvh(&path).unwrap(), b);
    std::fs::remove_dir_all(&dir).unwrap();
}

/// A two-joint chain with the given root and child channel lists.
fn chain(root_ch: &str, child_ch: &str, row: &str) -> String {
    let n = |s: &str| s.split_whitespace().count();
    format!(
        "HIERARCHY\nROOT R\n{{\n OFFSET 1 0 0\n CHANNELS {} {root_ch}\n JOINT C\n {{\n  OFFSET 0 2 0\n  \
         CHANNELS {} {child_ch}\n  End Site\n  {{\n   OFFSET 0 0 3\n  }}\n }}\n}}\nMOTION\nFrames: 1\n\
         Frame Time: 0.01\n{row}\n",
        n(root_ch),
        n(child_ch)
    )
}

fn mat_apply(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| (0..3).map(|k| m[i][k] * v[k]).sum())
}

#[test]
fn channel_orders_compose_in_listed_order() {
    // Root: X rotation 90 then Z rotation 90 listed as "Xrotation Zrotation" → R = Rx·Rz.
    let t = chain(
        "Xposition Yposition Zposition Xrotation Zrotation",
        "Yrotation",
        "0 0 0 90 90 0",
    );
    let b = parse_bvh(&t, Path::new("c.bvh")).unwrap();
    let r = panoman_mocap::bvh::mul3(&axis_rotation(0, 90.0), &axis_rotation(2, 90.0));
    let child = mat_apply(&r, [0.0, 2.0, 0.0]);
    let p = b.joint_positions(0);
    assert!(dist(p[1], [1.0 + child[0], child[1], child[2]]) < 1e-12);
    // The other order gives a different place: Rz·Rx·(0, 2, 0) ≠ Rx·Rz·(0, 2, 0).
    let t2 = chain(
        "Xposition Yposition Zposition Zrotation Xrotation",
        "Yrotation",
        "0 0 0 90 90 0",
    );
    let p2 = parse_bvh(&t2, Path::new("c.bvh"))
        .unwrap()
        .joint_positions(0);
    assert!(dist(p[1], p2[1]) > 1.0);
    // Positions only on the child (no root channels at all), and an end site.
    let t3 = chain("", "Zposition Xrotation", "0.5 90");
    let b3 = parse_bvh(&t3, Path::new("c.bvh")).unwrap();
    assert_eq!(b3.joint_positions(0)[1], [1.0, 2.0, 0.5]);
    let e = b3.end_site_positions(0);
    // Rx(90°)·(0, 0, 3) = (0, −3, 0).
    assert!(dist(e[0].1, [1.0, -1.0, 0.5]) < 1e-12);
    let rt = parse_bvh(&b3.to_text(), Path::new("c.bvh")).unwrap();
    assert_eq!(rt, b3);
}

#[test]
fn bad_bvh_input() {
    let p = Path::new("bad.bvh");
    let ok = chain("Xrotation", "Yrotation", "1 2");
    assert!(parse_bvh(&ok, p).is_ok());
    let cases = [
        (
            ok.replace("CHANNELS 1 Xrotation", "CHANNELS 1 Wrotation"),
            "unknown channel `Wrotation`",
        ),
        (
            ok.replace("CHANNELS 1 Xrotation", "CHANNELS 2 Xrotation Xrotation"),
            "repeated",
        ),
        (
            ok.replace("CHANNELS 1 Xrotation", "CHANNELS 7 Xrotation"),
            "channel count 7",
        ),
        (ok.replace("\n1 2\n", "\n1 2 3\n"), "3 values, expected 2"),
        (ok.replace("\n1 2\n", "\n1\n"), "1 values, expected 2"),
        (ok.replace("\n1 2\n", "\n1 nan\n"), "not a finite number"),
        (
            ok.replace("\n1 2\n", "\n1 2\n3 4\n"),
            "Frames: 1 but the file has 2 rows",
        ),
        (
            ok.replace("Frames: 1", "Frames: 100000000"),
            "but the file has 1 rows",
        ),
        (
            ok.replace("Frame Time: 0.01", "Frame Time: 0"),
            "not positive",
        ),
        (
            ok.replace("Frame Time: 0.01", "Frame Tim: 0.01"),
            "expected `Frame Time:`",
        ),
        (ok.replace("MOTION", "MOTON"), "no MOTION"),
        (ok.replace("JOINT C", "JOINT R"), "duplicate joint name"),
        (
            ok.replace("OFFSET 0 2 0", "OFFSET 0 x 0"),
            "not a finite number",
        ),
        (
            ok.replace("OFFSET 0 2 0", "OFFSET 0 inf 0"),
            "not a finite number",
        ),
        (ok.replacen("}\n", "", 1), "expected `}`"),
        (
            ok.replace("MOTION", "JOINT X\nMOTION"),
            "after the hierarchy",
        ),
        (chain("", "", ""), "no channels"),
    ];
    for (text, needle) in cases {
        assert_format_err(parse_bvh(&text, p), "bad.bvh", needle);
    }
    // Unknown channel: the message names the file, the line and the joint.
    let e = parse_bvh(&ok.replace("CHANNELS 1 Yrotation", "CHANNELS 1 Xscale"), p).unwrap_err();
    assert_eq!(
        e.to_string(),
        "bad.bvh: line 9: unknown channel `Xscale` on joint `C`"
    );
    // Deep nesting is refused rather than overflowing the stack.
    let mut deep = String::from("HIERARCHY\nROOT J0\n{\nOFFSET 0 0 0\nCHANNELS 1 Xrotation\n");
    for k in 1..2000 {
        deep.push_str(&format!("JOINT J{k}\n{{\nOFFSET 0 0 0\n"));
    }
    deep.push_str("MOTION\nFrames: 0\nFrame Time: 0.01\n");
    assert_format_err(parse_bvh(&deep, p), "bad.bvh", "nested deeper");
    // Every proper prefix of the real excerpt errors cleanly (the last row is > 97 bytes).
    let text = std::fs::read_to_string(data("01_01_head.bvh")).unwrap();
    for cut in (0..text.len()).step_by(97) {
        assert!(parse_bvh(&text[..cut], p).is_err(), "prefix of {cut} bytes");
    }
}

#[test]
fn scaled_scales_lengths_not_angles() {
    let b = parse_bvh(
        &chain("Xposition Zrotation", "Yrotation", "2 30 40"),
        Path::new("s.bvh"),
    )
    .unwrap();
    let s: Bvh = b.scaled(0.5);
    assert_eq!(s.frame(0), [1.0, 30.0, 40.0]);
    assert_eq!(s.joints[1].offset, [0.0, 1.0, 0.0]);
    let (p, q) = (b.joint_positions(0), s.joint_positions(0));
    assert!(dist(q[1], p[1].map(|x| x * 0.5)) < 1e-12);
}

#[test]
fn two_roots_and_reordered_joints_round_trip() {
    let one = chain("Xposition Zrotation", "Yrotation", "1 2 3");
    let two = one.replace(
        "MOTION",
        "ROOT S\n{\n OFFSET 5 5 5\n CHANNELS 1 Zrotation\n}\nMOTION",
    );
    let two = two.replace("\n1 2 3\n", "\n1 2 3 45\n");
    let b = parse_bvh(&two, Path::new("two.bvh")).unwrap();
    assert_eq!(b.joints.len(), 3);
    assert_eq!((b.joints[2].name.as_str(), b.joints[2].parent), ("S", None));
    assert_eq!(b.joint_positions(0)[2], [5.0, 5.0, 5.0]);
    assert_eq!(parse_bvh(&b.to_text(), Path::new("rt.bvh")).unwrap(), b);
    // Joints stored R, S, C (C a child of R; parents still first): the text is written
    // depth-first per root (R, C, S) and the rows follow, so FK is unchanged on reading.
    let mut r = b.clone();
    r.joints = vec![
        b.joints[0].clone(),
        b.joints[2].clone(),
        b.joints[1].clone(),
    ];
    r.joints[2].parent = Some(0);
    r.motion = vec![1.0, 2.0, 45.0, 3.0];
    let back = parse_bvh(&r.to_text(), Path::new("rt.bvh")).unwrap();
    assert_eq!(back.joints[1].name, "C");
    assert_eq!(back.motion, [1.0, 2.0, 3.0, 45.0]);
    let (p, q) = (r.joint_positions(0), back.joint_positions(0));
    for (j, x) in r.joints.iter().zip(&p) {
        assert!(
            dist(*x, q[back.joint_index(&j.name).unwrap()]) < 1e-12,
            "{}",
            j.name
        );
    }
}
