//! Calibration of marker placement and shape ([`MarkerSolver::calibrate`], module docs of
//! [`super`]).

use super::placement::PlacementSample;
use super::*;

impl MarkerSolver {
    /// Calibrates shape and marker placement on frames of `seq` (see the module docs);
    /// markers with `active[i] == false` are left out (their placement is kept).
    ///
    /// # Errors
    /// Too few frames with markers; IK failures.
    pub fn calibrate(
        &self,
        seq: &MarkerSequence,
        frames: &[usize],
        initial: &MarkerMap,
        active: &[bool],
    ) -> Result<Calibration> {
        let t0 = Instant::now();
        let o = &self.options;
        let nm = initial.markers.len();
        let calib = pick_frames(seq, frames, active, o.calibration_frames);
        if calib.is_empty() {
            return Err(MocapError::Invalid {
                what: "no frame has 3 or more of the markers observed".into(),
            });
        }
        let mut map = initial.clone();
        let mut phen = [0.5; 6];
        let mut states: Vec<(IkState, Vec<V3>)> = Vec::new();
        for &f in &calib {
            let st = self.cold_state(&map, seq.frame(f), active, phen);
            let r = self.ik_frame(
                &map,
                seq.frame(f),
                active,
                st,
                &self.template.vertices,
                true,
                3,
                40,
                0.15,
                None,
                None,
            )?;
            states.push((r.result.state.clone(), r.result.posed.clone()));
        }
        for (i, p) in phen.iter_mut().enumerate() {
            *p = states.iter().map(|s| s.0.phenotype[i]).sum::<f64>() / states.len() as f64;
        }
        let rest = self.rest_mesh(phen)?;
        let init_rest: Vec<V3> = initial
            .markers
            .iter()
            .map(|m| surface_point(self.faces(), &rest, m.triangle, m.barycentric))
            .collect();
        let mut mean_res = f64::NAN;
        // The pose-dependent placements: fitted after round ⌈R/2⌉, once the fixed
        // placements have settled, and used from the next round on.
        let mut placements: Vec<Option<PosePlacement>> = Vec::new();
        let first_fit = o.calibration_rounds.max(1).div_ceil(2);
        for round in 0..o.calibration_rounds.max(1) {
            // Wide weights first (the initial placement may be centimetres off), then the
            // tracking σ.
            let sigma = (0.1 / (1 << round) as f64).max(o.robust_sigma_m);
            let mut outs = Vec::with_capacity(calib.len());
            for (k, &f) in calib.iter().enumerate() {
                let (mut st, mesh) = states[k].clone();
                st.phenotype = phen;
                let r = self.ik_frame(
                    &map,
                    seq.frame(f),
                    active,
                    st,
                    &mesh,
                    false,
                    2,
                    20,
                    sigma,
                    None,
                    placements
                        .iter()
                        .any(Option::is_some)
                        .then_some((placements.as_slice(), rest.as_slice())),
                )?;
                states[k] = (r.result.state.clone(), r.result.posed.clone());
                outs.push(r);
            }
            let obs: Vec<Obs> = calib.iter().map(|&f| seq.frame(f)).collect();
            let samples =
                self.marker_step(&mut map, initial, &init_rest, &rest, &outs, &obs, active);
            if o.pose_placement_ridge > 0.0 && round + 1 >= first_fit {
                placements = self.fit_pose_placement(&map, &rest, &outs, &samples);
            }
            let all: Vec<f64> = outs
                .iter()
                .flat_map(|r| r.residuals.iter().copied().filter(|x| x.is_finite()))
                .collect();
            mean_res = 1e3 * all.iter().sum::<f64>() / all.len().max(1) as f64;
        }
        let shift: f64 = (0..nm)
            .map(|i| {
                let m = &map.markers[i];
                norm(sub(
                    surface_point(self.faces(), &rest, m.triangle, m.barycentric),
                    init_rest[i],
                ))
            })
            .sum::<f64>()
            / nm.max(1) as f64;
        let alpha = self
            .model
            .project_shape(&rest)
            .map_err(|e| MocapError::Invalid {
                what: format!("calibrated rest mesh: {e}"),
            })?;
        let patches = marker_patches(self.faces(), &map, &rest, o.patch_sigma_m);
        Ok(Calibration {
            map,
            phenotype: phen,
            rest,
            alpha,
            frames: calib,
            mean_residual_mm: mean_res,
            mean_marker_shift_mm: 1e3 * shift,
            patches,
            seconds: t0.elapsed().as_secs_f64(),
            pose_placement: placements,
        })
    }

    /// `map` with each marker that has a pose-dependent placement moved to its surface point
    /// for the bone angles of `state` ([`PosePlacement`]; `rest` is the calibrated rest mesh).
    pub fn posed_map(
        &self,
        map: &MarkerMap,
        placement: &[Option<PosePlacement>],
        rest: &[V3],
        state: &IkState,
    ) -> MarkerMap {
        let faces = self.faces();
        let mut m = map.clone();
        for (mk, p) in m.markers.iter_mut().zip(placement) {
            let Some(p) = p else { continue };
            let r = p.rest_point(&state.angles);
            if let Some((t, bc)) = closest_point_among(faces, rest, r, p.candidates.iter().copied())
            {
                mk.triangle = t;
                mk.barycentric = bc;
            }
        }
        m
    }

    /// The marker-placement step of the calibration (see the module docs); returns each
    /// marker's per-frame samples (for [`PosePlacement`]).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn marker_step(
        &self,
        map: &mut MarkerMap,
        initial: &MarkerMap,
        init_rest: &[V3],
        rest: &[V3],
        outs: &[IkOut],
        obs: &[Obs],
        active: &[bool],
    ) -> Vec<Vec<PlacementSample>> {
        let o = &self.options;
        let faces = self.faces();
        let normals: Vec<Vec<V3>> = outs
            .iter()
            .map(|r| vertex_normals(faces, &r.result.posed, self.template.normal_sign))
            .collect();
        let mut samples = vec![Vec::new(); map.markers.len()];
        for (i, m) in map.markers.iter_mut().enumerate() {
            if !active[i] {
                continue;
            }
            let (mut acc, mut wsum, mut dsum) = ([0.0; 3], 0.0, 0.0);
            for (k, (r, ob)) in outs.iter().zip(obs).enumerate() {
                let w = r.weights[i];
                if !(w > 0.0 && finite(&ob[i])) {
                    continue;
                }
                let x = &r.result.posed;
                // The frame's own placement (pose-dependent) gives the normal.
                let pm = &r.map.markers[i];
                let n = surface_normal(faces, &normals[k], pm.triangle, pm.barycentric);
                let s = sub(ob[i], scale(n, m.offset_m));
                let (t, b) = closest_point(faces, x, s, 0.08);
                let q = surface_point(faces, x, t, b);
                let nq = surface_normal(faces, &normals[k], t, b);
                let on_rest = surface_point(faces, rest, t, b);
                acc = add(acc, scale(on_rest, w));
                dsum += w * dot(sub(ob[i], q), nq);
                wsum += w;
                samples[i].push(PlacementSample {
                    frame: k,
                    on_rest,
                    weight: w,
                });
            }
            if wsum <= 0.0 {
                continue;
            }
            let lambda = o.placement_prior_weight.max(1e-9);
            let q0 = init_rest[i];
            let mut q = scale(add(acc, scale(q0, lambda)), 1.0 / (wsum + lambda));
            let d = sub(q, q0);
            if norm(d) > o.marker_prior_m {
                q = add(q0, scale(d, o.marker_prior_m / norm(d)));
            }
            let (t, b) = closest_point(faces, rest, q, 0.06);
            m.triangle = t;
            m.barycentric = b;
            let off0 = initial.markers[i].offset_m;
            m.offset_m = ((dsum + lambda * off0) / (wsum + lambda)).clamp(0.003, 0.06);
        }
        samples
    }
}

/// Up to `n` frames of `frames`, evenly spread, each with ≥ 3 active markers observed
/// (preferring frames with ≥ 80 % of them).
pub(super) fn pick_frames(
    seq: &MarkerSequence,
    frames: &[usize],
    active: &[bool],
    n: usize,
) -> Vec<usize> {
    let count = |f: usize| {
        seq.frame(f)
            .iter()
            .zip(active)
            .filter(|(p, a)| **a && finite(p))
            .count()
    };
    let n_active = active.iter().filter(|a| **a).count();
    for frac in [0.8, 0.0] {
        let good: Vec<usize> = frames
            .iter()
            .copied()
            .filter(|&f| {
                let c = count(f);
                c >= 3 && c as f64 >= frac * n_active as f64
            })
            .collect();
        if good.len() >= n.min(frames.len()).max(1) || frac == 0.0 {
            let k = n.min(good.len());
            return (0..k)
                .map(|j| good[(j * good.len() + good.len() / (2 * k.max(1))) / k.max(1)])
                .collect();
        }
    }
    Vec::new()
}
