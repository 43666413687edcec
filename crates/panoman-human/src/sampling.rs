//! Seeded samplers of identities, body poses, hand gestures and facial expressions for the
//! synthetic training data (docs/design/rig-and-ik.md §3; docs/formats.md).
//!
//! # Random numbers
//! Every draw comes from a [`ChaCha8Rng`] keyed by `(seed, domain, index)` ([`stream_rng`]):
//! the 32-byte ChaCha key is `seed ‖ domain ‖ index ‖ "panoman!"` (little-endian `u64`s), so
//! each identity, row or split gets its own independent stream. A sample depends only on its
//! key, never on the order in which samples are drawn or on the number of threads.
//! Uniforms are `U = (next_u64 >> 11) · 2⁻⁵³ ∈ [0, 1)`; normals use Box–Muller
//! (`√(−2 ln(1−U₁)) · cos 2πU₂`); Gamma uses Marsaglia–Tsang (2000) in log space, with the
//! `Gamma(a) = Gamma(a+1) · U^{1/a}` boost for `a < 1`; `Beta(a, b) = G_a / (G_a + G_b)`
//! evaluated as `1 / (1 + exp(ln G_b − ln G_a))`, which stays finite for the very small shape
//! parameters of Anny's calibration (e.g. `β = 0.0094`). "TN(μ, σ; lo, hi)" below is a
//! normal truncated to `[lo, hi]` by rejection (after 16 rejections the last draw is clamped).
//!
//! # Angles
//! Poses are [`Theta`]: local Euler angles `[x, y, z]` in degrees (`R = Rz(z)·Ry(y)·Rx(x)`,
//! [`crate::params::PoseParams`]) for the [`posable_bones`]. The samplers reason in the
//! *left-side* convention of docs/design/rig-and-ik.md §3.1/§3.3 and store right-side bones mirrored as
//! `(x, −y, −z)`; the eyes take the same angles on both sides (conjugate gaze, docs/design/rig-and-ik.md §3.1). Every
//! sampled angle lies inside [`bone_range`] (docs/design/rig-and-ik.md §3.3, with the measured twist limits
//! [`TWIST_LIMIT_DEG`]). Bones not listed stay at identity (pelvis, breasts, toes, the face
//! muscle bones, tongue), and so does the root: rows carry no global rotation or translation.

use rand_chacha::ChaCha8Rng;
use rand_chacha::rand_core::{RngCore, SeedableRng};

use crate::error::{HumanError, Result};
use crate::params::{PoseParams, ShapeParams};
use crate::phenotype::{FACE_UNITS, face_unit_index};

// ---------------------------------------------------------------------------------------------
// Random numbers.

/// Domain of [`stream_rng`] for identity draws (index = identity id).
pub const DOMAIN_IDENTITY: u64 = 1;
/// Domain of [`stream_rng`] for row draws (index = row number).
pub const DOMAIN_ROW: u64 = 2;
/// Domain of [`stream_rng`] for the train/held-out split (index 0).
pub const DOMAIN_SPLIT: u64 = 3;

/// The random stream of sample `index` in `domain` under `seed`: ChaCha8 with the key
/// `seed ‖ domain ‖ index ‖ "panoman!"` (each a little-endian `u64`), stream 0.
///
/// Distinct `(seed, domain, index)` give distinct keys, so streams never overlap.
pub fn stream_rng(seed: u64, domain: u64, index: u64) -> ChaCha8Rng {
    let mut key = [0u8; 32];
    key[..8].copy_from_slice(&seed.to_le_bytes());
    key[8..16].copy_from_slice(&domain.to_le_bytes());
    key[16..24].copy_from_slice(&index.to_le_bytes());
    key[24..].copy_from_slice(b"panoman!");
    ChaCha8Rng::from_seed(key)
}

/// `U ∈ [0, 1)` with 53 random bits: `(next_u64 >> 11) · 2⁻⁵³`.
#[inline]
pub fn uniform(rng: &mut (impl RngCore + ?Sized)) -> f64 {
    (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// `U(lo, hi)`: `lo + (hi − lo) · U`.
#[inline]
pub fn uniform_in(rng: &mut (impl RngCore + ?Sized), lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * uniform(rng)
}

/// Standard normal by Box–Muller: `√(−2 ln(1 − U₁)) · cos(2π U₂)` (one value per two
/// uniforms; `1 − U₁ ∈ (0, 1]` keeps the logarithm finite).
#[inline]
pub fn normal(rng: &mut (impl RngCore + ?Sized)) -> f64 {
    let u1 = 1.0 - uniform(rng);
    let u2 = uniform(rng);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Truncated normal TN(μ, σ; lo, hi): redraws `μ + σ·N(0,1)` until it falls in `[lo, hi]`
/// (at most 16 times, then clamps the last draw).
pub fn truncated_normal(
    rng: &mut (impl RngCore + ?Sized),
    mean: f64,
    sd: f64,
    lo: f64,
    hi: f64,
) -> f64 {
    let mut x = mean;
    for _ in 0..16 {
        x = mean + sd * normal(rng);
        if (lo..=hi).contains(&x) {
            return x;
        }
    }
    x.clamp(lo, hi)
}

/// `ln G` for `G ~ Gamma(shape a, scale 1)`, `a > 0`.
///
/// Marsaglia–Tsang: with `d = a − 1/3`, `c = 1/√(9d)`, draw `x ~ N(0,1)`, `v = (1 + c x)³`
/// (reject `v ≤ 0`) and `u ~ U(0,1]`; accept `d·v` if `ln u < x²/2 + d(1 − v + ln v)`. For
/// `a < 1`: `ln G_a = ln G_{a+1} + ln(u)/a` (log space, so tiny shapes cannot underflow).
pub fn ln_gamma_sample(rng: &mut (impl RngCore + ?Sized), a: f64) -> f64 {
    assert!(a > 0.0 && a.is_finite(), "Gamma shape must be positive");
    if a < 1.0 {
        let u = 1.0 - uniform(rng);
        return ln_gamma_sample(rng, a + 1.0) + u.ln() / a;
    }
    let d = a - 1.0 / 3.0;
    let c = 1.0 / (9.0 * d).sqrt();
    loop {
        let x = normal(rng);
        let t = 1.0 + c * x;
        if t <= 0.0 {
            continue;
        }
        let v = t * t * t;
        let u = 1.0 - uniform(rng);
        let x2 = x * x;
        if u < 1.0 - 0.0331 * x2 * x2 || u.ln() < 0.5 * x2 + d * (1.0 - v + v.ln()) {
            return d.ln() + v.ln();
        }
    }
}

/// `Beta(a, b)` from two Gamma draws: `G_a / (G_a + G_b) = 1 / (1 + exp(ln G_b − ln G_a))`,
/// in `[0, 1]`.
pub fn beta(rng: &mut (impl RngCore + ?Sized), a: f64, b: f64) -> f64 {
    let la = ln_gamma_sample(rng, a);
    let lb = ln_gamma_sample(rng, b);
    (1.0 / (1.0 + (lb - la).exp())).clamp(0.0, 1.0)
}

/// Picks index `i` with probability `w_i / Σ w`.
fn choose_weighted(rng: &mut (impl RngCore + ?Sized), weights: &[f64]) -> usize {
    let total: f64 = weights.iter().sum();
    let mut u = uniform(rng) * total;
    for (i, &w) in weights.iter().enumerate() {
        if u < w {
            return i;
        }
        u -= w;
    }
    weights.len() - 1
}

// ---------------------------------------------------------------------------------------------
// Identities (docs/design/rig-and-ik.md §3.4).

/// Morphological-age anchors in years (docs/design/rig-and-ik.md §3.4 step 2).
pub const AGE_YEARS_ANCHORS: [f64; 8] = [0.0, 1.0, 4.0, 11.0, 16.0, 18.0, 64.0, 110.0];
/// Anny-age anchors matching [`AGE_YEARS_ANCHORS`]; also the anchors of the weight, muscle
/// and proportions Beta tables.
pub const ANNY_AGE_ANCHORS: [f64; 8] = [0.0, 0.05, 0.215, 0.415, 0.67, 0.77, 0.83, 1.0];

/// Beta-parameter anchors of one sex (`shape_calibration.json`, full precision).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CalibrationTable {
    /// Height α at Anny ages `ANNY_AGE_ANCHORS[..5]` (adults keep the 0.67 value).
    pub height_alpha: [f64; 5],
    /// Height β, same anchors.
    pub height_beta: [f64; 5],
    /// Weight α at [`ANNY_AGE_ANCHORS`].
    pub weight_alpha: [f64; 8],
    /// Weight β.
    pub weight_beta: [f64; 8],
    /// Muscle α.
    pub muscle_alpha: [f64; 8],
    /// Muscle β.
    pub muscle_beta: [f64; 8],
}

/// Anny's calibration for boys/men (`gender ≤ 0.5`), from `shape_calibration.json`.
pub const BOYS: CalibrationTable = CalibrationTable {
    height_alpha: [
        21.59569876450918,
        51.9783334557359,
        22.147254386939128,
        13.404505930812913,
        16.495562848906868,
    ],
    height_beta: [
        58.60050612100851,
        57.360044726733896,
        45.85863887866753,
        22.104951191986984,
        25.656183288468334,
    ],
    weight_alpha: [
        1.5128728151321411,
        0.27302244305610657,
        0.9053267240524292,
        0.3063071370124817,
        0.23414914309978485,
        0.7016359567642212,
        0.3144572675228119,
        0.25125861167907715,
    ],
    weight_beta: [
        0.9485068917274475,
        0.009368693456053734,
        1.2030186653137207,
        0.9829350113868713,
        0.6836292743682861,
        1.2365859746932983,
        0.22144970297813416,
        0.1742255836725235,
    ],
    muscle_alpha: [
        1.3058923482894897,
        0.00995633378624916,
        0.9128995537757874,
        0.5553823709487915,
        0.6273819208145142,
        0.6080248355865479,
        1.46012544631958,
        0.9803528785705566,
    ],
    muscle_beta: [
        1.0371087789535522,
        0.2929062247276306,
        0.9840489029884338,
        2.3419950008392334,
        0.7151288986206055,
        1.192458152770996,
        1.6300795078277588,
        0.8095288276672363,
    ],
};

/// Anny's calibration for girls/women (`gender > 0.5`), from `shape_calibration.json`.
pub const GIRLS: CalibrationTable = CalibrationTable {
    height_alpha: [
        29.520749046886845,
        66.28195905142273,
        31.81614447180559,
        21.26417254409934,
        13.683852173198092,
    ],
    height_beta: [
        96.72243255765622,
        74.54048997863622,
        59.49074917535684,
        23.975297996662132,
        25.74761089445589,
    ],
    weight_alpha: [
        1.559728980064392,
        0.31907039880752563,
        2.2728323936462402,
        0.7031490802764893,
        0.7232686877250671,
        0.8814058899879456,
        1.8921327590942383,
        1.9019638299942017,
    ],
    weight_beta: [
        0.9010456800460815,
        0.010879168286919594,
        0.9199190139770508,
        0.6017749309539795,
        0.5567191243171692,
        0.6262189745903015,
        0.6995136737823486,
        0.6808692812919617,
    ],
    muscle_alpha: [
        0.9999916553497314,
        0.014186132699251175,
        1.1285271644592285,
        0.5115915536880493,
        0.6257697939872742,
        0.5737931728363037,
        0.46011051535606384,
        0.5306271910667419,
    ],
    muscle_beta: [
        1.0046303272247314,
        0.39454182982444763,
        0.9525918364524841,
        0.5593905448913574,
        0.6426863074302673,
        0.7388191819190979,
        1.9971593618392944,
        2.2776384353637695,
    ],
};

/// Shape parameter of the proportions Beta (both sexes, all ages): Beta(1.0000005, 1.0000005),
/// i.e. uniform.
pub const PROPORTIONS_AB: f64 = 1.000_000_476_837_158_2;

/// Piecewise-linear interpolation of `(xs, ys)` at `x`; outside `[xs₀, xs_last]` it
/// extrapolates the end segments if `extrapolate`, else clamps.
pub fn interp(xs: &[f64], ys: &[f64], x: f64, extrapolate: bool) -> f64 {
    let n = xs.len();
    assert!(n >= 2 && ys.len() == n);
    if !extrapolate {
        if x <= xs[0] {
            return ys[0];
        }
        if x >= xs[n - 1] {
            return ys[n - 1];
        }
    }
    let i = xs[1..n - 1].partition_point(|&a| a < x) + 1; // segment [i-1, i]
    let t = (x - xs[i - 1]) / (xs[i] - xs[i - 1]);
    ys[i - 1] + t * (ys[i] - ys[i - 1])
}

/// Anny age of a morphological age in years (docs/design/rig-and-ik.md §3.4 step 2; linear extrapolation).
pub fn anny_age_of_years(years: f64) -> f64 {
    interp(&AGE_YEARS_ANCHORS, &ANNY_AGE_ANCHORS, years, true)
}

/// How the three race weights are drawn.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RaceMode {
    /// Anny's default phenotype set: african = asian = caucasian (1/3 each after
    /// normalisation). The values are left at 0.5.
    #[default]
    Equal,
    /// Each race value ~ U(0, 1) (normalised by the generator), as Anny's sampler does for
    /// exposed races (docs/design/rig-and-ik.md §3.4 step 6).
    Uniform,
}

/// Anny's age-calibrated identity distribution (`SimpleShapeDistribution`, docs/design/rig-and-ik.md §3.4):
///
/// 1. morphological age `A ~ U(0, 90)` years, `gender ~ U(0, 1)` (0 male, 1 female);
/// 2. `age = interp(A)` over the anchors years [0, 1, 4, 11, 16, 18, 64, 110] → Anny age
///    [0, .05, .215, .415, .67, .77, .83, 1] (linear extrapolation; A ≤ 90 gives ≤ 0.926);
/// 3. tables [`BOYS`] if `gender ≤ 0.5`, else [`GIRLS`];
/// 4. `height ~ Beta(α_h(age), β_h(age))`, `weight ~ Beta(α_w, β_w)`, `muscle ~ Beta(α_m,
///    β_m)`, with α, β piecewise linear in the Anny age over the anchors (clamped; height's
///    anchors stop at .67);
/// 5. `proportions ~ Beta(1.0000005, 1.0000005)` (≈ U(0, 1));
/// 6. races per [`RaceMode`]; cupsize and firmness stay 0.5 (no breast shapes, Anny's
///    default phenotype set); no face units, no local changes.
///
/// Draw order per identity: A, gender, height, weight, muscle, proportions, then races.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct IdentitySampler {
    /// How races are drawn (default: 1/3 each).
    pub races: RaceMode,
}

/// One sampled identity.
#[derive(Clone, Debug, PartialEq)]
pub struct SampledIdentity {
    /// Morphological age in years (step 1).
    pub years: f64,
    /// The shape parameters (face units and local changes zero).
    pub shape: ShapeParams,
}

impl IdentitySampler {
    /// Draws one identity (see the type docs).
    pub fn sample(&self, rng: &mut impl RngCore) -> SampledIdentity {
        let years = uniform_in(rng, 0.0, 90.0);
        let gender = uniform(rng);
        let age = anny_age_of_years(years).clamp(0.0, 1.0);
        let t = if gender <= 0.5 { &BOYS } else { &GIRLS };
        let h_anchors = &ANNY_AGE_ANCHORS[..5];
        let ab = |al: &[f64], be: &[f64], xs: &[f64]| {
            (interp(xs, al, age, false), interp(xs, be, age, false))
        };
        let (ha, hb) = ab(&t.height_alpha, &t.height_beta, h_anchors);
        let height = beta(rng, ha, hb);
        let (wa, wb) = ab(&t.weight_alpha, &t.weight_beta, &ANNY_AGE_ANCHORS);
        let weight = beta(rng, wa, wb);
        let (ma, mb) = ab(&t.muscle_alpha, &t.muscle_beta, &ANNY_AGE_ANCHORS);
        let muscle = beta(rng, ma, mb);
        let proportions = beta(rng, PROPORTIONS_AB, PROPORTIONS_AB);
        let mut shape = ShapeParams::default();
        let p = &mut shape.phenotype;
        p.gender = gender;
        p.age = age;
        p.height = height;
        p.weight = weight;
        p.muscle = muscle;
        p.proportions = proportions;
        if self.races == RaceMode::Uniform {
            p.african = uniform(rng);
            p.asian = uniform(rng);
            p.caucasian = uniform(rng);
        }
        SampledIdentity { years, shape }
    }
}

// ---------------------------------------------------------------------------------------------
// Bones and ranges.

/// Body bones sampled for body poses (docs/design/rig-and-ik.md §3.2), `[33]`.
pub const BODY_BONES: [&str; 33] = [
    "spine05",
    "spine04",
    "spine03",
    "spine02",
    "spine01",
    "neck01",
    "neck02",
    "neck03",
    "head",
    "clavicle.L",
    "clavicle.R",
    "shoulder01.L",
    "shoulder01.R",
    "upperarm01.L",
    "upperarm01.R",
    "upperarm02.L",
    "upperarm02.R",
    "lowerarm01.L",
    "lowerarm01.R",
    "lowerarm02.L",
    "lowerarm02.R",
    "wrist.L",
    "wrist.R",
    "upperleg01.L",
    "upperleg01.R",
    "upperleg02.L",
    "upperleg02.R",
    "lowerleg01.L",
    "lowerleg01.R",
    "lowerleg02.L",
    "lowerleg02.R",
    "foot.L",
    "foot.R",
];

/// The 19 hand bones of one hand without side suffix (docs/design/rig-and-ik.md §3.2): thumb, metacarpals (cupping),
/// index, middle, ring, little.
pub const HAND_BONES: [&str; 19] = [
    "finger1-1",
    "finger1-2",
    "finger1-3",
    "metacarpal1",
    "metacarpal2",
    "metacarpal3",
    "metacarpal4",
    "finger2-1",
    "finger2-2",
    "finger2-3",
    "finger3-1",
    "finger3-2",
    "finger3-3",
    "finger4-1",
    "finger4-2",
    "finger4-3",
    "finger5-1",
    "finger5-2",
    "finger5-3",
];

/// Face bones (docs/design/rig-and-ik.md §3.2): the jaw and the two eyes (gaze).
pub const FACE_BONES: [&str; 3] = ["jaw", "eye.L", "eye.R"];

/// Number of posable bones: 33 body + 2 × 19 hand + 3 face.
pub const N_POSABLE: usize = 74;
/// First [`posable_bones`] slot of the left hand (19 slots `HAND_BONES` + `.L`).
pub const LEFT_HAND_SLOT: usize = 33;
/// First slot of the right hand (19 slots `HAND_BONES` + `.R`).
pub const RIGHT_HAND_SLOT: usize = 52;
/// First slot of the face bones (jaw, eye.L, eye.R).
pub const FACE_SLOT: usize = 71;

/// The posable bones in [`Theta`] (and dataset `theta`) order: [`BODY_BONES`], the left
/// hand's [`HAND_BONES`] with `.L`, the right hand's with `.R`, then [`FACE_BONES`].
pub fn posable_bones() -> Vec<String> {
    let mut v: Vec<String> = BODY_BONES.iter().map(|s| s.to_string()).collect();
    for side in ["L", "R"] {
        v.extend(HAND_BONES.iter().map(|b| format!("{b}.{side}")));
    }
    v.extend(FACE_BONES.iter().map(|s| s.to_string()));
    v
}

/// Twist limits (degrees, Y) of the `*02` limb bones, chosen from the measured volume loss
/// of the LBS skin (the example `sampling_measurements twist`; default and adult identity).
///
/// LBS twist shrinks the limb where the `*01`/`*02` weights blend (the "candy wrapper"); the
/// worst cross-section radius loss grows like `1 − cos(θ/2)`: about −1.5 % at 20°, −3.1 to
/// −3.8 % at 30°, −7 to −7.6 % at 45°, −12 to −13 % at 60°, −27 to −29 % at 90°, for all
/// four bones (segment volume of revolution −3 % at 30°, −7 % at 45°). The whole-body
/// enclosed volume changes by −0.04 % (forearm) to −0.45 % (thigh) at 30°. The limit keeps the
/// worst radius loss within ≈ 3.5 %: ±30° for the arm bones (docs/design/rig-and-ik.md §3.3 allowed ±45° for
/// lowerarm02: −7.5 % radius), and docs/design/rig-and-ik.md §3.3's own tighter ±15° / ±10° for the legs (−0.9 % /
/// −0.4 %). Samples are `TN(0, L/2; ±L)`, so most twists are well inside.
pub const TWIST_LIMIT_DEG: [(&str, f64); 4] = [
    ("upperarm02", 30.0),
    ("lowerarm02", 30.0),
    ("upperleg02", 15.0),
    ("lowerleg02", 10.0),
];

/// [`bone_range`] of every posable bone, in theta order.
pub fn posable_ranges() -> &'static [[[f64; 2]; 3]] {
    static R: std::sync::OnceLock<Vec<[[f64; 2]; 3]>> = std::sync::OnceLock::new();
    R.get_or_init(|| {
        posable_bones()
            .iter()
            .map(|b| bone_range(b).expect("posable bones have ranges"))
            .collect()
    })
}

fn twist_limit(bone: &str) -> f64 {
    TWIST_LIMIT_DEG
        .iter()
        .find(|(b, _)| *b == bone)
        .map_or(0.0, |(_, l)| *l)
}

/// Allowed range `[[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]]` (degrees) of a posable bone
/// in its *own* frame: docs/design/rig-and-ik.md §3.3 for left-side and central bones; right-side bones get the mirror
/// `(x, −y, −z)` of the left range; eyes share one range. The `*02` twists use
/// [`TWIST_LIMIT_DEG`]. `None` for a bone that is not posable.
pub fn bone_range(bone: &str) -> Option<[[f64; 2]; 3]> {
    let (base, right) = match bone.strip_suffix(".R") {
        Some(b) => (b, true),
        None => (bone.strip_suffix(".L").unwrap_or(bone), false),
    };
    let r = |x: [f64; 2], y: [f64; 2], z: [f64; 2]| Some([x, y, z]);
    let left = match base {
        "spine05" | "spine04" | "spine03" => r([-8., 12.], [-8., 8.], [-6., 6.]),
        "spine02" | "spine01" => r([-6., 10.], [-8., 8.], [-6., 6.]),
        "neck01" | "neck02" | "neck03" => r([-10., 15.], [-15., 15.], [-10., 10.]),
        "head" => r([-15., 20.], [-20., 20.], [-12., 12.]),
        "clavicle" => r([-8., 12.], [-5., 5.], [-8., 15.]),
        "shoulder01" => r([-8., 8.], [-5., 5.], [-8., 12.]),
        "upperarm01" => r([-40., 90.], [-45., 45.], [-40., 90.]),
        "lowerarm01" => r([-35., 95.], [-20., 20.], [0., 0.]),
        "upperarm02" | "lowerarm02" | "upperleg02" | "lowerleg02" => {
            let t = twist_limit(base);
            r([0., 0.], [-t, t], [0., 0.])
        }
        "wrist" => r([-20., 20.], [-10., 10.], [-60., 50.]),
        "upperleg01" => r([-90., 25.], [-30., 30.], [-35., 15.]),
        "lowerleg01" => r([0., 120.], [-8., 8.], [0., 0.]),
        "foot" => r([-20., 40.], [-10., 10.], [-15., 15.]),
        "finger1-1" => r([-15., 35.], [-15., 15.], [-25., 25.]),
        "finger1-2" => r([0., 55.], [0., 0.], [-5., 5.]),
        "finger1-3" => r([-5., 75.], [0., 0.], [0., 0.]),
        "metacarpal1" | "metacarpal2" => r([0., 6.], [0., 0.], [-3., 3.]),
        "metacarpal3" => r([0., 8.], [0., 0.], [-3., 3.]),
        "metacarpal4" => r([0., 10.], [0., 0.], [-3., 3.]),
        "finger2-1" | "finger3-1" | "finger4-1" | "finger5-1" => {
            r([-15., 85.], [0., 0.], [-12., 12.])
        }
        "finger2-2" | "finger3-2" | "finger4-2" | "finger5-2" => r([0., 100.], [0., 0.], [0., 0.]),
        "finger2-3" | "finger3-3" | "finger4-3" | "finger5-3" => r([0., 70.], [0., 0.], [0., 0.]),
        "jaw" => r([0., 22.], [-3., 3.], [-4., 4.]),
        "eye" => return Some([[-20., 20.], [0., 0.], [-30., 30.]]),
        _ => None,
    }?;
    if right {
        let [x, y, z] = left;
        Some([x, [-y[1], -y[0]], [-z[1], -z[0]]])
    } else {
        Some(left)
    }
}

// ---------------------------------------------------------------------------------------------
// Theta.

/// A pose of the [`POSABLE_BONES`](posable_bones): `deg[k] = [x, y, z]` local Euler angles in
/// degrees of bone `k` in its own frame (`R = Rz(z)·Ry(y)·Rx(x)`), zero = rest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Theta {
    /// Euler angles in degrees, `[N_POSABLE]`.
    pub deg: [[f64; 3]; N_POSABLE],
}

impl Default for Theta {
    /// The rest pose (all zero).
    fn default() -> Self {
        Theta {
            deg: [[0.0; 3]; N_POSABLE],
        }
    }
}

impl Theta {
    /// The angles in radians as `f32`, flattened bone-major: `[x₀, y₀, z₀, x₁, …]`
    /// (`3 · N_POSABLE` values), the dataset's `theta` row.
    pub fn to_radians_f32(&self) -> Vec<f32> {
        self.deg
            .iter()
            .flat_map(|e| e.map(|a| a.to_radians() as f32))
            .collect()
    }

    /// Clamps every angle into [`bone_range`].
    pub fn clamp_to_ranges(&mut self) {
        for (e, r) in self.deg.iter_mut().zip(posable_ranges()) {
            for (v, lim) in e.iter_mut().zip(r) {
                *v = v.clamp(lim[0], lim[1]);
            }
        }
    }

    /// True if every angle is finite and lies in [`bone_range`] (within `tol` degrees).
    pub fn in_ranges(&self, tol: f64) -> bool {
        self.deg.iter().zip(posable_ranges()).all(|(e, r)| {
            e.iter()
                .zip(r)
                .all(|(v, lim)| v.is_finite() && *v >= lim[0] - tol && *v <= lim[1] + tol)
        })
    }

    /// Sets slot `k` from angles in the left-side convention: the right side stores the
    /// mirror `(x, −y, −z)` (docs/design/rig-and-ik.md §3.1).
    fn set_lr(&mut self, k: usize, right: bool, e: [f64; 3]) {
        self.deg[k] = if right { [e[0], -e[1], -e[2]] } else { e };
    }
}

/// Rig index of each posable bone, to turn a [`Theta`] into [`PoseParams`].
#[derive(Clone, Debug)]
pub struct BoneMap {
    names: Vec<String>,
    rig_index: Vec<usize>,
    n_bones: usize,
}

impl BoneMap {
    /// Looks the [`posable_bones`] up in the rig's bone names (e.g.
    /// [`crate::generator::Generator::bone_names`]).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] naming a posable bone the rig lacks.
    pub fn new(rig_bone_names: &[String]) -> Result<BoneMap> {
        let names = posable_bones();
        let rig_index = names
            .iter()
            .map(|n| {
                rig_bone_names.iter().position(|b| b == n).ok_or_else(|| {
                    HumanError::Invalid(format!("the rig has no bone `{n}` (posable bone)"))
                })
            })
            .collect::<Result<Vec<usize>>>()?;
        Ok(BoneMap {
            names,
            rig_index,
            n_bones: rig_bone_names.len(),
        })
    }

    /// The posable bone names (theta order).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Rig index of each posable bone.
    pub fn rig_index(&self) -> &[usize] {
        &self.rig_index
    }

    /// The generator pose of a theta: angles at the posable bones, zero elsewhere, no root
    /// rotation or translation.
    pub fn pose_params(&self, theta: &Theta) -> PoseParams {
        let mut euler_deg = vec![[0.0; 3]; self.n_bones];
        for (k, &c) in self.rig_index.iter().enumerate() {
            euler_deg[c] = theta.deg[k];
        }
        PoseParams {
            euler_deg,
            root_rotation_z_deg: 0.0,
            root_translation: [0.0; 3],
        }
    }
}

fn slot(bone: &str) -> usize {
    BODY_BONES
        .iter()
        .position(|&b| b == bone)
        .expect("body bone")
}

// ---------------------------------------------------------------------------------------------
// Body poses.

/// Leg modes of [`BodyPoseSampler`] and their probabilities.
pub const LEG_MODES: [(&str, f64); 4] = [
    ("stand", 0.40),
    ("walk", 0.30),
    ("sit", 0.15),
    ("raise", 0.15),
];

/// Correlated body poses (docs/design/rig-and-ik.md §3.2 body bones, docs/design/rig-and-ik.md §3.3 ranges); hands relaxed (mild grip), face at
/// rest. Left-side convention, right side mirrored (module docs). All draws are clamped to
/// [`bone_range`] at the end.
///
/// * **Spine** (5 bones): total flexion `F ~ TN(8, 15; −36, 56)` (the sum of the per-bone
///   ranges, inside docs/design/rig-and-ik.md §3.3's −40..60), split 22/22/22/17/17 % from spine05 (lowest) up, plus
///   `N(0, 1.5)` per bone; lateral bend `TN(0, 6; −20, 20)` and twist `TN(0, 8; −25, 25)`
///   split evenly, plus `N(0, 1)`.
/// * **Neck + head**: pitch `TN(0, 12; −35, 45)`, yaw `TN(0, 20; −50, 50)`, roll
///   `TN(0, 6; −20, 20)`, 18 / 18 / 18 / 46 % (pitch), 20 / 20 / 20 / 40 % (yaw, roll) over
///   neck01–03 and head, plus `N(0, 1)`.
/// * **Arms** (each side): with p = 0.35 *relaxed* — upperarm01 abduction (z)
///   `TN(−25, 10; −40, 10)`, flexion (x) `TN(5, 12; −30, 40)`, elbow `TN(15, 20; −35, 70)`;
///   else *free* — abduction `U(−40, 90)`, flexion `U(−40, 90)`, elbow `U(−35, 95)`. With
///   p = 0.3 the right arm copies the left draw plus `N(0, 6)` (symmetric tendency).
///   upperarm01 twist `TN(0, 15; ±45)`; elbow y `TN(0, 5; ±20)`. Shoulder girdle follows the
///   arm (scapulohumeral rhythm): clavicle z = 0.12·max(abd, 0) + N(0, 3), x = 0.08·flex +
///   N(0, 3), y ~ N(0, 2); shoulder01 z = 0.08·max(abd, 0) + N(0, 2.5), x = 0.05·flex +
///   N(0, 2.5), y ~ N(0, 2). Wrist deviation `TN(0, 7; ±20)`, twist `TN(0, 4; ±10)`,
///   flexion `TN(−5, 18; −60, 50)`.
/// * **Legs**: a mode from [`LEG_MODES`]: *stand* — hip flexion (x) `TN(−4, 7; −25, 15)`,
///   knee `TN(5, 7; 0, 30)` per leg; *walk* — phase `φ ~ U(0, 2π)`, amplitude
///   `a ~ U(10, 35)`, hip x = −a·sin φ (right leg φ + π), knee = 5 + 1.6·a·max(0, sin(φ +
///   0.9)) + N(0, 4), ankle x = 0.3·a·sin φ; *sit* — shared hip flexion `U(−90, −45)` and knee
///   `U(45, 120)` with `N(0, 6)` asymmetry; *raise* — one random leg with hip `U(−90, −20)`,
///   knee `U(0, 120)`, the other standing. Every leg then adds hip abduction (z)
///   `TN(−4, 8; −35, 15)` (−z = abduction on L), hip twist `TN(0, 8; ±30)`, knee y
///   `TN(0, 3; ±8)`, foot x `+TN(0, 6; −20, 40)`, foot y `TN(0, 3; ±10)`, foot z
///   `TN(0, 5; ±15)`.
/// * **`*02` twists**: `TN(0, L/2; ±L)` with `L` from [`TWIST_LIMIT_DEG`].
/// * **Hands**: [`HandSampler::relaxed_into`] per hand.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BodyPoseSampler;

impl BodyPoseSampler {
    /// Draws one body pose (see the type docs).
    pub fn sample(&self, rng: &mut impl RngCore) -> Theta {
        let mut th = Theta::default();
        sample_spine_and_head(rng, &mut th);
        sample_arms(rng, &mut th);
        sample_legs(rng, &mut th);

        // Hands relaxed.
        let hands = HandSampler;
        for right in [false, true] {
            hands.relaxed_into(rng, &mut th, right);
        }
        th.clamp_to_ranges();
        th
    }
}

/// The spine, neck and head part of [`BodyPoseSampler::sample`].
fn sample_spine_and_head(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Spine.
    let flex = tn(rng, 8.0, 15.0, -36.0, 56.0);
    let bend = tn(rng, 0.0, 6.0, -20.0, 20.0);
    let twist = tn(rng, 0.0, 8.0, -25.0, 25.0);
    let shares = [0.22, 0.22, 0.22, 0.17, 0.17];
    for (b, share) in shares.iter().enumerate() {
        th.deg[b] = [
            flex * share + n(rng, 1.5),
            twist / 5.0 + n(rng, 1.0),
            bend / 5.0 + n(rng, 1.0),
        ];
    }
    // Neck and head.
    let pitch = tn(rng, 0.0, 12.0, -35.0, 45.0);
    let yaw = tn(rng, 0.0, 20.0, -50.0, 50.0);
    let roll = tn(rng, 0.0, 6.0, -20.0, 20.0);
    for (k, (sp, sr)) in [(0.18, 0.2), (0.18, 0.2), (0.18, 0.2), (0.46, 0.4)]
        .iter()
        .enumerate()
    {
        th.deg[5 + k] = [
            pitch * sp + n(rng, 1.0),
            yaw * sr + n(rng, 1.0),
            roll * sr + n(rng, 1.0),
        ];
    }
}

/// The arms of [`BodyPoseSampler::sample`] (clavicles to wrists, both sides).
fn sample_arms(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Arms: (abduction z, flexion x, elbow x) per side, left convention.
    let draw_arm = |rng: &mut dyn RngCore| -> [f64; 3] {
        if uniform(rng) < 0.35 {
            [
                truncated_normal(rng, -25.0, 10.0, -40.0, 10.0),
                truncated_normal(rng, 5.0, 12.0, -30.0, 40.0),
                truncated_normal(rng, 15.0, 20.0, -35.0, 70.0),
            ]
        } else {
            [
                uniform_in(rng, -40.0, 90.0),
                uniform_in(rng, -40.0, 90.0),
                uniform_in(rng, -35.0, 95.0),
            ]
        }
    };
    let left_arm = draw_arm(rng);
    let right_arm = if uniform(rng) < 0.3 {
        left_arm.map(|v| v + 6.0 * normal(rng))
    } else {
        draw_arm(rng)
    };
    for (side, arm) in [(false, left_arm), (true, right_arm)] {
        let s = usize::from(side);
        let [abd, flx, elbow] = arm;
        let abd = abd.clamp(-40.0, 90.0);
        let flx = flx.clamp(-40.0, 90.0);
        let clav = [
            0.08 * flx + n(rng, 3.0),
            n(rng, 2.0),
            0.12 * abd.max(0.0) + n(rng, 3.0),
        ];
        th.set_lr(slot("clavicle.L") + s, side, clav);
        let sh = [
            0.05 * flx + n(rng, 2.5),
            n(rng, 2.0),
            0.08 * abd.max(0.0) + n(rng, 2.5),
        ];
        th.set_lr(slot("shoulder01.L") + s, side, sh);
        let ua = [flx, tn(rng, 0.0, 15.0, -45.0, 45.0), abd];
        th.set_lr(slot("upperarm01.L") + s, side, ua);
        let la = [elbow, tn(rng, 0.0, 5.0, -20.0, 20.0), 0.0];
        th.set_lr(slot("lowerarm01.L") + s, side, la);
        for bone in ["upperarm02", "lowerarm02"] {
            let l = twist_limit(bone);
            let t = tn(rng, 0.0, l / 2.0, -l, l);
            th.set_lr(slot(&format!("{bone}.L")) + s, side, [0.0, t, 0.0]);
        }
        let wr = [
            tn(rng, 0.0, 7.0, -20.0, 20.0),
            tn(rng, 0.0, 4.0, -10.0, 10.0),
            tn(rng, -5.0, 18.0, -60.0, 50.0),
        ];
        th.set_lr(slot("wrist.L") + s, side, wr);
    }
}

/// The legs of [`BodyPoseSampler::sample`] (a leg mode, then hips to feet, both sides).
fn sample_legs(rng: &mut dyn RngCore, th: &mut Theta) {
    let tn = |rng: &mut dyn RngCore, m: f64, s: f64, lo: f64, hi: f64| {
        truncated_normal(rng, m, s, lo, hi)
    };
    let n = |rng: &mut dyn RngCore, s: f64| s * normal(rng);
    // Legs: (hip flexion x, knee x, foot x) per side.
    let mode = choose_weighted(rng, &LEG_MODES.map(|(_, p)| p));
    let stand = |rng: &mut dyn RngCore| -> [f64; 3] {
        [
            truncated_normal(rng, -4.0, 7.0, -25.0, 15.0),
            truncated_normal(rng, 5.0, 7.0, 0.0, 30.0),
            0.0,
        ]
    };
    let legs: [[f64; 3]; 2] = match LEG_MODES[mode].0 {
        "stand" => [stand(rng), stand(rng)],
        "walk" => {
            let phi = uniform_in(rng, 0.0, std::f64::consts::TAU);
            let a = uniform_in(rng, 10.0, 35.0);
            let mut leg = |ph: f64| {
                let knee = 5.0 + 1.6 * a * (ph + 0.9).sin().max(0.0) + n(rng, 4.0);
                [-a * ph.sin(), knee, 0.3 * a * ph.sin()]
            };
            [leg(phi), leg(phi + std::f64::consts::PI)]
        }
        "sit" => {
            let hip = uniform_in(rng, -90.0, -45.0);
            let knee = uniform_in(rng, 45.0, 120.0);
            let mut leg = || [hip + n(rng, 6.0), knee + n(rng, 6.0), n(rng, 5.0)];
            [leg(), leg()]
        }
        _ => {
            let raised = [
                uniform_in(rng, -90.0, -20.0),
                uniform_in(rng, 0.0, 120.0),
                n(rng, 8.0),
            ];
            let other = stand(rng);
            if uniform(rng) < 0.5 {
                [raised, other]
            } else {
                [other, raised]
            }
        }
    };
    for (side, leg) in [(false, legs[0]), (true, legs[1])] {
        let s = usize::from(side);
        let [hip, knee, foot] = leg;
        let ul = [
            hip,
            tn(rng, 0.0, 8.0, -30.0, 30.0),
            tn(rng, -4.0, 8.0, -35.0, 15.0),
        ];
        th.set_lr(slot("upperleg01.L") + s, side, ul);
        let ll = [knee, tn(rng, 0.0, 3.0, -8.0, 8.0), 0.0];
        th.set_lr(slot("lowerleg01.L") + s, side, ll);
        for bone in ["upperleg02", "lowerleg02"] {
            let l = twist_limit(bone);
            let t = tn(rng, 0.0, l / 2.0, -l, l);
            th.set_lr(slot(&format!("{bone}.L")) + s, side, [0.0, t, 0.0]);
        }
        let ft = [
            foot + tn(rng, 0.0, 6.0, -20.0, 40.0),
            tn(rng, 0.0, 3.0, -10.0, 10.0),
            tn(rng, 0.0, 5.0, -15.0, 15.0),
        ];
        th.set_lr(slot("foot.L") + s, side, ft);
    }
}

// ---------------------------------------------------------------------------------------------
// Hands.

/// A hand prototype: per-finger curl `c ∈ [0, 1]` (thumb, index, middle, ring, little),
/// thumb opposition `o ∈ [0, 1]` and finger spread `s ∈ [0, 1]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HandShape {
    /// Name of the prototype.
    pub name: &'static str,
    /// Curl of thumb, index, middle, ring, little (0 straight, 1 fully flexed).
    pub curl: [f64; 5],
    /// Thumb opposition (0 beside the index, 1 across the palm).
    pub opposition: f64,
    /// Spread of the straight fingers (0 together, 1 wide).
    pub spread: f64,
}

/// The gesture prototypes of [`HandSampler`] and their weights.
pub const HAND_SHAPES: [(HandShape, f64); 9] = [
    (
        HandShape {
            name: "relaxed",
            curl: [0.30, 0.25, 0.30, 0.35, 0.40],
            opposition: 0.35,
            spread: 0.3,
        },
        3.0,
    ),
    (
        HandShape {
            name: "flat",
            curl: [0.0; 5],
            opposition: 0.0,
            spread: 0.15,
        },
        1.0,
    ),
    (
        HandShape {
            name: "spread",
            curl: [0.0; 5],
            opposition: 0.0,
            spread: 1.0,
        },
        1.0,
    ),
    (
        HandShape {
            name: "fist",
            curl: [0.85, 1.0, 1.0, 1.0, 1.0],
            opposition: 0.7,
            spread: 0.0,
        },
        2.0,
    ),
    (
        HandShape {
            name: "grip",
            curl: [0.5, 0.6, 0.65, 0.7, 0.75],
            opposition: 0.8,
            spread: 0.0,
        },
        2.0,
    ),
    (
        HandShape {
            name: "point",
            curl: [0.8, 0.0, 1.0, 1.0, 1.0],
            opposition: 0.6,
            spread: 0.0,
        },
        1.0,
    ),
    (
        HandShape {
            name: "peace",
            curl: [0.8, 0.0, 0.0, 1.0, 1.0],
            opposition: 0.7,
            spread: 0.7,
        },
        1.0,
    ),
    (
        HandShape {
            name: "pinch",
            curl: [0.5, 0.55, 0.2, 0.25, 0.3],
            opposition: 0.9,
            spread: 0.2,
        },
        1.0,
    ),
    (
        HandShape {
            name: "thumbs_up",
            curl: [0.0, 1.0, 1.0, 1.0, 1.0],
            opposition: 0.0,
            spread: 0.0,
        },
        1.0,
    ),
];

/// Spread direction (degrees of finger{2..5}-1 z at spread 1, left hand) of index, middle,
/// ring, little: index away from the middle finger is +z on the left hand (docs/design/rig-and-ik.md §3.1), the others
/// fan out the other way.
pub const SPREAD_DEG: [f64; 4] = [10.0, 0.0, -6.0, -12.0];

/// Hand gestures (19 bones per hand, docs/design/rig-and-ik.md §3.2), MANO-style: Gaussian around prototypes.
///
/// Per hand: a prototype from [`HAND_SHAPES`] (by weight), one grip value
/// `g ~ N(0, 0.12)` added to every curl, per-finger curl noise `N(0, 0.06)`, opposition
/// `+N(0, 0.1)`, spread `+N(0, 0.1)` (curl, opposition, spread clipped to [0, 1]). Joint
/// angles (left convention, degrees) from curl `c` of fingers 2–5: MCP x = −5 + 85c, PIP
/// x = 95c, DIP x = 65c, MCP z = SPREAD_DEG·s·(1 − c); thumb (curl `c_t`, opposition `o`):
/// CMC x = −10 + 40o, CMC z = 10(1 − o) − 10c_t, CMC y = 0, MCP x = 50c_t, IP x = 70c_t;
/// metacarpal k x = max_k · (0.3 + 0.7c_{k+1}) · κ with cupping `κ ~ U(0.3, 1)`. Then
/// per-joint noise `N(0, 3°)` on every non-zero-range axis, clamped to [`bone_range`].
/// The two hands are drawn independently.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HandSampler;

impl HandSampler {
    /// Draws a gesture for both hands into `theta` (other slots untouched).
    pub fn sample_into(&self, rng: &mut impl RngCore, theta: &mut Theta) {
        let w: Vec<f64> = HAND_SHAPES.iter().map(|(_, w)| *w).collect();
        for right in [false, true] {
            let shape = HAND_SHAPES[choose_weighted(rng, &w)].0;
            self.shape_into(rng, &shape, 0.12, 0.06, 3.0, theta, right);
        }
    }

    /// A gesture for both hands on an otherwise rest pose.
    pub fn sample(&self, rng: &mut impl RngCore) -> Theta {
        let mut th = Theta::default();
        self.sample_into(rng, &mut th);
        th
    }

    /// A relaxed hand (mild natural grip), for body rows: the "relaxed" prototype with grip
    /// `N(0, 0.06)`, curl noise `N(0, 0.03)` and joint noise `N(0, 2°)`.
    pub fn relaxed_into(&self, rng: &mut impl RngCore, theta: &mut Theta, right: bool) {
        let shape = HAND_SHAPES[0].0;
        self.shape_into(rng, &shape, 0.06, 0.03, 2.0, theta, right);
    }

    #[allow(clippy::too_many_arguments)]
    fn shape_into(
        &self,
        rng: &mut impl RngCore,
        shape: &HandShape,
        grip_sd: f64,
        curl_sd: f64,
        joint_sd: f64,
        theta: &mut Theta,
        right: bool,
    ) {
        let g = grip_sd * normal(rng);
        let curl = shape
            .curl
            .map(|c| (c + g + curl_sd * normal(rng)).clamp(0.0, 1.0));
        let o = (shape.opposition + 0.1 * normal(rng)).clamp(0.0, 1.0);
        let s = (shape.spread + 0.1 * normal(rng)).clamp(0.0, 1.0);
        let cup = uniform_in(rng, 0.3, 1.0);
        let ct = curl[0];
        let mut e = [[0.0; 3]; 19];
        e[0] = [-10.0 + 40.0 * o, 0.0, 10.0 * (1.0 - o) - 10.0 * ct];
        e[1] = [50.0 * ct, 0.0, 0.0];
        e[2] = [70.0 * ct, 0.0, 0.0];
        let mc_max = [6.0, 6.0, 8.0, 10.0];
        for k in 0..4 {
            e[3 + k] = [mc_max[k] * (0.3 + 0.7 * curl[k + 1]) * cup, 0.0, 0.0];
            let c = curl[k + 1];
            let b = 7 + 3 * k;
            e[b] = [-5.0 + 85.0 * c, 0.0, SPREAD_DEG[k] * s * (1.0 - c)];
            e[b + 1] = [95.0 * c, 0.0, 0.0];
            e[b + 2] = [65.0 * c, 0.0, 0.0];
        }
        let first = if right {
            RIGHT_HAND_SLOT
        } else {
            LEFT_HAND_SLOT
        };
        for (j, mut a) in e.into_iter().enumerate() {
            let r = bone_range(&format!("{}.L", HAND_BONES[j])).expect("hand bone range");
            for ax in 0..3 {
                if r[ax][0] < r[ax][1] {
                    a[ax] = (a[ax] + joint_sd * normal(rng)).clamp(r[ax][0], r[ax][1]);
                } else {
                    a[ax] = r[ax][0];
                }
            }
            theta.set_lr(first + j, right, a);
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Faces.

/// The eight `eyeLook*` units (gaze by blendshape).
pub const EYE_LOOK_UNITS: [&str; 8] = [
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
];

/// Mutually exclusive unit pairs (opposite motions): never both active.
pub const EXCLUSIVE_UNITS: [(&str, &str); 2] =
    [("jawLeft", "jawRight"), ("mouthLeft", "mouthRight")];

/// The mirror unit of a `…Left`/`…Right` unit (`None` for central units and for the
/// exclusive pairs).
pub fn mirror_unit(unit: &str) -> Option<&'static str> {
    if EXCLUSIVE_UNITS
        .iter()
        .any(|(a, b)| *a == unit || *b == unit)
    {
        return None;
    }
    let m = if let Some(b) = unit.strip_suffix("Left") {
        format!("{b}Right")
    } else if let Some(b) = unit.strip_suffix("Right") {
        format!("{b}Left")
    } else {
        return None;
    };
    face_unit_index(&m).map(|k| FACE_UNITS[k])
}

/// A facial expression: face-unit values (docs/design/assets.md §5.4) and the jaw/eye bone angles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Expression {
    /// Unit values in [`FACE_UNITS`] order, each in [0, 1].
    pub units: [f64; 52],
    /// Jaw `[x, y, z]` degrees (x = open).
    pub jaw: [f64; 3],
    /// Gaze `[x, y, z]` degrees, the same on both eyes (x = up, z = toward +x).
    pub eyes: [f64; 3],
}

impl Expression {
    /// Writes the jaw and eye angles into the face slots of `theta`.
    pub fn write_theta(&self, theta: &mut Theta) {
        theta.deg[FACE_SLOT] = self.jaw;
        theta.deg[FACE_SLOT + 1] = self.eyes;
        theta.deg[FACE_SLOT + 2] = self.eyes;
    }
}

/// Sparse facial expressions avoiding docs/design/rig-and-ik.md §3.2's double counting.
///
/// 1. Gaze: with p = 0.5 by the *eye bones* — x `TN(0, 8; ±20)`, z `TN(0, 12; ±30)`, the
///    same on both eyes, and no `eyeLook*` unit; else by *units* with p = 0.5 — horizontal
///    `h ~ TN(0, 0.5; ±1)` (h > 0 looks toward +x: eyeLookOutLeft = eyeLookInRight = h; h < 0:
///    eyeLookInLeft = eyeLookOutRight = |h|) and vertical `v ~ TN(0, 0.4; ±1)` (Up or Down
///    on both eyes), each axis active with p = 0.6; else no gaze.
/// 2. `k ~ U{1, …, 6}` distinct units drawn uniformly from the 43 units other than
///    `eyeLook*` and mouthClose, each `~ U(0.1, 1)`; a second unit of an
///    [`EXCLUSIVE_UNITS`] pair is dropped. A unit with a mirror ([`mirror_unit`]) gets its
///    mirror set to the same value with p = 0.5 (symmetric), to an independent `U(0.1, 1)`
///    with p = 0.2, else stays one-sided (unless the mirror was drawn itself).
/// 3. If jawOpen > 0: mouthClose `~ U(0, jawOpen)` with p = 0.3 (ARKit: used with jawOpen).
/// 4. Jaw bone with p = 0.4: x `~ U(0, 22)·(1 − jawOpen)` (a large jawOpen leaves little
///    rotation), y `TN(0, 1.5; ±3)`, z `TN(0, 2; ±4)`; else at rest.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExpressionSampler;

impl ExpressionSampler {
    /// Draws one expression (see the type docs).
    pub fn sample(&self, rng: &mut impl RngCore) -> Expression {
        let mut units = [0.0; 52];
        let mut eyes = [0.0; 3];
        let idx = |u: &str| face_unit_index(u).expect("face unit");
        let gaze = uniform(rng);
        if gaze < 0.5 {
            eyes = [
                truncated_normal(rng, 0.0, 8.0, -20.0, 20.0),
                0.0,
                truncated_normal(rng, 0.0, 12.0, -30.0, 30.0),
            ];
        } else if gaze < 0.75 {
            let h = truncated_normal(rng, 0.0, 0.5, -1.0, 1.0);
            let v = truncated_normal(rng, 0.0, 0.4, -1.0, 1.0);
            if uniform(rng) < 0.6 {
                let (a, b) = if h > 0.0 {
                    ("eyeLookOutLeft", "eyeLookInRight")
                } else {
                    ("eyeLookInLeft", "eyeLookOutRight")
                };
                units[idx(a)] = h.abs();
                units[idx(b)] = h.abs();
            }
            if uniform(rng) < 0.6 {
                let (a, b) = if v > 0.0 {
                    ("eyeLookUpLeft", "eyeLookUpRight")
                } else {
                    ("eyeLookDownLeft", "eyeLookDownRight")
                };
                units[idx(a)] = v.abs();
                units[idx(b)] = v.abs();
            }
        }
        let mut pool: Vec<usize> = (0..52)
            .filter(|&k| !EYE_LOOK_UNITS.contains(&FACE_UNITS[k]) && FACE_UNITS[k] != "mouthClose")
            .collect();
        let k = 1 + (uniform(rng) * 6.0) as usize;
        let mut chosen = Vec::with_capacity(6);
        for _ in 0..k.min(6) {
            let j = (uniform(rng) * pool.len() as f64) as usize;
            chosen.push(pool.swap_remove(j.min(pool.len() - 1)));
        }
        for &u in &chosen {
            let name = FACE_UNITS[u];
            let v = uniform_in(rng, 0.1, 1.0);
            let excluded = EXCLUSIVE_UNITS.iter().any(|&(a, b)| {
                (name == a && units[idx(b)] > 0.0) || (name == b && units[idx(a)] > 0.0)
            });
            if excluded {
                continue;
            }
            units[u] = v;
            if let Some(m) = mirror_unit(name) {
                let mi = idx(m);
                let p = uniform(rng);
                let mv = uniform_in(rng, 0.1, 1.0);
                if !chosen.contains(&mi) {
                    if p < 0.5 {
                        units[mi] = v;
                    } else if p < 0.7 {
                        units[mi] = mv;
                    }
                }
            }
        }
        let jaw_open = units[idx("jawOpen")];
        if jaw_open > 0.0 && uniform(rng) < 0.3 {
            units[idx("mouthClose")] = uniform_in(rng, 0.0, jaw_open);
        }
        let mut jaw = [0.0; 3];
        if uniform(rng) < 0.4 {
            jaw = [
                uniform_in(rng, 0.0, 22.0) * (1.0 - jaw_open),
                truncated_normal(rng, 0.0, 1.5, -3.0, 3.0),
                truncated_normal(rng, 0.0, 2.0, -4.0, 4.0),
            ];
        }
        for u in &mut units {
            *u = u.clamp(0.0, 1.0);
        }
        Expression { units, jaw, eyes }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn beta_moments_and_tiny_shapes() {
        let mut rng = stream_rng(7, 99, 0);
        for (a, b) in [(2.0, 5.0), (0.3, 0.7), (21.6, 58.6)] {
            let n = 20000;
            let xs: Vec<f64> = (0..n).map(|_| beta(&mut rng, a, b)).collect();
            let m = xs.iter().sum::<f64>() / n as f64;
            let want = a / (a + b);
            assert!((m - want).abs() < 0.01, "Beta({a},{b}) mean {m} vs {want}");
        }
        for _ in 0..1000 {
            let x = beta(&mut rng, 0.273, 0.00937);
            assert!((0.0..=1.0).contains(&x));
            let y = beta(&mut rng, 0.00996, 0.2929);
            assert!((0.0..=1.0).contains(&y));
        }
    }

    #[test]
    fn interp_matches_anchors() {
        assert_eq!(anny_age_of_years(0.0), 0.0);
        assert!((anny_age_of_years(16.0) - 0.67).abs() < 1e-15);
        assert!((anny_age_of_years(90.0) - (0.83 + 26.0 / 46.0 * 0.17)).abs() < 1e-12);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 3.0, false), 4.0);
        assert_eq!(interp(&[0.0, 1.0], &[2.0, 4.0], 3.0, true), 8.0);
    }

    #[test]
    fn mirror_units() {
        assert_eq!(mirror_unit("browDownLeft"), Some("browDownRight"));
        assert_eq!(mirror_unit("mouthSmileRight"), Some("mouthSmileLeft"));
        assert_eq!(mirror_unit("jawLeft"), None);
        assert_eq!(mirror_unit("cheekPuff"), None);
    }
}
