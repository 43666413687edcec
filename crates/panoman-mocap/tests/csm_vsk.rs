//! Vicon CSM and VSK readers on the committed real files and on malformed input.

use std::path::{Path, PathBuf};

use panoman_mocap::MocapError;
use panoman_mocap::csm::{parse_csm, read_csm};
use panoman_mocap::markers::{UpAxis, UpSource};
use panoman_mocap::vsk::{parse_vsk, read_vsk};

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

#[test]
fn csm_excerpt_facts() {
    let (m, info) = read_csm(&data("ThomasFechten_head.csm")).unwrap();
    assert_eq!(
        (m.n_markers(), m.n_frames(), m.rate_hz, m.first_frame),
        (43, 40, 120.0, 1)
    );
    assert_eq!(
        (m.up_axis, m.up_source),
        (Some(UpAxis::Z), UpSource::Convention)
    );
    assert_eq!(m.names[0], "LFHD");
    assert_eq!(m.names[42], "RMT5");
    assert_eq!(m.n_missing(), 0);
    // Row "1  26.327553 157.341293 1656.915527 …" (mm).
    let p = m.get(0, 0).unwrap();
    assert!((p[0] - 0.026327553).abs() < 1e-15 && (p[2] - 1.656915527).abs() < 1e-15);
    // Last row "40 75.224754 … -403.406067 309.430206 57.793896".
    let q = m.get(39, 42).unwrap();
    assert!((q[0] + 0.403406067).abs() < 1e-15 && (q[2] - 0.057793896).abs() < 1e-15);
    assert!(info.header.contains(&("Actor".into(), "Thomas_Neu".into())));
}

const SMALL: &str = "$FirstFrame 10\n$LastFrame 12\n$Rate 60\n\n$Order\nA B\n\n$Points\n\
10 1 2 3 4 5 6\n11 DROPOUT 7 8 9\n12 1 1 1 DROPOUT\n";

#[test]
fn csm_dropouts_are_missing() {
    let (m, _) = parse_csm(SMALL, Path::new("s.csm")).unwrap();
    assert_eq!((m.n_frames(), m.first_frame, m.rate_hz), (3, 10, 60.0));
    assert!(m.get(1, 0).is_none() && m.get(2, 1).is_none());
    assert_eq!(m.get(1, 1), Some([0.007, 0.008, 0.009]));
    assert_eq!(m.n_missing(), 2);
}

#[test]
fn csm_bad_input() {
    let p = Path::new("bad.csm");
    let cases = [
        (
            SMALL.replace("12 1 1 1 DROPOUT", "12 1 1 1"),
            "line 11",
            "1 markers' values, expected 2",
        ),
        (
            SMALL.replace("12 1 1 1 DROPOUT", "12 1 1 1 2 2"),
            "line 11",
            "2 of 3 coordinates",
        ),
        (
            SMALL.replace("11 DROPOUT", "11 DROPOUT 1 2 3 DROPOUT"),
            "line 10",
            "more values",
        ),
        (
            SMALL.replace("4 5 6", "4 NaN 6"),
            "line 9",
            "not a finite number",
        ),
        (
            SMALL.replace("11 DROPOUT", "13 DROPOUT"),
            "line 10",
            "out of sequence",
        ),
        (
            SMALL.replace("$LastFrame 12", "$LastFrame 20"),
            "",
            "file has 3",
        ),
        (SMALL.replace("A B", ""), "", "no marker names"),
        (SMALL.replace("$Rate 60", "$Rate 0"), "", "not positive"),
        (SMALL.replace("$Rate 60", ""), "", "no `$Rate`"),
        (
            SMALL.split("10 1 2").next().unwrap().to_string(),
            "",
            "zero frames",
        ),
        (
            SMALL.replace("$Points", "$Pts"),
            "line 9",
            "expected a `$Key` line",
        ),
        (
            SMALL.split("$Points").next().unwrap().to_string(),
            "",
            "no `$Points`",
        ),
        ("garbage\n".to_string(), "line 1", "expected a `$Key` line"),
    ];
    for (text, line, needle) in cases {
        let r = parse_csm(&text, p);
        assert_format_err(r, "bad.csm", needle);
        if !line.is_empty() {
            assert_format_err(parse_csm(&text, p), "bad.csm", line);
        }
    }
    // Every prefix of the real excerpt errors or parses, never panics.
    let text = std::fs::read_to_string(data("ThomasFechten_head.csm")).unwrap();
    for cut in (0..text.len()).step_by(301) {
        let _ = parse_csm(&text[..cut], p);
    }
}

#[test]
fn vsk_facts() {
    let v = read_vsk(&data("Nick01.vsk")).unwrap();
    assert_eq!(
        (v.parameters.len(), v.segments.len(), v.markers.len()),
        (169, 30, 53)
    );
    assert_eq!(v.sticks.len(), 73);
    assert_eq!(v.parameter("HipWidth"), Some(116.705));
    let hips = &v.segments[0];
    assert_eq!(
        (hips.name.as_str(), hips.parent, hips.joint.as_str()),
        ("Hips", None, "JointFree")
    );
    let i = v.segments.iter().position(|s| s.name == "LeftLeg").unwrap();
    let s = &v.segments[i];
    assert_eq!(v.segments[s.parent.unwrap()].name, "LeftUpLeg");
    assert_eq!(s.joint, "JointHinge");
    // POSITION "0 -UpperLegLength 0", UpperLegLength = 429.072 mm.
    assert_eq!(s.position, [0.0, -0.429072, 0.0]);
    let foot = v.segments.iter().find(|s| s.name == "LeftFoot").unwrap();
    assert_eq!(foot.orientation, [0.261799, 0.0, 0.0]);
    // <Marker NAME="LKNE" SEGMENT=… POSITION="LKNE_L_Femur_X …">: 58.0227 −420.533 41.5222 mm.
    let m = v.markers.iter().find(|m| m.name == "LKNE").unwrap();
    assert!((m.position[0] - 0.0580227).abs() < 1e-15 && (m.position[1] + 0.420533).abs() < 1e-15);
    let rtoe = v.markers.iter().find(|m| m.name == "RTOE").unwrap();
    assert_eq!(rtoe.segment, "RightToe");
    assert_eq!(v.segments[rtoe.segment_index.unwrap()].name, "RightToe");
    assert!((rtoe.radius - 0.0071).abs() < 1e-15);
}

#[test]
fn vsk_bad_input() {
    let text = std::fs::read_to_string(data("Nick01.vsk")).unwrap();
    let p = Path::new("bad.vsk");
    assert_format_err(
        parse_vsk(&text.replace("0 -UpperLegLength 0", "0 -UpperLegLen 0"), p),
        "bad.vsk",
        "unknown parameter `UpperLegLen`",
    );
    assert_format_err(
        parse_vsk(&text.replace("HipWidth 0 0\"", "HipWidth 0\""), p),
        "bad.vsk",
        "three values",
    );
    assert_format_err(
        parse_vsk(&text[..text.len() / 2], p),
        "bad.vsk",
        "invalid XML",
    );
    assert_format_err(
        parse_vsk("<Other/>", p),
        "bad.vsk",
        "expected <KinematicModel>",
    );
    assert_format_err(parse_vsk("<KinematicModel/>", p), "bad.vsk", "no <Segment>");
    assert_format_err(
        parse_vsk(&text.replace("VALUE=\"116.705\"", "VALUE=\"wide\""), p),
        "bad.vsk",
        "no numeric VALUE",
    );
}
