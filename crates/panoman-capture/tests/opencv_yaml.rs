//! OpenCV / EasyMocap `intri.yml` + `extri.yml`: the rig written by hand in OpenCV's
//! FileStorage style reads back, `D_`/`Rot_` variants, unknown image size, and files that lie.

mod common;

use common::{cloud, max_px_diff, rig};
use panoman_capture::Camera;
use panoman_capture::opencv_yaml::{parse_opencv_yaml, read_opencv_yaml};
use panoman_mesh::rotation::rotation_vector;
use std::path::Path;

/// A number as OpenCV prints it: `1.1000000000000000e+03`, `0.`.
fn cv(x: f64) -> String {
    if x == 0.0 {
        return "0.".into();
    }
    let s = format!("{x:.16e}");
    let (m, e) = s.split_once('e').unwrap();
    let e: i32 = e.parse().unwrap();
    format!("{m}e{}{:02}", if e < 0 { '-' } else { '+' }, e.abs())
}

fn mat(key: &str, rows: usize, cols: usize, data: &[f64]) -> String {
    let vals: Vec<String> = data.iter().map(|&v| cv(v)).collect();
    // OpenCV wraps long data lines; do the same after four values.
    let mut body = String::new();
    for (i, v) in vals.iter().enumerate() {
        if i > 0 {
            body += if i % 4 == 0 { ",\n       " } else { ", " };
        }
        body += v;
    }
    format!(
        "{key}: !!opencv-matrix\n   rows: {rows}\n   cols: {cols}\n   dt: d\n   data: [ {body} ]\n"
    )
}

fn intri(cams: &[Camera], dist_key: &str) -> String {
    let mut s = String::from("%YAML:1.0\n---\nnames:\n");
    for c in cams {
        s += &format!("   - \"{}\"\n", c.name);
    }
    for c in cams {
        let k = [c.fx, c.skew, c.cx, 0.0, c.fy, c.cy, 0.0, 0.0, 1.0];
        s += &mat(&format!("K_{}", c.name), 3, 3, &k);
        s += &mat(&format!("{dist_key}_{}", c.name), 1, 5, &c.dist);
    }
    s
}

fn extri(cams: &[Camera], with_rot: bool, with_rvec: bool) -> String {
    let mut s = String::from("%YAML:1.0\n---\nnames:\n");
    for c in cams {
        s += &format!("   - \"{}\"\n", c.name);
    }
    for c in cams {
        if with_rvec {
            s += &mat(&format!("R_{}", c.name), 3, 1, &rotation_vector(&c.r));
        }
        if with_rot {
            let r: Vec<f64> = c.r.iter().flatten().copied().collect();
            s += &mat(&format!("Rot_{}", c.name), 3, 3, &r);
        }
        s += &mat(&format!("T_{}", c.name), 3, 1, &c.t);
    }
    s
}

const IP: &str = "/em/intri.yml";
const EP: &str = "/em/extri.yml";

fn parse(i: &str, e: &str, size: Option<[u32; 2]>) -> panoman_capture::Result<Vec<Camera>> {
    parse_opencv_yaml(i, Path::new(IP), e, Path::new(EP), size)
}

#[test]
fn rig_written_in_opencv_yaml_reads_back_to_1e6_px() {
    let cams = rig();
    let dir = common::temp_dir("yaml");
    let (ip, ep) = (dir.join("intri.yml"), dir.join("extri.yml"));
    std::fs::write(&ip, intri(&cams, "dist")).unwrap();
    std::fs::write(&ep, extri(&cams, true, true)).unwrap();
    let back = read_opencv_yaml(&ip, &ep, Some([1920, 1080])).unwrap();
    let names: Vec<&str> = back.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["cam01", "cam02", "cam03", "cam04"]);
    assert!(back.iter().all(|c| c.image_size == Some([1920, 1080])));
    let d = max_px_diff(&cams, &back, &cloud());
    assert!(d <= 1e-6, "{d} px");
    std::fs::remove_dir_all(dir).ok();

    // `D_` instead of `dist_`, Rot only, Rodrigues only; unknown size stays unknown and valid.
    for (i, e) in [
        (intri(&cams, "D"), extri(&cams, true, false)),
        (intri(&cams, "dist"), extri(&cams, false, true)),
    ] {
        let back = parse(&i, &e, None).unwrap();
        assert!(
            back.iter()
                .all(|c| c.image_size.is_none() && c.validate().is_ok())
        );
        assert!(max_px_diff(&cams, &back, &cloud()) <= 1e-6);
    }
}

#[test]
fn files_that_lie_give_one_error_naming_the_file_and_camera() {
    let cams = rig();
    let (i, e) = (intri(&cams, "dist"), extri(&cams, true, true));
    // Rot_cam03 rotated by ~1e-4 rad about z relative to R_cam03.
    let mut tilted = cams.clone();
    let (c, s) = (1e-4f64.cos(), 1e-4f64.sin());
    let r = tilted[2].r;
    tilted[2].r = [
        [
            c * r[0][0] - s * r[1][0],
            c * r[0][1] - s * r[1][1],
            c * r[0][2] - s * r[1][2],
        ],
        [
            s * r[0][0] + c * r[1][0],
            s * r[0][1] + c * r[1][1],
            s * r[0][2] + c * r[1][2],
        ],
        r[2],
    ];
    let rot_only = |cs: &[Camera]| extri(cs, true, false);
    let disagree = {
        // R_ from the true rig, Rot_ from the tilted one.
        let a = extri(&cams, false, true);
        let b = rot_only(&tilted);
        let rot3 = b
            .split("Rot_cam03")
            .nth(1)
            .unwrap()
            .split("T_cam03")
            .next()
            .unwrap();
        a.replacen("T_cam03", &format!("Rot_cam03{rot3}T_cam03"), 1)
    };
    let mut not_rot = cams.clone();
    not_rot[1].r[0][0] = 0.9;
    let cases: Vec<(String, String, &str, &str)> = vec![
        (
            i[..i.len() / 2].to_string(),
            e.clone(),
            IP,
            "not valid YAML",
        ),
        (
            i[..i.find("K_cam03").unwrap()].to_string(),
            e.clone(),
            IP,
            "camera \"cam03\": missing `K_cam03`",
        ),
        (
            i.clone(),
            e[..e.len() / 2].to_string(),
            EP,
            "not valid YAML",
        ),
        (
            i.replacen("cols: 3", "cols: 4", 1),
            e.clone(),
            IP,
            "camera \"cam01\": `K_cam01` is 3×4, want 3×3",
        ),
        (
            i.clone(),
            e.replacen("T_cam02", "X_cam02", 1),
            EP,
            "camera \"cam02\": missing `T_cam02`",
        ),
        (
            i.replacen("data: [ ", "data: [ .nan, ", 1),
            e.clone(),
            IP,
            "`K_cam01`",
        ),
        (
            i.clone(),
            e.replacen(
                "rows: 3\n   cols: 1\n   dt: d\n   data: [ ",
                "rows: 3\n   cols: 1\n   dt: d\n   data: [ .nan, ",
                1,
            ),
            EP,
            "has 4 values",
        ),
        (
            i.clone(),
            disagree,
            EP,
            "R_cam03 (Rodrigues) and Rot_cam03 disagree",
        ),
        (
            i.clone(),
            rot_only(&not_rot),
            EP,
            "camera \"cam02\": rotation is not orthonormal",
        ),
        (
            i.replacen("   - \"cam02\"", "   - \"cam01\"", 1),
            e.clone(),
            IP,
            "\"cam01\" appears twice",
        ),
        (
            i.clone(),
            e.replacen("   - \"cam04\"\n", "", 1),
            EP,
            "differ",
        ),
        (i.replacen("dt: d", "dt: u", 1), e.clone(), IP, "dt"),
        (
            i.replacen("data: [ 1.1", "data: [ x1.1", 1),
            e.clone(),
            IP,
            "not a number",
        ),
    ];
    for (k, (it, et, file, what)) in cases.into_iter().enumerate() {
        let err = parse(&it, &et, None).unwrap_err().to_string();
        assert!(err.starts_with(&format!("{file}: ")), "case {k}: {err}");
        assert!(err.contains(what), "case {k}: want {what:?} in: {err}");
    }
    // A non-finite value of the right count.
    let nan = i.replacen(&cv(cams[0].fx), ".nan", 1);
    let err = parse(&nan, &e, None).unwrap_err().to_string();
    assert!(err.contains("not finite") && err.starts_with(IP), "{err}");
    assert!(parse(&i, &e, Some([0, 10])).is_err());
}
