//! Qualisys `.qca.txt`: a hand-made two-camera file whose pixels are derived by hand, the rig
//! written as a QCA file, and files that lie.

mod common;

use common::{cloud, max_px_diff, rig};
use panoman_capture::Camera;
use panoman_capture::qualisys::{QcaOptions, parse_qca, read_qca};
use std::path::Path;

/// Camera A ("A1"): at (0, −3, 1) m looking along +Y (world Z up); R_qca row by row
/// [[1,0,0],[0,0,1],[0,−1,0]] ⇒ OpenCV R = diag(1,−1,−1)·R_qca = [[1,0,0],[0,0,−1],[0,1,0]]
/// (x right = +X, y down = −Z, z forward = +Y). fx = fy = 64000/64 = 1000, principal point
/// (61440/64, 34560/64) = (960, 540), no distortion, 1920×1080.
///
/// Camera B ("B2", inactive): at (3, 0, 1) m looking along −X; R_qca [[0,1,0],[0,0,1],[1,0,0]]
/// ⇒ R = [[0,1,0],[0,0,−1],[−1,0,0]] (x right = +Y, y down = −Z, z forward = −X).
/// fov_video left 100, top 50, right 1379, bottom 1073 ⇒ 1280×1024; fx = 76800/64 = 1200,
/// fy = 77440/64 = 1210, cx = 47360/64 − 100 = 640, cy = 35968/64 − 50 = 512;
/// k1 = −6.4/64 = −0.1.
const HAND_MADE: &str = r#"<?xml version="1.0" encoding="UTF-8"?>
<calibration source="hand made" type="regular" wandLength="601.0">
  <results std-dev="0.1" min-max-diff="0.2"/>
  <cameras>
    <camera active="1" avg-residual="0.2" serial="A1" model="Miqus Video" viewrotation="0">
      <fov_marker left="0" top="0" right="1919" bottom="1079"/>
      <fov_marker_max left="0" top="0" right="1919" bottom="1079"/>
      <fov_video left="0" top="0" right="1919" bottom="1079"/>
      <fov_video_max left="0" top="0" right="1919" bottom="1079"/>
      <transform x="0.0" y="-3000.0" z="1000.0" r11="1" r12="0" r13="0" r21="0" r22="0" r23="1" r31="0" r32="-1" r33="0"/>
      <intrinsic focallength="8.0" sensorMinU="0" sensorMaxU="122816" sensorMinV="0" sensorMaxV="69056" focalLengthU="64000" focalLengthV="64000" centerPointU="61440" centerPointV="34560" skew="0" radialDistortion1="0" radialDistortion2="0" radialDistortion3="0" tangentalDistortion1="0" tangentalDistortion2="0"/>
    </camera>
    <camera active="0" avg-residual="0.3" serial="B2" model="Miqus Video" viewrotation="0">
      <fov_marker left="100" top="50" right="1379" bottom="1073"/>
      <fov_marker_max left="0" top="0" right="1919" bottom="1079"/>
      <fov_video left="100" top="50" right="1379" bottom="1073"/>
      <fov_video_max left="0" top="0" right="1919" bottom="1079"/>
      <transform x="3000" y="0" z="1000" r11="0" r12="1" r13="0" r21="0" r22="0" r23="1" r31="1" r32="0" r33="0"/>
      <intrinsic focallength="9.0" sensorMinU="0" sensorMaxU="122816" sensorMinV="0" sensorMaxV="69056" focalLengthU="76800" focalLengthV="77440" centerPointU="47360" centerPointV="35968" skew="0" radialDistortion1="-6.4" radialDistortion2="0" radialDistortion3="0" tangentalDistortion1="0" tangentalDistortion2="0"/>
    </camera>
  </cameras>
</calibration>
"#;

fn close(a: [f64; 2], b: [f64; 2]) -> bool {
    (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9
}

#[test]
fn hand_made_two_camera_file_projects_as_derived_by_hand() {
    let cams = parse_qca(HAND_MADE, Path::new("hand.qca.txt"), &QcaOptions::default()).unwrap();
    assert_eq!(cams.len(), 2);
    let (a, b) = (&cams[0], &cams[1]);
    assert_eq!((a.name.as_str(), a.active), ("A1", true));
    assert_eq!((b.name.as_str(), b.active), ("B2", false));
    assert_eq!(a.image_size, Some([1920, 1080]));
    assert_eq!(b.image_size, Some([1280, 1024]));
    assert_eq!((b.fx, b.fy, b.cx, b.cy), (1200.0, 1210.0, 640.0, 512.0));
    assert_eq!(b.dist, [-0.1, 0.0, 0.0, 0.0, 0.0]);
    // Centres are the file's positions, and the optical axes point into the volume.
    assert_eq!(a.centre(), [0.0, -3.0, 1.0]);
    assert_eq!(b.centre(), [3.0, 0.0, 1.0]);
    assert_eq!(a.r[2], [0.0, 1.0, 0.0]);
    assert_eq!(b.r[2], [-1.0, 0.0, 0.0]);

    // A: (0,0,1) is straight ahead 3 m → principal point.
    assert!(close(a.project([0.0, 0.0, 1.0]).unwrap(), [960.0, 540.0]));
    // A: (0.3, 0, 1.2) → camera (0.3, −0.2, 3) → (960 + 1000·0.1, 540 − 1000·0.2/3).
    let want = [1060.0, 540.0 - 200.0 / 3.0];
    assert!(close(a.project([0.3, 0.0, 1.2]).unwrap(), want));
    // B: (0.3, 0, 1.2) → camera (0, −0.2, 2.7); y' = −0.2/2.7, r² = y'², radial 1 − 0.1 r².
    let y = -0.2 / 2.7;
    let want = [640.0, 512.0 + 1210.0 * y * (1.0 - 0.1 * y * y)];
    assert!(close(b.project([0.3, 0.0, 1.2]).unwrap(), want));
    // B: (0, 0.5, 1) → camera (0.5, 0, 3); x' = 1/6.
    let x = 1.0 / 6.0;
    let want = [640.0 + 1200.0 * x * (1.0 - 0.1 * x * x), 512.0];
    assert!(close(b.project([0.0, 0.5, 1.0]).unwrap(), want));
    // B does not see A's side of the world behind it.
    assert!(b.project([4.0, 0.0, 1.0]).is_none());

    // Undivided distortion on request.
    let raw = parse_qca(
        HAND_MADE,
        Path::new("hand.qca.txt"),
        &QcaOptions {
            distortion_divisor: 1.0,
        },
    )
    .unwrap();
    assert_eq!(raw[1].dist[0], -6.4);
}

/// The QCA text of cameras (inverse of the documented conversion), with a video window
/// offset so that the principal-point shift is exercised.
fn qca_text(cams: &[Camera]) -> String {
    let mut s = String::from("<?xml version=\"1.0\"?>\n<calibration>\n<cameras>\n");
    for c in cams {
        let [w, h] = c.image_size.unwrap();
        let (left, top) = (16.0, 8.0);
        let p = c.centre();
        let r = c.r;
        // R_qca = diag(1, −1, −1)·R
        let q = [r[0], r[1].map(|v| -v), r[2].map(|v| -v)];
        let d = c.dist;
        s += &format!(
            "<camera active=\"1\" serial=\"{}\" model=\"Miqus Video\" viewrotation=\"0\">\n\
             <fov_video left=\"{left}\" top=\"{top}\" right=\"{}\" bottom=\"{}\"/>\n\
             <transform x=\"{:?}\" y=\"{:?}\" z=\"{:?}\" r11=\"{:?}\" r12=\"{:?}\" r13=\"{:?}\" r21=\"{:?}\" r22=\"{:?}\" r23=\"{:?}\" r31=\"{:?}\" r32=\"{:?}\" r33=\"{:?}\"/>\n\
             <intrinsic focalLengthU=\"{:?}\" focalLengthV=\"{:?}\" centerPointU=\"{:?}\" centerPointV=\"{:?}\" skew=\"{:?}\" \
             radialDistortion1=\"{:?}\" radialDistortion2=\"{:?}\" radialDistortion3=\"{:?}\" tangentalDistortion1=\"{:?}\" tangentalDistortion2=\"{:?}\"/>\n\
             </camera>\n",
            c.name,
            left + w as f64 - 1.0,
            top + h as f64 - 1.0,
            p[0] * 1000.0,
            p[1] * 1000.0,
            p[2] * 1000.0,
            q[0][0],
            q[0][1],
            q[0][2],
            q[1][0],
            q[1][1],
            q[1][2],
            q[2][0],
            q[2][1],
            q[2][2],
            c.fx * 64.0,
            c.fy * 64.0,
            (c.cx + left) * 64.0,
            (c.cy + top) * 64.0,
            c.skew * 64.0,
            d[0] * 64.0,
            d[1] * 64.0,
            d[4] * 64.0,
            d[2] * 64.0,
            d[3] * 64.0,
        );
    }
    s + "</cameras>\n</calibration>\n"
}

#[test]
fn rig_written_as_qca_reads_back_to_1e6_px() {
    let cams = rig();
    let dir = common::temp_dir("qca");
    let path = dir.join("rig.qca.txt");
    std::fs::write(&path, qca_text(&cams)).unwrap();
    let back = read_qca(&path, &QcaOptions::default()).unwrap();
    let names: Vec<&str> = back.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam01", "cam02", "cam03", "cam04"]);
    assert!(back.iter().all(|c| c.image_size == Some([1920, 1080])));
    let d = max_px_diff(&cams, &back, &cloud());
    assert!(d <= 1e-6, "{d} px");
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn files_that_lie_give_one_error_naming_the_file_and_camera() {
    let p = Path::new("/cal/lie.qca.txt");
    let cases: Vec<(String, &str)> = vec![
        (
            HAND_MADE[..HAND_MADE.len() / 2].to_string(),
            "not valid XML",
        ),
        (
            HAND_MADE.replacen(" r23=\"1\"", "", 1),
            "camera 1 (serial \"A1\"): <transform> has no attribute r23",
        ),
        (
            HAND_MADE.replacen("focalLengthU=\"76800\"", "focalLengthU=\"NaN\"", 1),
            "B2\"): <intrinsic> focalLengthU=NaN is not finite",
        ),
        (
            HAND_MADE.replacen("focalLengthU=\"76800\"", "focalLengthU=\"7x\"", 1),
            "not a number",
        ),
        (
            HAND_MADE.replacen("r11=\"1\"", "r11=\"2\"", 1),
            "not orthonormal",
        ),
        (
            HAND_MADE.replacen("serial=\"B2\"", "serial=\"A1\"", 1),
            "\"A1\" appears twice",
        ),
        (
            HAND_MADE.replacen(
                "<fov_video left=\"100\" top=\"50\" right=\"1379\" bottom=\"1073\"/>",
                "",
                1,
            ),
            "no <fov_video>",
        ),
        (
            HAND_MADE.replacen("active=\"0\"", "active=\"yes\"", 1),
            "active",
        ),
        (
            HAND_MADE
                .replace("<camera ", "<kamera ")
                .replace("</camera>", "</kamera>"),
            "no <camera>",
        ),
    ];
    for (text, what) in cases {
        let e = parse_qca(&text, p, &QcaOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/cal/lie.qca.txt: "), "{e}");
        assert!(e.contains(what), "want {what:?} in: {e}");
    }
    let e = read_qca(Path::new("/nonexistent/x.qca.txt"), &QcaOptions::default()).unwrap_err();
    assert!(e.to_string().contains("/nonexistent/x.qca.txt"));
}
