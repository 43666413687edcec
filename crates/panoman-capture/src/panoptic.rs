//! CMU Panoptic Studio calibration (`calibration_<seq>.json`).
//!
//! Layout: `{"calibDataSource": …, "cameras": [{"name": "00_00", "type": "hd", "resolution":
//! [w, h], "K": [[…]×3], "distCoef": [k1, k2, p1, p2, k3], "R": [[…]×3], "t": [[tx], [ty],
//! [tz]]}, …]}`. `R`, `t` are world → camera (OpenCV); `t` is in **centimetres** (Panoptic's
//! world unit) and is converted to metres. Other keys are ignored. Camera types in the
//! dataset: `"vga"`, `"hd"`, `"kinect-color"` (and `"kinect-depth"` in some files).

use crate::camera::Camera;
use crate::check_unique_names;
use crate::error::{CaptureError, Result, read_text};
use serde_json::Value;
use std::path::Path;

/// Reads a Panoptic calibration → cameras in file order; with `only_type` (e.g. `Some("hd")`)
/// only the cameras of that `type`. Names must be distinct over the whole file.
pub fn read_panoptic(path: &Path, only_type: Option<&str>) -> Result<Vec<Camera>> {
    parse_panoptic(&read_text(path)?, path, only_type)
}

/// Parses the text of a Panoptic calibration; `path` names it in errors.
pub fn parse_panoptic(text: &str, path: &Path, only_type: Option<&str>) -> Result<Vec<Camera>> {
    let root: Value = serde_json::from_str(text)
        .map_err(|e| CaptureError::format(path, format!("not valid JSON: {e}")))?;
    let list = root
        .get("cameras")
        .and_then(Value::as_array)
        .ok_or_else(|| CaptureError::format(path, "no \"cameras\" array"))?;
    let mut all = Vec::with_capacity(list.len());
    let mut keep = Vec::with_capacity(list.len());
    for (i, cam) in list.iter().enumerate() {
        let label = match cam.get("name").and_then(Value::as_str) {
            Some(n) => format!("camera {i} ({n:?})"),
            None => format!("camera {i}"),
        };
        let err = |what: String| CaptureError::format(path, format!("{label}: {what}"));
        let get = |k: &str| {
            cam.get(k)
                .ok_or_else(|| err(format!("missing field \"{k}\"")))
        };
        let name = get("name")?
            .as_str()
            .ok_or_else(|| err("\"name\" is not a string".into()))?
            .to_string();
        let kind = get("type")?
            .as_str()
            .ok_or_else(|| err("\"type\" is not a string".into()))?;
        let res =
            matrix(get("resolution")?, 1, 2).map_err(|w| err(format!("\"resolution\": {w}")))?;
        let px = |v: f64, what: &str| {
            if v >= 1.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
                Ok(v as u32)
            } else {
                Err(err(format!(
                    "\"resolution\" {what} {v} is not a positive whole number"
                )))
            }
        };
        let size = [px(res[0], "width")?, px(res[1], "height")?];
        let k = matrix(get("K")?, 3, 3).map_err(|w| err(format!("\"K\": {w}")))?;
        if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(err(format!("\"K\" is not an intrinsic matrix: {k:?}")));
        }
        let d = matrix(get("distCoef")?, 1, 0).map_err(|w| err(format!("\"distCoef\": {w}")))?;
        let dist = match d.len() {
            4 => [d[0], d[1], d[2], d[3], 0.0],
            5 => [d[0], d[1], d[2], d[3], d[4]],
            n => return Err(err(format!("\"distCoef\" has {n} values, want 5 (or 4)"))),
        };
        let r = matrix(get("R")?, 3, 3).map_err(|w| err(format!("\"R\": {w}")))?;
        let t = matrix(get("t")?, 3, 1).map_err(|w| err(format!("\"t\": {w}")))?;
        let camera = Camera::from_intrinsic_matrix(
            name,
            &k,
            dist,
            [[r[0], r[1], r[2]], [r[3], r[4], r[5]], [r[6], r[7], r[8]]],
            [t[0] / 100.0, t[1] / 100.0, t[2] / 100.0],
            Some(size),
        );
        camera.problem().map_err(err)?;
        keep.push(only_type.is_none_or(|want| want == kind));
        all.push(camera);
    }
    check_unique_names(path, &all)?;
    Ok(all
        .into_iter()
        .zip(keep)
        .filter_map(|(c, k)| k.then_some(c))
        .collect())
}

/// A `rows × cols` matrix of finite numbers, row-major. `rows == 1` accepts a flat array
/// (`cols == 0`: any length); `cols == 1` wants an array of one-element arrays.
fn matrix(v: &Value, rows: usize, cols: usize) -> std::result::Result<Vec<f64>, String> {
    let a = v.as_array().ok_or("not an array")?;
    let num = |x: &Value, at: String| -> std::result::Result<f64, String> {
        let f = x.as_f64().ok_or_else(|| format!("{at} is not a number"))?;
        if f.is_finite() {
            Ok(f)
        } else {
            Err(format!("{at} is not finite"))
        }
    };
    if rows == 1 {
        if cols != 0 && a.len() != cols {
            return Err(format!("has {} values, want {cols}", a.len()));
        }
        return a
            .iter()
            .enumerate()
            .map(|(i, x)| num(x, format!("value {i}")))
            .collect();
    }
    if a.len() != rows {
        return Err(format!("has {} rows, want {rows}", a.len()));
    }
    let mut out = Vec::with_capacity(rows * cols);
    for (i, row) in a.iter().enumerate() {
        let r = row
            .as_array()
            .ok_or_else(|| format!("row {i} is not an array"))?;
        if r.len() != cols {
            return Err(format!("row {i} has {} values, want {cols}", r.len()));
        }
        for (j, x) in r.iter().enumerate() {
            out.push(num(x, format!("entry [{i}][{j}]"))?);
        }
    }
    Ok(out)
}
