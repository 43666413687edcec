//! The solver's precomputed model: skinned linear rows (keypoints of the set, point targets)
//! collapsed per bone into pairs, their evaluation, and how the keypoint model of a solver is
//! built (relevant vertices, face-unit bases, posable bones).

use std::sync::Arc;

use panoman_human::generator::Generator;
use panoman_human::keypoints::{N_KEYPOINTS, keypoint_index};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::params::ShapeParams;
use panoman_human::rig::Affine;
use panoman_human::sampling::{bone_range, posable_bones};
use panoman_human::skinning::SkinWeights;
use panoman_mesh::geom::{M3, V3, add, dot, matvec, norm, scale, sub};
use rayon::prelude::*;

use super::grid::{PhenGrid, VertexGrid, corner_weights, derivative_weights};
use super::solver::{IkSolver, rel_mean};
use super::targets::PointTarget;
use super::{IkState, N_UNITS};
use crate::error::{FitError, Result};

/// A (keypoint, bone) term `M_b X_kb + σ_kb t_b`.
#[derive(Clone, Debug)]
pub(super) struct Pair {
    pub(super) bone: usize,
    pub(super) sigma: f64,
    /// `(relevant vertex, a_kv w_vb)` entries in `coef`.
    pub(super) coef: std::ops::Range<usize>,
    /// Positions in the keypoint's ancestor list of `b` and its ancestors, in `anc_pos`.
    pub(super) anc: std::ops::Range<usize>,
    /// `(unit, X^{(j)}_kb)` entries in `unit_x`.
    pub(super) units: std::ops::Range<usize>,
}

/// One row of a [`Skinned`] model (a keypoint of the set, or a point target).
#[derive(Clone, Debug)]
pub(super) struct KpModel {
    /// TC-133 index of the name, if it is one.
    pub(super) tc: Option<usize>,
    pub(super) pairs: std::ops::Range<usize>,
    /// `A_k`: every bone skinning a vertex of the keypoint and its ancestors, ascending.
    pub(super) anc: Vec<usize>,
    /// `S_kc` for `c ∈ A_k`.
    pub(super) anc_sigma: Vec<f64>,
}

/// Skinned linear rows `Σ_a c_a x_a` over Anny output vertices (the keypoints of the set, or
/// the point targets of one [`IkSolver::solve_with_points`] call), collapsed per skinning
/// bone into pairs (module docs). `coef` indexes a list of relevant vertices owned by whoever
/// supplies the rest positions.
#[derive(Clone, Debug, Default)]
pub(super) struct Skinned {
    pub(super) rows: Vec<KpModel>,
    pub(super) pairs: Vec<Pair>,
    pub(super) coef: Vec<(u32, f64)>,
    pub(super) anc_pos: Vec<u32>,
    pub(super) unit_x: Vec<(u8, V3)>,
}

/// One row of a [`Skinned`] model before concatenation (ranges relative to its own lists).
pub(super) struct RowPart {
    pub(super) pairs: Vec<Pair>,
    pub(super) coef: Vec<(u32, f64)>,
    pub(super) anc_pos: Vec<u32>,
    pub(super) unit_x: Vec<(u8, V3)>,
    pub(super) anc: Vec<usize>,
    pub(super) anc_sigma: Vec<f64>,
}

impl Skinned {
    /// Appends a row, shifting its ranges.
    pub(super) fn push(&mut self, tc: Option<usize>, part: RowPart) {
        let first = self.pairs.len();
        let (c0, a0, u0) = (self.coef.len(), self.anc_pos.len(), self.unit_x.len());
        let shift = |r: &std::ops::Range<usize>, o: usize| r.start + o..r.end + o;
        self.pairs.extend(part.pairs.into_iter().map(|p| Pair {
            bone: p.bone,
            sigma: p.sigma,
            coef: shift(&p.coef, c0),
            anc: shift(&p.anc, a0),
            units: shift(&p.units, u0),
        }));
        self.coef.extend(part.coef);
        self.anc_pos.extend(part.anc_pos);
        self.unit_x.extend(part.unit_x);
        self.rows.push(KpModel {
            tc,
            pairs: first..self.pairs.len(),
            anc: part.anc,
            anc_sigma: part.anc_sigma,
        });
    }
}

/// The face-unit terms `(j, X^{(j)}_b)` of a pair from its coefficient list.
pub(super) type UnitTerms<'f> = &'f dyn Fn(&[(u32, f64)]) -> Vec<(u8, V3)>;

/// The skinned model of one row `Σ_a c_a x_a` over Anny output vertices `a`: per skinning
/// bone `b` the pair `σ_b = Σ_a c_a w_ab` with coefficients `(rel(a), c_a w_ab)`, the
/// ancestor set `A` (every skinning bone and its ancestors) with `S_c`, and per pair the
/// face-unit terms `X^{(j)}_b` given by `units` from the pair's coefficient list.
pub(super) fn skinned_row(
    row: &[(u32, f64)],
    rel_of_anny: &dyn Fn(u32) -> u32,
    skin: &SkinWeights,
    parents: &[Option<usize>],
    units: UnitTerms<'_>,
) -> RowPart {
    let n_bones = parents.len();
    let mut per_bone: std::collections::BTreeMap<usize, Vec<(u32, f64)>> =
        std::collections::BTreeMap::new();
    for &(a, w) in row {
        let r = rel_of_anny(a);
        let (s, e) = (
            skin.offsets[a as usize] as usize,
            skin.offsets[a as usize + 1] as usize,
        );
        for i in s..e {
            per_bone
                .entry(skin.bones[i] as usize)
                .or_default()
                .push((r, w * skin.weights[i]));
        }
    }
    let mut in_anc = vec![false; n_bones];
    for &b in per_bone.keys() {
        let mut c = Some(b);
        while let Some(x) = c {
            if in_anc[x] {
                break;
            }
            in_anc[x] = true;
            c = parents[x];
        }
    }
    let anc: Vec<usize> = (0..n_bones).filter(|&c| in_anc[c]).collect();
    let mut part = RowPart {
        pairs: Vec::with_capacity(per_bone.len()),
        coef: Vec::new(),
        anc_pos: Vec::new(),
        unit_x: Vec::new(),
        anc_sigma: vec![0.0; anc.len()],
        anc,
    };
    for (&b, list) in &per_bone {
        let sigma: f64 = list.iter().map(|e| e.1).sum();
        let c0 = part.coef.len();
        part.coef.extend_from_slice(list);
        let a0 = part.anc_pos.len();
        let mut c = Some(b);
        while let Some(x) = c {
            let p = part.anc.binary_search(&x).expect("ancestor");
            part.anc_pos.push(p as u32);
            part.anc_sigma[p] += sigma;
            c = parents[x];
        }
        let u0 = part.unit_x.len();
        part.unit_x.extend(units(list));
        part.pairs.push(Pair {
            bone: b,
            sigma,
            coef: c0..part.coef.len(),
            anc: a0..part.anc_pos.len(),
            units: u0..part.unit_x.len(),
        });
    }
    part
}

/// A row over vertices of `topology` composed with the topology map onto Anny output
/// vertices (duplicates merged, ascending).
pub(super) fn anny_row(
    map: &TopologyMap,
    topology: OutputTopology,
    row: &[(u32, f64)],
) -> Vec<(u32, f64)> {
    let mut r: Vec<(u32, f64)> = Vec::new();
    for &(v, w) in row {
        match topology {
            OutputTopology::Anny => r.push((v, w)),
            OutputTopology::Full => r.push((map.full_from_anny()[v as usize], w)),
            OutputTopology::Small => {
                let b = &map.small_binding()[v as usize];
                for i in 0..3 {
                    r.push((b.tri[i], w * b.bary[i]));
                }
            }
        }
    }
    r.sort_by_key(|e| e.0);
    let mut merged: Vec<(u32, f64)> = Vec::with_capacity(r.len());
    for (v, w) in r {
        match merged.last_mut() {
            Some(last) if last.0 == v => last.1 += w,
            _ => merged.push((v, w)),
        }
    }
    merged
}

/// A posable bone: rig index and range in radians.
#[derive(Clone, Debug)]
pub(super) struct Posable {
    pub(super) rig: usize,
    pub(super) slot: usize,
    pub(super) range: [[f64; 2]; 3],
    /// Per axis `1/s²` with `s = max(|lo|, |hi|)` of the range (0 for an empty range): the
    /// prior measures each angle against the largest angle its range allows.
    pub(super) prior: [f64; 3],
    /// The lower bound of the flexion axis (x) under [`super::IkConfig::full_extension`]
    /// ([`ik_extension_limit`], radians): elbows and knees only.
    pub(super) extension: Option<f64>,
    /// Per axis, the range (radians) and prior factor under [`super::IkConfig::wide_ranges`]
    /// ([`ik_wide_range`]); `None` where the sampler's range stands.
    pub(super) wide: [Option<([f64; 2], f64)>; 3],
    /// The forearm's roll bone (`lowerarm02.L/R`, axis y), whose range
    /// [`super::IkConfig::forearm_roll_deg`] sets.
    pub(super) roll: bool,
}

impl Posable {
    /// Range and prior factor of `axis` under `cfg`: the wide one under
    /// [`super::IkConfig::wide_ranges`] where the axis has one, else the sampler's; under
    /// [`super::IkConfig::full_extension`] the lower flexion bound of an elbow or a knee then
    /// moves down to the full extension ([`ik_extension_limit`]). The prior factor is the
    /// range's own either way (the extension leaves `max(|lo|, |hi|)` unchanged). Without
    /// the wide ranges, [`super::IkConfig::forearm_roll_deg`] `L` makes the forearm's roll
    /// `±L` with prior factor `1/L²`.
    pub(super) fn axis(&self, axis: usize, cfg: &super::IkConfig) -> ([f64; 2], f64) {
        let (mut range, prior) = match (self.wide[axis], cfg.forearm_roll_deg) {
            (Some(w), _) if cfg.wide_ranges => w,
            (_, Some(l)) if self.roll && axis == 1 => {
                let l = l.to_radians();
                ([-l, l], 1.0 / (l * l))
            }
            _ => (self.range[axis], self.prior[axis]),
        };
        if let Some(lo) = self.extension.filter(|_| axis == 0 && cfg.full_extension) {
            range[0] = range[0].min(lo);
        }
        (range, prior)
    }
}

/// Rest-shape quantities of one `(β, f)`.
#[derive(Clone, Debug)]
pub(super) struct ShapeEval {
    pub(super) heads: Vec<V3>,
    pub(super) local: Vec<Affine>,
    pub(super) inv_rest: Vec<Affine>,
    /// `X_kb` per pair.
    pub(super) x: Vec<V3>,
    pub(super) tails: Vec<V3>,
}

/// Forward kinematics of one state.
#[derive(Clone, Debug, Default)]
pub(super) struct Kin {
    pub(super) world: Vec<Affine>,
    /// Rotation of `W_parent P_parent⁻¹ P_c` (the frame before the bone's delta).
    pub(super) pre: Vec<M3>,
    pub(super) skin: Vec<Affine>,
}

/// Everything evaluated at one state.
#[derive(Clone, Debug)]
pub(super) struct Current {
    pub(super) state: IkState,
    pub(super) shape: Arc<ShapeEval>,
    pub(super) kin: Kin,
    /// Keypoints per set row.
    pub(super) k: Vec<V3>,
    /// The point targets' part, when the evaluation had a point model.
    pub(super) pts: Option<PtEval>,
}

/// Point targets evaluated at one state.
#[derive(Clone, Debug)]
pub(super) struct PtEval {
    /// `X_pb` per pair of the point model at the state's `(β, f)`.
    pub(super) x: Arc<Vec<V3>>,
    /// `Σ_m b_m x_m` per point target.
    pub(super) p: Vec<V3>,
}

/// What an evaluation needs besides the state: the phenotype grid of the keypoints and,
/// when point targets are fitted, their model.
#[derive(Clone, Copy)]
pub(super) struct Ctx<'c> {
    pub(super) grid: &'c PhenGrid,
    pub(super) pts: Option<&'c PointModel>,
}

impl<'c> Ctx<'c> {
    pub(super) fn new(grid: &'c PhenGrid, pts: Option<&'c PointModel>) -> Ctx<'c> {
        Ctx { grid, pts }
    }
}

/// `Z_b = M_b X_b + σ_b t_b` of pair `i` of `sk`, `X_b = x[i]`.
#[inline]
pub(super) fn pair_term(sk: &Skinned, i: usize, x: &[V3], kin: &Kin) -> V3 {
    let p = &sk.pairs[i];
    let t = &kin.skin[p.bone];
    add(matvec(&t.m, x[i]), scale(t.t, p.sigma))
}

/// The rows of `sk`, `Σ_b Z_b`, for pair rest quantities `x`.
pub(super) fn rows_into(sk: &Skinned, x: &[V3], kin: &Kin, out: &mut Vec<V3>) {
    out.clear();
    out.extend(sk.rows.iter().map(|k| {
        let mut s = [0.0; 3];
        for i in k.pairs.clone() {
            s = add(s, pair_term(sk, i, x, kin));
        }
        s
    }));
}

/// `X_b = Σ_v c_v x̄_v` of every pair of `sk` for rest positions `rest` (its relevant
/// vertices).
pub(super) fn pair_sums(sk: &Skinned, rest: &[V3]) -> Vec<V3> {
    sk.pairs
        .iter()
        .map(|p| {
            let mut x = [0.0; 3];
            for &(r, w) in &sk.coef[p.coef.clone()] {
                let q = rest[r as usize];
                x = [x[0] + w * q[0], x[1] + w * q[1], x[2] + w * q[2]];
            }
            x
        })
        .collect()
}

/// Adds the face units' terms `Σ_j f_j X^{(j)}_b` to the pair quantities `x`.
pub(super) fn add_unit_terms(sk: &Skinned, units: &[f64; 52], x: &mut [V3]) {
    for (p, xp) in sk.pairs.iter().zip(x.iter_mut()) {
        for &(j, d) in &sk.unit_x[p.units.clone()] {
            let f = units[j as usize];
            if f != 0.0 {
                *xp = add(*xp, scale(d, f));
            }
        }
    }
}

/// One point target in solver terms.
#[derive(Clone, Copy, Debug)]
pub(super) struct PtRow {
    pub(super) target: V3,
    pub(super) weight: f64,
    /// Unit normal (point-to-plane), or `None` (point-to-point).
    pub(super) normal: Option<V3>,
}

impl PtRow {
    /// `P v`: the projection `n̂ n̂ᵀ v` on the normal, or `v`.
    #[inline]
    pub(super) fn proj(&self, v: V3) -> V3 {
        match self.normal {
            Some(n) => scale(n, dot(n, v)),
            None => v,
        }
    }
}

/// The skinned model of a list of point targets (see [`IkSolver::solve_with_points`]).
#[derive(Debug)]
pub(super) struct PointModel {
    /// Rows in target order; `coef` indexes `verts`.
    pub(super) sk: Skinned,
    /// Slots of the relevant vertices.
    pub(super) verts: Vec<u32>,
    pub(super) rows: Vec<PtRow>,
    pub(super) grid: Arc<VertexGrid>,
}

impl PointModel {
    /// `X_pb` of every pair at `(β, f)`: the vertex grid interpolated at `β`, summed per
    /// pair, plus `Σ_j f_j X^{(j)}_pb`.
    pub(super) fn shape_x(&self, beta: &[f64; 6], units: &[f64; 52]) -> Vec<V3> {
        let w = corner_weights(beta, &[1; 6], None);
        let mut x = pair_sums(&self.sk, &self.grid.interp(&self.verts, &w));
        add_unit_terms(&self.sk, units, &mut x);
        x
    }

    /// `∂X_pb/∂β_i` of every pair for each request `(i, side)` (one-sided on a kink,
    /// `side < 0` the cell below), in one pass over the grid.
    pub(super) fn dx(&self, beta: &[f64; 6], requests: &[(usize, i8)]) -> Vec<Vec<V3>> {
        let sets = derivative_weights(beta, requests);
        self.grid
            .interp_many(&self.verts, &sets)
            .iter()
            .map(|xv| pair_sums(&self.sk, xv))
            .collect()
    }

    /// The point positions for pair quantities `x` and kinematics `kin`.
    pub(super) fn eval(&self, x: Arc<Vec<V3>>, kin: &Kin) -> PtEval {
        let mut p = Vec::with_capacity(self.rows.len());
        rows_into(&self.sk, &x, kin, &mut p);
        PtEval { x, p }
    }
}

impl IkSolver {
    /// Checks point targets and builds their skinned model (rows composed with the topology
    /// map, pairs, ancestors, face-unit terms; in parallel over the points).
    pub(super) fn point_model(
        &self,
        points: &[PointTarget],
        template: &ShapeParams,
    ) -> Result<PointModel> {
        let nv = self.map.n_vertices(self.topology);
        for (i, p) in points.iter().enumerate() {
            let bad = |what: String| Err(FitError::Invalid(format!("point target {i}: {what}")));
            if p.rows.is_empty() {
                return bad("no vertices".into());
            }
            if let Some(&(v, w)) = p
                .rows
                .iter()
                .find(|(v, w)| *v as usize >= nv || !w.is_finite())
            {
                return bad(format!(
                    "vertex {v} (coefficient {w}) out of range or not finite \
                     (topology `{}` has {nv} vertices)",
                    self.topology
                ));
            }
            if !p.position.iter().all(|x| x.is_finite()) {
                return bad(format!("non-finite position {:?}", p.position));
            }
            if !p.weight.is_finite() || p.weight < 0.0 {
                return bad(format!(
                    "invalid weight {} (must be finite and ≥ 0)",
                    p.weight
                ));
            }
            if let Some(n) = p.normal
                && !(n.iter().all(|x| x.is_finite()) && norm(n) > 1e-12)
            {
                return bad(format!("invalid normal {n:?}"));
            }
        }
        let surface = self.surface()?;
        let grid = self.vertex_grid(template, &surface)?;
        let rows: Vec<Vec<(u32, f64)>> = points
            .par_iter()
            .with_min_len(256)
            .map(|p| anny_row(&self.map, self.topology, &p.rows))
            .collect();
        let mut local_of_slot = vec![u32::MAX; surface.kept_of_slot.len()];
        let mut verts: Vec<u32> = Vec::new();
        for r in &rows {
            for &(a, _) in r {
                let slot = surface.slot_of_anny[a as usize];
                debug_assert!(slot != u32::MAX, "reachable vertex");
                let l = &mut local_of_slot[slot as usize];
                if *l == u32::MAX {
                    *l = verts.len() as u32;
                    verts.push(slot);
                }
            }
        }
        let rel = |a: u32| local_of_slot[surface.slot_of_anny[a as usize] as usize];
        let units = |list: &[(u32, f64)]| -> Vec<(u8, V3)> {
            let mut acc = [[0.0; 3]; N_UNITS];
            let mut any = false;
            for &(r, w) in list {
                let slot = verts[r as usize] as usize;
                let (a, b) = (
                    surface.unit_off[slot] as usize,
                    surface.unit_off[slot + 1] as usize,
                );
                for &(j, d) in &surface.unit_val[a..b] {
                    acc[j as usize] = add(acc[j as usize], scale(d, w));
                    any = true;
                }
            }
            if !any {
                return Vec::new();
            }
            (0..N_UNITS)
                .filter(|&j| acc[j] != [0.0; 3])
                .map(|j| (j as u8, acc[j]))
                .collect()
        };
        let skin = self.generator.skin_weights();
        let parts: Vec<RowPart> = rows
            .par_iter()
            .with_min_len(128)
            .map(|r| skinned_row(r, &rel, skin, &self.parents, &units))
            .collect();
        let mut sk = Skinned::default();
        for part in parts {
            sk.push(None, part);
        }
        let rows = points
            .iter()
            .map(|p| PtRow {
                target: p.position,
                weight: p.weight,
                normal: p.normal.map(|n| scale(n, 1.0 / norm(n))),
            })
            .collect();
        Ok(PointModel {
            sk,
            verts,
            rows,
            grid,
        })
    }
}

/// The relevant vertices of a solver: the kept vertices (of the generator) whose rest
/// positions it needs — the vertices of the keypoint rows and of the joint regressors — in
/// the order they are first met.
pub(super) struct Relevant {
    /// Kept-vertex index per relevant vertex.
    pub(super) kept: Vec<u32>,
    /// Per bone, the relevant indices of its head's regressor vertices.
    pub(super) head: Vec<Vec<u32>>,
    /// Per bone, the relevant indices of its tail's regressor vertices.
    pub(super) tail: Vec<Vec<u32>>,
    /// `(Anny output vertex, relevant index)` of the keypoint rows' vertices, ascending.
    pub(super) anny: Vec<(u32, u32)>,
}

impl Relevant {
    /// The relevant vertices of keypoint rows `anny_rows` (over Anny output vertices) and
    /// of the rig's joint regressors.
    pub(super) fn new(generator: &Generator, anny_rows: &[Vec<(u32, f64)>]) -> Relevant {
        let rig = generator.rig();
        let kob = generator.kept_of_base();
        let out_base = generator.output_vertices();
        let n_kept = generator.kept_vertices().len();
        let mut rel_of_kept = vec![u32::MAX; n_kept];
        let mut rel_kept: Vec<u32> = Vec::new();
        let mut rel = |kept: u32| -> u32 {
            let slot = &mut rel_of_kept[kept as usize];
            if *slot == u32::MAX {
                *slot = rel_kept.len() as u32;
                rel_kept.push(kept);
            }
            *slot
        };
        let mut anny_rel: Vec<(u32, u32)> = Vec::new();
        for row in anny_rows {
            for &(a, _) in row {
                let k = kob[out_base[a as usize] as usize];
                anny_rel.push((a, rel(k)));
            }
        }
        let to_rel = |vs: &[u32], rel: &mut dyn FnMut(u32) -> u32| -> Vec<u32> {
            vs.iter().map(|&b| rel(kob[b as usize])).collect()
        };
        let head_rel: Vec<Vec<u32>> = rig
            .bones
            .iter()
            .map(|b| to_rel(&b.head_vertices, &mut rel))
            .collect();
        let tail_rel: Vec<Vec<u32>> = rig
            .bones
            .iter()
            .map(|b| to_rel(&b.tail_vertices, &mut rel))
            .collect();
        anny_rel.sort_unstable();
        anny_rel.dedup();
        Relevant {
            kept: rel_kept,
            head: head_rel,
            tail: tail_rel,
            anny: anny_rel,
        }
    }

    /// The relevant index of Anny output vertex `a` of a keypoint row.
    pub(super) fn of_anny(&self, a: u32) -> u32 {
        let i = self
            .anny
            .binary_search_by_key(&a, |e| e.0)
            .expect("touched vertex");
        self.anny[i].1
    }
}

/// The face units' displacements `B_j = rest(f = e_j) − rest(0)` at the relevant vertices
/// `rel_kept` (53 rest meshes of the generator, in parallel).
pub(super) fn unit_bases(generator: &Generator, rel_kept: &[u32]) -> Result<Vec<Vec<V3>>> {
    let default = ShapeParams::default();
    let rest0 = generator.rest_mesh(&default)?;
    (0..N_UNITS)
        .into_par_iter()
        .map(|j| -> Result<Vec<V3>> {
            let mut s = default.clone();
            s.facial_actions[j] = 1.0;
            let r = generator.rest_mesh(&s)?;
            Ok(rel_kept
                .iter()
                .map(|&k| sub(r[k as usize], rest0[k as usize]))
                .collect())
        })
        .collect::<Result<Vec<_>>>()
}

/// Per face unit, `(bone, Δhead, Δtail)` of every joint it moves (unit value 1).
pub(super) fn unit_joint_moves(
    unit_dense: &[Vec<V3>],
    rel: &Relevant,
    n_bones: usize,
) -> Vec<Vec<(usize, V3, V3)>> {
    unit_dense
        .iter()
        .map(|d| {
            (0..n_bones)
                .filter_map(|c| {
                    let dh = rel_mean(&rel.head[c], d);
                    let dt = rel_mean(&rel.tail[c], d);
                    (dh != [0.0; 3] || dt != [0.0; 3]).then_some((c, dh, dt))
                })
                .collect()
        })
        .collect()
}

/// The IK's wide ranges (degrees, with the prior scale `s` of each), used under
/// [`super::IkConfig::wide_ranges`] instead of the sampler's ([`panoman_human::sampling::bone_range`],
/// chosen for what the training data should contain — e.g. ±30° arm twists, where the LBS
/// skin starts to collapse — not for anatomy): the arms' `*02` twist bones ±180° (a forearm
/// rolls about ±90° and the keypoints of a large twist must be reachable; the prior scale is
/// 90° on the forearm and 30° on the upper arm, so that a roll the keypoints cannot place, on
/// a straight arm, goes mostly to the forearm: the prior splits a roll in proportion to the
/// squared scales), the shoulder to 180° of flexion and abduction, the elbow to 160°, the hip
/// to 140° of flexion, the knee to 165° and the ankle to −40…60° (a crouch, a hand on the
/// head). Per axis `[x, y, z]`, in the bone's own frame (right-side bones mirrored as
/// [`panoman_human::sampling::bone_range`] does); `None` where the sampler's range stands.
pub fn ik_wide_range(bone: &str) -> [Option<([f64; 2], f64)>; 3] {
    let (base, right) = match bone.strip_suffix(".R") {
        Some(b) => (b, true),
        None => (bone.strip_suffix(".L").unwrap_or(bone), false),
    };
    let left: [Option<([f64; 2], f64)>; 3] = match base {
        "lowerarm02" => [None, Some(([-180.0, 180.0], 90.0)), None],
        "upperarm02" => [None, Some(([-180.0, 180.0], 30.0)), None],
        "upperarm01" => [
            Some(([-90.0, 180.0], 90.0)),
            None,
            Some(([-90.0, 180.0], 90.0)),
        ],
        "lowerarm01" => [Some(([-35.0, 160.0], 95.0)), None, None],
        "upperleg01" => [Some(([-140.0, 45.0], 90.0)), None, None],
        "lowerleg01" => [Some(([0.0, 165.0], 120.0)), None, None],
        "foot" => [Some(([-40.0, 60.0], 40.0)), None, None],
        _ => [None; 3],
    };
    if !right {
        return left;
    }
    let m = |a: Option<([f64; 2], f64)>| a.map(|([lo, hi], s)| ([-hi, -lo], s));
    [left[0], m(left[1]), m(left[2])]
}

/// Lower bound of the elbow's flexion (`lowerarm01` x, degrees) at full extension. The rig's
/// rest elbow is bent: its straight arm (shoulder, elbow and wrist joints on one line, e.g.
/// the T-pose of a CMU BVH retargeted) is at about −43°, while the sampler's range
/// ([`panoman_human::sampling::bone_range`]) stops at −35°, 8° short of straight. −50°
/// allows a straight arm and about 7° of hyperextension.
pub const ELBOW_EXTENSION_DEG: f64 = -50.0;

/// Lower bound of the knee's flexion (`lowerleg01` x, degrees) at full extension: the rig's
/// straight leg is at about −10° (its rest knee is bent), the sampler stops at 0°; −15°
/// allows a straight leg and about 5° of hyperextension.
pub const KNEE_EXTENSION_DEG: f64 = -15.0;

/// The lower bound (degrees) of `bone`'s flexion axis at full extension — [`ELBOW_EXTENSION_DEG`]
/// for `lowerarm01.L/R`, [`KNEE_EXTENSION_DEG`] for `lowerleg01.L/R` (the x axis is not
/// mirrored on the right) — or `None` for other bones: the bounds under
/// [`super::IkConfig::full_extension`].
pub fn ik_extension_limit(bone: &str) -> Option<f64> {
    let base = bone
        .strip_suffix(".R")
        .or_else(|| bone.strip_suffix(".L"))?;
    match base {
        "lowerarm01" => Some(ELBOW_EXTENSION_DEG),
        "lowerleg01" => Some(KNEE_EXTENSION_DEG),
        _ => None,
    }
}

/// The posable bones of the sampler in `rig`, with their ranges in radians and prior
/// factors (and the wide ones of [`ik_wide_range`]).
///
/// # Errors
/// [`FitError::Invalid`] if the rig lacks a posable bone.
pub(super) fn posable_of(rig: &panoman_human::rig::Rig) -> Result<Vec<Posable>> {
    posable_bones()
        .iter()
        .enumerate()
        .map(|(slot, name)| {
            let c = rig.index(name).ok_or_else(|| {
                FitError::Invalid(format!("the rig has no posable bone `{name}`"))
            })?;
            let r = bone_range(name).expect("posable bones have ranges");
            let range = r.map(|a| a.map(f64::to_radians));
            let extension = ik_extension_limit(name).map(f64::to_radians);
            let prior = range.map(|[lo, hi]| {
                let s = lo.abs().max(hi.abs());
                if lo < hi { 1.0 / (s * s) } else { 0.0 }
            });
            let wide = ik_wide_range(name).map(|a| {
                a.map(|(r, scale)| (r.map(f64::to_radians), 1.0 / scale.to_radians().powi(2)))
            });
            Ok(Posable {
                rig: c,
                slot,
                range,
                prior,
                extension,
                wide,
                roll: matches!(name.as_str(), "lowerarm02.L" | "lowerarm02.R"),
            })
        })
        .collect::<Result<Vec<_>>>()
}

/// The face units whose joint motion changes the frame of a posable bone or the root.
pub(super) fn frame_units(
    posable: &[Posable],
    unit_joints: &[Vec<(usize, V3, V3)>],
    n_bones: usize,
) -> Vec<usize> {
    let mut frame_bone = vec![false; n_bones];
    frame_bone[0] = true;
    for p in posable {
        frame_bone[p.rig] = true;
    }
    (0..N_UNITS)
        .filter(|&j| unit_joints[j].iter().any(|(c, _, _)| frame_bone[*c]))
        .collect()
}

/// The skinned model of the keypoint rows (pairs, ancestors, face-unit terms from the unit
/// bases `unit_dense`) and the set row of every TC-133 keypoint.
pub(super) fn skinned_keypoints(
    anny_rows: &[Vec<(u32, f64)>],
    names: &[String],
    rel: &Relevant,
    skin: &SkinWeights,
    parents: &[Option<usize>],
    unit_dense: &[Vec<V3>],
) -> (Skinned, Vec<Option<usize>>) {
    let unit_terms = |list: &[(u32, f64)]| -> Vec<(u8, V3)> {
        let mut out = Vec::new();
        for (j, d) in unit_dense.iter().enumerate() {
            let mut x = [0.0; 3];
            for &(r, w) in list {
                x = add(x, scale(d[r as usize], w));
            }
            if x != [0.0; 3] {
                out.push((j as u8, x));
            }
        }
        out
    };
    let rel_of_anny = |a: u32| rel.of_anny(a);
    let mut kp = Skinned::default();
    for (row, name) in anny_rows.iter().zip(names) {
        let part = skinned_row(row, &rel_of_anny, skin, parents, &unit_terms);
        kp.push(keypoint_index(name), part);
    }
    let mut row_of_tc = vec![None; N_KEYPOINTS];
    for (r, k) in kp.rows.iter().enumerate() {
        if let Some(t) = k.tc {
            row_of_tc[t] = Some(r);
        }
    }
    (kp, row_of_tc)
}
