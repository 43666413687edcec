//! A multi-view sequence: per camera and frame, the 2D detections (OpenPose JSON files as the
//! detector writes them, `DIR/<camera>/<camera>_<frame:012>_keypoints.json`), the cameras'
//! frame offsets (videos that are not frame-aligned), and the sequence triangulated frame by
//! frame.
//!
//! Synchronization: camera `c`'s frame `t + offset[c]` shows the instant of the common frame
//! `t` (`offset[0] = 0`). [`estimate_offsets`] picks, per camera, the offset that minimizes the
//! median two-view reprojection error of the body and foot keypoints against the first camera
//! (two views meet only where they see the same instant: the epipolar constraint).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use panoman_human::keypoints::{FACE_OFFSET, KeypointsFile};
use panoman_interchange::keypoints_in::{Keypoints2d, read_openpose_2d};
use panoman_mesh::geom::V3;
use panoman_mesh::stats::median;
use rayon::prelude::*;

use crate::camera::Camera;
use crate::error::{CaptureError, Result};
use crate::frame::{TriangulatedFrame, triangulate_frame};
use crate::triangulate::{Observation, TriangulateOptions, triangulate};

/// The detections of a sequence: `views[c][f]` are camera `c`'s 2D keypoints in its own frame
/// `f` (pixels, TC-133 indices, confidences).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Detections {
    /// Per camera (the calibration's order), per frame.
    pub views: Vec<Vec<Keypoints2d>>,
    /// Per camera, the folder read (for messages).
    pub dirs: Vec<PathBuf>,
    /// Per camera and frame, the file read (empty for in-memory detections).
    pub files: Vec<Vec<PathBuf>>,
}

impl Detections {
    /// The person mask written beside the detection file of camera `c`, frame `f`
    /// (`…_keypoints.json` → `…_mask.png`), if that file exists.
    pub fn mask_path(&self, c: usize, f: usize) -> Option<PathBuf> {
        let p = self.files.get(c)?.get(f)?;
        let name = p.file_name()?.to_str()?.strip_suffix("_keypoints.json")?;
        let m = p.with_file_name(format!("{name}_mask.png"));
        m.is_file().then_some(m)
    }

    /// Frames of camera `c`.
    pub fn frames(&self, c: usize) -> usize {
        self.views.get(c).map_or(0, Vec::len)
    }
}

/// Reads `dir/<name>/*_keypoints.json` (sorted by name) for every camera of `cameras`, person
/// `person` of each file.
///
/// # Errors
/// One error naming the folder or file: a camera without a detection folder, a folder that
/// names no camera of the calibration, a folder without detection files, frame counts that
/// differ between cameras, and every error of [`read_openpose_2d`] (another layout: wrong
/// array lengths; non-finite values).
pub fn read_detections_dir(dir: &Path, cameras: &[Camera], person: usize) -> Result<Detections> {
    let entries = std::fs::read_dir(dir).map_err(|e| CaptureError::io(dir, e))?;
    for e in entries {
        let e = e.map_err(|e| CaptureError::io(dir, e))?;
        if e.file_type().map(|t| t.is_dir()).unwrap_or(false) {
            let name = e.file_name().to_string_lossy().into_owned();
            if !cameras.iter().any(|c| c.name == name) {
                return Err(CaptureError::Invalid(format!(
                    "{}: detections of camera {name:?}, which the calibration does not have \
                     (cameras: {})",
                    e.path().display(),
                    camera_names(cameras)
                )));
            }
        }
    }
    for cam in cameras {
        let d = dir.join(&cam.name);
        if !d.is_dir() {
            return Err(CaptureError::Invalid(format!(
                "{}: no detections of camera {:?} (expected the folder {})",
                dir.display(),
                cam.name,
                d.display()
            )));
        }
    }
    let mut out = Detections::default();
    for cam in cameras {
        let d = dir.join(&cam.name);
        let mut files: Vec<PathBuf> = std::fs::read_dir(&d)
            .map_err(|e| CaptureError::io(&d, e))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| {
                p.file_name()
                    .and_then(|n| n.to_str())
                    .is_some_and(|n| n.ends_with("_keypoints.json"))
            })
            .collect();
        files.sort();
        if files.is_empty() {
            return Err(CaptureError::Invalid(format!(
                "{}: no *_keypoints.json files",
                d.display()
            )));
        }
        let frames = files
            .par_iter()
            .map(|p| {
                read_openpose_2d(p, person).map_err(|e| CaptureError::format(p, e.to_string()))
            })
            .collect::<Result<Vec<_>>>()?;
        out.views.push(frames);
        out.dirs.push(d);
        out.files.push(files);
    }
    let n0 = out.frames(0);
    for (c, cam) in cameras.iter().enumerate() {
        if out.frames(c) != n0 {
            return Err(CaptureError::Invalid(format!(
                "{}: {} frames of camera {:?} but {n0} of camera {:?}: every camera needs the \
                 same frame count",
                dir.display(),
                out.frames(c),
                cam.name,
                cameras[0].name
            )));
        }
    }
    Ok(out)
}

fn camera_names(cameras: &[Camera]) -> String {
    cameras
        .iter()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

/// The offset estimate of one camera against the first.
#[derive(Debug, Clone, PartialEq)]
pub struct OffsetEstimate {
    /// The camera.
    pub camera: String,
    /// The chosen offset (frames; camera frame = common frame + offset).
    pub offset: i64,
    /// Median two-view reprojection error at the chosen offset, pixels.
    pub median_px: f64,
    /// Median at offset 0, pixels.
    pub median_px_at_zero: f64,
    /// Keypoint pairs scored at the chosen offset.
    pub pairs: usize,
}

/// Least detector confidence of a point used for synchronization.
const SYNC_MIN_CONFIDENCE: f64 = 0.5;

/// Estimates each camera's frame offset against camera 0 within `±max_offset` frames (see the
/// module doc). Camera 0's estimate is offset 0.
///
/// # Errors
/// Invalid cameras; fewer than two cameras; camera and detection counts that differ.
pub fn estimate_offsets(
    cameras: &[Camera],
    detections: &Detections,
    max_offset: usize,
) -> Result<Vec<OffsetEstimate>> {
    if cameras.len() < 2 || detections.views.len() != cameras.len() {
        return Err(CaptureError::Invalid(format!(
            "synchronization needs ≥ 2 cameras with detections ({} cameras, {} detection sets)",
            cameras.len(),
            detections.views.len()
        )));
    }
    for c in cameras {
        c.validate()?;
    }
    let opts = TriangulateOptions {
        threshold_px: 1e9,
        min_views: 2,
        refine_iterations: 3,
    };
    let score = |c: usize, d: i64| -> (f64, usize) {
        let mut errs = Vec::new();
        let n0 = detections.frames(0) as i64;
        let nc = detections.frames(c) as i64;
        for t in 0..n0 {
            let tc = t + d;
            if tc < 0 || tc >= nc {
                continue;
            }
            let (a, b) = (
                &detections.views[0][t as usize],
                &detections.views[c][tc as usize],
            );
            for (k, &(pa, ca)) in a.range(..FACE_OFFSET) {
                let Some(&(pb, cb)) = b.get(k) else { continue };
                if ca < SYNC_MIN_CONFIDENCE || cb < SYNC_MIN_CONFIDENCE {
                    continue;
                }
                let obs = [
                    Observation {
                        camera: 0,
                        pixel: pa,
                        confidence: 1.0,
                    },
                    Observation {
                        camera: c,
                        pixel: pb,
                        confidence: 1.0,
                    },
                ];
                if let Ok(Some(t)) = triangulate(cameras, &obs, &opts) {
                    errs.push(t.reprojection_px);
                }
            }
        }
        (median(&mut errs), errs.len())
    };
    let max = max_offset as i64;
    let mut out = vec![OffsetEstimate {
        camera: cameras[0].name.clone(),
        offset: 0,
        median_px: 0.0,
        median_px_at_zero: 0.0,
        pairs: 0,
    }];
    for (c, cam) in cameras.iter().enumerate().skip(1) {
        let scores: Vec<(i64, f64, usize)> = (-max..=max)
            .into_par_iter()
            .map(|d| {
                let (m, n) = score(c, d);
                (d, m, n)
            })
            .collect();
        let zero = scores.iter().find(|s| s.0 == 0).map_or(f64::NAN, |s| s.1);
        // Ties (and offsets with too few pairs to judge) resolve toward 0.
        let min_pairs = scores.iter().map(|s| s.2).max().unwrap_or(0) / 4;
        let best = scores
            .iter()
            .filter(|s| s.2 >= min_pairs.max(1) && s.1.is_finite())
            .min_by(|a, b| a.1.total_cmp(&b.1).then(a.0.abs().cmp(&b.0.abs())))
            .copied()
            .unwrap_or((0, zero, 0));
        out.push(OffsetEstimate {
            camera: cam.name.clone(),
            offset: best.0,
            median_px: best.1,
            median_px_at_zero: zero,
            pairs: best.2,
        });
    }
    Ok(out)
}

/// The common frames of `detections` under `offsets`: `t` such that every camera's frame
/// `t + offset[c]` exists; returns the range of `t` (may be empty).
pub fn common_frames(detections: &Detections, offsets: &[i64]) -> std::ops::Range<usize> {
    let lo = offsets.iter().map(|&o| (-o).max(0)).max().unwrap_or(0);
    let hi = (0..detections.views.len())
        .map(|c| detections.frames(c) as i64 - offsets.get(c).copied().unwrap_or(0))
        .min()
        .unwrap_or(0);
    (lo as usize)..(hi.max(lo) as usize)
}

/// The views of common frame `t` (see [`common_frames`]), with the cameras of `skip` left out
/// (their detections emptied, so camera indices keep their meaning).
pub fn views_at(
    detections: &Detections,
    offsets: &[i64],
    t: usize,
    skip: &[usize],
) -> Vec<Keypoints2d> {
    (0..detections.views.len())
        .map(|c| {
            if skip.contains(&c) {
                return Keypoints2d::new();
            }
            let f = t as i64 + offsets[c];
            detections.views[c]
                .get(f as usize)
                .cloned()
                .unwrap_or_default()
        })
        .collect()
}

/// Triangulates every common frame (in parallel), leaving the cameras of `skip` out.
///
/// # Errors
/// The errors of [`triangulate_frame`], naming the frame.
pub fn triangulate_sequence(
    cameras: &[Camera],
    detections: &Detections,
    offsets: &[i64],
    skip: &[usize],
    options: &TriangulateOptions,
) -> Result<Vec<TriangulatedFrame>> {
    common_frames(detections, offsets)
        .into_par_iter()
        .map(|t| {
            triangulate_frame(cameras, &views_at(detections, offsets, t, skip), options).map_err(
                |e| match e {
                    CaptureError::Invalid(w) => CaptureError::Invalid(format!("frame {t}: {w}")),
                    other => other,
                },
            )
        })
        .collect()
}

/// The Gaussian's standard deviation (frames) whose −3 dB cutoff is `cutoff_hz` at `fps`:
/// the response `exp(−(2π f σ_t)²/2)` is `1/√2` at `f = √(ln 2)/(2π σ_t)`.
pub fn gaussian_sigma_frames(cutoff_hz: f64, fps: f64) -> f64 {
    (2f64.ln()).sqrt() / (2.0 * std::f64::consts::PI * cutoff_hz) * fps
}

/// Least outlier distance of [`smooth_keypoints`]'s Hampel test, metres.
pub const HAMPEL_MIN_M: f64 = 0.03;

/// Zero-phase temporal smoothing of the triangulated keypoints, robust to isolated wrong
/// triangulations: first a Hampel test per keypoint — a sample farther than
/// `max(3 · 1.4826 · MAD, HAMPEL_MIN_M)` from the coordinate-wise median of the samples within
/// `±max(3σ, 3)` frames is an outlier and dropped — then each trajectory is convolved with a
/// Gaussian of `sigma_frames` (truncated at 3σ) over the kept samples, normalized over them.
/// Frames whose sample was dropped get the average of their kept neighbours (or lose the point
/// when there are none); a point absent in a frame stays absent. `sigma_frames ≤ 0` leaves the
/// frames unchanged.
pub fn smooth_keypoints(frames: &[TriangulatedFrame], sigma_frames: f64) -> Vec<TriangulatedFrame> {
    let mut out = frames.to_vec();
    if sigma_frames.is_nan() || sigma_frames <= 0.0 {
        return out;
    }
    let r = (3.0 * sigma_frames).ceil() as i64;
    let rh = r.max(3);
    let w: Vec<f64> = (-r..=r)
        .map(|d| (-0.5 * (d as f64 / sigma_frames).powi(2)).exp())
        .collect();
    let n = frames.len() as i64;
    let sample = |s: i64, k: usize| -> Option<V3> {
        if s < 0 || s >= n {
            return None;
        }
        frames[s as usize].keypoints.points.get(&k).copied()
    };
    // Hampel: which samples are kept.
    let mut kept: Vec<BTreeMap<usize, bool>> = vec![BTreeMap::new(); frames.len()];
    for (t, f) in frames.iter().enumerate() {
        for (&k, &p) in &f.keypoints.points {
            let near: Vec<V3> = (-rh..=rh).filter_map(|d| sample(t as i64 + d, k)).collect();
            let mut med = [0.0; 3];
            for (j, m) in med.iter_mut().enumerate() {
                let mut c: Vec<f64> = near.iter().map(|q| q[j]).collect();
                *m = median(&mut c);
            }
            let dist = |q: V3| {
                ((q[0] - med[0]).powi(2) + (q[1] - med[1]).powi(2) + (q[2] - med[2]).powi(2)).sqrt()
            };
            let mut dev: Vec<f64> = near.iter().map(|&q| dist(q)).collect();
            let mad = median(&mut dev);
            let thr = (3.0 * 1.4826 * mad).max(HAMPEL_MIN_M);
            kept[t].insert(k, dist(p) <= thr);
        }
    }
    for (t, o) in out.iter_mut().enumerate() {
        let mut lost = Vec::new();
        for (k, p) in o.keypoints.points.iter_mut() {
            let (mut acc, mut sw) = ([0.0; 3], 0.0);
            for (i, d) in (-r..=r).enumerate() {
                let s = t as i64 + d;
                let Some(q) = sample(s, *k) else { continue };
                if !kept[s as usize].get(k).copied().unwrap_or(false) {
                    continue;
                }
                for j in 0..3 {
                    acc[j] += w[i] * q[j];
                }
                sw += w[i];
            }
            if sw > 0.0 {
                *p = [acc[0] / sw, acc[1] / sw, acc[2] / sw];
            } else {
                lost.push(*k);
            }
        }
        for k in lost {
            o.keypoints.points.remove(&k);
            o.keypoints.weights.remove(&k);
        }
    }
    out
}

/// How often camera `c` agrees with the triangulation of all cameras: the fraction of common
/// frames in which it is an inlier for at least half of its confidently detected (≥ 0.5) body
/// and foot keypoints that were triangulated. A camera that follows another person than the
/// others scores near 0. `frames` are [`triangulate_sequence`]'s (common frames in order, no
/// camera left out).
pub fn camera_agreement(
    frames: &[TriangulatedFrame],
    detections: &Detections,
    offsets: &[i64],
    c: usize,
) -> f64 {
    let range = common_frames(detections, offsets);
    let (mut agree, mut judged) = (0usize, 0usize);
    for (i, t) in range.enumerate() {
        let Some(frame) = frames.get(i) else { break };
        let f = (t as i64 + offsets[c]) as usize;
        let Some(det) = detections.views[c].get(f) else {
            continue;
        };
        let (mut used, mut seen) = (0usize, 0usize);
        for (k, (_, conf)) in det.range(..FACE_OFFSET) {
            let Some(tri) = frame.details.get(k) else {
                continue;
            };
            if *conf < 0.5 {
                continue;
            }
            seen += 1;
            used += usize::from(tri.views.contains(&c));
        }
        if seen >= 4 {
            judged += 1;
            agree += usize::from(2 * used >= seen);
        }
    }
    if judged == 0 {
        f64::NAN
    } else {
        agree as f64 / judged as f64
    }
}

/// Per camera and camera frame, the bounding box (pixels `[x0, y0, x1, y1]`) of the
/// projection of `frames`' body and foot keypoints (common frame `t` ↦ camera frame
/// `t + offset`): where a detector should look for the person the other cameras agree on.
pub fn person_boxes(
    camera: &Camera,
    frames: &[TriangulatedFrame],
    first_frame: usize,
    offset: i64,
) -> BTreeMap<usize, [f64; 4]> {
    let mut out = BTreeMap::new();
    for (i, f) in frames.iter().enumerate() {
        let pts: Vec<[f64; 2]> = f
            .keypoints
            .points
            .range(..FACE_OFFSET)
            .filter_map(|(_, &p)| camera.project(p))
            .collect();
        if pts.len() < 4 {
            continue;
        }
        let b = pts.iter().fold(
            [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ],
            |b, p| {
                [
                    b[0].min(p[0]),
                    b[1].min(p[1]),
                    b[2].max(p[0]),
                    b[3].max(p[1]),
                ]
            },
        );
        let t = (first_frame + i) as i64 + offset;
        if t >= 0 {
            out.insert(t as usize, b);
        }
    }
    out
}

/// Per-keypoint statistics of a triangulated sequence: TC-133 index → (frames triangulated,
/// median reprojection error in pixels).
pub fn triangulation_stats(frames: &[TriangulatedFrame]) -> BTreeMap<usize, (usize, f64)> {
    let mut per: BTreeMap<usize, Vec<f64>> = BTreeMap::new();
    for f in frames {
        for (&k, t) in &f.details {
            per.entry(k).or_default().push(t.reprojection_px);
        }
    }
    per.into_iter()
        .map(|(k, mut v)| (k, (v.len(), median(&mut v))))
        .collect()
}

/// The keypoints of a triangulated sequence as fit targets, one [`KeypointsFile`] per frame.
pub fn targets(frames: &[TriangulatedFrame]) -> Vec<KeypointsFile> {
    frames.iter().map(|f| f.keypoints.clone()).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::look_at;

    fn rig() -> Vec<Camera> {
        (0..4)
            .map(|i| {
                let a = i as f64 * std::f64::consts::FRAC_PI_2;
                let c = [3.0 * a.cos(), 3.0 * a.sin(), 1.2];
                let r = look_at(c, [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]);
                let t = panoman_mesh::geom::matvec(&r, c);
                Camera::pinhole(
                    format!("cam{i}"),
                    1000.0,
                    1000.0,
                    540.0,
                    960.0,
                    r,
                    [-t[0], -t[1], -t[2]],
                    Some([1080, 1920]),
                )
            })
            .collect()
    }

    /// A moving body: 21 points on a helix that turns over time (so that frames differ).
    fn scene(t: usize) -> Vec<[f64; 3]> {
        (0..21)
            .map(|k| {
                let s = 0.3 * k as f64 + 0.15 * t as f64;
                [0.3 * s.cos(), 0.3 * s.sin(), 0.1 + 0.08 * k as f64]
            })
            .collect()
    }

    fn detections(cams: &[Camera], offsets: &[i64], n: usize) -> Detections {
        let mut d = Detections::default();
        for (c, cam) in cams.iter().enumerate() {
            let frames = (0..n)
                .map(|f| {
                    let t = f as i64 - offsets[c];
                    let mut kp = Keypoints2d::new();
                    if t >= 0 {
                        for (k, x) in scene(t as usize).into_iter().enumerate() {
                            kp.insert(k, (cam.project(x).unwrap(), 0.9));
                        }
                    }
                    kp
                })
                .collect();
            d.views.push(frames);
            d.dirs.push(PathBuf::from(&cam.name));
        }
        d
    }

    #[test]
    fn offsets_are_recovered_and_the_aligned_sequence_triangulates_exactly() {
        let cams = rig();
        let truth = [0, 3, -2, 1];
        let det = detections(&cams, &truth, 40);
        let est = estimate_offsets(&cams, &det, 6).unwrap();
        let got: Vec<i64> = est.iter().map(|e| e.offset).collect();
        assert_eq!(got, truth);
        assert!(
            est[1].median_px < 1e-6 && est[1].median_px_at_zero > 1.0,
            "{est:?}"
        );
        let range = common_frames(&det, &got);
        assert_eq!(range, 2..37);
        let frames =
            triangulate_sequence(&cams, &det, &got, &[], &TriangulateOptions::default()).unwrap();
        assert_eq!(frames.len(), 35);
        for (i, f) in frames.iter().enumerate() {
            let t = range.start + i;
            for (k, x) in scene(t).into_iter().enumerate() {
                let p = f.keypoints.points[&k];
                let e = panoman_mesh::geom::norm(panoman_mesh::geom::sub(p, x));
                assert!(e < 1e-9, "frame {t} keypoint {k}: {e}");
            }
        }
        // Leaving a camera out keeps the others' indices.
        let three =
            triangulate_sequence(&cams, &det, &got, &[2], &TriangulateOptions::default()).unwrap();
        assert!(three[0].details[&0].views.iter().all(|&v| v != 2));
    }

    #[test]
    fn a_camera_that_follows_another_person_disagrees_and_gets_the_others_boxes() {
        let cams = rig();
        let mut det = detections(&cams, &[0, 0, 0, 0], 12);
        // Camera 3 sees someone 1 m to the side.
        for f in 0..12 {
            let mut kp = Keypoints2d::new();
            for (k, x) in scene(f).into_iter().enumerate() {
                kp.insert(k, (cams[3].project([x[0] + 1.0, x[1], x[2]]).unwrap(), 0.9));
            }
            det.views[3][f] = kp;
        }
        let offsets = [0, 0, 0, 0];
        let tri = triangulate_sequence(&cams, &det, &offsets, &[], &TriangulateOptions::default())
            .unwrap();
        let g: Vec<f64> = (0..4)
            .map(|c| camera_agreement(&tri, &det, &offsets, c))
            .collect();
        assert_eq!(g, vec![1.0, 1.0, 1.0, 0.0]);
        // The others' person projected into camera 3: the box holds the true person's points.
        let others =
            triangulate_sequence(&cams, &det, &offsets, &[3], &TriangulateOptions::default())
                .unwrap();
        let boxes = person_boxes(&cams[3], &others, 0, 0);
        assert_eq!(boxes.len(), 12);
        for (f, b) in &boxes {
            for x in scene(*f) {
                let p = cams[3].project(x).unwrap();
                assert!(
                    p[0] >= b[0] - 1e-6
                        && p[0] <= b[2] + 1e-6
                        && p[1] >= b[1] - 1e-6
                        && p[1] <= b[3] + 1e-6
                );
            }
        }
    }

    #[test]
    fn smoothing_keeps_a_line_and_damps_alternating_noise() {
        let mk = |x: f64| {
            let mut f = TriangulatedFrame {
                keypoints: KeypointsFile::default(),
                details: BTreeMap::new(),
                rejected: Vec::new(),
            };
            f.keypoints.points.insert(0, [x, 0.0, 0.0]);
            f
        };
        // A uniform motion is unchanged inside (zero phase, weights sum to one).
        let line: Vec<_> = (0..20).map(|t| mk(0.01 * t as f64)).collect();
        let s = smooth_keypoints(&line, 1.5);
        for (t, f) in s.iter().enumerate().take(15).skip(5) {
            assert!((f.keypoints.points[&0][0] - 0.01 * t as f64).abs() < 1e-12);
        }
        // ±1 mm alternating noise (the Nyquist frequency) is damped below 1 µm at σ = 1.5.
        let noise: Vec<_> = (0..20)
            .map(|t| mk(if t % 2 == 0 { 1e-3 } else { -1e-3 }))
            .collect();
        let s = smooth_keypoints(&noise, 1.5);
        assert!(s[10].keypoints.points[&0][0].abs() < 1e-6);
        // One wrong triangulation 20 cm off is dropped: its frame gets its neighbours' mean
        // and theirs stay on the line (dropping one sample of the window shifts a window's
        // mean by w_d · d · slope / (Σw − w_d), largest at d = 1: 0.80 · 0.01 / 2.96 ≈ 2.7 mm
        // at σ = 1.5; kept, the outlier would move its neighbour by 0.80 · 0.2 / 3.76 ≈ 4 cm).
        let mut jump: Vec<_> = (0..20).map(|t| mk(0.01 * t as f64)).collect();
        jump[10].keypoints.points.insert(0, [0.3, 0.0, 0.0]);
        let s = smooth_keypoints(&jump, 1.5);
        for (t, f) in s.iter().enumerate().take(15).skip(5) {
            assert!(
                (f.keypoints.points[&0][0] - 0.01 * t as f64).abs() < 2.8e-3,
                "frame {t}"
            );
        }
        // 6 Hz at 60 fps: σ ≈ 1.32 frames.
        assert!((gaussian_sigma_frames(6.0, 60.0) - 1.325).abs() < 0.01);
    }

    #[test]
    fn a_missing_camera_folder_and_an_unknown_one_are_named() {
        let dir = std::env::temp_dir().join(format!("panoman-seq-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let cams = rig();
        for c in &cams[..3] {
            std::fs::create_dir_all(dir.join(&c.name)).unwrap();
        }
        let e = read_detections_dir(&dir, &cams, 0).unwrap_err().to_string();
        assert!(e.contains("no detections of camera \"cam3\""), "{e}");
        std::fs::create_dir_all(dir.join("cam9")).unwrap();
        let e = read_detections_dir(&dir, &cams, 0).unwrap_err().to_string();
        assert!(e.contains("\"cam9\"") && e.contains("does not have"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
