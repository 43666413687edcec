//! Tracking a marker sequence with a calibration ([`MarkerSolver::track`]): IK per frame,
//! then for PanoMan the shell fit with the markers as handles.

use super::*;

/// Handles of the markers for the shell fit: each marker pulls its triangle's vertices
/// (weighted by the barycentric coordinates) so that the triangle, translated, puts its
/// marker point on `target`.
#[allow(clippy::too_many_arguments)]
pub(super) fn marker_handles(
    faces: &[[u32; 3]],
    map: &MarkerMap,
    x: &[V3],
    targets: &[Option<V3>],
    weights: &[f64],
    patches: &[Vec<(u32, f64)>],
    patch_weight: f64,
) -> Vec<VertexHandle> {
    let mut h = Vec::new();
    for (i, m) in map.markers.iter().enumerate() {
        let Some(t) = targets[i] else { continue };
        let f = faces[m.triangle as usize];
        let p = surface_point(faces, x, m.triangle, m.barycentric);
        let shift = sub(t, p);
        for k in 0..3 {
            let w = weights[i] * m.barycentric[k];
            if w > 1e-9 {
                h.push(VertexHandle {
                    vertex: f[k],
                    position: add(x[f[k] as usize], shift),
                    weight: w,
                });
            }
        }
        // The marker's surface patch follows it by the same displacement (a soft-tissue
        // field that the shell blends between markers).
        for &(v, g) in patches.get(i).map_or(&[][..], Vec::as_slice) {
            let w = patch_weight * weights[i] * g;
            if w > 1e-9 {
                h.push(VertexHandle {
                    vertex: v,
                    position: add(x[v as usize], shift),
                    weight: w,
                });
            }
        }
    }
    h
}

/// State carried from frame to frame.
#[derive(Clone)]
pub(super) struct Carry {
    pub(super) state: IkState,
    pub(super) mesh: Vec<V3>,
    pub(super) previous: Option<Previous>,
}

impl MarkerSolver {
    /// Tracks `frames` of `seq` in order with calibration `cal`; markers with
    /// `active[i] == false` are not used.
    ///
    /// # Errors
    /// IK or shell-fit failures (a frame with fewer than 3 markers keeps the previous
    /// frame's solution).
    pub fn track(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        cal: &Calibration,
        active: &[bool],
    ) -> Result<Vec<SolvedFrame>> {
        // On a worker of rayon's pool, as `panoman_fit::FrameSolver::fit` runs a frame: the frames'
        // many small fork-joins start from a worker.
        let mut res = None;
        rayon::scope(|_| res = Some(self.track_here(seq, frames, cal, active)));
        res.expect("the scope ran its closure")
    }

    /// [`MarkerSolver::track`] on the calling thread.
    pub(super) fn track_here(
        &mut self,
        seq: &MarkerSequence,
        frames: &[usize],
        cal: &Calibration,
        active: &[bool],
    ) -> Result<Vec<SolvedFrame>> {
        let mut out: Vec<SolvedFrame> = Vec::with_capacity(frames.len());
        let mut carry: Option<Carry> = None;
        let mut last_solved: Option<usize> = None;
        for &f in frames {
            let t = Instant::now();
            let obs = seq.frame(f);
            let n_obs = (0..obs.len())
                .filter(|&i| active[i] && finite(&obs[i]))
                .count();
            if n_obs < 3
                && let Some(prev) = out.last()
            {
                let mut s = prev.clone();
                s.frame = f;
                s.residuals = vec![f64::NAN; obs.len()];
                s.outliers = 0;
                s.seconds = t.elapsed().as_secs_f64();
                s.stage_seconds = Vec::new();
                out.push(s);
                continue;
            }
            let gap = last_solved.map_or(1, |p| f.saturating_sub(p));
            let (frame, next) = self.track_frame(obs, cal, active, carry.as_ref(), gap)?;
            carry = Some(next);
            last_solved = Some(f);
            out.push(SolvedFrame {
                frame: f,
                seconds: t.elapsed().as_secs_f64(),
                ..frame
            });
        }
        Ok(out)
    }

    pub(super) fn track_frame(
        &mut self,
        obs: Obs,
        cal: &Calibration,
        active: &[bool],
        carry: Option<&Carry>,
        gap: usize,
    ) -> Result<(SolvedFrame, Carry)> {
        let o = self.options.clone();
        let map = &cal.map;
        let t_ik = Instant::now();
        let ik = match carry {
            Some(c) => {
                // The prior is on velocity: over a gap of several frames the pose may move
                // that many times further.
                let temporal = (o.temporal_prior > 0.0).then(|| TemporalPrior {
                    weights: vec![
                        o.temporal_prior / (gap.max(1) as f64).powi(2);
                        c.state.angles.len()
                    ],
                    angles: c.state.angles.clone(),
                });
                self.ik_frame(
                    map,
                    obs,
                    active,
                    c.state.clone(),
                    &c.mesh,
                    false,
                    o.track_rounds,
                    o.track_iterations,
                    o.robust_sigma_m,
                    temporal,
                    cal.placement(),
                )?
            }
            None => {
                let st = self.cold_state(map, obs, active, cal.phenotype);
                self.ik_frame(
                    map,
                    obs,
                    active,
                    st,
                    &self.template.vertices,
                    false,
                    4,
                    40,
                    o.robust_sigma_m,
                    None,
                    cal.placement(),
                )?
            }
        };
        let mut stage_seconds = vec![("ik".to_string(), t_ik.elapsed().as_secs_f64())];
        let rig_params = ik.result.params.clone();
        let state = ik.result.state.clone();
        if o.method == Method::Lbs {
            let residuals = ik.residuals.clone();
            let outliers = count_outliers(&residuals, o.outlier_m);
            let mesh = ik.result.posed.clone();
            let frame = SolvedFrame {
                frame: 0,
                vertices: mesh.clone(),
                rig_params,
                params: None,
                residuals,
                outliers,
                seconds: 0.0,
                stage_seconds,
                placement: cal.placement().map(|_| ik.map.clone()),
            };
            let next = Carry {
                state,
                mesh,
                previous: None,
            };
            return Ok((frame, next));
        }
        let (vertices, params, stages) = self.shell_frame(&ik, obs, cal, active, carry)?;
        stage_seconds.extend(stages);
        let residuals = self.residuals(&ik.map, obs, active, &vertices);
        let outliers = count_outliers(&residuals, o.outlier_m);
        let next = Carry {
            state,
            mesh: ik.result.posed.clone(),
            previous: Some(Previous {
                vertices: vertices.clone(),
                params: params.clone(),
                init: Some(ik.result.posed.clone()),
            }),
        };
        let frame = SolvedFrame {
            frame: 0,
            vertices,
            rig_params,
            params: Some(params),
            residuals,
            outliers,
            seconds: 0.0,
            stage_seconds,
            placement: cal.placement().map(|_| ik.map.clone()),
        };
        Ok((frame, next))
    }

    /// PanoMan's shell fit of one frame from its IK.
    pub(super) fn shell_frame(
        &mut self,
        ik: &IkOut,
        obs: Obs,
        cal: &Calibration,
        active: &[bool],
        carry: Option<&Carry>,
    ) -> Result<(Vec<V3>, Params, StageTimes)> {
        let faces = self.template.faces.clone();
        let x = &ik.result.posed;
        let normals = vertex_normals(&faces, x, self.template.normal_sign);
        let targets: Vec<Option<V3>> = ik
            .map
            .markers
            .iter()
            .enumerate()
            .map(|(i, m)| {
                (active[i] && finite(&obs[i]) && ik.weights[i] > 0.0).then(|| {
                    let n = surface_normal(&faces, &normals, m.triangle, m.barycentric);
                    sub(obs[i], scale(n, m.offset_m))
                })
            })
            .collect();
        let handles = marker_handles(
            &faces,
            &ik.map,
            x,
            &targets,
            &ik.weights,
            &cal.patches,
            self.options.patch_weight,
        );
        let previous = carry.and_then(|c| c.previous.clone());
        let opts = if previous.is_some() {
            self.options.warm_fit.clone()
        } else {
            FitOptions::default()
        };
        let c = Constraints {
            targets: panoman_fit::Targets {
                handles,
                ..Default::default()
            },
            fixed: Some(Params {
                alpha: cal.alpha.clone(),
                ..Default::default()
            }),
            previous,
            ..Default::default()
        };
        let fit = self
            .solver
            .fit_from_ik(&c, &ik.result, &opts)
            .map_err(|e| MocapError::Invalid {
                what: format!("shell fit: {e}"),
            })?;
        let stages = fit
            .report
            .stages
            .iter()
            .map(|s| (format!("shell_{}", s.name), s.seconds))
            .collect();
        Ok((fit.vertices, fit.params, stages))
    }
}

pub(super) fn count_outliers(r: &[f64], limit: f64) -> usize {
    r.iter().filter(|x| x.is_finite() && **x > limit).count()
}

/// Mean and max (mm) of the finite entries.
pub fn mean_max_mm(r: impl IntoIterator<Item = f64>) -> (f64, f64, usize) {
    let (mut s, mut m, mut n) = (0.0, 0.0f64, 0usize);
    for x in r.into_iter().filter(|x| x.is_finite()) {
        s += x;
        m = m.max(x);
        n += 1;
    }
    if n == 0 {
        (f64::NAN, f64::NAN, 0)
    } else {
        (1e3 * s / n as f64, 1e3 * m, n)
    }
}
