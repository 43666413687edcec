//! The foot–floor contact prior. The layout's six foot keypoints (big toe, little toe and heel
//! of each foot, [`crate::FEET_NAMES`]) observe the feet; targets without them (the older TC-127
//! layout, a detector that misses the feet) leave a foot's flexion free. The contact prior
//! ([`ContactPrior`]) then constrains the feet of a tracked sequence from its ankle keypoints
//! alone: feet detected as planted
//! ([`FootContacts`]) get their soles held level ([`LevelPair`]s of [`Model::sole_levels`])
//! and their heels and toes held where they landed ([`FootAnchors`]);
//! docs/design/rig-and-ik.md §4.9.
//!
//! Units: metres.

use panoman_fit::fit::{LevelPair, VertexHandle};
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_mesh::geom::{V3, dot, norm, scale, sub};

use crate::error::{Error, Result};
use crate::model::Model;

/// The sole's big-toe, little-toe and heel vertices of each foot (the contact prior's
/// points, in [`crate::FEET_NAMES`] order; not the foot keypoints, which sit at the toe tips and the
/// back of the heel) on a standing rest mesh `rest` (`(V, 3)`, metres, Z
/// up, facing −Y, left +X, feet flat; e.g. the default identity at rest): per foot the
/// vertices within 3 cm of its lowest point (the sole), split at their mean |x| into a medial
/// and a lateral half; the big toe is the medial half's most forward vertex (least y), the
/// small toe the lateral half's, the heel the sole's rearmost (greatest y).
///
/// # Errors
/// [`Error::Invalid`] if a side of the mesh has no vertex or a sole no lateral half (not a
/// body mesh).
pub fn sole_points(rest: &[V3]) -> Result<[u32; 6]> {
    let mut out = [0u32; 6];
    for (k, side) in [1.0f64, -1.0].into_iter().enumerate() {
        let foot: Vec<usize> = (0..rest.len())
            .filter(|&i| rest[i][0] * side > 0.0)
            .collect();
        let low = foot
            .iter()
            .map(|&i| rest[i][2])
            .fold(f64::INFINITY, f64::min);
        let sole: Vec<usize> = foot
            .into_iter()
            .filter(|&i| rest[i][2] < low + 0.03)
            .collect();
        let mid = sole.iter().map(|&i| rest[i][0].abs()).sum::<f64>() / sole.len().max(1) as f64;
        let pick = |keep: &dyn Fn(usize) -> bool, key: &dyn Fn(usize) -> f64| {
            sole.iter()
                .copied()
                .filter(|&i| keep(i))
                .min_by(|&a, &b| key(a).total_cmp(&key(b)))
                .map(|i| i as u32)
                .ok_or_else(|| Error::Invalid("foot points: the mesh has no sole there".into()))
        };
        out[3 * k] = pick(&|i| rest[i][0].abs() < mid, &|i| rest[i][1])?;
        out[3 * k + 1] = pick(&|i| rest[i][0].abs() >= mid, &|i| rest[i][1])?;
        out[3 * k + 2] = pick(&|_| true, &|i| -rest[i][1])?;
    }
    Ok(out)
}

impl Model {
    /// The [`sole_points`] of this model's template, picked on the default identity's rest
    /// mesh (all phenotype values ½) of the embedded rig, in [`crate::FEET_NAMES`] order.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a model without an embedded rig (see `panoman embed-rig`) or on
    /// a topology the generator does not map to.
    pub fn sole_points(&self) -> Result<[u32; 6]> {
        sole_points(&self.default_rest()?)
    }

    /// The default identity's rest mesh (all phenotype values ½, rest pose) of the embedded
    /// rig on this model's topology, `(V, 3)` metres, Z up.
    fn default_rest(&self) -> Result<Vec<V3>> {
        let rig = self.inner().rig.as_ref().ok_or_else(|| {
            Error::Invalid("the model carries no rig (see `panoman embed-rig`)".into())
        })?;
        let id = rig
            .generator
            .identity(&ShapeParams::default())
            .map_err(|e| Error::Invalid(format!("default identity: {e}")))?;
        Ok(rig.map.map(
            self.output_topology()?,
            &id.pose(&PoseParams::default()).vertices,
        ))
    }
}

/// Controls of [`FootContacts::detect`]. Heights and speeds are of the ankle keypoints
/// (`l_ankle`, `r_ankle`), which TC-127 has; a foot is down when its ankle is near its lowest
/// height of the sequence and nearly still.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ContactOptions {
    /// World up (any length > 0). Default +Z (the model's frame and the retarget's).
    pub up: V3,
    /// Ankle height above the foot's floor level (the [`ContactOptions::floor_percentile`]
    /// of its ankle heights over the sequence) at or below which the contact weight's height
    /// factor is 1, and at or above which it is 0 (linear between), metres. Default
    /// (0.02, 0.05): standing on CMU `01_01` keeps the ankles within 2 cm of their floor
    /// level, a lifted foot's heel leaves it by more than 5 cm.
    pub height: (f64, f64),
    /// Ankle speed (central differences over the neighbouring frames) at or below which the
    /// speed factor is 1, at or above which it is 0, m/s. Default (0.25, 0.6): a planted
    /// foot's ankle rolls at ≤ 0.2 m/s, a swinging one moves at ≥ 1 m/s.
    pub speed: (f64, f64),
    /// Percentile (0–100) of a foot's ankle heights taken as its floor level. Default 2:
    /// robust to a few glitched frames; needs the foot down in more than 2 % of the frames.
    pub floor_percentile: f64,
    /// Weight of a fully planted foot's [`LevelPair`]s and of its [`FootAnchors`] handles,
    /// keypoint units. Default ½ (CMU `01_01`, TC-127 alone, mean per-vertex error: 11.20 mm
    /// at ½, 11.38 at 1, 11.52 at 4 with anchors at ¼; stiffer soles fight the ankle
    /// keypoints).
    pub weight: f64,
}

impl Default for ContactOptions {
    fn default() -> Self {
        ContactOptions {
            up: [0.0, 0.0, 1.0],
            height: (0.02, 0.05),
            speed: (0.25, 0.6),
            floor_percentile: 2.0,
            weight: 0.5,
        }
    }
}

/// Foot–floor contact weights of a keypoint sequence and the sole [`LevelPair`]s they weight:
/// a prior for the feet, whose flexion TC-127 does not observe (its body stops at the
/// ankles). A planted foot stands on a level floor, so its heel and toes are at their rest
/// heights relative to each other: per foot two level pairs (heel above big toe, heel above
/// small toe, offsets those of the default identity's rest mesh, [`sole_points`]), given to
/// the skeletal IK with the frame's contact weight. Frames where a foot is off the floor get
/// no prior for it.
#[derive(Clone, Debug, PartialEq)]
pub struct FootContacts {
    /// Per frame `[left, right]` contact weight in `[0, 1]` (height factor × speed factor).
    pub weights: Vec<[f64; 2]>,
    /// Per foot (left, right) the floor level: the ankle height (along `up`, metres) that
    /// counts as standing.
    pub floor: [f64; 2],
    /// The options used.
    pub options: ContactOptions,
}

/// `1` at or below `lo`, `0` at or above `hi`, linear between.
fn ramp(x: f64, (lo, hi): (f64, f64)) -> f64 {
    if x <= lo {
        1.0
    } else if x >= hi {
        0.0
    } else {
        (hi - x) / (hi - lo)
    }
}

impl FootContacts {
    /// Detects contacts from the ankle keypoints of a sequence: `ankles[i] = (t_i, [left,
    /// right])`, times in seconds (strictly increasing), positions in metres.
    ///
    /// Weight of foot `s` in frame `i`: `ramp(h_i − h_floor, height) · ramp(|v_i|, speed)`
    /// with `h = ûᵀ x_ankle`, `h_floor` the [`ContactOptions::floor_percentile`] of `h` over
    /// the sequence, `v_i` the central difference of the ankle over the neighbouring frames
    /// (one-sided at the ends; 0 for a single frame).
    ///
    /// # Errors
    /// [`Error::Invalid`] for an empty sequence, times that are not finite and strictly
    /// increasing, non-finite positions, or options out of range (zero or non-finite `up`,
    /// bands with `lo ≥ hi` or negative, a percentile outside 0–100, a negative weight).
    pub fn detect(ankles: &[(f64, [V3; 2])], options: &ContactOptions) -> Result<FootContacts> {
        let o = options;
        let bad = |w: String| Err(Error::Invalid(format!("foot contacts: {w}")));
        let un = norm(o.up);
        if !(o.up.iter().all(|x| x.is_finite()) && un > 1e-12) {
            return bad(format!("up direction {:?} is zero or not finite", o.up));
        }
        for (name, (lo, hi)) in [("height", o.height), ("speed", o.speed)] {
            if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo < hi) {
                return bad(format!("{name} band ({lo}, {hi}) needs 0 ≤ lo < hi"));
            }
        }
        let in_range =
            (0.0..=100.0).contains(&o.floor_percentile) && o.weight >= 0.0 && o.weight.is_finite();
        if !in_range {
            return bad(format!(
                "floor percentile {} (0–100) or weight {} (≥ 0) out of range",
                o.floor_percentile, o.weight
            ));
        }
        if ankles.is_empty() {
            return bad("no frames".into());
        }
        for (i, (t, a)) in ankles.iter().enumerate() {
            if !t.is_finite() || (i > 0 && *t <= ankles[i - 1].0) {
                return bad(format!(
                    "frame {i}: time {t} s is not finite or not increasing"
                ));
            }
            if !a.iter().flatten().all(|x| x.is_finite()) {
                return bad(format!("frame {i}: an ankle position is not finite"));
            }
        }
        let up = scale(o.up, 1.0 / un);
        let n = ankles.len();
        let mut floor = [0.0; 2];
        let mut weights = vec![[0.0; 2]; n];
        for s in 0..2 {
            let mut h: Vec<f64> = ankles.iter().map(|(_, a)| dot(up, a[s])).collect();
            let heights = h.clone();
            h.sort_by(f64::total_cmp);
            let k = ((o.floor_percentile / 100.0) * (n - 1) as f64).round() as usize;
            floor[s] = h[k.min(n - 1)];
            for i in 0..n {
                let (a, b) = (i.saturating_sub(1), (i + 1).min(n - 1));
                let speed = if a == b {
                    0.0
                } else {
                    norm(sub(ankles[b].1[s], ankles[a].1[s])) / (ankles[b].0 - ankles[a].0)
                };
                weights[i][s] = ramp(heights[i] - floor[s], o.height) * ramp(speed, o.speed);
            }
        }
        Ok(FootContacts {
            weights,
            floor,
            options: *o,
        })
    }

    /// The sole level pairs of frame `i` (`soles` from [`Model::sole_levels`], weight 1),
    /// each weighted by [`ContactOptions::weight`] × the foot's contact weight, with the up
    /// direction of the options; feet with weight 0 give none.
    pub fn levels(&self, i: usize, soles: &[[LevelPair; 2]; 2]) -> Vec<LevelPair> {
        let Some(w) = self.weights.get(i) else {
            return Vec::new();
        };
        (0..2)
            .filter(|&s| w[s] > 0.0)
            .flat_map(|s| {
                soles[s].iter().map(move |l| LevelPair {
                    up: self.options.up,
                    weight: l.weight * w[s] * self.options.weight,
                    ..l.clone()
                })
            })
            .collect()
    }
}

impl Model {
    /// Per foot (left, right) the two sole [`LevelPair`]s of a flat-standing foot: heel above
    /// big toe and heel above small toe ([`Model::sole_points`]), offsets their heights on the
    /// default identity's rest mesh (Z up, feet flat), `up` +Z, weight 1. See
    /// [`FootContacts`].
    ///
    /// # Errors
    /// As [`Model::sole_points`].
    pub fn sole_levels(&self) -> Result<[[LevelPair; 2]; 2]> {
        let rest = self.default_rest()?;
        let p = sole_points(&rest)?;
        let pair = |heel: u32, toe: u32| LevelPair {
            a: heel,
            b: toe,
            up: [0.0, 0.0, 1.0],
            offset: rest[heel as usize][2] - rest[toe as usize][2],
            weight: 1.0,
        };
        Ok([
            [pair(p[2], p[0]), pair(p[2], p[1])],
            [pair(p[5], p[3]), pair(p[5], p[4])],
        ])
    }
}

/// Planted feet stay put: the anchors of a [`FootContacts`] sequence, kept by a tracker in
/// frame order. When a foot comes down (contact weight ≥ ½) its three [`sole_points`] are
/// anchored where that frame's fit put them; in the following frames while it stays down
/// they are vertex handles at those positions (weight: the frame's contact weight × the
/// options' weight), so a foot that the fit cannot see — TC-127 observes neither its
/// flexion nor, with a straight knee, its turn about the leg — does not turn or slide while
/// the body moves over it; when the foot lifts (weight < ½) the anchor is released.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct FootAnchors {
    /// Per foot (left, right) the anchored positions of big toe, small toe and heel, metres.
    pub anchors: [Option<[V3; 3]>; 2],
}

impl FootAnchors {
    /// The anchor handles for a frame with contact weights `w` (`[left, right]`), foot
    /// points `points` ([`Model::sole_points`]) and the contact options' `weight`.
    pub fn handles(&self, w: [f64; 2], points: &[u32; 6], weight: f64) -> Vec<VertexHandle> {
        let mut out = Vec::new();
        for s in 0..2 {
            if let Some(a) = &self.anchors[s]
                && w[s] >= 0.5
            {
                out.extend((0..3).map(|k| VertexHandle {
                    vertex: points[3 * s + k],
                    position: a[k],
                    weight: weight * w[s],
                }));
            }
        }
        out
    }

    /// After a frame's fit (`solved`, `(V, 3)` metres): anchors a foot that is down and has
    /// none, releases a foot that is up.
    pub fn update(&mut self, w: [f64; 2], points: &[u32; 6], solved: &[V3]) {
        for s in 0..2 {
            if w[s] < 0.5 {
                self.anchors[s] = None;
            } else if self.anchors[s].is_none() {
                self.anchors[s] = Some(std::array::from_fn(|k| solved[points[3 * s + k] as usize]));
            }
        }
    }
}

/// The `[l_ankle, r_ankle]` keypoints of a frame's targets (metres), the contact detector's
/// input; `Err` names the first one missing.
pub fn ankles(t: &crate::Targets) -> std::result::Result<[V3; 2], &'static str> {
    let at = |name: &'static str| {
        panoman_human::keypoints::keypoint_index(name)
            .and_then(|k| t.keypoints.points.get(&k).copied())
            .ok_or(name)
    };
    Ok([at("l_ankle")?, at("r_ankle")?])
}

/// The foot–floor contact prior of one sequence, applied frame by frame: its
/// [`FootContacts`], the model's sole level pairs and foot points, the [`FootAnchors`] of the
/// planted feet, and the index of the next frame. Give it to a tracker
/// ([`crate::Tracker::set_contacts`]), which adds the frame's level pairs and anchor handles
/// to its targets ([`ContactPrior::apply`]) and advances it after each fit.
#[derive(Clone, Debug, PartialEq)]
pub struct ContactPrior {
    /// The detected contacts (one weight pair per frame of the sequence).
    pub contacts: FootContacts,
    /// Per foot the sole level pairs ([`Model::sole_levels`]).
    pub soles: [[LevelPair; 2]; 2],
    /// The foot points ([`Model::sole_points`]).
    pub points: [u32; 6],
    /// The anchors of the planted feet, from the fits so far.
    pub anchors: FootAnchors,
    /// The sequence index of the next frame to fit.
    pub next: usize,
}

impl ContactPrior {
    /// Detects the contacts of a sequence (`ankles`: see [`FootContacts::detect`]) on
    /// `model`'s feet; the next frame is the sequence's first.
    ///
    /// # Errors
    /// [`FootContacts::detect`]'s; [`Model::sole_levels`]'s (a model without a rig).
    pub fn new(
        model: &Model,
        ankles: &[(f64, [V3; 2])],
        options: &ContactOptions,
    ) -> Result<ContactPrior> {
        Ok(ContactPrior {
            contacts: FootContacts::detect(ankles, options)?,
            soles: model.sole_levels()?,
            points: model.sole_points()?,
            anchors: FootAnchors::default(),
            next: 0,
        })
    }

    /// [`ContactPrior::new`] from the frames' targets, frame `i` at `i / frame_rate` s, the
    /// ankles their `l_ankle` and `r_ankle` keypoints.
    ///
    /// # Errors
    /// [`Error::Invalid`] naming the first frame (0-based) without both ankle keypoints, or a
    /// frame rate that is not positive; then as [`ContactPrior::new`].
    pub fn from_targets(
        model: &Model,
        frames: &[crate::Targets],
        frame_rate: f64,
        options: &ContactOptions,
    ) -> Result<ContactPrior> {
        if !(frame_rate.is_finite() && frame_rate > 0.0) {
            return Err(Error::Invalid(format!(
                "foot contacts: the frame rate must be positive (got {frame_rate} Hz)"
            )));
        }
        let ankles = frames
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let a = ankles(t).map_err(|name| {
                    Error::Invalid(format!(
                        "foot contacts: frame {i} has no {name} keypoint (both ankles are \
                         needed in every frame)"
                    ))
                })?;
                Ok((i as f64 / frame_rate, a))
            })
            .collect::<Result<Vec<_>>>()?;
        ContactPrior::new(model, &ankles, options)
    }

    /// The targets of the next frame with its planted feet's level pairs and anchor handles
    /// added.
    ///
    /// # Errors
    /// [`Error::Invalid`] when every frame of the sequence has been fitted.
    pub fn apply(&self, t: &crate::Targets) -> Result<crate::Targets> {
        let Some(&w) = self.contacts.weights.get(self.next) else {
            return Err(Error::Invalid(format!(
                "foot contacts: the sequence has {} frames, all fitted",
                self.contacts.weights.len()
            )));
        };
        let mut t = t.clone();
        t.levels
            .extend(self.contacts.levels(self.next, &self.soles));
        t.handles.extend(
            self.anchors
                .handles(w, &self.points, self.contacts.options.weight),
        );
        Ok(t)
    }

    /// After the next frame's fit (`solved`, `(V, 3)` metres): updates the anchors and moves
    /// to the following frame.
    pub fn advance(&mut self, solved: &[V3]) {
        if let Some(&w) = self.contacts.weights.get(self.next) {
            self.anchors.update(w, &self.points, solved);
        }
        self.next += 1;
    }

    /// Per foot the frames with contact weight ≥ ½.
    pub fn frames_down(&self) -> [usize; 2] {
        let w = &self.contacts.weights;
        [0, 1].map(|s| w.iter().filter(|x| x[s] >= 0.5).count())
    }
}
