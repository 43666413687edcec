//! TC-133 keypoints (docs/formats.md §3): 15 body joints (CMU Panoptic order), Total Capture's
//! 6 foot points (big toe, little toe, heel per foot), 70 face landmarks (iBUG 300-W 68 + 2
//! pupils) and 2 × 21 hand joints, each a fixed sparse linear combination of template
//! vertices ([`KeypointSet`]). The layout before the feet, TC-127, is TC-133 without
//! [`FEET_NAMES`] ([`tc127_names`], [`KeypointsFile::from_points`]).
//!
//! # Layout
//! [`keypoint_names`]: `neck, nose, body_center, l_shoulder, l_elbow, l_wrist, l_hip, l_knee,
//! l_ankle, r_shoulder, …, r_ankle`, then `l_big_toe, l_small_toe, l_heel, r_big_toe,
//! r_small_toe, r_heel`, then `face_00`…`face_69` (300-W order: jaw 0–16, brows
//! 17–26, nose 27–35, eyes 36–47 with 36–41 the subject's right eye, lips 48–67; `face_68`
//! right pupil, `face_69` left pupil), `lhand_00`…`lhand_20`, `rhand_00`…`rhand_20` (0 wrist;
//! thumb 1–4 CMC, MCP, IP, tip; index 5–8, middle 9–12, ring 13–16, little 17–20: MCP, PIP,
//! DIP, tip). "Left" is the character's left, +x.
//!
//! # Definitions
//! Every row's weights sum to 1, so keypoints move with any translation of the mesh.
//!
//! **Joint centres** ([`KeypointKind::Regressor`]: the body joints but the nose, the hand
//! joints but the tips, the pupils) are sparse affine regressors fitted on generated data
//! (posed vertices → posed joint centres). Ground truth from the posed rig (bone heads are
//! joint centres, docs/design/rig-and-ik.md §2):
//!
//! | keypoint | ground truth |
//! |---|---|
//! | `neck` | head of `neck01` (base of the neck, between the shoulders) |
//! | `body_center` | midpoint of the heads of `upperleg01.L/R` (the hip joint centres) |
//! | `l_shoulder`, `l_elbow`, `l_wrist` | heads of `upperarm01.L`, `lowerarm01.L`, `wrist.L` |
//! | `l_hip`, `l_knee`, `l_ankle` | heads of `upperleg01.L`, `lowerleg01.L`, `foot.L` |
//! | `r_…` | the same `.R` bones |
//! | hand 0 (wrist) | head of `wrist.L/R` (same point as `l_wrist`/`r_wrist`) |
//! | thumb 1, 2, 3 | heads of `finger1-1`, `finger1-2`, `finger1-3` (CMC, MCP, IP) |
//! | index 5, 6, 7 | heads of `finger2-1`, `finger2-2`, `finger2-3` (MCP, PIP, DIP); middle `finger3-*`, ring `finger4-*`, little `finger5-*` |
//! | `face_68`, `face_69` | cornea apex of the right/left eyeball: `h + (max_v (v − h)·d) d`, `h` the eye bone's head, `d` its unit direction (the gaze), `v` over the eyeball's vertices ([`EYE_R_BASE`], [`EYE_L_BASE`]) |
//!
//! The template has no eyeballs, so the pupils are defined for straight gaze (the fit's
//! expressions carry no gaze). Fit ([`build_definitions`], [`FitConfig`]): candidates are the
//! `k` vertices nearest to the target on the default identity's rest mesh, among the body
//! part's vertices for body joints (the wrists also their hand's), the hand part grown by 3
//! rings for hand joints, the face part for the pupils; the weights minimise the squared
//! error over all training samples and coordinates subject to `Σ w = 1` (KKT system) plus a
//! ridge `λ ‖w‖²`, `λ = ridge · tr(A)/k` (per group: body 1e-5, hands 1e-4, pupils 1e-3),
//! each sample centred on its candidates' mean. The ridge is an i.i.d. vertex-noise prior:
//! it keeps the noise gain `‖w‖₂` (vertex noise → keypoint noise) at about 5 for the body
//! and 1.5 for the hands and the pupils (a nearly unregularised fit, ridge 1e-7, is 0.7 mm
//! more accurate on the body and 0.1 mm on the hands, with gains of 10–27). Samples: sample `i` of `n_train` uses
//! `stream_rng(seed, DOMAIN_KEYPOINT_TRAIN, i)` for an identity
//! ([`crate::sampling::IdentitySampler`]), a body pose
//! ([`crate::sampling::BodyPoseSampler`]) whose hands get gestures
//! ([`crate::sampling::HandSampler`]) and, with probability [`EXPRESSION_FRACTION`], a facial
//! expression ([`crate::sampling::ExpressionSampler`], gaze units and eye bones left out).
//! The held-out samples come from [`DOMAIN_KEYPOINT_TEST`]: other identities and poses.
//! Held-out accuracy of the default fit (800 training, 200 held-out samples), mean / max:
//! full template — body 1.28 / 10.7 mm (hips and knees ≈ 2 mm, wrists and ankles ≤ 0.4 mm),
//! hands 0.30 / 3.7 mm, pupils 0.37 / 2.3 mm; small topology — body 2.6 / 20 mm, hands
//! 0.34 / 3.5 mm, pupils 0.43 / 1.9 mm ([`KeypointDefinitions::held_out_full`] and
//! [`KeypointDefinitions::held_out_small`] carry the numbers of a build).
//!
//! **Surface points** ([`KeypointKind::Surface`]: face landmarks 0–67, `nose` = `face_30`,
//! the fingertips, the foot points) are barycentric points of template triangles (3-vertex
//! rows), picked on the default identity's rest mesh (all phenotype values 0.5, no
//! expression). Fingertips: the ray from the head of the distal bone (`finger1-3` for the
//! thumb, `fingerN-3`) along the bone meets the hand's skin. Toe tips the same with the big
//! toe's `toe1-2` and the little toe's `toe5-3` on the body's skin; the heel is where the ray
//! from the ankle (head of `foot.L/R`) 45° backwards and down ([`HEEL_DIRECTION`]) leaves
//! the skin: the back-bottom of the heel. Face landmarks ([`face_landmarks`]): with x lateral, y
//! depth (the face looks along −y) and z up, on the `head` skin label (cavities excluded):
//!
//! * **Eyes 36–47**: the lid margin is the loop between the `head` and `eye_cavity.R/L`
//!   faces. Its smallest- and largest-x points are the corners (36 outer, 39 inner on the
//!   right eye; 42 inner, 45 outer on the left); 37, 38 (43, 44) are where the upper arc
//!   crosses 1/3 and 2/3 of the way from the first corner, 41, 40 (47, 46) the same on the
//!   lower arc.
//! * **Inner lips 60–67**: the loop between `head` and `mouth_cavity`: 60, 64 its extreme-x
//!   points; 61, 62, 63 (67, 66, 65) on the upper (lower) arc at 1/4, 1/2, 3/4 of the width.
//! * **Outer lips 48–59**: the [`LIP_BORDER_RING`]-th vertex ring of the quad graph around
//!   the mouth opening — hm08's vermilion-border edge loop, where the midline profile turns
//!   from the lip to the philtrum and the chin. 48, 54 its extreme-x points; 50, 52 the
//!   highest points of its upper arc on each side (cupid's bow), 51 its centre, 49, 53 half
//!   way (in x) between corner and peak; on the lower arc 57 at the centre, 58, 56 and 59, 55
//!   below 50, 52 and 49, 53 (same x).
//! * **Nose 27–35**: in the midline section, 30 is the most anterior point between mouth and
//!   eye height; walking up from it, 27 is the first local maximum of y (the nasion, 1 mm
//!   hysteresis); 28, 29 at 1/3 and 2/3 of the height from 27 to 30. "Nose bottom at x": in
//!   the section x = const, walking down from the tip's height, the sharpest concave bend
//!   above the upper lip (±1.5 mm chords) — the junction of columella or ala with the lip.
//!   33 is the nose bottom at the midline; the alar half-width is, in the horizontal section
//!   a third of the way from 33 up to 30, walking out from the front of the nose, the outer
//!   end of the outermost chord steeper than 45° (the ala's occluding contour seen from the
//!   front); 31, 35 are the nose bottoms at [`ALA_FRACTION`] of it; 32, 34 the first skin
//!   points of the frontal view rays through the image midpoints of 31–33 and 33–35.
//! * **Jaw 0–16**: the face's occluding contour seen from the front. For each angle θ (1°
//!   steps from straight down, outwards and up), the plane through the view axis and the
//!   image ray from the mouth centre at θ cuts the skin; walking outwards from the front
//!   point 2.8–3.4 cm from the mouth centre, the contour is the first place where, over 3 mm
//!   of arc, the section moves away from the camera faster than outwards (`Δs < 0.36 Δy`),
//!   or where it turns back (2 mm hysteresis). The trace stops at the mean height of the eye
//!   corners; 0–8 (right, −x) and 8–16 (left) are spaced at equal frontal arc length, 8 the
//!   chin.
//! * **Brows 17–26**: sections x = const at 5 positions evenly spaced from a third of an eye
//!   width beyond the outer corner to a tenth of it inside the inner corner; walking up from
//!   the upper lid (beyond the corners from the corner's height), the sharpest convex bend
//!   within 4 cm, over ±4 mm chords (the superior orbital rim, where the lid sulcus turns
//!   into the forehead). 17 → 21 run outer → inner on the right, 22 → 26 inner → outer on
//!   the left.
//!
//! Each point is finally projected onto the head skin (closest point) and stored as
//! (triangle, barycentric). Renders of the result: the module's tests and the report.
//!
//! # Small topology
//! Surface points: the closest point of the small rest mesh (the default identity prolonged
//! through the binding; faces of the keypoint's part) to the full-template point. Regressors:
//! refitted on the small vertices of the same samples (prolonged), with `k_small_*`
//! candidates, so they are as exact as the coarse mesh allows (see the numbers above).
//!
//! # Storage
//! The definitions are computed from the assets at run time and are deterministic (seeded
//! per-sample streams, sums in sample order); a build takes 2–4 s including loading the
//! generator, so [`load_or_build`] caches them as JSON in `<asset dir>-derived/`
//! ([`CACHE_FILE`], full rows by base-mesh index) and rebuilds when the file is missing or
//! invalid or its version, asset version or settings differ. Changes to the rules, the
//! samplers or the generator must bump [`DEFINITIONS_VERSION`] (and the file name).
//!
//! # Keypoints files
//! [`KeypointsFile`]: `{"units": "m", "keypoints": {name: [x, y, z]}, "weights": {name: w}}`
//! with any subset of the names (docs/formats.md); unknown names, keys, non-finite values
//! and negative weights are errors.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::sync::LazyLock;

use panoman_mesh::Topology;
use panoman_mesh::geom::{V3, add, cross, dot, norm, scale, sub};
use rayon::prelude::*;

use crate::assets::AssetDir;
use crate::error::{HumanError, Result};
use crate::generator::{Generator, Posed};
use crate::params::{PoseParams, ShapeParams};
use crate::regions::{Part, Regions};
use crate::template::{Binding, SmallTopology, Template, closest_point_on_triangle};

mod cache;
mod definitions;
mod landmarks;
mod surface;

pub use cache::{CACHE_FILE, DEFINITIONS_VERSION, derived_dir, load_or_build};
pub use definitions::{
    DOMAIN_KEYPOINT_TEST, DOMAIN_KEYPOINT_TRAIN, EXPRESSION_FRACTION, EYE_L_BASE, EYE_R_BASE,
    FitConfig, GroupError, KeypointDefinitions, KeypointError, KeypointKind, build_definitions,
};
pub use landmarks::{ALA_FRACTION, LIP_BORDER_RING, face_landmarks};

// ---------------------------------------------------------------------------------------------
// Layout.

/// The 15 body keypoints in CMU Panoptic order.
pub const BODY_NAMES: [&str; 15] = [
    "neck",
    "nose",
    "body_center",
    "l_shoulder",
    "l_elbow",
    "l_wrist",
    "l_hip",
    "l_knee",
    "l_ankle",
    "r_shoulder",
    "r_elbow",
    "r_wrist",
    "r_hip",
    "r_knee",
    "r_ankle",
];

/// The six foot keypoints of Total Capture (supplementary §2.1; OpenPose BODY_25 19–24 in
/// this order): tip of the big toe, tip of the little toe and the heel, left foot first.
pub const FEET_NAMES: [&str; 6] = [
    "l_big_toe",
    "l_small_toe",
    "l_heel",
    "r_big_toe",
    "r_small_toe",
    "r_heel",
];

/// Number of body keypoints.
pub const N_BODY: usize = 15;
/// Number of foot keypoints.
pub const N_FEET: usize = 6;
/// Number of face keypoints (300-W 68 + 2 pupils).
pub const N_FACE: usize = 70;
/// Number of keypoints per hand.
pub const N_HAND: usize = 21;
/// Total number of keypoints of the TC-133 layout (133).
pub const N_KEYPOINTS: usize = N_BODY + N_FEET + N_FACE + 2 * N_HAND;
/// Index of `l_big_toe`.
pub const FEET_OFFSET: usize = N_BODY;
/// Index of `face_00`.
pub const FACE_OFFSET: usize = N_BODY + N_FEET;
/// Index of `lhand_00`.
pub const LHAND_OFFSET: usize = FACE_OFFSET + N_FACE;
/// Index of `rhand_00`.
pub const RHAND_OFFSET: usize = LHAND_OFFSET + N_HAND;
/// Name of the layout, as files and reports give it.
pub const LAYOUT_NAME: &str = "TC-133";
/// Name of the older layout without the feet ([`tc127_names`]).
pub const LAYOUT_NAME_TC127: &str = "TC-127";
/// Number of keypoints of the older TC-127 layout (TC-133 without the feet).
pub const N_KEYPOINTS_TC127: usize = N_KEYPOINTS - N_FEET;

static NAMES: LazyLock<Vec<String>> = LazyLock::new(|| {
    let mut v: Vec<String> = BODY_NAMES.iter().map(|s| s.to_string()).collect();
    v.extend(FEET_NAMES.iter().map(|s| s.to_string()));
    v.extend((0..N_FACE).map(|i| format!("face_{i:02}")));
    v.extend((0..N_HAND).map(|i| format!("lhand_{i:02}")));
    v.extend((0..N_HAND).map(|i| format!("rhand_{i:02}")));
    v
});

static INDEX: LazyLock<HashMap<&'static str, usize>> = LazyLock::new(|| {
    NAMES
        .iter()
        .enumerate()
        .map(|(i, n)| (n.as_str(), i))
        .collect()
});

/// The 133 keypoint names in TC-133 order: [`BODY_NAMES`], [`FEET_NAMES`],
/// `face_00`…`face_69`, `lhand_00`…`lhand_20`, `rhand_00`…`rhand_20`.
pub fn keypoint_names() -> &'static [String] {
    &NAMES
}

/// The TC-133 index of each TC-127 keypoint (TC-127 is TC-133 without [`FEET_NAMES`]; its
/// names are the same).
pub fn tc127_to_tc133() -> &'static [usize; N_KEYPOINTS_TC127] {
    static MAP: LazyLock<[usize; N_KEYPOINTS_TC127]> = LazyLock::new(|| {
        let mut m = [0; N_KEYPOINTS_TC127];
        let kept = (0..N_KEYPOINTS).filter(|i| !(FEET_OFFSET..FACE_OFFSET).contains(i));
        for (slot, i) in m.iter_mut().zip(kept) {
            *slot = i;
        }
        m
    });
    &MAP
}

/// The 127 names of the TC-127 layout in its order ([`keypoint_names`] without the feet).
pub fn tc127_names() -> Vec<&'static str> {
    tc127_to_tc133()
        .iter()
        .map(|&i| keypoint_names()[i].as_str())
        .collect()
}

/// TC-133 index of a keypoint name.
pub fn keypoint_index(name: &str) -> Option<usize> {
    INDEX.get(name).copied()
}

/// The five keypoint groups (reports give errors per group, keyed by the group; in JSON by its
/// [`KeypointGroup::name`]). The variants are declared in the order of their names, so that a
/// map keyed by groups lists them as one keyed by names would; [`KeypointGroup::ALL`] is the
/// TC-133 order.
#[derive(
    Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "snake_case")]
pub enum KeypointGroup {
    /// The 15 body keypoints.
    Body,
    /// The 70 face keypoints.
    Face,
    /// The 6 foot keypoints.
    Feet,
    /// The 21 left-hand keypoints.
    LeftHand,
    /// The 21 right-hand keypoints.
    RightHand,
}

impl std::fmt::Display for KeypointGroup {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl KeypointGroup {
    /// All groups in TC-133 order.
    pub const ALL: [KeypointGroup; 5] = [
        KeypointGroup::Body,
        KeypointGroup::Feet,
        KeypointGroup::Face,
        KeypointGroup::LeftHand,
        KeypointGroup::RightHand,
    ];

    /// The group of a TC-133 index.
    ///
    /// # Panics
    /// If `index >= N_KEYPOINTS`.
    pub fn of(index: usize) -> KeypointGroup {
        assert!(index < N_KEYPOINTS, "keypoint index {index} out of range");
        if index < FEET_OFFSET {
            KeypointGroup::Body
        } else if index < FACE_OFFSET {
            KeypointGroup::Feet
        } else if index < LHAND_OFFSET {
            KeypointGroup::Face
        } else if index < RHAND_OFFSET {
            KeypointGroup::LeftHand
        } else {
            KeypointGroup::RightHand
        }
    }

    /// Position in [`KeypointGroup::ALL`].
    pub fn position(self) -> usize {
        match self {
            KeypointGroup::Body => 0,
            KeypointGroup::Feet => 1,
            KeypointGroup::Face => 2,
            KeypointGroup::LeftHand => 3,
            KeypointGroup::RightHand => 4,
        }
    }

    /// Name used in reports: `body`, `feet`, `face`, `left_hand`, `right_hand`.
    pub fn name(self) -> &'static str {
        match self {
            KeypointGroup::Body => "body",
            KeypointGroup::Feet => "feet",
            KeypointGroup::Face => "face",
            KeypointGroup::LeftHand => "left_hand",
            KeypointGroup::RightHand => "right_hand",
        }
    }

    /// TC-133 indices of the group.
    pub fn range(self) -> std::ops::Range<usize> {
        match self {
            KeypointGroup::Body => 0..FEET_OFFSET,
            KeypointGroup::Feet => FEET_OFFSET..FACE_OFFSET,
            KeypointGroup::Face => FACE_OFFSET..LHAND_OFFSET,
            KeypointGroup::LeftHand => LHAND_OFFSET..RHAND_OFFSET,
            KeypointGroup::RightHand => RHAND_OFFSET..N_KEYPOINTS,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Keypoint sets.

/// Keypoints as fixed sparse linear combinations of the vertices of one topology:
/// keypoint `k` is `Σ_(v, w) ∈ rows[k] w · positions[v]`.
#[derive(Clone, Debug, PartialEq)]
pub struct KeypointSet {
    /// Keypoint names (TC-133 order for the sets built here).
    pub names: Vec<String>,
    /// Per keypoint, `(vertex, weight)` pairs; weights sum to 1.
    pub rows: Vec<Vec<(u32, f64)>>,
    /// Number of vertices of the topology the rows refer to.
    pub n_vertices: usize,
}

impl KeypointSet {
    /// Number of keypoints.
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// True when there are no keypoints.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Checks that names and rows match, vertex ids are in range, weights are finite and each
    /// row's weights sum to 1 (within 1e-9).
    ///
    /// # Errors
    /// One line naming the first bad keypoint.
    pub fn validate(&self) -> Result<()> {
        self.validate_msg().map_err(HumanError::Invalid)
    }

    /// [`Self::validate`] with the message as a `String`.
    fn validate_msg(&self) -> std::result::Result<(), String> {
        if self.names.len() != self.rows.len() {
            return Err(format!(
                "{} names for {} rows",
                self.names.len(),
                self.rows.len()
            ));
        }
        for (name, row) in self.names.iter().zip(&self.rows) {
            if row.is_empty() {
                return Err(format!("keypoint `{name}` has no vertices"));
            }
            let mut sum = 0.0;
            for &(v, w) in row {
                if v as usize >= self.n_vertices {
                    return Err(format!(
                        "keypoint `{name}` uses vertex {v}, but the topology has {} vertices",
                        self.n_vertices
                    ));
                }
                if !w.is_finite() {
                    return Err(format!("keypoint `{name}` has a non-finite weight"));
                }
                sum += w;
            }
            if (sum - 1.0).abs() > 1e-9 {
                return Err(format!("keypoint `{name}`: weights sum to {sum}, not 1"));
            }
        }
        Ok(())
    }

    /// Evaluates every keypoint on `positions` (a mesh of this set's topology).
    ///
    /// # Panics
    /// If `positions.len() != self.n_vertices` (see [`KeypointSet::try_evaluate`]).
    pub fn evaluate(&self, positions: &[V3]) -> Vec<V3> {
        self.try_evaluate(positions)
            .unwrap_or_else(|e| panic!("KeypointSet::evaluate: {e}"))
    }

    /// [`KeypointSet::evaluate`], failing with one line on a vertex-count mismatch.
    ///
    /// # Errors
    /// The mesh does not have `n_vertices` vertices.
    pub fn try_evaluate(&self, positions: &[V3]) -> Result<Vec<V3>> {
        self.try_evaluate_msg(positions)
            .map_err(HumanError::Invalid)
    }

    /// [`Self::try_evaluate`] with the message as a `String`.
    fn try_evaluate_msg(&self, positions: &[V3]) -> std::result::Result<Vec<V3>, String> {
        if positions.len() != self.n_vertices {
            return Err(format!(
                "the mesh has {} vertices, the keypoint definitions expect {}",
                positions.len(),
                self.n_vertices
            ));
        }
        Ok(self
            .rows
            .iter()
            .map(|row| eval_row(row, positions))
            .collect())
    }

    /// Index of a keypoint name in this set.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }
}

#[inline]
fn eval_row(row: &[(u32, f64)], positions: &[V3]) -> V3 {
    let mut p = [0.0; 3];
    for &(v, w) in row {
        let q = positions[v as usize];
        p[0] += w * q[0];
        p[1] += w * q[1];
        p[2] += w * q[2];
    }
    p
}

// ---------------------------------------------------------------------------------------------
// Keypoints JSON (docs/formats.md).

/// Observed keypoints as read from or written to a keypoints JSON file:
/// `{"units": "m", "keypoints": {name: [x, y, z]}, "weights": {name: w}}` with any subset of
/// the TC-133 names (so files of the TC-127 layout read as they are, without the feet).
#[derive(Clone, Debug, PartialEq, Default)]
pub struct KeypointsFile {
    /// Position of each given keypoint (metres), by TC-133 index.
    pub points: BTreeMap<usize, V3>,
    /// Weight of each given keypoint (default 1); only for keypoints in `points`.
    pub weights: BTreeMap<usize, f64>,
}

impl KeypointsFile {
    /// All 133 keypoints of `points` (TC-133 order) with unit weights.
    ///
    /// # Panics
    /// If `points.len() != N_KEYPOINTS`.
    pub fn from_all(points: &[V3]) -> KeypointsFile {
        assert_eq!(points.len(), N_KEYPOINTS, "one point per TC-133 keypoint");
        KeypointsFile {
            points: points.iter().copied().enumerate().collect(),
            weights: (0..N_KEYPOINTS).map(|i| (i, 1.0)).collect(),
        }
    }

    /// One point per keypoint of either layout, with unit weights: 133 points in TC-133
    /// order, or 127 in the older TC-127 order ([`tc127_names`]: the feet absent).
    ///
    /// # Errors
    /// Any other count.
    pub fn from_points(points: &[V3]) -> Result<KeypointsFile> {
        let index: Vec<usize> = match points.len() {
            N_KEYPOINTS => (0..N_KEYPOINTS).collect(),
            N_KEYPOINTS_TC127 => tc127_to_tc133().to_vec(),
            n => {
                return Err(HumanError::Invalid(format!(
                    "expected {N_KEYPOINTS} keypoints (TC-133) or {N_KEYPOINTS_TC127} (TC-127), \
                     got {n}"
                )));
            }
        };
        Ok(KeypointsFile {
            points: index.iter().copied().zip(points.iter().copied()).collect(),
            weights: index.iter().map(|&i| (i, 1.0)).collect(),
        })
    }

    /// This file without the keypoints of `group` (e.g. [`KeypointGroup::Feet`]: the TC-127
    /// view of TC-133 targets).
    pub fn without_group(mut self, group: KeypointGroup) -> KeypointsFile {
        let r = group.range();
        self.points.retain(|i, _| !r.contains(i));
        self.weights.retain(|i, _| !r.contains(i));
        self
    }

    /// Weight of keypoint `index` (1 if the file gives none).
    pub fn weight(&self, index: usize) -> f64 {
        self.weights.get(&index).copied().unwrap_or(1.0)
    }

    /// Checks finiteness (positions and weights), positions within
    /// [`panoman_mesh::geom::MAX_COORDINATE`] (10 km) of the origin per coordinate, weights ≥ 0,
    /// and that every weight belongs to a given keypoint.
    ///
    /// # Errors
    /// One line naming the keypoint.
    pub fn validate(&self) -> Result<()> {
        self.validate_msg().map_err(HumanError::Invalid)
    }

    /// [`Self::validate`] with the message as a `String`.
    fn validate_msg(&self) -> std::result::Result<(), String> {
        let names = keypoint_names();
        for (&i, p) in &self.points {
            let name = names.get(i).ok_or_else(|| format!("keypoint index {i}"))?;
            if p.iter().any(|c| !c.is_finite()) {
                return Err(format!("keypoint `{name}` is not finite: {p:?}"));
            }
            if !panoman_mesh::geom::is_in_bounds(*p) {
                return Err(format!(
                    "keypoint `{name}` at {p:?} is out of bounds (|coordinate| > {} m; \
                     positions are in metres)",
                    panoman_mesh::geom::MAX_COORDINATE
                ));
            }
        }
        for (&i, &w) in &self.weights {
            let name = names.get(i).ok_or_else(|| format!("keypoint index {i}"))?;
            if !w.is_finite() || w < 0.0 {
                return Err(format!(
                    "weight of `{name}` must be finite and ≥ 0, got {w}"
                ));
            }
            if !self.points.contains_key(&i) {
                return Err(format!("weight for `{name}`, which has no position"));
            }
        }
        Ok(())
    }

    /// Parses keypoints JSON. `units` must be `"m"` when present; unknown top-level keys,
    /// unknown keypoint names, non-numbers, non-finite values and negative weights are errors.
    ///
    /// # Errors
    /// One line saying what is wrong.
    pub fn parse(text: &str) -> Result<KeypointsFile> {
        Self::parse_msg(text).map_err(HumanError::Invalid)
    }

    /// [`Self::parse`] with the message as a `String`.
    fn parse_msg(text: &str) -> std::result::Result<KeypointsFile, String> {
        let value: serde_json::Value =
            serde_json::from_str(text).map_err(|e| format!("invalid JSON: {e}"))?;
        let obj = value
            .as_object()
            .ok_or("expected a JSON object with `keypoints`")?;
        let mut out = KeypointsFile::default();
        let mut have_points = false;
        for (key, v) in obj {
            match key.as_str() {
                "units" => {
                    if v.as_str() != Some("m") {
                        return Err(format!("`units` must be \"m\", got {v}"));
                    }
                }
                "keypoints" => {
                    have_points = true;
                    let map = v.as_object().ok_or("`keypoints` must be an object")?;
                    for (name, p) in map {
                        let i = keypoint_index(name)
                            .ok_or_else(|| format!("unknown keypoint `{name}`"))?;
                        let arr = p
                            .as_array()
                            .filter(|a| a.len() == 3)
                            .ok_or_else(|| format!("keypoint `{name}`: expected [x, y, z]"))?;
                        let mut q = [0.0; 3];
                        for (c, x) in q.iter_mut().zip(arr) {
                            *c = x.as_f64().ok_or_else(|| {
                                format!("keypoint `{name}`: `{x}` is not a number")
                            })?;
                        }
                        out.points.insert(i, q);
                    }
                }
                "weights" => {
                    let map = v.as_object().ok_or("`weights` must be an object")?;
                    for (name, w) in map {
                        let i = keypoint_index(name)
                            .ok_or_else(|| format!("weight for unknown keypoint `{name}`"))?;
                        let w = w
                            .as_f64()
                            .ok_or_else(|| format!("weight of `{name}`: `{w}` is not a number"))?;
                        out.weights.insert(i, w);
                    }
                }
                other => return Err(format!("unknown key `{other}`")),
            }
        }
        if !have_points {
            return Err("missing `keypoints`".into());
        }
        out.validate_msg()?;
        Ok(out)
    }

    /// The JSON text (keys in TC-133 order, coordinates printed so that they read back
    /// exactly).
    ///
    /// # Errors
    /// A non-finite value (see [`KeypointsFile::validate`]).
    pub fn to_json(&self) -> Result<String> {
        self.to_json_msg().map_err(HumanError::Invalid)
    }

    /// [`Self::to_json`] with the message as a `String`.
    fn to_json_msg(&self) -> std::result::Result<String, String> {
        self.validate_msg()?;
        let names = keypoint_names();
        let mut s = String::from("{\n  \"units\": \"m\",\n  \"keypoints\": {");
        for (k, (&i, p)) in self.points.iter().enumerate() {
            let sep = if k == 0 { "\n" } else { ",\n" };
            s.push_str(&format!(
                "{sep}    \"{}\": [{}, {}, {}]",
                names[i],
                fmt_f64(p[0]),
                fmt_f64(p[1]),
                fmt_f64(p[2])
            ));
        }
        s.push_str("\n  },\n  \"weights\": {");
        for (k, (&i, &w)) in self.weights.iter().enumerate() {
            let sep = if k == 0 { "\n" } else { ",\n" };
            s.push_str(&format!("{sep}    \"{}\": {}", names[i], fmt_f64(w)));
        }
        s.push_str("\n  }\n}\n");
        Ok(s)
    }

    /// Reads a keypoints JSON file.
    ///
    /// # Errors
    /// I/O or format errors naming the file.
    pub fn read(path: &Path) -> Result<KeypointsFile> {
        let text = std::fs::read_to_string(path).map_err(|e| HumanError::io(path, e))?;
        KeypointsFile::parse(&text).map_err(|e| e.in_file(path))
    }

    /// Writes a keypoints JSON file atomically (temporary file in the same directory, then
    /// rename).
    ///
    /// # Errors
    /// I/O errors or non-finite values, naming the file.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = self.to_json().map_err(|e| e.in_file(path))?;
        Ok(panoman_mesh::io::write_bytes_atomically(
            path,
            text.as_bytes(),
        )?)
    }
}

/// Shortest round-trip decimal of a finite `f64`, always with a `.` or exponent so that it
/// reads back as a float.
fn fmt_f64(x: f64) -> String {
    let s = format!("{x:?}");
    if s.contains(['.', 'e', 'E']) || s.contains("inf") || s.contains("NaN") {
        s
    } else {
        format!("{s}.0")
    }
}
