//! Calibration of the identity from several frames of keypoints: limb and trunk lengths.
//!
//! The IK fits six phenotype values per solve ([`crate::ik::IK_PHENOTYPE`]); they set a body's
//! build but not its limb lengths one by one, so a person whose forearms are long for their
//! height is fitted with the wrong joints in every frame. MoSh calibrates shape once from a
//! set of frames spread over a capture; this module does that for keypoint sequences, with
//! the generator's own length controls (local changes, [`LENGTH_KNOBS`]) as the shape:
//!
//! 1. every calibration frame is fitted cold by [`crate::pipeline::ik_fit`] with the base
//!    shape;
//! 2. with the poses (and each frame's phenotype) held, the knob values `v` minimise
//!    `Σ_frames Σ_(a,b) w_ab (|K_a − K_b|(v, θ_f) − |k̂_a − k̂_b|)² + λ_v Σ_j (v_j − v̄_j)²`
//!    over the [`SEGMENTS`] (keypoint pairs on one bone chain segment: upper arm, forearm,
//!    thigh, shank, shoulder and hip width, torso; `K` the keypoints of the posed generator
//!    mesh, `k̂` the given ones, metres) by Levenberg–Marquardt with forward differences
//!    ([`fit_knobs`]). Distances, not positions: with the poses held, a position residual
//!    would resist a length change that the IK's pose had compensated (a bent elbow reaching
//!    with a short forearm), and the alternation would crawl (measured: 8 rounds recover a
//!    fifth of the forearm's change); a segment's length is the same in any pose;
//! 3. every frame is solved again, warm, with the knobs fixed in the IK's template; steps
//!    2–3 repeat ([`ShapeCalibrationOptions::rounds`]).
//!
//! The result is a template shape ([`ShapeCalibration::shape`]: the knobs, and the frames'
//! mean phenotype) for the sequence's IK ([`crate::ik::IkConfig::initial_shape`]); the
//! `panoman` tracker holds it whole, the phenotype included (`fit_phenotype` off).

use std::time::Instant;

use panoman_human::keypoints::keypoint_index;
use panoman_human::params::ShapeParams;
use panoman_mesh::geom::{V3, norm, sub};
use rayon::prelude::*;

use crate::error::{FitError, Result};
use crate::fit::Constraints;
use crate::ik::{IK_PHENOTYPE, IkConfig, IkResult, IkSolver};
use crate::pipeline::ik_fit;

/// One shape value of the generator fitted as a whole: a phenotype value, or local changes
/// that share one value.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShapeKnob {
    /// A phenotype value (in [0, 1]) by name, e.g. `proportions`.
    Phenotype(&'static str),
    /// Local changes (each in [−1, 1]) that share one value, e.g. both feet.
    Changes(&'static [&'static str]),
}

impl ShapeKnob {
    /// The knob's range: `[0, 1]` for a phenotype value, `[−1, 1]` for local changes.
    pub fn bounds(self) -> (f64, f64) {
        match self {
            ShapeKnob::Phenotype(_) => (0.0, 1.0),
            ShapeKnob::Changes(_) => (-1.0, 1.0),
        }
    }

    /// The knob's name: the phenotype value's, or the first local change's.
    pub fn name(self) -> &'static str {
        match self {
            ShapeKnob::Phenotype(n) => n,
            ShapeKnob::Changes(l) => l[0],
        }
    }

    /// The knob's value in `s` (a phenotype value absent from `s` reads ½, a local change
    /// absent reads 0; for shared changes the first one's).
    pub fn get(self, s: &ShapeParams) -> f64 {
        match self {
            ShapeKnob::Phenotype(n) => s.phenotype.get(n).unwrap_or(0.5),
            ShapeKnob::Changes(l) => s.local_changes.get(l[0]).copied().unwrap_or(0.0),
        }
    }

    /// Sets the knob to `v` in `s` (every local change of the knob).
    pub fn set(self, s: &mut ShapeParams, v: f64) {
        match self {
            ShapeKnob::Phenotype(n) => {
                if let Some(x) = s.phenotype.get_mut(n) {
                    *x = v;
                }
            }
            ShapeKnob::Changes(l) => {
                for label in l {
                    s.local_changes.insert((*label).to_string(), v);
                }
            }
        }
    }
}

/// The length controls of the generator that [`calibrate_shape`] fits by default: upper and
/// lower arm length, upper and lower leg length, shoulder distance, hip width, torso and hip
/// height, foot size (both feet one value). Each is a local change in [−1, 1]; the phenotype
/// is left to the IK.
pub const LENGTH_KNOBS: [ShapeKnob; 9] = [
    ShapeKnob::Changes(&["measure-upperarm-length-incr"]),
    ShapeKnob::Changes(&["measure-lowerarm-length-incr"]),
    ShapeKnob::Changes(&["measure-upperleg-height-incr"]),
    ShapeKnob::Changes(&["measure-lowerleg-height-incr"]),
    ShapeKnob::Changes(&["measure-shoulder-dist-incr"]),
    ShapeKnob::Changes(&["hip-scale-horiz-incr"]),
    ShapeKnob::Changes(&["torso-scale-vert-incr"]),
    ShapeKnob::Changes(&["hip-scale-vert-incr"]),
    ShapeKnob::Changes(&["l-foot-scale-incr", "r-foot-scale-incr"]),
];

/// `shape` with each of `knobs` set to its value in `v`.
pub fn with_knobs(shape: &ShapeParams, knobs: &[ShapeKnob], v: &[f64]) -> ShapeParams {
    let mut s = shape.clone();
    for (k, x) in knobs.iter().zip(v) {
        k.set(&mut s, *x);
    }
    s
}

/// The result of [`fit_knobs`].
#[derive(Clone, Debug)]
pub struct KnobFit {
    /// The knob values (within their bounds).
    pub values: Vec<f64>,
    /// The residual vector at `values`.
    pub residuals: Vec<f64>,
    /// Levenberg–Marquardt iterations taken.
    pub iterations: usize,
}

/// Minimises `|r(v)|²` over the knob values `v` (from `start`, each clamped to its
/// [`ShapeKnob::bounds`]) by Levenberg–Marquardt: forward-difference Jacobian (step 10⁻³,
/// backwards at an upper bound), damping `μ diag(JᵀJ)`, a step kept only if it lowers the
/// cost; at most `max_iterations` Jacobians. `residuals` evaluates `r`.
///
/// # Errors
/// The first error of `residuals`.
pub fn fit_knobs<E>(
    knobs: &[ShapeKnob],
    start: &[f64],
    max_iterations: usize,
    residuals: impl Fn(&[f64]) -> std::result::Result<Vec<f64>, E>,
) -> std::result::Result<KnobFit, E> {
    let n = knobs.len();
    let mut v: Vec<f64> = knobs
        .iter()
        .zip(start)
        .map(|(k, x)| x.clamp(k.bounds().0, k.bounds().1))
        .collect();
    let mut r = residuals(&v)?;
    let cost = |r: &[f64]| r.iter().map(|x| x * x).sum::<f64>();
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let (mut mu, mut iterations) = (1e-3, 0);
    for _ in 0..max_iterations {
        iterations += 1;
        let h = 1e-3;
        let mut jac = Vec::with_capacity(n);
        for (i, k) in knobs.iter().enumerate() {
            let (lo, hi) = k.bounds();
            let step = if v[i] + h > hi { -h } else { h };
            let mut w = v.clone();
            w[i] = (w[i] + step).clamp(lo, hi);
            let rw = residuals(&w)?;
            jac.push(
                rw.iter()
                    .zip(&r)
                    .map(|(a, b)| (a - b) / step)
                    .collect::<Vec<f64>>(),
            );
        }
        let jtj: Vec<Vec<f64>> = (0..n)
            .map(|i| (0..n).map(|j| dot(&jac[i], &jac[j])).collect())
            .collect();
        let jtr: Vec<f64> = (0..n).map(|i| -dot(&jac[i], &r)).collect();
        let mut improved = false;
        for _ in 0..8 {
            let mut a = jtj.clone();
            for (i, row) in a.iter_mut().enumerate() {
                row[i] += mu * (jtj[i][i] + 1e-12);
            }
            let Some(d) = solve_dense(a, jtr.clone()) else {
                break;
            };
            let w: Vec<f64> = knobs
                .iter()
                .zip(v.iter().zip(&d))
                .map(|(k, (x, dx))| (x + dx).clamp(k.bounds().0, k.bounds().1))
                .collect();
            let rw = residuals(&w)?;
            if cost(&rw) < cost(&r) {
                (v, r, improved) = (w, rw, true);
                mu = (mu / 3.0).max(1e-9);
                break;
            }
            mu *= 4.0;
        }
        if !improved {
            break;
        }
    }
    Ok(KnobFit {
        values: v,
        residuals: r,
        iterations,
    })
}

/// Solves the small dense system `a x = b` by Gaussian elimination with partial pivoting
/// (`None` if singular).
fn solve_dense(mut a: Vec<Vec<f64>>, mut b: Vec<f64>) -> Option<Vec<f64>> {
    let n = b.len();
    for c in 0..n {
        let p = (c..n).max_by(|&i, &j| a[i][c].abs().total_cmp(&a[j][c].abs()))?;
        if a[p][c].abs() < 1e-300 {
            return None;
        }
        a.swap(c, p);
        b.swap(c, p);
        for r in c + 1..n {
            let f = a[r][c] / a[c][c];
            let (top, bottom) = a.split_at_mut(r);
            for (x, y) in bottom[0][c..].iter_mut().zip(&top[c][c..]) {
                *x -= f * y;
            }
            b[r] -= f * b[c];
        }
    }
    let mut x = vec![0.0; n];
    for r in (0..n).rev() {
        let s: f64 = (r + 1..n).map(|k| a[r][k] * x[k]).sum();
        x[r] = (b[r] - s) / a[r][r];
    }
    Some(x)
}

/// `n` frame indices spread evenly over `len` frames (`⌊i·len/n⌋`, the first one 0; all
/// of them when `n ≥ len`): the calibration frames of a sequence.
pub fn spread_frames(len: usize, n: usize) -> Vec<usize> {
    let n = n.min(len);
    (0..n).map(|i| i * len / n).collect()
}

/// Settings of [`calibrate_shape`].
#[derive(Clone, Debug, PartialEq)]
pub struct ShapeCalibrationOptions {
    /// The shape values fitted (default [`LENGTH_KNOBS`]).
    pub knobs: Vec<ShapeKnob>,
    /// Knob fits, each followed by the frames' IK solved again (default 3).
    pub rounds: usize,
    /// Levenberg–Marquardt iterations of each knob fit (default 8).
    pub iterations: usize,
    /// `√λ_v` per frame (metres per knob unit): a knob moved by 1 from the base costs as much
    /// as this distance on one keypoint of every frame (default 0.005). Keeps a knob that
    /// the targets do not see (foot size without foot points) at its base value.
    pub knob_prior_m: f64,
}

impl Default for ShapeCalibrationOptions {
    fn default() -> Self {
        ShapeCalibrationOptions {
            knobs: LENGTH_KNOBS.to_vec(),
            rounds: 3,
            iterations: 8,
            knob_prior_m: 0.005,
        }
    }
}

/// The result of [`calibrate_shape`].
#[derive(Clone, Debug)]
pub struct ShapeCalibration {
    /// The template shape for the sequence's IK ([`IkConfig::initial_shape`]): the base
    /// with the fitted knobs, the six IK phenotype values at the frames' mean.
    pub shape: ShapeParams,
    /// The knobs fitted (in [`ShapeCalibrationOptions::knobs`] order) with their values.
    pub knobs: Vec<(ShapeKnob, f64)>,
    /// The calibration frames' IK results with that shape.
    pub frames: Vec<IkResult>,
    /// Mean distance of the given keypoints and handles from the model's, over the
    /// calibration frames, with the base shape (mm).
    pub before_mm: f64,
    /// The same with the calibrated shape (mm).
    pub after_mm: f64,
    /// Levenberg–Marquardt iterations of the knob fits, all rounds.
    pub iterations: usize,
    /// Wall time (s).
    pub seconds: f64,
}

/// Calibrates the identity's lengths from `frames` (module docs): the knobs of `opts` on top
/// of `base`, with the IK settings `cfg` (its `initial_shape` and `initial_state` are
/// replaced). Frames are solved in parallel.
///
/// # Errors
/// [`FitError::Invalid`] for no frames, a frame without keypoints (naming it) or knob values
/// of `base` outside their bounds; IK and generator errors.
pub fn calibrate_shape(
    ik: &IkSolver,
    frames: &[Constraints],
    base: &ShapeParams,
    cfg: &IkConfig,
    opts: &ShapeCalibrationOptions,
) -> Result<ShapeCalibration> {
    let t0 = Instant::now();
    if frames.is_empty() {
        return Err(FitError::Invalid(
            "shape calibration: no frames given".into(),
        ));
    }
    if let Some(i) = frames
        .iter()
        .position(|c| c.targets.keypoints.points.is_empty())
    {
        return Err(FitError::Invalid(format!(
            "shape calibration: frame {i} has no keypoints"
        )));
    }
    let knobs = &opts.knobs;
    let v0: Vec<f64> = knobs.iter().map(|k| k.get(base)).collect();
    for (k, x) in knobs.iter().zip(&v0) {
        let (lo, hi) = k.bounds();
        if !(lo..=hi).contains(x) {
            return Err(FitError::Invalid(format!(
                "shape calibration: the base value {x} of {k:?} is outside [{lo}, {hi}]"
            )));
        }
    }
    let solve_all = |template: &ShapeParams, warm: Option<&[IkResult]>| -> Result<Vec<IkResult>> {
        frames
            .par_iter()
            .enumerate()
            .map(|(i, c)| {
                let cfg = IkConfig {
                    initial_shape: Some(template.clone()),
                    initial_state: warm.map(|w| w[i].state.clone()),
                    ..cfg.clone()
                };
                ik_fit(ik, c, &cfg)
            })
            .collect()
    };
    let mut template = base.clone();
    let mut solved = solve_all(&template, None)?;
    let before_mm = mean_error_mm(ik, frames, &solved)?;
    let mut v = v0.clone();
    let mut iterations = 0;
    let prior = opts.knob_prior_m * (frames.len() as f64).sqrt();
    let segs = segments(frames);
    for _ in 0..opts.rounds.max(1) {
        let mean_phen = mean_phenotype(&solved);
        let residuals = |v: &[f64]| -> Result<Vec<f64>> {
            let t = with_knobs(&template, knobs, v);
            let per: Vec<Vec<f64>> = frames
                .par_iter()
                .zip(&solved)
                .map(|(c, r)| frame_residuals(ik, c, r, &t, &segs))
                .collect::<Result<_>>()?;
            let mut out: Vec<f64> = per.concat();
            out.extend(v.iter().zip(&v0).map(|(x, b)| prior * (x - b)));
            Ok(out)
        };
        let fit = fit_knobs(knobs, &v, opts.iterations, residuals)?;
        iterations += fit.iterations;
        v = fit.values;
        template = with_knobs(&template, knobs, &v);
        for (name, x) in IK_PHENOTYPE.iter().zip(mean_phen) {
            if let Some(slot) = template.phenotype.get_mut(name) {
                *slot = x;
            }
        }
        solved = solve_all(&template, Some(&solved))?;
    }
    let after_mm = mean_error_mm(ik, frames, &solved)?;
    Ok(ShapeCalibration {
        shape: template,
        knobs: knobs.iter().copied().zip(v).collect(),
        frames: solved,
        before_mm,
        after_mm,
        iterations,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// The mean of the six IK phenotype values over `solved`.
fn mean_phenotype(solved: &[IkResult]) -> [f64; 6] {
    let n = solved.len() as f64;
    let mut m = [0.0; 6];
    for r in solved {
        for (a, b) in m.iter_mut().zip(r.state.phenotype) {
            *a += b / n;
        }
    }
    m
}

/// Keypoint pairs whose distance is a segment length of the skeleton (TC-133 names): upper
/// arms, forearms, thighs, shanks, shoulder and hip width, the torso (neck to body centre,
/// shoulder to hip), the pelvis (body centre to hip) and the feet (ankle to heel, heel to big
/// toe). A pose moves them only by the skin's deformation near the joints (and the toes'
/// bend), so their distances measure the lengths whatever pose the IK found for the frame.
pub const SEGMENTS: [(&str, &str); 19] = [
    ("l_shoulder", "l_elbow"),
    ("r_shoulder", "r_elbow"),
    ("l_elbow", "l_wrist"),
    ("r_elbow", "r_wrist"),
    ("l_hip", "l_knee"),
    ("r_hip", "r_knee"),
    ("l_knee", "l_ankle"),
    ("r_knee", "r_ankle"),
    ("l_shoulder", "r_shoulder"),
    ("l_hip", "r_hip"),
    ("neck", "body_center"),
    ("l_shoulder", "l_hip"),
    ("r_shoulder", "r_hip"),
    ("body_center", "l_hip"),
    ("body_center", "r_hip"),
    ("l_ankle", "l_heel"),
    ("r_ankle", "r_heel"),
    ("l_heel", "l_big_toe"),
    ("r_heel", "r_big_toe"),
];

/// One end of a segment: a keypoint (TC-133 index) or a vertex handle's vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum End {
    Keypoint(usize),
    Vertex(u32),
}

/// Largest relative spread (standard deviation / mean) of a handle pair's given distance
/// over the calibration frames for the pair to count as one rigid segment.
const RIGID_SPREAD: f64 = 0.01;

/// Longest handle pair (m) that counts as a segment.
const RIGID_MAX_M: f64 = 0.35;

/// The segments of `frames`: [`SEGMENTS`], and with two or more frames the pairs of a vertex
/// handle with another handle or a body keypoint whose given distance is under
/// [`RIGID_MAX_M`] and varies by less than [`RIGID_SPREAD`] over the frames (rigidly
/// connected: heel and big toe of a foot, heel and ankle), when both ends are given in every
/// frame.
fn segments(frames: &[Constraints]) -> Vec<(End, End)> {
    let mut out: Vec<(End, End)> = SEGMENTS
        .iter()
        .filter_map(|(a, b)| {
            Some((
                End::Keypoint(keypoint_index(a)?),
                End::Keypoint(keypoint_index(b)?),
            ))
        })
        .collect();
    if frames.len() < 2 {
        return out;
    }
    let vertices: Vec<u32> = frames[0]
        .targets
        .handles
        .iter()
        .map(|h| h.vertex)
        .filter(|v| {
            frames
                .iter()
                .all(|c| c.targets.handles.iter().any(|h| h.vertex == *v))
        })
        .collect();
    let body: Vec<End> = panoman_human::keypoints::BODY_NAMES
        .iter()
        .filter_map(|n| keypoint_index(n))
        .filter(|i| {
            frames
                .iter()
                .all(|c| c.targets.keypoints.points.contains_key(i))
        })
        .map(End::Keypoint)
        .collect();
    for (i, &v) in vertices.iter().enumerate() {
        let others = vertices[i + 1..]
            .iter()
            .map(|&w| End::Vertex(w))
            .chain(body.iter().copied());
        for other in others {
            let d: Vec<f64> = frames
                .iter()
                .filter_map(|c| Some(norm(sub(given(c, End::Vertex(v))?.0, given(c, other)?.0))))
                .collect();
            let n = d.len() as f64;
            let mean = d.iter().sum::<f64>() / n;
            let sd = (d.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n).sqrt();
            if mean < RIGID_MAX_M && sd < RIGID_SPREAD * mean {
                out.push((End::Vertex(v), other));
            }
        }
    }
    out
}

/// The given position and weight of `e` in `c` (`None` if not given).
fn given(c: &Constraints, e: End) -> Option<(V3, f64)> {
    match e {
        End::Keypoint(i) => c
            .targets
            .keypoints
            .points
            .get(&i)
            .map(|p| (*p, c.targets.keypoints.weight(i))),
        End::Vertex(v) => c
            .targets
            .handles
            .iter()
            .find(|h| h.vertex == v)
            .map(|h| (h.position, h.weight)),
    }
}

/// The segment residuals `√w (|M_a − M_b| − |p̂_a − p̂_b|)` (`segs` given in `c`,
/// `w = min(w_a, w_b)`, `M` the model's keypoint or vertex) of one frame on the generator
/// mesh of `r`'s pose and phenotype with the template `t`.
fn frame_residuals(
    ik: &IkSolver,
    c: &Constraints,
    r: &IkResult,
    t: &ShapeParams,
    segs: &[(End, End)],
) -> Result<Vec<f64>> {
    let mesh = ik.posed_mesh(&ik.params(&r.state, t))?;
    let k = ik.keypoints_on(&mesh)?;
    let model = |e: End| match e {
        End::Keypoint(i) => k.get(i).copied().flatten(),
        End::Vertex(v) => mesh.get(v as usize).copied(),
    };
    let mut out = Vec::with_capacity(segs.len());
    for &(a, b) in segs {
        if let (Some((pa, wa)), Some((pb, wb)), Some(ma), Some(mb)) =
            (given(c, a), given(c, b), model(a), model(b))
        {
            let w = wa.min(wb);
            if w > 0.0 {
                out.push(w.sqrt() * (norm(sub(ma, mb)) - norm(sub(pa, pb))));
            }
        }
    }
    Ok(out)
}

/// Per given keypoint and handle of `c` with a positive weight: (model − target, weight) on
/// `mesh`.
fn frame_offsets(ik: &IkSolver, c: &Constraints, mesh: &[V3]) -> Result<Vec<(V3, f64)>> {
    let k = ik.keypoints_on(mesh)?;
    let mut out = Vec::new();
    for (&i, &p) in &c.targets.keypoints.points {
        let w = c.targets.keypoints.weights.get(&i).copied().unwrap_or(1.0);
        if let Some(Some(m)) = k.get(i)
            && w > 0.0
        {
            out.push((sub(*m, p), w));
        }
    }
    for h in &c.targets.handles {
        let Some(&m) = mesh.get(h.vertex as usize) else {
            return Err(FitError::Invalid(format!(
                "shape calibration: handle vertex {} is not on the mesh ({} vertices)",
                h.vertex,
                mesh.len()
            )));
        };
        if h.weight > 0.0 {
            out.push((sub(m, h.position), h.weight));
        }
    }
    Ok(out)
}

/// Mean distance (mm) of the targets of `frames` from the posed meshes of `solved`.
fn mean_error_mm(ik: &IkSolver, frames: &[Constraints], solved: &[IkResult]) -> Result<f64> {
    let (mut sum, mut n) = (0.0, 0usize);
    for (c, r) in frames.iter().zip(solved) {
        for (d, _) in frame_offsets(ik, c, &r.posed)? {
            sum += norm(d);
            n += 1;
        }
    }
    Ok(if n == 0 {
        f64::NAN
    } else {
        1e3 * sum / n as f64
    })
}
