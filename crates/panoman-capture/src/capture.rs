//! Markerless capture: a synchronized, triangulated sequence ([`crate::sequence`]) tracked by
//! a PanoMan model (or its LBS baseline), and the leave-one-camera-out evaluation — fit and
//! track from the other cameras, project into the held-out one, compare with its detections
//! and its person mask.
//!
//! Measures (per held-out camera, over the common frames):
//! * 2D keypoint error: `‖π_h(X_k) − u_k‖` (pixels) for the body keypoints `k` detected in
//!   the held-out view with confidence ≥ [`CaptureConfig::eval_min_confidence`] and
//!   triangulated from the other views, so that the model and the triangulation are scored on
//!   the same points; the median over keypoints and frames, also as a percentage of the
//!   detections' bounding-box height in that view.
//! * Silhouette IoU: `|S ∩ M| / |S ∪ M|` of the mesh's projected triangles `S` and the
//!   detector's person mask `M` (pixels of the mask's grid).
//! * Jitter: mean acceleration `‖x_{t+1} − 2x_t + x_{t−1}‖·fps²` (m/s²) of the tracked
//!   mesh's vertices, of its keypoints, and of the triangulated keypoints (the same keypoints,
//!   where triangulated in three consecutive frames).

use std::collections::BTreeMap;

use panoman::{FitRequest, IkStart, Method, Model, Targets, Tracker};
use panoman_human::keypoints::{FACE_OFFSET, FEET_OFFSET, KeypointsFile};
use panoman_interchange::keypoints_in::Keypoints2d;
use panoman_mesh::geom::{V3, norm, sub};

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::frame::TriangulatedFrame;
use panoman_mesh::stats::median;
use rayon::prelude::*;

/// Options of a capture.
#[derive(Debug, Clone)]
pub struct CaptureConfig {
    /// Shape calibration frames spread over the sequence (0: none; default 8).
    pub calibrate_shape: usize,
    /// Frames per second of the videos (jitter; default 60).
    pub fps: f64,
    /// Least detector confidence of a held-out detection that is scored (default 0.5).
    pub eval_min_confidence: f64,
    /// Least body keypoints (TC-133 0–14) triangulated for a frame to be fitted; frames with
    /// fewer hold the previous frame's fit (default 8).
    pub min_body_keypoints: usize,
    /// Expected noise of the triangulated keypoints, metres per coordinate: the fit's priors
    /// and quality thresholds ([`panoman::FitRequest::keypoint_sigma`]; default 0.015).
    pub keypoint_sigma: f64,
    /// TC-133 keypoints left out of the fit's targets (e.g. points a detector synthesizes
    /// rather than detects); they are still triangulated and scored.
    pub ignore: Vec<usize>,
    /// Keypoints the detector does not detect but forms as the midpoint of two others
    /// (`(k, a, b)`: MediaPipe's neck is its shoulders' midpoint): `k` is left out of the fit's
    /// targets, and the tracked keypoint `k` is the midpoint of the model's `a` and `b`, so
    /// that it means what the detections mean ([`MEDIAPIPE_MIDPOINTS`]).
    pub midpoints: Vec<(usize, usize, usize)>,
}

/// The keypoints MediaPipe's OpenPose output forms as midpoints (TC-133 indices): the neck
/// (0) between the shoulders (3, 9). Its mid-hip is also a midpoint of its hips, but the
/// model's pelvis point sits within millimetres of its hips' midpoint, so it stays a target.
pub const MEDIAPIPE_MIDPOINTS: [(usize, usize, usize); 1] = [(0, 3, 9)];

impl Default for CaptureConfig {
    fn default() -> Self {
        CaptureConfig {
            calibrate_shape: 8,
            fps: 60.0,
            eval_min_confidence: 0.5,
            min_body_keypoints: 8,
            keypoint_sigma: 0.015,
            ignore: Vec::new(),
            midpoints: Vec::new(),
        }
    }
}

/// A tracked sequence.
#[derive(Debug, Clone)]
pub struct Tracked {
    /// The method.
    pub method: Method,
    /// Per frame, the mesh (the model's topology, metres).
    pub vertices: Vec<Vec<V3>>,
    /// Per frame, the mesh's TC-133 keypoints (metres), the detector's midpoints
    /// ([`CaptureConfig::midpoints`]) formed as it forms them.
    pub keypoints: Vec<Vec<V3>>,
    /// Per frame, the keypoints the fit followed (TC-133, metres): the triangulated ones, or
    /// after the 2D refit ([`track_2d`]) the reprojection targets.
    pub targets: Vec<KeypointsFile>,
    /// Frames that held the previous fit (too few keypoints triangulated).
    pub held: Vec<usize>,
    /// Frames whose fit did not pass the quality check.
    pub not_converged: Vec<usize>,
    /// Mean keypoint residual per frame after the fit (mm; body group).
    pub residual_mm: Vec<f64>,
    /// Shape calibration seconds and per-frame fit seconds.
    pub calibration_seconds: f64,
    /// See `calibration_seconds`.
    pub frame_seconds: Vec<f64>,
}

/// The fit targets of a triangulated frame: its keypoints but those of `config.ignore` and
/// the detector's midpoints.
fn targets_of(frame: &TriangulatedFrame, config: &CaptureConfig) -> Targets {
    let mut keypoints = frame.keypoints.clone();
    for k in config
        .ignore
        .iter()
        .chain(config.midpoints.iter().map(|m| &m.0))
    {
        keypoints.points.remove(k);
        keypoints.weights.remove(k);
    }
    Targets {
        keypoints,
        ..Default::default()
    }
}

fn body_count(k: &KeypointsFile) -> usize {
    k.points.range(..FEET_OFFSET.min(15)).count()
}

/// Tracks `frames` with `model` by `method`: the identity calibrated from
/// `config.calibrate_shape` frames spread over the sequence and held, then every frame warm
/// from the previous one. `progress(done)` after each frame.
///
/// # Errors
/// No frame with enough body keypoints; the tracker's errors (naming the frame).
pub fn track(
    model: &Model,
    frames: &[TriangulatedFrame],
    method: Method,
    config: &CaptureConfig,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Tracked> {
    let fit_err = |f: usize, e: panoman::Error| CaptureError::Invalid(format!("frame {f}: {e}"));
    let usable: Vec<usize> = (0..frames.len())
        .filter(|&f| body_count(&frames[f].keypoints) >= config.min_body_keypoints)
        .collect();
    if usable.is_empty() {
        return Err(CaptureError::Invalid(format!(
            "no frame of {} has {} body keypoints triangulated: nothing to fit",
            frames.len(),
            config.min_body_keypoints
        )));
    }
    let req = FitRequest {
        method,
        keypoint_sigma: config.keypoint_sigma,
        ..Default::default()
    };
    let mut tracker = Tracker::new(model, req, IkStart::Warm)
        .map_err(|e| CaptureError::Invalid(e.to_string()))?;
    let t0 = std::time::Instant::now();
    if config.calibrate_shape > 0 {
        let n = config.calibrate_shape.min(usable.len());
        let picked: Vec<Targets> = (0..n)
            .map(|i| usable[(i * usable.len() + usable.len() / (2 * n)) / n])
            .map(|f| targets_of(&frames[f], config))
            .collect();
        tracker
            .calibrate_shape(&picked, &Default::default())
            .map_err(|e| CaptureError::Invalid(format!("shape calibration: {e}")))?;
    }
    let calibration_seconds = t0.elapsed().as_secs_f64();
    let mut out = Tracked {
        method,
        vertices: Vec::with_capacity(frames.len()),
        keypoints: Vec::with_capacity(frames.len()),
        targets: frames.iter().map(|f| f.keypoints.clone()).collect(),
        held: Vec::new(),
        not_converged: Vec::new(),
        residual_mm: Vec::new(),
        calibration_seconds,
        frame_seconds: Vec::new(),
    };
    let first = usable[0];
    for (f, frame) in frames.iter().enumerate().skip(first) {
        if body_count(&frame.keypoints) < config.min_body_keypoints {
            out.held.push(f);
            let (v, k) = (out.vertices.last().cloned(), out.keypoints.last().cloned());
            out.vertices.push(v.unwrap_or_default());
            out.keypoints.push(k.unwrap_or_default());
            out.residual_mm.push(f64::NAN);
            progress(f + 1);
            continue;
        }
        let t = std::time::Instant::now();
        let targets = targets_of(frame, config);
        let fit = tracker.track(&targets).map_err(|e| fit_err(f, e))?;
        out.frame_seconds.push(t.elapsed().as_secs_f64());
        if !fit.report.converged() {
            out.not_converged.push(f);
        }
        out.residual_mm.push(
            fit.report
                .keypoint_residuals
                .get(&panoman::KeypointGroup::Body)
                .map_or(f64::NAN, |g| g.mean_mm),
        );
        let mut kp = model.keypoints(&fit.vertices).map_err(|e| fit_err(f, e))?;
        for &(k, a, b) in &config.midpoints {
            if let (Some(&pa), Some(&pb), true) = (kp.get(a), kp.get(b), k < kp.len()) {
                kp[k] = [
                    0.5 * (pa[0] + pb[0]),
                    0.5 * (pa[1] + pb[1]),
                    0.5 * (pa[2] + pb[2]),
                ];
            }
        }
        out.vertices.push(fit.vertices);
        out.keypoints.push(kp);
        progress(f + 1);
    }
    // Frames before the first usable one take its fit.
    for _ in 0..first {
        out.vertices.insert(0, out.vertices[0].clone());
        out.keypoints.insert(0, out.keypoints[0].clone());
        out.residual_mm.insert(0, f64::NAN);
    }
    out.held.extend(0..first);
    out.held.sort_unstable();
    Ok(out)
}

/// Tracks with the 2D detections ([`crate::reproject`]): `frames` tracked as by [`track`],
/// then every frame's targets replaced by the robust reprojection targets of `views[t]` (per
/// camera, the frame's 2D keypoints; empty for a camera left out) anchored at the tracked
/// keypoints, smoothed over time like the triangulated ones (`sigma_frames`,
/// [`crate::sequence::smooth_keypoints`]), and the sequence tracked again from them.
///
/// # Errors
/// See [`track`]; a view count that differs from the frame count.
#[allow(clippy::too_many_arguments)]
pub fn track_2d(
    model: &Model,
    cameras: &[Camera],
    views: &[Vec<Keypoints2d>],
    frames: &[TriangulatedFrame],
    method: Method,
    config: &CaptureConfig,
    options: &crate::reproject::ReprojectionOptions,
    sigma_frames: f64,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Tracked> {
    if views.len() != frames.len() {
        return Err(CaptureError::Invalid(format!(
            "{} frames of 2D views for {} triangulated frames",
            views.len(),
            frames.len()
        )));
    }
    let first = track(model, frames, method, config, progress)?;
    let refined: Vec<TriangulatedFrame> = views
        .par_iter()
        .zip(first.keypoints.par_iter())
        .map(|(v, p)| TriangulatedFrame {
            keypoints: crate::reproject::refine_frame(cameras, v, p, options),
            details: BTreeMap::new(),
            rejected: Vec::new(),
        })
        .collect();
    let refined = crate::sequence::smooth_keypoints(&refined, sigma_frames);
    let mut second = track(model, &refined, method, config, progress)?;
    second.calibration_seconds += first.calibration_seconds;
    Ok(second)
}

/// The 2D keypoint error of predictions in one view: per scored keypoint (TC-133 index in
/// `keypoints`) the pixel distance. `predicted(k)` is the 3D point of keypoint `k`, if any.
fn errors_in_view(
    camera: &Camera,
    detected: &Keypoints2d,
    keypoints: &[usize],
    predicted: impl Fn(usize) -> Option<V3>,
) -> Vec<(usize, f64)> {
    keypoints
        .iter()
        .filter_map(|&k| {
            let (u, _) = detected.get(&k)?;
            let p = camera.project(predicted(k)?)?;
            Some((k, ((p[0] - u[0]).powi(2) + (p[1] - u[1]).powi(2)).sqrt()))
        })
        .collect()
}

/// Height (pixels) of the bounding box of the confident detections of a view.
fn bbox_height(detected: &Keypoints2d, min_conf: f64) -> Option<f64> {
    let ys: Vec<f64> = detected
        .range(..FACE_OFFSET)
        .filter(|(_, (_, c))| *c >= min_conf)
        .map(|(_, (u, _))| u[1])
        .collect();
    let (lo, hi) = ys
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &y| {
            (a.min(y), b.max(y))
        });
    (ys.len() >= 2 && hi > lo).then_some(hi - lo)
}

/// The 2D keypoint errors of one held-out camera.
#[derive(Debug, Clone, Default, PartialEq, serde::Serialize)]
pub struct ViewErrors {
    /// Median pixel error over frames and scored body keypoints (TC-133 0–14).
    pub body_px: f64,
    /// The same as a percentage of the detections' bounding-box height (median per frame).
    pub body_pct_bbox: f64,
    /// Median pixel error of the foot keypoints (TC-133 15–20) where detected.
    pub feet_px: f64,
    /// Body keypoints scored (over all frames).
    pub scored: usize,
    /// Per frame, the median body error (pixels; NaN where none was scored).
    pub per_frame_px: Vec<f64>,
    /// Per body and foot keypoint (TC-133 index), the median error over frames (pixels).
    pub per_keypoint_px: BTreeMap<usize, f64>,
}

/// Scores per-frame 3D keypoints (`predicted[f](k)`) in `camera` against `detections[f]`,
/// on the keypoints that `triangulated[f]` also has (the common set).
pub fn view_errors(
    camera: &Camera,
    detections: &[Keypoints2d],
    triangulated: &[TriangulatedFrame],
    predicted: &dyn Fn(usize, usize) -> Option<V3>,
    min_conf: f64,
) -> ViewErrors {
    let mut all = Vec::new();
    let mut feet = Vec::new();
    let mut pct = Vec::new();
    let mut per_frame = Vec::new();
    let mut per_keypoint: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for (f, det) in detections.iter().enumerate() {
        let confident: Keypoints2d = det
            .iter()
            .filter(|(_, (_, c))| *c >= min_conf)
            .map(|(&k, &v)| (k, v))
            .collect();
        let tri = &triangulated[f].keypoints.points;
        let body: Vec<usize> = (0..15).filter(|k| tri.contains_key(k)).collect();
        let foot: Vec<usize> = (15..21).filter(|k| tri.contains_key(k)).collect();
        let eb = errors_in_view(camera, &confident, &body, |k| predicted(f, k));
        let ef = errors_in_view(camera, &confident, &foot, |k| predicted(f, k));
        for &(k, e) in eb.iter().chain(&ef) {
            per_keypoint.entry(k).or_default().push(e);
        }
        feet.extend(ef.iter().map(|p| p.1));
        let mut e: Vec<f64> = eb.iter().map(|p| p.1).collect();
        let m = median(&mut e.clone());
        per_frame.push(m);
        if let (Some(h), true) = (bbox_height(&confident, min_conf), m.is_finite()) {
            pct.push(100.0 * m / h);
        }
        all.append(&mut e);
    }
    ViewErrors {
        scored: all.len(),
        body_px: median(&mut all),
        body_pct_bbox: median(&mut pct),
        feet_px: median(&mut feet),
        per_frame_px: per_frame,
        per_keypoint_px: per_keypoint
            .into_iter()
            .map(|(k, mut v)| (k, median(&mut v)))
            .collect(),
    }
}

/// A binary person mask on a grid of `width × height` cells, each `scale` image pixels⁻¹
/// (mask pixel = image pixel × scale).
#[derive(Debug, Clone, PartialEq)]
pub struct Mask {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Mask pixels per image pixel.
    pub scale: f64,
    /// Row-major, `true` inside the person.
    pub data: Vec<bool>,
}

impl Mask {
    /// Reads an 8-bit greyscale (or RGB/RGBA: first channel) PNG; values ≥ 128 are inside.
    ///
    /// # Errors
    /// I/O or a PNG that cannot be decoded, naming the file.
    pub fn read_png(path: &std::path::Path, scale: f64) -> Result<Mask> {
        let file = std::fs::File::open(path).map_err(|e| CaptureError::io(path, e))?;
        let mut dec = png::Decoder::new(std::io::BufReader::new(file));
        dec.set_transformations(png::Transformations::normalize_to_color8());
        let mut reader = dec
            .read_info()
            .map_err(|e| CaptureError::format(path, format!("PNG: {e}")))?;
        let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
        let info = reader
            .next_frame(&mut buf)
            .map_err(|e| CaptureError::format(path, format!("PNG: {e}")))?;
        let ch = info.color_type.samples();
        let (w, h) = (info.width as usize, info.height as usize);
        let data = (0..w * h).map(|i| buf[i * ch] >= 128).collect();
        Ok(Mask {
            width: w,
            height: h,
            scale,
            data,
        })
    }

    /// The mesh's silhouette in `camera` on this mask's grid: every triangle whose three
    /// corners project is filled (cell centres inside it).
    pub fn silhouette(&self, camera: &Camera, vertices: &[V3], faces: &[[u32; 3]]) -> Mask {
        let mut out = Mask {
            data: vec![false; self.width * self.height],
            ..self.clone()
        };
        let proj: Vec<Option<[f64; 2]>> = vertices
            .iter()
            .map(|&v| {
                camera
                    .project(v)
                    .map(|p| [p[0] * self.scale, p[1] * self.scale])
            })
            .collect();
        for f in faces {
            let [Some(a), Some(b), Some(c)] = f.map(|i| proj[i as usize]) else {
                continue;
            };
            fill_triangle(&mut out, a, b, c);
        }
        out
    }

    /// The mask as an 8-bit greyscale PNG (255 inside, 0 outside).
    pub fn encode_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width as u32, self.height as u32);
            enc.set_color(png::ColorType::Grayscale);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Fast);
            let data: Vec<u8> = self.data.iter().map(|&b| if b { 255 } else { 0 }).collect();
            // Writing into a Vec cannot fail for a non-empty image of the stated size.
            if let Ok(mut w) = enc.write_header() {
                let _ = w.write_image_data(&data);
            }
        }
        out
    }

    /// Intersection over union with `other` (same grid); NaN when both are empty.
    pub fn iou(&self, other: &Mask) -> f64 {
        let (mut i, mut u) = (0usize, 0usize);
        for (a, b) in self.data.iter().zip(&other.data) {
            i += usize::from(*a && *b);
            u += usize::from(*a || *b);
        }
        if u == 0 {
            f64::NAN
        } else {
            i as f64 / u as f64
        }
    }
}

fn fill_triangle(m: &mut Mask, a: [f64; 2], b: [f64; 2], c: [f64; 2]) {
    let edge = |p: [f64; 2], q: [f64; 2], x: [f64; 2]| {
        (q[0] - p[0]) * (x[1] - p[1]) - (q[1] - p[1]) * (x[0] - p[0])
    };
    let area = edge(a, b, c);
    if area == 0.0 || !area.is_finite() {
        return;
    }
    let lo_x = a[0].min(b[0]).min(c[0]).floor().max(0.0) as usize;
    let lo_y = a[1].min(b[1]).min(c[1]).floor().max(0.0) as usize;
    let hi_x = (a[0].max(b[0]).max(c[0]).ceil().max(0.0) as usize).min(m.width);
    let hi_y = (a[1].max(b[1]).max(c[1]).ceil().max(0.0) as usize).min(m.height);
    for y in lo_y..hi_y {
        for x in lo_x..hi_x {
            let p = [x as f64 + 0.5, y as f64 + 0.5];
            let (w0, w1, w2) = (edge(b, c, p), edge(c, a, p), edge(a, b, p));
            let inside = if area > 0.0 {
                w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0
            } else {
                w0 <= 0.0 && w1 <= 0.0 && w2 <= 0.0
            };
            if inside {
                m.data[y * m.width + x] = true;
            }
        }
    }
}

/// Mean acceleration (m/s²) of point tracks: `tracks[t][i]` the position of point `i` at
/// frame `t` or `None`; the mean over the triples of consecutive frames where a point exists.
pub fn mean_acceleration(tracks: &[Vec<Option<V3>>], fps: f64) -> f64 {
    let (mut sum, mut n) = (0.0, 0usize);
    for w in tracks.windows(3) {
        for i in 0..w[1].len() {
            if let (Some(a), Some(b), Some(c)) = (
                w[0].get(i).copied().flatten(),
                w[1][i],
                w[2].get(i).copied().flatten(),
            ) {
                sum += norm(sub(sub(c, b), sub(b, a))) * fps * fps;
                n += 1;
            }
        }
    }
    if n == 0 { f64::NAN } else { sum / n as f64 }
}

/// Per held-out camera, the figures of the leave-one-camera-out evaluation.
#[derive(Debug, Clone, serde::Serialize)]
pub struct HeldOutCamera {
    /// The held-out camera.
    pub camera: String,
    /// Frames scored.
    pub frames: usize,
    /// 2D keypoint errors by method: `panoman`, `lbs`, `triangulation`, `triangulation_smoothed`,
    /// and `panoman_targets`, `lbs_targets` (the keypoints each fit followed).
    pub keypoint_error: BTreeMap<String, ViewErrors>,
    /// Median over frames of the silhouette IoU by method (`panoman`, `lbs`), where masks
    /// exist.
    pub silhouette_iou: BTreeMap<panoman::Method, f64>,
    /// Mean acceleration (m/s²): `panoman_vertices`, `panoman_keypoints`, `lbs_vertices`,
    /// `lbs_keypoints`, `triangulation_keypoints`.
    pub jitter: BTreeMap<String, f64>,
    /// Per method, per body and foot keypoint name, the median 3D distance (mm) between the
    /// tracked keypoint and its target (the other cameras' smoothed triangulation).
    pub fit_residual_mm: BTreeMap<panoman::Method, BTreeMap<String, f64>>,
}

/// The triangulated keypoints as point tracks (TC-133 0–20) and a tracked sequence's
/// keypoints on the same points (present where triangulated).
pub fn keypoint_tracks(
    tri: &[TriangulatedFrame],
    tracked: Option<&Tracked>,
) -> Vec<Vec<Option<V3>>> {
    tri.iter()
        .enumerate()
        .map(|(f, t)| {
            (0..FACE_OFFSET.min(21))
                .map(|k| {
                    let p = *t.keypoints.points.get(&k)?;
                    match tracked {
                        Some(tr) => tr.keypoints.get(f)?.get(k).copied(),
                        None => Some(p),
                    }
                })
                .collect()
        })
        .collect()
}

/// Vertex tracks of a tracked sequence (every vertex every frame).
pub fn vertex_tracks(tracked: &Tracked) -> Vec<Vec<Option<V3>>> {
    tracked
        .vertices
        .iter()
        .map(|v| v.iter().map(|&x| Some(x)).collect())
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_square_of_two_triangles_fills_its_cells_and_iou_counts_them() {
        let base = Mask {
            width: 10,
            height: 10,
            scale: 1.0,
            data: vec![false; 100],
        };
        let mut m = base.clone();
        fill_triangle(&mut m, [2.0, 2.0], [6.0, 2.0], [6.0, 6.0]);
        fill_triangle(&mut m, [2.0, 2.0], [6.0, 6.0], [2.0, 6.0]);
        let inside = m.data.iter().filter(|&&b| b).count();
        assert_eq!(inside, 16);
        let mut half = base.clone();
        for y in 2..6 {
            for x in 2..4 {
                half.data[y * 10 + x] = true;
            }
        }
        assert!((m.iou(&half) - 0.5).abs() < 1e-12);
        assert!(base.iou(&base).is_nan());
    }

    #[test]
    fn a_mask_round_trips_through_png() {
        let mut m = Mask {
            width: 7,
            height: 5,
            scale: 0.5,
            data: vec![false; 35],
        };
        m.data[3] = true;
        m.data[20] = true;
        let p = std::env::temp_dir().join(format!("panoman-mask-{}.png", std::process::id()));
        std::fs::write(&p, m.encode_png()).unwrap();
        let back = Mask::read_png(&p, 0.5).unwrap();
        std::fs::remove_file(&p).unwrap();
        assert_eq!(back, m);
    }

    #[test]
    fn acceleration_of_a_uniformly_accelerated_point() {
        // x(t) = ½ a t², a = 2 m/s², 10 fps.
        let fps = 10.0;
        let tracks: Vec<Vec<Option<V3>>> = (0..6)
            .map(|f| {
                let t = f as f64 / fps;
                vec![Some([t * t, 0.0, 0.0]), None]
            })
            .collect();
        assert!((mean_acceleration(&tracks, fps) - 2.0).abs() < 1e-9);
    }
}
