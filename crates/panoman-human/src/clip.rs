//! A smooth synthetic motion clip: one person moving body, face and hands together, for the
//! evaluation's held-out motion sequence ("a smooth synthetic clip of ≥ 60 frames combining
//! body motion, expressions and gestures").
//!
//! # Drawing
//! [`Clip::generate`] draws, from [`stream_rng`] keyed by the clip's own domains (so the clip
//! never shares a random stream with a dataset identity or row of the same seed):
//!
//! * one identity by [`IdentitySampler`] from `stream_rng(seed, DOMAIN_CLIP_IDENTITY, 0)`;
//! * `K` keyframes, keyframe `k` from `stream_rng(seed, DOMAIN_CLIP_KEYFRAME, k)`, in this
//!   order: a body pose ([`BodyPoseSampler`]: the 33 body bones, relaxed hands, face bones at
//!   rest), a gesture of both hands ([`HandSampler::sample_into`]: overwrites exactly the
//!   2 × 19 hand slots, so the relaxed hands of the body draw are replaced and no body bone
//!   is touched), then an expression ([`ExpressionSampler`]: the 52 face units, and the
//!   jaw/eye slots through [`Expression::write_theta`], which the body and hand samplers
//!   leave at rest). The three samplers therefore write disjoint slots.
//!
//! # Interpolation
//! Keyframe `k` sits at frame `t_k = k·h`, `h = (N − 1)/(K − 1)`, so frame 0 is keyframe 0
//! and frame `N − 1` the last keyframe. Every scalar channel `y` (each bone's Euler angles
//! `x, y, z` in degrees, each face unit) is interpolated in the keyframe coordinate
//! `u = f/h ∈ [0, K − 1]` by a monotone piecewise-cubic Hermite curve ([`MonotoneCubic`]):
//! on `[k, k + 1]` with `s = u − k`,
//!
//! `p(u) = h₀₀(s)·y_k + h₁₀(s)·m_k + h₀₁(s)·y_{k+1} + h₁₁(s)·m_{k+1}`,
//! `h₀₀ = 2s³ − 3s² + 1`, `h₁₀ = s³ − 2s² + s`, `h₀₁ = −2s³ + 3s²`, `h₁₁ = s³ − s²`,
//!
//! with the Fritsch–Butland tangents `m_k = 2 δ_{k−1} δ_k / (δ_{k−1} + δ_k)` when the secants
//! `δ_k = y_{k+1} − y_k` have the same sign, else `m_k = 0`, and `m_0 = m_{K−1} = 0` (the clip
//! starts and ends at rest velocity). Properties used by the tests:
//!
//! * **C¹**: `p` interpolates the keyframes and its derivative `m_k` is shared by the two
//!   segments that meet at a keyframe; the second derivative jumps there (bounded).
//! * **No overshoot**: the harmonic mean gives `0 ≤ m_k/δ ≤ 2` for both end tangents of a
//!   segment, inside the Fritsch–Carlson monotonicity region (`α² + β² ≤ 9`), so `p` is
//!   monotone on each segment and stays between `y_k` and `y_{k+1}`. Bone ranges are boxes
//!   and face units live in `[0, 1]`, so every frame is inside [`bone_range`] and `[0, 1]`
//!   without clamping (a final clamp only absorbs rounding).
//! * **Bounded speed and acceleration**: with `α, β ∈ [0, 2]`, `|dp/ds| ≤ 2|δ_k|` and
//!   `|d²p/ds²| ≤ 6|δ_k|`; per frame (`ds = 1/h`) a channel moves at most `2|δ_k|/h` and
//!   its second difference is at most `6 max|δ|/h²` (`O(1/h²)`, against `O(1/h)` at the
//!   kink of a C⁰ scheme such as linear interpolation).
//! * **Odd symmetry**: the tangents are odd in `y`, so interpolation commutes with the
//!   right-side mirror `(x, −y, −z)` of [`Theta`]: mirrored keyframes give mirrored frames.
//!
//! ## Why Euler angles are interpolated directly
//! Each angle channel is interpolated on its own rather than slerping rotations, because the
//! ranges are moderate and make this safe: every [`bone_range`] is a strict sub-interval of
//! `(−180°, 180°)` (at most `[−90°, 120°]`), so there is no `±360°` wrap-around to choose;
//! the middle (`y`) angle of `R = Rz(z)·Ry(y)·Rx(x)` stays within ±45°, far from the gimbal
//! singularity at `|y| = 90°`, so the map from angles to rotations is a smooth local
//! diffeomorphism with a bounded condition number there and a C¹ angle path is a C¹ rotation
//! path. Per-channel interpolation also keeps every frame inside the per-axis joint limits
//! (box ranges are convex), which slerp would not. The path is not the SO(3) geodesic
//! between keyframes, which is fine for a synthetic clip.
//!
//! ## Face-unit couplings kept along the clip
//! The expression sampler's rules hold for every frame, not only at keyframes:
//!
//! * *Exclusive pairs* ([`EXCLUSIVE_UNITS`]: jawLeft/jawRight, mouthLeft/mouthRight): the first
//!   keyframe that uses a pair fixes its side for the clip; a later keyframe drawing the other
//!   unit has its value moved to that side. So one unit of each pair is zero at every keyframe,
//!   its curve is identically zero, and the two are never active together.
//! * *mouthClose ≤ jawOpen*: the ratio `r = mouthClose/jawOpen` (0 where jawOpen = 0) is
//!   interpolated, then `mouthClose = r·jawOpen` (a product of C¹ curves, `r ∈ [0, 1]`).
//! * *Jaw bone x ≤ 22°·(1 − jawOpen)*: likewise through `q = x/(22°·(1 − jawOpen))`, then
//!   `x = 22°·q·(1 − jawOpen)`.
//!
//! Gaze may be drawn by the eye bones at one keyframe and by the `eyeLook*` units at the next;
//! between the two both are partially active (a continuous blend of two gazes).
//!
//! # Meshes
//! [`Clip::meshes`] builds the neutral identity (rest mesh), then per frame the identity with
//! the frame's face units added to its shape (face units are blendshapes of the rest mesh, as
//! on dataset expression rows), posed by the frame's theta (no root motion) and mapped to the
//! requested topology. Frames are independent and computed in parallel (rayon), so the output
//! is identical for any number of threads.

use panoman_mesh::geom::V3;
use rayon::prelude::*;

use crate::error::{HumanError, Result};
use crate::generator::Generator;
use crate::outputs::{OutputTopology, TopologyMap};
use crate::params::ShapeParams;
use crate::phenotype::face_unit_index;
use crate::sampling::{
    BodyPoseSampler, BoneMap, EXCLUSIVE_UNITS, ExpressionSampler, FACE_SLOT, HandSampler,
    IdentitySampler, N_POSABLE, SampledIdentity, Theta, stream_rng,
};
#[cfg(doc)]
use crate::sampling::{Expression, bone_range};

/// Domain of [`stream_rng`] for the clip's identity (index 0): `0x434c_0001` ("CL", 1).
/// The dataset uses domains 1–3 ([`crate::sampling::DOMAIN_IDENTITY`] …), the keypoint
/// regressors `0x4b50_000x` and the synth preview 4, so the clip's person is never a
/// dataset identity of the same seed (distinct ChaCha keys).
pub const DOMAIN_CLIP_IDENTITY: u64 = 0x434c_0001;
/// Domain of [`stream_rng`] for the clip's keyframes (index = keyframe number `k`):
/// `0x434c_0002`.
pub const DOMAIN_CLIP_KEYFRAME: u64 = 0x434c_0002;
/// Default number of frames `N` (≥ 60, as the evaluation asks).
pub const DEFAULT_FRAMES: usize = 72;
/// Default number of keyframes `K` (segments of `h = 71/3 ≈ 23.7` frames).
pub const DEFAULT_KEYFRAMES: usize = 4;
/// Scale of the jaw bone's opening (x, degrees) in [`ExpressionSampler`]:
/// `x ~ U(0, 22)·(1 − jawOpen)`.
pub const JAW_X_MAX_DEG: f64 = 22.0;

/// What clip to draw: seed, number of frames `N` and of keyframes `K`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct ClipConfig {
    /// Seed of every draw (identity and keyframes).
    pub seed: u64,
    /// Number of frames `N ≥ 2` (default [`DEFAULT_FRAMES`]).
    pub n_frames: usize,
    /// Number of keyframes `K`, `2 ≤ K ≤ N` (default [`DEFAULT_KEYFRAMES`]); the first and
    /// last frames are keyframes.
    pub n_keyframes: usize,
}

impl Default for ClipConfig {
    /// Seed 0, [`DEFAULT_FRAMES`] frames, [`DEFAULT_KEYFRAMES`] keyframes.
    fn default() -> Self {
        ClipConfig {
            seed: 0,
            n_frames: DEFAULT_FRAMES,
            n_keyframes: DEFAULT_KEYFRAMES,
        }
    }
}

impl ClipConfig {
    /// The default configuration with `seed`.
    pub fn with_seed(seed: u64) -> ClipConfig {
        ClipConfig {
            seed,
            ..ClipConfig::default()
        }
    }

    /// Checks `N ≥ 2` and `2 ≤ K ≤ N`.
    ///
    /// # Errors
    /// [`HumanError::Invalid`] naming the offending count.
    pub fn validate(&self) -> Result<()> {
        if self.n_frames < 2 {
            return Err(HumanError::Invalid(format!(
                "a clip needs at least 2 frames, not {}",
                self.n_frames
            )));
        }
        if self.n_keyframes < 2 || self.n_keyframes > self.n_frames {
            return Err(HumanError::Invalid(format!(
                "a clip of {} frames needs 2 to {} keyframes, not {}",
                self.n_frames, self.n_frames, self.n_keyframes
            )));
        }
        Ok(())
    }

    /// Frames per keyframe segment `h = (N − 1)/(K − 1)`.
    pub fn segment_frames(&self) -> f64 {
        (self.n_frames - 1) as f64 / (self.n_keyframes - 1) as f64
    }

    /// Keyframe coordinate `u = f/h = f·(K − 1)/(N − 1) ∈ [0, K − 1]` of frame `f`
    /// (keyframe `k` at `u = k`).
    pub fn keyframe_coordinate(&self, frame: usize) -> f64 {
        if frame + 1 >= self.n_frames {
            return (self.n_keyframes - 1) as f64;
        }
        (frame * (self.n_keyframes - 1)) as f64 / (self.n_frames - 1) as f64
    }
}

/// One frame (or keyframe) of a clip: the skeleton pose and the face units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ClipFrame {
    /// Local Euler angles in degrees of the posable bones (body, hands, jaw and eyes; no root
    /// motion), see [`Theta`].
    pub theta: Theta,
    /// Face-unit values in [`crate::phenotype::FACE_UNITS`] order, each in `[0, 1]`, added to
    /// the identity's shape.
    pub face_units: [f64; 52],
}

impl ClipFrame {
    /// Keyframe `k` of the clip with `seed`, drawn from
    /// `stream_rng(seed, DOMAIN_CLIP_KEYFRAME, k)`: body pose, then both hands' gesture
    /// (replacing the body draw's relaxed hands), then an expression (face units, jaw and
    /// eyes); see the module docs. The exclusive-pair harmonisation of [`Clip::generate`] is
    /// not applied here.
    pub fn draw_keyframe(seed: u64, k: usize) -> ClipFrame {
        let mut rng = stream_rng(seed, DOMAIN_CLIP_KEYFRAME, k as u64);
        let mut theta = BodyPoseSampler.sample(&mut rng);
        HandSampler.sample_into(&mut rng, &mut theta);
        let e = ExpressionSampler.sample(&mut rng);
        e.write_theta(&mut theta);
        ClipFrame {
            theta,
            face_units: e.units,
        }
    }

    /// The identity's shape with this frame's face units (`facial_actions = face_units`).
    pub fn shape(&self, identity: &ShapeParams) -> ShapeParams {
        let mut s = identity.clone();
        s.facial_actions = self.face_units;
        s
    }
}

/// A monotone piecewise-cubic Hermite interpolant of values `y_0 … y_{K−1}` at the integer
/// knots `u = 0 … K − 1` (Fritsch–Butland tangents, zero end tangents): C¹, monotone on
/// every segment, never leaving `[min(y_k, y_{k+1}), max(y_k, y_{k+1})]` on segment `k`.
/// See the module docs for the formulas and bounds.
#[derive(Clone, Debug, PartialEq)]
pub struct MonotoneCubic {
    values: Vec<f64>,
    tangents: Vec<f64>,
}

impl MonotoneCubic {
    /// The interpolant of `values` (`K ≥ 1`; one value gives a constant). Tangents: `m_0 =
    /// m_{K−1} = 0`; inside, `m_k = 2 δ_{k−1} δ_k / (δ_{k−1} + δ_k)` if `δ_{k−1} δ_k > 0`,
    /// else 0, with `δ_k = y_{k+1} − y_k`.
    ///
    /// # Panics
    /// If `values` is empty.
    pub fn new(values: &[f64]) -> MonotoneCubic {
        assert!(!values.is_empty(), "MonotoneCubic needs at least one value");
        let n = values.len();
        let mut tangents = vec![0.0; n];
        for k in 1..n.saturating_sub(1) {
            let d0 = values[k] - values[k - 1];
            let d1 = values[k + 1] - values[k];
            if d0 * d1 > 0.0 {
                tangents[k] = 2.0 * d0 * d1 / (d0 + d1);
            }
        }
        MonotoneCubic {
            values: values.to_vec(),
            tangents,
        }
    }

    /// The knot values `y_k`.
    pub fn values(&self) -> &[f64] {
        &self.values
    }

    /// The knot tangents `m_k = dp/du` at `u = k`.
    pub fn tangents(&self) -> &[f64] {
        &self.tangents
    }

    /// `p(u)` for `u ∈ [0, K − 1]` (clamped outside): segment `k = min(⌊u⌋, K − 2)`,
    /// `s = u − k`, `p = h₀₀ y_k + h₁₀ m_k + h₀₁ y_{k+1} + h₁₁ m_{k+1}`. Exact at the knots.
    pub fn eval(&self, u: f64) -> f64 {
        let n = self.values.len();
        if n == 1 {
            return self.values[0];
        }
        let u = u.clamp(0.0, (n - 1) as f64);
        let k = (u.floor() as usize).min(n - 2);
        let s = u - k as f64;
        let (s2, s3) = (s * s, s * s * s);
        let h00 = 2.0 * s3 - 3.0 * s2 + 1.0;
        let h10 = s3 - 2.0 * s2 + s;
        let h01 = -2.0 * s3 + 3.0 * s2;
        let h11 = s3 - s2;
        h00 * self.values[k]
            + h10 * self.tangents[k]
            + h01 * self.values[k + 1]
            + h11 * self.tangents[k + 1]
    }
}

/// A synthetic motion clip: one identity, its keyframes and the interpolated frames.
#[derive(Clone, Debug, PartialEq)]
pub struct Clip {
    /// The configuration it was drawn with.
    pub config: ClipConfig,
    /// The person (its shape has no face units; they come per frame).
    pub identity: SampledIdentity,
    /// The `K` keyframes after the exclusive-pair harmonisation (module docs), keyframe `k` at
    /// frame `k·h`.
    pub keyframes: Vec<ClipFrame>,
    /// The `N` frames, frame `f` the interpolant at `u = f/h` ([`Clip::interpolate`]).
    pub frames: Vec<ClipFrame>,
}

impl Clip {
    /// Draws the clip of `config` (see the module docs): identity from
    /// `stream_rng(seed, DOMAIN_CLIP_IDENTITY, 0)`, keyframes by
    /// [`ClipFrame::draw_keyframe`], exclusive pairs harmonised, frames by
    /// [`Clip::interpolate`]. Deterministic: depends on `config` only.
    ///
    /// # Errors
    /// [`HumanError::Invalid`] for an invalid configuration ([`ClipConfig::validate`]).
    pub fn generate(config: &ClipConfig) -> Result<Clip> {
        config.validate()?;
        let identity = IdentitySampler::default().sample(&mut stream_rng(
            config.seed,
            DOMAIN_CLIP_IDENTITY,
            0,
        ));
        let mut keyframes: Vec<ClipFrame> = (0..config.n_keyframes)
            .map(|k| ClipFrame::draw_keyframe(config.seed, k))
            .collect();
        harmonise_exclusive_pairs(&mut keyframes);
        let frames = Clip::interpolate(&keyframes, config);
        Ok(Clip {
            config: *config,
            identity,
            keyframes,
            frames,
        })
    }

    /// The `N` frames interpolating `keyframes` (placed at frames `k·h`): every Euler angle and
    /// face unit by [`MonotoneCubic`] in `u = f/h`, except the coupled channels — mouthClose
    /// `= r(u)·jawOpen(u)` with `r` the interpolated ratio mouthClose/jawOpen (0 where
    /// jawOpen = 0), and jaw x `= 22°·q(u)·(1 − jawOpen(u))` with `q` the interpolated ratio
    /// `x/(22°·(1 − jawOpen))` (0 where jawOpen = 1), both ratios clamped to `[0, 1]` at the
    /// keyframes. Finally angles are clamped to [`bone_range`] and units to `[0, 1]` (no-ops up
    /// to rounding, by the no-overshoot property).
    ///
    /// # Panics
    /// If `keyframes.len()` is not `config.n_keyframes` or the configuration is invalid.
    pub fn interpolate(keyframes: &[ClipFrame], config: &ClipConfig) -> Vec<ClipFrame> {
        config.validate().expect("valid clip configuration");
        assert_eq!(keyframes.len(), config.n_keyframes, "one keyframe per K");
        let jaw_open = face_unit_index("jawOpen").expect("jawOpen unit");
        let mouth_close = face_unit_index("mouthClose").expect("mouthClose unit");
        let us: Vec<f64> = (0..config.n_frames)
            .map(|f| config.keyframe_coordinate(f))
            .collect();
        let track = |value: &dyn Fn(&ClipFrame) -> f64| -> Vec<f64> {
            let keys: Vec<f64> = keyframes.iter().map(value).collect();
            let c = MonotoneCubic::new(&keys);
            us.iter().map(|&u| c.eval(u)).collect()
        };
        let mut frames = vec![
            ClipFrame {
                theta: Theta::default(),
                face_units: [0.0; 52],
            };
            config.n_frames
        ];
        for b in 0..N_POSABLE {
            for a in 0..3 {
                let t = track(&|k: &ClipFrame| k.theta.deg[b][a]);
                for (fr, v) in frames.iter_mut().zip(t) {
                    fr.theta.deg[b][a] = v;
                }
            }
        }
        for j in 0..52 {
            let t = track(&|k: &ClipFrame| k.face_units[j]);
            for (fr, v) in frames.iter_mut().zip(t) {
                fr.face_units[j] = v;
            }
        }
        // Couplings: mouthClose ≤ jawOpen, jaw x ≤ 22°·(1 − jawOpen).
        let ratio = |num: f64, den: f64| {
            if den > 0.0 {
                (num / den).clamp(0.0, 1.0)
            } else {
                0.0
            }
        };
        let r = track(&|k: &ClipFrame| ratio(k.face_units[mouth_close], k.face_units[jaw_open]));
        let q = track(&|k: &ClipFrame| {
            ratio(
                k.theta.deg[FACE_SLOT][0],
                JAW_X_MAX_DEG * (1.0 - k.face_units[jaw_open]),
            )
        });
        for ((fr, r), q) in frames.iter_mut().zip(r).zip(q) {
            let jo = fr.face_units[jaw_open].clamp(0.0, 1.0);
            fr.face_units[mouth_close] = r * jo;
            fr.theta.deg[FACE_SLOT][0] = JAW_X_MAX_DEG * q * (1.0 - jo);
            fr.theta.clamp_to_ranges();
            for v in &mut fr.face_units {
                *v = v.clamp(0.0, 1.0);
            }
        }
        frames
    }

    /// Number of frames `N`.
    pub fn n_frames(&self) -> usize {
        self.frames.len()
    }

    /// The shape of frame `f`: the identity with the frame's face units.
    ///
    /// # Panics
    /// If `f ≥ N`.
    pub fn frame_shape(&self, f: usize) -> ShapeParams {
        self.frames[f].shape(&self.identity.shape)
    }

    /// The clip's meshes in `topology` (metres, world frame Z up, facing −Y): the neutral
    /// rest mesh of the identity (no face units, rest pose) and, per frame `f`, the identity
    /// with frame `f`'s face units ([`Generator::identity`]) posed by its theta
    /// ([`BoneMap::pose_params`], LBS), mapped by [`TopologyMap::map`]. Frames are computed in
    /// parallel; the result does not depend on the number of threads.
    ///
    /// # Errors
    /// A rig without the posable bones, or invalid shape parameters (generator errors).
    pub fn meshes(
        &self,
        generator: &Generator,
        map: &TopologyMap,
        topology: OutputTopology,
    ) -> Result<(Vec<V3>, Vec<Vec<V3>>)> {
        let bones = BoneMap::new(generator.bone_names())?;
        let neutral = generator.identity(&self.identity.shape)?;
        let rest = map.map(topology, neutral.rest_vertices());
        let posed = self
            .frames
            .par_iter()
            .map(|fr| {
                let person = generator.identity(&fr.shape(&self.identity.shape))?;
                let p = person.pose(&bones.pose_params(&fr.theta));
                Ok(map.map(topology, &p.vertices))
            })
            .collect::<Result<Vec<Vec<V3>>>>()?;
        Ok((rest, posed))
    }
}

/// Gives each [`EXCLUSIVE_UNITS`] pair one side for the whole clip: the side of the first
/// keyframe using the pair; a later keyframe's value on the other side is moved over.
fn harmonise_exclusive_pairs(keyframes: &mut [ClipFrame]) {
    for (a, b) in EXCLUSIVE_UNITS {
        let ia = face_unit_index(a).expect("exclusive unit");
        let ib = face_unit_index(b).expect("exclusive unit");
        let mut side: Option<(usize, usize)> = None; // (kept, dropped)
        for k in keyframes.iter_mut() {
            let u = &mut k.face_units;
            if side.is_none() {
                if u[ia] > 0.0 {
                    side = Some((ia, ib));
                } else if u[ib] > 0.0 {
                    side = Some((ib, ia));
                }
            }
            if let Some((keep, drop)) = side
                && u[drop] > 0.0
            {
                u[keep] = u[keep].max(u[drop]);
                u[drop] = 0.0;
            }
        }
    }
}
