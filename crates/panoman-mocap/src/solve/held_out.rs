//! The held-out marker error ([`MarkerSolver::held_out`]) and which markers stay observable
//! in a fold.

use super::*;

impl MarkerSolver {
    /// Per marker: whether it is observable by the `active` markers — it is active, or
    /// another active marker is on its rig bone or on a bone below it.
    pub fn observable(&self, map: &MarkerMap, active: &[bool]) -> Vec<bool> {
        let names = self.bone_names();
        let parents = self.solver.rig().generator.bone_parents();
        let bone = |i: usize| names.iter().position(|n| *n == map.markers[i].bone);
        let below = |b: usize, mut c: usize| loop {
            if c == b {
                return true;
            }
            match parents[c] {
                Some(p) => c = p,
                None => return false,
            }
        };
        (0..map.markers.len())
            .map(|i| {
                active[i]
                    || bone(i).is_none_or(|b| {
                        (0..map.markers.len())
                            .filter(|&j| j != i && active[j])
                            .any(|j| bone(j).is_some_and(|c| below(b, c)))
                    })
            })
            .collect()
    }

    /// The held-out marker error (see the module docs) on `frames` (every
    /// `held_out_step`-th is used) with the full calibration `full`; `full_solve` (the
    /// tracking with every marker) marks glitch observations for
    /// [`HeldOut::mean_inliers`].
    ///
    /// # Errors
    /// Calibration or tracking failures of a fold.
    pub fn held_out(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        full: &Calibration,
        full_solve: Option<&[SolvedFrame]>,
    ) -> Result<HeldOut> {
        let full_res: BTreeMap<usize, &[f64]> = full_solve
            .unwrap_or(&[])
            .iter()
            .map(|s| (s.frame, s.residuals.as_slice()))
            .collect();
        let mut inliers: Vec<f64> = Vec::new();
        let t0 = Instant::now();
        let k = self.options.held_out_folds.max(2);
        let nm = full.map.markers.len();
        // The calibration frames (where the full calibration saw every marker) are not
        // evaluated, unless they are all there is (a clip of a few frames).
        let stepped: Vec<usize> = frames
            .iter()
            .copied()
            .step_by(self.options.held_out_step.max(1))
            .collect();
        let mut sub_frames: Vec<usize> = stepped
            .iter()
            .copied()
            .filter(|f| !full.frames.contains(f))
            .collect();
        if sub_frames.is_empty() {
            sub_frames = stepped;
        }
        let mut per: Vec<Vec<f64>> = vec![Vec::new(); nm];
        let mut unobservable = vec![false; nm];
        for fold in 0..k {
            let active: Vec<bool> = (0..nm).map(|i| i % k != fold).collect();
            for (u, o) in unobservable
                .iter_mut()
                .zip(self.observable(&full.map, &active))
            {
                *u |= !o;
            }
            let cal = if self.options.held_out_recalibrate {
                self.calibrate(seq, frames, &full.map, &active)?
            } else {
                full.clone()
            };
            let solved = self.track(seq, &sub_frames, &cal, &active)?;
            for s in &solved {
                let mm = self.model_markers(s.map(full), &s.vertices);
                let obs = seq.frame(s.frame);
                for i in (0..nm).filter(|&i| !active[i] && finite(&obs[i])) {
                    let e = norm(sub(mm[i], obs[i]));
                    per[i].push(e);
                    if !unobservable[i]
                        && full_res
                            .get(&s.frame)
                            .is_some_and(|r| r[i] <= self.options.outlier_m)
                    {
                        inliers.push(e);
                    }
                }
            }
        }
        let all: Vec<f64> = per.iter().flatten().copied().collect();
        let kept: Vec<f64> = per
            .iter()
            .zip(&unobservable)
            .filter(|(_, u)| !**u)
            .flat_map(|(v, _)| v.iter().copied())
            .collect();
        let mean_mm = |v: &[f64]| {
            if v.is_empty() {
                f64::NAN
            } else {
                1e3 * v.iter().sum::<f64>() / v.len() as f64
            }
        };
        let per_marker = full
            .map
            .markers
            .iter()
            .zip(&per)
            .filter(|(_, v)| !v.is_empty())
            .map(|(m, v)| (m.name.clone(), 1e3 * v.iter().sum::<f64>() / v.len() as f64))
            .collect();
        Ok(HeldOut {
            mean: mean_mm(&kept),
            mean_all: mean_mm(&all),
            unobservable: (0..nm)
                .filter(|&i| unobservable[i] && !per[i].is_empty())
                .map(|i| full.map.markers[i].name.clone())
                .collect(),
            per_marker,
            mean_inliers: if full_solve.is_some() {
                mean_mm(&inliers)
            } else {
                f64::NAN
            },
            observations: [kept.len(), inliers.len(), all.len()],
            method: format!(
                "{k}-fold over markers (marker i in fold i mod {k}); {}; each fold tracked without its markers on {} (calibration frames left out); error = |observed − (surface point + offset·n̂)| on the solved mesh, with the held-out marker's placement from the full calibration (MoSh), moved to the solved pose when the placement is pose-dependent (pose_placement_ridge > 0); capture glitches (markers that leave their rigid neighbours) are missing; `mean` leaves out the markers that no other marker of their fold observes (`unobservable`), `mean_all` keeps them",
                if self.options.held_out_recalibrate {
                    "each fold calibrated anew without its markers"
                } else {
                    "shape and placement calibrated once with every marker (MoSh)"
                },
                match self.options.held_out_step.max(1) {
                    1 => "every solved frame, as the solve tracks".to_string(),
                    k => format!(
                        "every {k}-th solved frame, with 1/{} of the temporal prior",
                        k * k
                    ),
                }
            ),
            folds: k,
            frames: sub_frames.len(),
            seconds: t0.elapsed().as_secs_f64(),
        })
    }
}
