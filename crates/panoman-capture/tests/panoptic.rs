//! CMU Panoptic calibration JSON: the rig written with `t` in centimetres reads back, type
//! filtering, and files that lie.

mod common;

use common::{cloud, max_px_diff, rig};
use panoman_capture::panoptic::{parse_panoptic, read_panoptic};
use serde_json::{Value, json};
use std::path::Path;

fn panoptic_json() -> Value {
    let cams: Vec<Value> = rig()
        .iter()
        .enumerate()
        .map(|(i, c)| {
            let [w, h] = c.image_size.unwrap();
            json!({
                "name": format!("00_{i:02}"),
                "type": if i % 2 == 0 { "hd" } else { "vga" },
                "resolution": [w, h],
                "panel": 0, "node": i,
                "K": [[c.fx, c.skew, c.cx], [0.0, c.fy, c.cy], [0.0, 0.0, 1.0]],
                "distCoef": c.dist,
                "R": c.r,
                "t": [[c.t[0] * 100.0], [c.t[1] * 100.0], [c.t[2] * 100.0]],
            })
        })
        .collect();
    json!({"calibDataSource": "160906_calib_norm", "cameras": cams})
}

#[test]
fn rig_written_in_centimetres_reads_back_to_1e6_px_and_filters_by_type() {
    let dir = common::temp_dir("panoptic");
    let path = dir.join("calibration_160906_pizza1.json");
    std::fs::write(
        &path,
        serde_json::to_string_pretty(&panoptic_json()).unwrap(),
    )
    .unwrap();
    let all = read_panoptic(&path, None).unwrap();
    assert_eq!(all.len(), 4);
    assert_eq!(all[3].name, "00_03");
    let d = max_px_diff(&rig(), &all, &cloud());
    assert!(d <= 1e-6, "{d} px");
    let hd = read_panoptic(&path, Some("hd")).unwrap();
    let names: Vec<&str> = hd.iter().map(|c| c.name.as_str()).collect();
    assert_eq!(names, ["00_00", "00_02"]);
    let r = rig();
    assert!(max_px_diff(&[r[0].clone(), r[2].clone()], &hd, &cloud()) <= 1e-6);
    assert!(
        read_panoptic(&path, Some("kinect-color"))
            .unwrap()
            .is_empty()
    );
    std::fs::remove_dir_all(dir).ok();
}

#[test]
fn files_that_lie_give_one_error_naming_the_file_and_camera() {
    let good = serde_json::to_string(&panoptic_json()).unwrap();
    let p = Path::new("/pan/calibration_x.json");
    let edit = |f: &dyn Fn(&mut Value)| {
        let mut v = panoptic_json();
        f(&mut v);
        serde_json::to_string(&v).unwrap()
    };
    let cases: Vec<(String, &str)> = vec![
        (good[..good.len() / 2].to_string(), "not valid JSON"),
        (
            edit(&|v| {
                v["cameras"][1].as_object_mut().unwrap().remove("K");
            }),
            "camera 1 (\"00_01\"): missing field \"K\"",
        ),
        (
            edit(&|v| v["cameras"][2]["R"][0][0] = json!(0.5)),
            "camera 2 (\"00_02\"): rotation is not orthonormal",
        ),
        (
            edit(&|v| v["cameras"][0]["t"] = json!([1.0, 2.0, 3.0])),
            "\"t\": row 0 is not an array",
        ),
        (
            edit(&|v| v["cameras"][0]["K"][0][0] = json!("abc")),
            "\"K\": entry [0][0] is not a number",
        ),
        (
            edit(&|v| v["cameras"][3]["name"] = json!("00_00")),
            "\"00_00\" appears twice",
        ),
        (
            edit(&|v| v["cameras"][0]["distCoef"] = json!([0.1, 0.2])),
            "\"distCoef\" has 2 values",
        ),
        (
            edit(&|v| v["cameras"][0]["resolution"] = json!([1920.5, 1080])),
            "\"resolution\"",
        ),
        (r#"{"cameras": 3}"#.to_string(), "no \"cameras\" array"),
        (good.replacen("1100.0", "NaN", 1), "not valid JSON"),
    ];
    for (text, what) in cases {
        let e = parse_panoptic(&text, p, None).unwrap_err().to_string();
        assert!(e.starts_with("/pan/calibration_x.json: "), "{e}");
        assert!(e.contains(what), "want {what:?} in: {e}");
    }
}
