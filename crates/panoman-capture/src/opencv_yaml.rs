//! OpenCV `FileStorage` YAML calibrations as EasyMocap writes them: `intri.yml` + `extri.yml`.
//!
//! Parser choice: the files are YAML 1.0 as OpenCV emits it, so they go through `yaml-rust2`
//! (a maintained, pure-Rust YAML 1.2 parser: block and flow collections, multi-line flow
//! sequences, duplicate-key detection) after two textual fixes it needs: the non-standard
//! first line `%YAML:1.0` is dropped, and the `!!opencv-matrix` tags are removed (the matrix
//! is then a plain mapping `{rows, cols, dt, data}`, checked here). A hand-written reader of
//! the subset would have to re-implement flow sequences across lines, quoting and comments.
//!
//! `intri.yml`: `names: ["1", "2", …]` then, per name `N`, `K_N` (3×3 intrinsic matrix) and
//! `dist_N` (or `D_N`), 1×5 or 5×1 (1×4 / 4×1 read with k3 = 0), OpenCV order.
//! `extri.yml`: `names` (the same set, when present), `R_N` (3×1 Rodrigues vector, world →
//! camera, radians), optional `Rot_N` (3×3; when both are present they must agree within 1e-6
//! per entry), `T_N` (3×1, metres). Matrices need `rows`, `cols` and `data` with
//! `rows·cols` finite numbers; `dt`, when present, must be `d` or `f`.
//!
//! The image size is not in these files: the `image_size` argument sets it for every camera;
//! without it the cameras have `image_size: None` ("unknown"), which [`Camera::validate`]
//! accepts; only this reader produces it.

use crate::camera::Camera;
use crate::check_unique_names;
use crate::error::{CaptureError, Result, read_text};
use panoman_mesh::rotation::from_rotation_vector;
use std::path::Path;
use yaml_rust2::{Yaml, YamlLoader};

/// Tolerance (per entry) between `R_N` (Rodrigues) and `Rot_N` when both are given.
pub const ROT_AGREEMENT: f64 = 1e-6;

/// Reads `intri.yml` + `extri.yml` → cameras in the order of `names` in `intri.yml`.
pub fn read_opencv_yaml(
    intri: &Path,
    extri: &Path,
    image_size: Option<[u32; 2]>,
) -> Result<Vec<Camera>> {
    let it = read_text(intri)?;
    let et = read_text(extri)?;
    parse_opencv_yaml(&it, intri, &et, extri, image_size)
}

/// Parses the texts of `intri.yml` and `extri.yml`; the paths name them in errors.
pub fn parse_opencv_yaml(
    intri_text: &str,
    intri: &Path,
    extri_text: &str,
    extri: &Path,
    image_size: Option<[u32; 2]>,
) -> Result<Vec<Camera>> {
    if let Some([w, h]) = image_size
        && (w == 0 || h == 0)
    {
        return Err(CaptureError::Invalid(format!(
            "image size {w}×{h} is not positive"
        )));
    }
    let idoc = load(intri_text, intri)?;
    let edoc = load(extri_text, extri)?;
    let names = names_of(&idoc, intri)?
        .ok_or_else(|| CaptureError::format(intri, "missing `names` (the list of camera names)"))?;
    if let Some(enames) = names_of(&edoc, extri)? {
        let mut a = names.clone();
        let mut b = enames;
        a.sort();
        b.sort();
        if a != b {
            return Err(CaptureError::format(
                extri,
                format!(
                    "`names` {b:?} differ from those of {} {a:?}",
                    intri.display()
                ),
            ));
        }
    }
    let mut cameras = Vec::with_capacity(names.len());
    for n in &names {
        let k = matrix(&idoc, intri, &format!("K_{n}"), n, &[(3, 3)])?
            .ok_or_else(|| missing(intri, n, &format!("K_{n}")))?;
        if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
            return Err(CaptureError::format(
                intri,
                format!("camera {n:?}: K_{n} is not an intrinsic matrix: {k:?}"),
            ));
        }
        let shapes = [(1, 5), (5, 1), (1, 4), (4, 1)];
        let d = match matrix(&idoc, intri, &format!("dist_{n}"), n, &shapes)? {
            Some(d) => d,
            None => matrix(&idoc, intri, &format!("D_{n}"), n, &shapes)?
                .ok_or_else(|| missing(intri, n, &format!("dist_{n}` (or `D_{n}")))?,
        };
        let dist = [d[0], d[1], d[2], d[3], d.get(4).copied().unwrap_or(0.0)];
        let rv = matrix(&edoc, extri, &format!("R_{n}"), n, &[(3, 1)])?;
        let rot = matrix(&edoc, extri, &format!("Rot_{n}"), n, &[(3, 3)])?;
        let r = match (rv, rot) {
            (Some(v), rot) => {
                let r = from_rotation_vector([v[0], v[1], v[2]]);
                if let Some(m) = rot {
                    let worst = (0..9)
                        .map(|i| (r[i / 3][i % 3] - m[i]).abs())
                        .fold(0.0, f64::max);
                    if worst > ROT_AGREEMENT {
                        return Err(CaptureError::format(
                            extri,
                            format!(
                                "camera {n:?}: R_{n} (Rodrigues) and Rot_{n} disagree by {worst:.3e} (> {ROT_AGREEMENT:e})"
                            ),
                        ));
                    }
                }
                r
            }
            (None, Some(m)) => [[m[0], m[1], m[2]], [m[3], m[4], m[5]], [m[6], m[7], m[8]]],
            (None, None) => return Err(missing(extri, n, &format!("R_{n}"))),
        };
        let t = matrix(&edoc, extri, &format!("T_{n}"), n, &[(3, 1)])?
            .ok_or_else(|| missing(extri, n, &format!("T_{n}")))?;
        let camera =
            Camera::from_intrinsic_matrix(n.clone(), &k, dist, r, [t[0], t[1], t[2]], image_size);
        if let Err(what) = camera.problem() {
            // A bad rotation or translation comes from extri.yml, anything else from intri.yml.
            let extrinsic = crate::camera::rotation_error(&camera.r).is_err()
                || camera.t.iter().any(|v| !v.is_finite());
            let file = if extrinsic { extri } else { intri };
            return Err(CaptureError::format(file, format!("camera {n:?}: {what}")));
        }
        cameras.push(camera);
    }
    check_unique_names(intri, &cameras)?;
    Ok(cameras)
}

fn missing(path: &Path, cam: &str, key: &str) -> CaptureError {
    CaptureError::format(path, format!("camera {cam:?}: missing `{key}`"))
}

/// Parses one OpenCV YAML file into its top-level mapping.
fn load(text: &str, path: &Path) -> Result<yaml_rust2::yaml::Hash> {
    let mut body = String::with_capacity(text.len());
    for (i, line) in text.lines().enumerate() {
        if i == 0 && line.trim_start().starts_with("%YAML") {
            continue;
        }
        body.push_str(&line.replace("!!opencv-matrix", ""));
        body.push('\n');
    }
    // yaml-rust2's loader has internal `unwrap`s: a panic on hostile input becomes this
    // file's error, not a crash.
    let parsed = std::panic::catch_unwind(|| YamlLoader::load_from_str(&body)).map_err(|_| {
        CaptureError::format(path, "not valid YAML (the YAML parser gave up on it)")
    })?;
    let docs = parsed.map_err(|e| CaptureError::format(path, format!("not valid YAML: {e}")))?;
    match docs.into_iter().next() {
        Some(Yaml::Hash(h)) => Ok(h),
        Some(_) => Err(CaptureError::format(path, "the document is not a mapping")),
        None => Err(CaptureError::format(path, "empty file")),
    }
}

/// The `names` sequence as strings (numbers are accepted and printed); `None` when absent.
fn names_of(doc: &yaml_rust2::yaml::Hash, path: &Path) -> Result<Option<Vec<String>>> {
    let Some(v) = doc.get(&Yaml::String("names".into())) else {
        return Ok(None);
    };
    let Yaml::Array(a) = v else {
        return Err(CaptureError::format(path, "`names` is not a sequence"));
    };
    let mut out: Vec<String> = Vec::with_capacity(a.len());
    for (i, x) in a.iter().enumerate() {
        let s = match x {
            Yaml::String(s) => s.clone(),
            Yaml::Integer(n) => n.to_string(),
            _ => {
                return Err(CaptureError::format(
                    path,
                    format!("`names` entry {i} is not a string"),
                ));
            }
        };
        if out.contains(&s) {
            return Err(CaptureError::format(
                path,
                format!("camera name {s:?} appears twice in `names`"),
            ));
        }
        out.push(s);
    }
    if out.is_empty() {
        return Err(CaptureError::format(path, "`names` is empty"));
    }
    Ok(Some(out))
}

/// The matrix `key` (row-major data) when present, checked against the allowed shapes.
fn matrix(
    doc: &yaml_rust2::yaml::Hash,
    path: &Path,
    key: &str,
    cam: &str,
    shapes: &[(i64, i64)],
) -> Result<Option<Vec<f64>>> {
    let Some(v) = doc.get(&Yaml::String(key.into())) else {
        return Ok(None);
    };
    let err = |what: String| CaptureError::format(path, format!("camera {cam:?}: `{key}` {what}"));
    let Yaml::Hash(m) = v else {
        return Err(err("is not an opencv-matrix mapping".into()));
    };
    let field = |f: &str| m.get(&Yaml::String(f.into()));
    let int = |f: &str| match field(f) {
        Some(Yaml::Integer(n)) => Ok(*n),
        Some(_) => Err(err(format!("`{f}` is not an integer"))),
        None => Err(err(format!("has no `{f}`"))),
    };
    let rows = int("rows")?;
    let cols = int("cols")?;
    match field("dt") {
        None => {}
        Some(Yaml::String(s)) if s == "d" || s == "f" => {}
        Some(other) => return Err(err(format!("has dt {other:?}, want d or f"))),
    }
    if !shapes.contains(&(rows, cols)) {
        let want: Vec<String> = shapes.iter().map(|(r, c)| format!("{r}×{c}")).collect();
        return Err(err(format!("is {rows}×{cols}, want {}", want.join(" or "))));
    }
    let Some(Yaml::Array(data)) = field("data") else {
        return Err(err("has no `data` sequence".into()));
    };
    if data.len() as i64 != rows * cols {
        return Err(err(format!(
            "has {} values in `data`, want rows·cols = {}",
            data.len(),
            rows * cols
        )));
    }
    let mut out = Vec::with_capacity(data.len());
    for (i, x) in data.iter().enumerate() {
        let f = match x {
            Yaml::Real(s) => s.parse::<f64>().ok().or_else(|| x.as_f64()),
            Yaml::Integer(n) => Some(*n as f64),
            _ => None,
        };
        match f {
            Some(f) if f.is_finite() => out.push(f),
            Some(f) => return Err(err(format!("value {i} is not finite ({f})"))),
            None => return Err(err(format!("value {i} is not a number ({x:?})"))),
        }
    }
    Ok(Some(out))
}
