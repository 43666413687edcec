//! Hand gestures: shapes, spreads and their blends (docs/design/rig-and-ik.md §3.2).

use super::*;

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
