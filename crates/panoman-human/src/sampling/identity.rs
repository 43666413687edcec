//! Identities: age, sex, phenotype and race from Anny's calibration tables
//! (docs/design/rig-and-ik.md §3.4).

use super::*;

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
