//! Pose2Sim / anipose calibration TOML, read and write.
//!
//! Layout: one table per camera (any table name), in file order, plus an optional `[metadata]`
//! table that is ignored:
//!
//! ```toml
//! [cam_1]
//! name = "cam01"
//! size = [ 1920.0, 1080.0 ]                      # width, height (pixels)
//! matrix = [ [ fx, 0.0, cx ], [ 0.0, fy, cy ], [ 0.0, 0.0, 1.0 ] ]
//! distortions = [ k1, k2, p1, p2 ]               # OpenCV order; k3 = 0 (a 5th value is read as k3)
//! rotation = [ rx, ry, rz ]                      # Rodrigues vector, world → camera (radians)
//! translation = [ tx, ty, tz ]                   # world → camera, metres in Pose2Sim
//! fisheye = false
//! ```
//!
//! The rotation and translation follow OpenCV: `x_cam = R(rotation)·X + translation`. Pose2Sim
//! writes translations in metres; anipose in the unit of its calibration board (often
//! millimetres), hence [`TomlOptions::translation_unit_m`]. Fisheye cameras are rejected.
//! `matrix[0][1]` is read as the skew.

use crate::camera::Camera;
use crate::check_unique_names;
use crate::error::{CaptureError, Result, read_text};
use panoman_mesh::rotation::{from_rotation_vector, rotation_vector};
use std::fmt::Write as _;
use std::path::Path;
use toml::Value;

/// Options of [`read_toml`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TomlOptions {
    /// Metres per unit of `translation` in the file: 1 for Pose2Sim (the default), 0.001 for
    /// an anipose calibration made with a board measured in millimetres.
    pub translation_unit_m: f64,
}

impl Default for TomlOptions {
    fn default() -> Self {
        TomlOptions {
            translation_unit_m: 1.0,
        }
    }
}

/// Reads a Pose2Sim / anipose calibration TOML (see the module doc) → cameras in file order.
pub fn read_toml(path: &Path, options: &TomlOptions) -> Result<Vec<Camera>> {
    parse_toml(&read_text(path)?, path, options)
}

/// Parses the text of a calibration TOML; `path` names it in errors.
pub fn parse_toml(text: &str, path: &Path, options: &TomlOptions) -> Result<Vec<Camera>> {
    let unit = options.translation_unit_m;
    if !(unit.is_finite() && unit > 0.0) {
        return Err(CaptureError::Invalid(format!(
            "translation unit must be a positive number of metres, got {unit}"
        )));
    }
    let table: toml::Table = text.parse().map_err(|e: toml::de::Error| {
        CaptureError::format(path, format!("not valid TOML: {}", e.message()))
    })?;
    let mut cameras = Vec::new();
    for (key, value) in &table {
        if key == "metadata" {
            continue;
        }
        let err = |what: String| CaptureError::format(path, format!("camera [{key}]: {what}"));
        let Value::Table(cam) = value else {
            return Err(err("is not a table".into()));
        };
        let get = |field: &str| {
            cam.get(field)
                .ok_or_else(|| err(format!("missing field `{field}`")))
        };
        let name = match get("name")? {
            Value::String(s) => s.clone(),
            _ => return Err(err("`name` is not a string".into())),
        };
        if let Some(f) = cam.get("fisheye") {
            match f {
                Value::Boolean(false) => {}
                Value::Boolean(true) => {
                    return Err(err(
                        "fisheye = true: fisheye cameras are not supported (only the pinhole + OpenCV distortion model)".into(),
                    ));
                }
                _ => return Err(err("`fisheye` is not a boolean".into())),
            }
        }
        let size = numbers(get("size")?).map_err(|w| err(format!("`size`: {w}")))?;
        let [w, h] = <[f64; 2]>::try_from(size.as_slice())
            .map_err(|_| err(format!("`size` has {} values, want 2", size.len())))?;
        let to_px = |v: f64, what: &str| {
            if v >= 1.0 && v <= u32::MAX as f64 && v.fract() == 0.0 {
                Ok(v as u32)
            } else {
                Err(err(format!(
                    "`size` {what} {v} is not a positive whole number"
                )))
            }
        };
        let image_size = [to_px(w, "width")?, to_px(h, "height")?];
        let m = matrix3(get("matrix")?).map_err(|w| err(format!("`matrix`: {w}")))?;
        if m[1][0] != 0.0 || m[2][0] != 0.0 || m[2][1] != 0.0 || m[2][2] != 1.0 {
            return Err(err(format!(
                "`matrix` is not an intrinsic matrix [[fx, s, cx], [0, fy, cy], [0, 0, 1]]: {m:?}"
            )));
        }
        let d = numbers(get("distortions")?).map_err(|w| err(format!("`distortions`: {w}")))?;
        let dist = match d.len() {
            4 => [d[0], d[1], d[2], d[3], 0.0],
            5 => [d[0], d[1], d[2], d[3], d[4]],
            n => {
                return Err(err(format!(
                    "`distortions` has {n} values, want 4 (k1, k2, p1, p2) or 5 (… k3)"
                )));
            }
        };
        let rv = vec3(get("rotation")?).map_err(|w| err(format!("`rotation`: {w}")))?;
        let tv = vec3(get("translation")?).map_err(|w| err(format!("`translation`: {w}")))?;
        let camera = Camera {
            name,
            fx: m[0][0],
            fy: m[1][1],
            cx: m[0][2],
            cy: m[1][2],
            skew: m[0][1],
            dist,
            r: from_rotation_vector(rv),
            t: [tv[0] * unit, tv[1] * unit, tv[2] * unit],
            image_size: Some(image_size),
            active: true,
        };
        camera.problem().map_err(err)?;
        cameras.push(camera);
    }
    check_unique_names(path, &cameras)?;
    Ok(cameras)
}

/// A TOML array of finite numbers (integers or floats).
fn numbers(v: &Value) -> std::result::Result<Vec<f64>, String> {
    let Value::Array(a) = v else {
        return Err("not an array".into());
    };
    a.iter()
        .enumerate()
        .map(|(i, x)| {
            let f = match x {
                Value::Float(f) => *f,
                Value::Integer(n) => *n as f64,
                _ => return Err(format!("value {i} is not a number")),
            };
            if f.is_finite() {
                Ok(f)
            } else {
                Err(format!("value {i} is not finite ({f})"))
            }
        })
        .collect()
}

fn vec3(v: &Value) -> std::result::Result<[f64; 3], String> {
    let n = numbers(v)?;
    <[f64; 3]>::try_from(n.as_slice()).map_err(|_| format!("has {} values, want 3", n.len()))
}

fn matrix3(v: &Value) -> std::result::Result<[[f64; 3]; 3], String> {
    let Value::Array(rows) = v else {
        return Err("not an array of rows".into());
    };
    if rows.len() != 3 {
        return Err(format!("has {} rows, want 3", rows.len()));
    }
    let mut m = [[0.0; 3]; 3];
    for (i, row) in rows.iter().enumerate() {
        m[i] = vec3(row).map_err(|w| format!("row {i}: {w}"))?;
    }
    Ok(m)
}

/// The Pose2Sim TOML text of `cameras` (translations in metres, `[metadata]` last). Every
/// camera must pass [`Camera::validate`] and have a known image size; names must be distinct
/// and not `metadata`.
pub fn to_toml_string(cameras: &[Camera]) -> Result<String> {
    let mut out = String::new();
    let mut seen = std::collections::HashSet::new();
    for c in cameras {
        c.validate()?;
        let Some([w, h]) = c.image_size else {
            return Err(CaptureError::Invalid(format!(
                "camera {:?}: image size unknown; the TOML format needs it",
                c.name
            )));
        };
        if c.name == "metadata" {
            return Err(CaptureError::Invalid(
                "a camera named \"metadata\" cannot be written (the name is reserved)".into(),
            ));
        }
        if !seen.insert(c.name.as_str()) {
            return Err(CaptureError::Invalid(format!(
                "camera name {:?} appears twice",
                c.name
            )));
        }
        let rv = rotation_vector(&c.r);
        let [k1, k2, p1, p2, k3] = c.dist;
        let dist = if k3 == 0.0 {
            format!("[ {k1:?}, {k2:?}, {p1:?}, {p2:?}]")
        } else {
            format!("[ {k1:?}, {k2:?}, {p1:?}, {p2:?}, {k3:?}]")
        };
        let _ = writeln!(out, "[{}]", toml_key(&c.name));
        let _ = writeln!(out, "name = {}", toml_string(&c.name));
        let _ = writeln!(out, "size = [ {:?}, {:?}]", w as f64, h as f64);
        let _ = writeln!(
            out,
            "matrix = [ [ {:?}, {:?}, {:?}], [ 0.0, {:?}, {:?}], [ 0.0, 0.0, 1.0]]",
            c.fx, c.skew, c.cx, c.fy, c.cy
        );
        let _ = writeln!(out, "distortions = {dist}");
        let _ = writeln!(out, "rotation = [ {:?}, {:?}, {:?}]", rv[0], rv[1], rv[2]);
        let _ = writeln!(
            out,
            "translation = [ {:?}, {:?}, {:?}]",
            c.t[0], c.t[1], c.t[2]
        );
        let _ = writeln!(out, "fisheye = false\n");
    }
    out.push_str("[metadata]\nadjusted = false\nerror = 0.0\n");
    Ok(out)
}

/// Writes `cameras` as a Pose2Sim calibration TOML (see [`to_toml_string`]).
pub fn write_toml(path: &Path, cameras: &[Camera]) -> Result<()> {
    let text = to_toml_string(cameras)?;
    std::fs::write(path, text).map_err(|e| CaptureError::io(path, e))
}

/// A bare key when the name allows it, else a quoted one.
fn toml_key(name: &str) -> String {
    let bare = !name.is_empty()
        && name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || c == '_' || c == '-');
    if bare {
        name.to_string()
    } else {
        toml_string(name)
    }
}

/// A TOML basic string with `"`, `\` and control characters escaped.
fn toml_string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 || c == '\u{7f}' => {
                let _ = write!(out, "\\u{:04X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}
