//! Pose2Sim / anipose TOML: write → read round trip, a hand-written file, units, and files
//! that lie.

mod common;

use common::{cloud, max_px_diff, rig, temp_dir};
use panoman_capture::toml_calib::{TomlOptions, parse_toml, read_toml, to_toml_string, write_toml};
use panoman_mesh::rotation::rotation_vector;
use std::path::Path;

#[test]
fn write_then_read_round_trips_to_1e9_px() {
    let mut cams = rig();
    cams[2].skew = 0.7;
    cams[3].name = "cam with \"quotes\" and spaces".into();
    let dir = temp_dir("toml-rt");
    let path = dir.join("Calib.toml");
    write_toml(&path, &cams).unwrap();
    let back = read_toml(&path, &TomlOptions::default()).unwrap();
    assert_eq!(back.len(), 4);
    for (a, b) in cams.iter().zip(&back) {
        assert_eq!(a.name, b.name);
        assert_eq!(a.image_size, b.image_size);
        assert_eq!(a.dist, b.dist);
    }
    let d = max_px_diff(&cams, &back, &cloud());
    assert!(d <= 1e-9, "round trip moved projections by {d} px");
    std::fs::remove_dir_all(dir).ok();
}

/// The text Pose2Sim writes, composed here by hand from the rig's parameters (metres), and
/// the same with translations in millimetres read with the anipose unit option.
fn pose2sim_text(unit_per_m: f64) -> String {
    let mut s = String::new();
    for (i, c) in rig().iter().enumerate() {
        let rv = rotation_vector(&c.r);
        let [w, h] = c.image_size.unwrap();
        s += &format!(
            "[cam_{i}]\nname = \"{}\"\nsize = [ {w}.0, {h}.0]\nmatrix = [ [ {:?}, 0.0, {:?}], [ 0.0, {:?}, {:?}], [ 0.0, 0.0, 1.0]]\n\
             distortions = [ {:?}, {:?}, {:?}, {:?}, {:?}]\nrotation = [ {:?}, {:?}, {:?}]\n\
             translation = [ {:?}, {:?}, {:?}]\nfisheye = false\n\n",
            c.name,
            c.fx,
            c.cx,
            c.fy,
            c.cy,
            c.dist[0],
            c.dist[1],
            c.dist[2],
            c.dist[3],
            c.dist[4],
            rv[0],
            rv[1],
            rv[2],
            c.t[0] * unit_per_m,
            c.t[1] * unit_per_m,
            c.t[2] * unit_per_m
        );
    }
    s + "[metadata]\nadjusted = false\nerror = 0.0\n"
}

#[test]
fn hand_written_pose2sim_and_anipose_files_read_back() {
    let p = Path::new("Calib_scene.toml");
    let m = parse_toml(&pose2sim_text(1.0), p, &TomlOptions::default()).unwrap();
    assert!(max_px_diff(&rig(), &m, &cloud()) <= 1e-6);
    let mm = parse_toml(
        &pose2sim_text(1000.0),
        p,
        &TomlOptions {
            translation_unit_m: 0.001,
        },
    )
    .unwrap();
    assert!(max_px_diff(&rig(), &mm, &cloud()) <= 1e-6);
    // Four distortion values mean k3 = 0.
    let four = pose2sim_text(1.0).replace(", 0.01]\nrotation", "]\nrotation");
    let c = parse_toml(&four, p, &TomlOptions::default()).unwrap();
    assert_eq!(c[1].dist[4], 0.0);
}

#[test]
fn files_that_lie_give_one_error_naming_the_file() {
    let good = pose2sim_text(1.0);
    let p = Path::new("/data/Calib_lie.toml");
    let cases: Vec<(String, &str)> = vec![
        (good[..good.len() / 2].to_string(), "Calib_lie.toml"),
        (
            good.replacen("translation = ", "translatio = ", 1),
            "`translation`",
        ),
        (
            good.replacen("fisheye = false", "fisheye = true", 1),
            "fisheye",
        ),
        (
            good.replacen("size = [ 1920.0", "size = [ nan", 1),
            "not finite",
        ),
        (
            good.replacen("size = [ 1920.0, 1080.0]", "size = [ 1920.0]", 1),
            "`size`",
        ),
        (good.replacen("[ 0.0, 0.0, 1.0]]", "]", 1), "`matrix`"),
        (
            good.replacen("rotation = [", "rotation = [ \"x\",", 1),
            "`rotation`",
        ),
        (
            good.replacen("name = \"cam02\"", "name = \"cam01\"", 1),
            "appears twice",
        ),
        (
            good.replacen("size = [ 1920.0", "size = [ 0.0", 1),
            "`size`",
        ),
    ];
    for (text, what) in cases {
        let e = parse_toml(&text, p, &TomlOptions::default())
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("/data/Calib_lie.toml: "), "{e}");
        assert!(e.contains(what), "want {what:?} in: {e}");
    }
    // The camera is named for field errors.
    let e = parse_toml(
        &good.replacen("translation = ", "translatio = ", 1),
        p,
        &TomlOptions::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("[cam_0]"), "{e}");
}

#[test]
fn writer_refuses_unknown_size_duplicates_and_invalid_cameras() {
    let mut cams = rig();
    cams[0].image_size = None;
    assert!(
        to_toml_string(&cams)
            .unwrap_err()
            .to_string()
            .contains("image size")
    );
    let mut cams = rig();
    cams[1].name = "cam01".into();
    assert!(
        to_toml_string(&cams)
            .unwrap_err()
            .to_string()
            .contains("twice")
    );
    let mut cams = rig();
    cams[2].r[0][0] = 3.0;
    assert!(to_toml_string(&cams).is_err());
}
