//! Qualisys Track Manager calibration export (`.qca.txt`, XML).
//!
//! Layout: `<calibration …><cameras><camera active= serial= model= …>` with the children
//! `<fov_video left= top= right= bottom=/>` (the video sensor window, pixels, inclusive),
//! `<transform x= y= z= r11= … r33=/>` and `<intrinsic focalLengthU= focalLengthV=
//! centerPointU= centerPointV= skew= radialDistortion1..3= tangentalDistortion1..2= …/>`.
//! Other children and attributes are ignored.
//!
//! Conversion to a [`Camera`] (OpenCV conventions), as Pose2Sim does it:
//! * position `P = (x, y, z)` is the camera centre in millimetres → `P/1000` metres;
//! * `R_qca` = the nine `r` attributes read **row by row** (`[[r11, r12, r13], [r21, …], …]`)
//!   is the world → *Qualisys-camera* rotation, whose camera looks along its −z with y up;
//!   flipping y and z gives OpenCV: `R = diag(1, −1, −1)·R_qca`, `t = −R·P`, hence
//!   [`Camera::centre`] `= P` exactly. (Pose2Sim reads the attributes column by column as the
//!   camera → world rotation, transposes it, then applies the same flip: the same `R`.)
//!   Checked on Pose2Sim's demo `Calib.qca.txt`: each camera's optical axis (third row of
//!   `R`) points from its position into the capture volume, and `R` and the centre agree
//!   with an independent OpenCV calibration of the same scene (`Calib_scene.toml`) within
//!   0.02 per entry and 5 cm; the transposed reading makes the cameras look away.
//! * intrinsics are stored in 1/64 pixel of the full sensor: `fx = focalLengthU/64`,
//!   `fy = focalLengthV/64`, `cx = centerPointU/64 − fov_video.left`,
//!   `cy = centerPointV/64 − fov_video.top`, `skew = skew/64`;
//! * distortion: `k1, k2, k3 = radialDistortion1..3 / d`, `p1, p2 = tangentalDistortion1..2
//!   / d` with `d` = [`QcaOptions::distortion_divisor`], 64 by default as in Pose2Sim. **Doubt**:
//!   on Pose2Sim's demo the undivided values (k1 ≈ −0.046, k2 ≈ 0.14) are the ones close to the
//!   independent OpenCV calibration of the same cameras (k1 ≈ −0.053, k2 ≈ 0.15); divided by
//!   64 they are negligible. Pass `distortion_divisor: 1.0` to use them undivided.
//! * `skew` and `radialDistortion3` default to 0 when absent; every other attribute named
//!   above is required;
//! * image size = `(right − left + 1) × (bottom − top + 1)` of `fov_video`;
//! * name = `serial`, or the camera's 1-based position in the file when it has none;
//! * `active="0"` cameras are read too, with [`Camera::active`] `= false` (missing → active).
//!
//! Not handled: Pose2Sim's `video_resolution` rescaling and binning factor (the video is taken
//! to be at the `fov_video` resolution).

use crate::camera::Camera;
use crate::check_unique_names;
use crate::error::{CaptureError, Result, read_text};
use panoman_mesh::geom::{matvec, scale};
use std::path::Path;

/// Options of [`read_qca`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QcaOptions {
    /// Divisor applied to the distortion coefficients (64 as Pose2Sim; see the module doc).
    pub distortion_divisor: f64,
}

impl Default for QcaOptions {
    fn default() -> Self {
        QcaOptions {
            distortion_divisor: 64.0,
        }
    }
}

/// Reads a Qualisys `.qca.txt` calibration → every camera in file order (inactive ones too).
pub fn read_qca(path: &Path, options: &QcaOptions) -> Result<Vec<Camera>> {
    parse_qca(&read_text(path)?, path, options)
}

/// Parses the text of a `.qca.txt`; `path` names it in errors.
pub fn parse_qca(text: &str, path: &Path, options: &QcaOptions) -> Result<Vec<Camera>> {
    let div = options.distortion_divisor;
    if !(div.is_finite() && div > 0.0) {
        return Err(CaptureError::Invalid(format!(
            "distortion divisor must be positive, got {div}"
        )));
    }
    let doc = roxmltree::Document::parse(text)
        .map_err(|e| CaptureError::format(path, format!("not valid XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "calibration" {
        return Err(CaptureError::format(
            path,
            format!(
                "root element is <{}>, want <calibration>",
                root.tag_name().name()
            ),
        ));
    }
    let cams_el =
        child(root, "cameras").ok_or_else(|| CaptureError::format(path, "no <cameras> element"))?;
    let mut cameras = Vec::new();
    for (i, cam) in cams_el
        .children()
        .filter(|n| n.is_element() && n.tag_name().name() == "camera")
        .enumerate()
    {
        let label = match cam.attribute("serial") {
            Some(s) => format!("camera {} (serial {s:?})", i + 1),
            None => format!("camera {}", i + 1),
        };
        let err = |what: String| CaptureError::format(path, format!("{label}: {what}"));
        let name = cam
            .attribute("serial")
            .map(str::to_string)
            .unwrap_or_else(|| (i + 1).to_string());
        let active = match cam.attribute("active") {
            None | Some("1") => true,
            Some("0") => false,
            Some(v) => return Err(err(format!("attribute active={v:?} is not 0 or 1"))),
        };
        let el = |tag: &str| child(cam, tag).ok_or_else(|| err(format!("no <{tag}> element")));
        let fov = el("fov_video")?;
        let tr = el("transform")?;
        let intr = el("intrinsic")?;
        let num = |node: roxmltree::Node, attr: &str, default: Option<f64>| -> Result<f64> {
            let tag = node.tag_name().name();
            match node.attribute(attr) {
                None => default.ok_or_else(|| err(format!("<{tag}> has no attribute {attr}"))),
                Some(s) => match s.trim().parse::<f64>() {
                    Ok(v) if v.is_finite() => Ok(v),
                    Ok(v) => Err(err(format!("<{tag}> {attr}={v} is not finite"))),
                    Err(_) => Err(err(format!("<{tag}> {attr}={s:?} is not a number"))),
                },
            }
        };
        let [left, top, right, bottom] = [
            num(fov, "left", None)?,
            num(fov, "top", None)?,
            num(fov, "right", None)?,
            num(fov, "bottom", None)?,
        ];
        let extent = |lo: f64, hi: f64, what: &str| -> Result<u32> {
            let n = hi - lo + 1.0;
            if lo.fract() == 0.0 && hi.fract() == 0.0 && n >= 1.0 && n <= u32::MAX as f64 {
                Ok(n as u32)
            } else {
                Err(err(format!(
                    "<fov_video> {what} extent {lo}..{hi} is not a positive pixel range"
                )))
            }
        };
        let width = extent(left, right, "horizontal")?;
        let height = extent(top, bottom, "vertical")?;
        let mut r_qca = [[0.0; 3]; 3];
        for (r, row) in r_qca.iter_mut().enumerate() {
            for (c, v) in row.iter_mut().enumerate() {
                *v = num(tr, &format!("r{}{}", r + 1, c + 1), None)?;
            }
        }
        let position = [
            num(tr, "x", None)? / 1000.0,
            num(tr, "y", None)? / 1000.0,
            num(tr, "z", None)? / 1000.0,
        ];
        // OpenCV R = diag(1, −1, −1)·R_qca
        let r = [r_qca[0], scale(r_qca[1], -1.0), scale(r_qca[2], -1.0)];
        let t = scale(matvec(&r, position), -1.0);
        let camera = Camera {
            name,
            fx: num(intr, "focalLengthU", None)? / 64.0,
            fy: num(intr, "focalLengthV", None)? / 64.0,
            cx: num(intr, "centerPointU", None)? / 64.0 - left,
            cy: num(intr, "centerPointV", None)? / 64.0 - top,
            skew: num(intr, "skew", Some(0.0))? / 64.0,
            dist: [
                num(intr, "radialDistortion1", None)? / div,
                num(intr, "radialDistortion2", None)? / div,
                num(intr, "tangentalDistortion1", None)? / div,
                num(intr, "tangentalDistortion2", None)? / div,
                num(intr, "radialDistortion3", Some(0.0))? / div,
            ],
            r,
            t,
            image_size: Some([width, height]),
            active,
        };
        camera.problem().map_err(err)?;
        cameras.push(camera);
    }
    if cameras.is_empty() {
        return Err(CaptureError::format(path, "no <camera> in <cameras>"));
    }
    check_unique_names(path, &cameras)?;
    Ok(cameras)
}

/// The first child element named `tag`.
fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, tag: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children()
        .find(|n| n.is_element() && n.tag_name().name() == tag)
}
