//! Capture glitches found without a model: an observation is a glitch when its distances to
//! the markers that move most rigidly with it disagree with their usual values.
//!
//! For each marker `i`, its candidate neighbours are the [`CANDIDATES`] markers `j` (within
//! [`NEIGHBOUR_RANGE_M`] of it) whose distance `d_ij(f)` varies least over the capture (the
//! median absolute deviation from its median `m_ij`, on every [`SAMPLE_STEP`]-th frame); in
//! frame `f` its rigid neighbours are the first [`NEIGHBOURS`] of them that are observed (a
//! foot whose other markers drop out is judged by the ankle and shank). In frame `f`, `i` is
//! a glitch when at least two of its neighbours are observed and the median
//! over them of `|d_ij(f) − m_ij| − min(3·MAD_ij, 1 cm)` exceeds the threshold: a
//! mislabelled, drifting or ghost marker moves
//! away from all its neighbours at once, while one glitched neighbour (one term of the
//! median) does not flag `i`; a marker whose neighbours move relative to it (a hand's only
//! marker) has a larger MAD, so its usual motion is not flagged. The cap keeps a marker that
//! is wrong for a large part of the capture (whose MAD the glitch itself inflates) flagged.
//! Each median needs more than half of the samples right.
//!
//! **Runs (hysteresis).** A glitch that builds up or fades — a marker that slides on the skin
//! or a label that drifts back over hundreds of frames — crosses the threshold only at its
//! worst; its tails score between half the threshold and the threshold and would pass as
//! observations (Thomas' `RANK`: its score falls from 4 cm to 1 cm while it is still about
//! 60 mm from its calibrated place).
//! As in hysteresis thresholding (Canny's edge linking), a flagged run is extended forwards
//! and backwards through the frames whose score stays above a second, lower threshold
//! (`low_m`); frames where the marker is missing or cannot be judged continue the run. A
//! score above `low_m` that no frame above the threshold joins is not flagged.
use crate::markers::MarkerSequence;
use panoman_mesh::stats::median;

/// Rigid neighbours per marker and frame.
pub const NEIGHBOURS: usize = 3;
/// Candidate neighbours per marker, most rigid first.
pub const CANDIDATES: usize = 8;
/// Only markers whose median distance is below this are neighbours (m).
pub const NEIGHBOUR_RANGE_M: f64 = 0.5;
/// Largest tolerance a neighbour's MAD adds (m).
pub const MAD_CAP_M: f64 = 0.01;
/// Frame step of the neighbour statistics.
pub const SAMPLE_STEP: usize = 5;

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

fn observed(p: &[f64; 3]) -> bool {
    p.iter().all(|c| c.is_finite())
}

/// Per marker: its candidate neighbours `(j, m_ij, MAD_ij)`, most rigid first (see the
/// module docs; metres).
pub fn rigid_neighbours(seq: &MarkerSequence) -> Vec<Vec<(usize, f64, f64)>> {
    let nm = seq.n_markers();
    let frames: Vec<usize> = (0..seq.n_frames()).step_by(SAMPLE_STEP).collect();
    let mut stats = vec![vec![(f64::INFINITY, f64::NAN); nm]; nm];
    for i in 0..nm {
        for j in i + 1..nm {
            let mut d: Vec<f64> = frames
                .iter()
                .filter_map(|&f| {
                    let x = seq.frame(f);
                    (observed(&x[i]) && observed(&x[j])).then(|| dist(&x[i], &x[j]))
                })
                .collect();
            if d.len() < 3 {
                continue;
            }
            let m = median(&mut d);
            let mut dev: Vec<f64> = d.iter().map(|x| (x - m).abs()).collect();
            let mad = median(&mut dev);
            if m < NEIGHBOUR_RANGE_M {
                stats[i][j] = (mad, m);
                stats[j][i] = (mad, m);
            }
        }
    }
    stats
        .iter()
        .map(|row| {
            let mut c: Vec<(usize, f64, f64)> = row
                .iter()
                .enumerate()
                .filter(|(_, s)| s.0.is_finite())
                .map(|(j, s)| (j, s.0, s.1))
                .collect();
            c.sort_by(|a, b| a.1.total_cmp(&b.1));
            c.iter()
                .take(CANDIDATES)
                .map(|&(j, mad, m)| (j, m, mad))
                .collect()
        })
        .collect()
}

/// Glitch flags of every observation, frame-major like [`MarkerSequence::positions`]
/// (`false` for missing ones): the observations whose score (module docs) exceeds
/// `threshold_m`, each such run extended through the neighbouring frames whose score exceeds
/// `low_m` (metres; `low_m ≥ threshold_m` turns the extension off).
pub fn find_glitches(seq: &MarkerSequence, threshold_m: f64, low_m: f64) -> Vec<bool> {
    let nm = seq.n_markers();
    let nf = seq.n_frames();
    let nb = rigid_neighbours(seq);
    // Score per observation; NaN where the marker is missing or fewer than two of its
    // neighbours are observed.
    let mut score = vec![f64::NAN; seq.positions.len()];
    for f in 0..nf {
        let x = seq.frame(f);
        for i in (0..nm).filter(|&i| observed(&x[i])) {
            let mut dev: Vec<f64> = nb[i]
                .iter()
                .filter(|(j, _, _)| observed(&x[*j]))
                .take(NEIGHBOURS)
                .map(|&(j, m, mad)| (dist(&x[i], &x[j]) - m).abs() - (3.0 * mad).min(MAD_CAP_M))
                .collect();
            if dev.len() >= 2 {
                score[f * nm + i] = median(&mut dev);
            }
        }
    }
    let mut flags: Vec<bool> = score.iter().map(|&s| s > threshold_m).collect();
    let low = low_m.min(threshold_m);
    for i in 0..nm {
        // Forwards, then backwards: a run goes on while the score stays above `low`.
        for backwards in [false, true] {
            let mut on = false;
            for t in 0..nf {
                let k = if backwards { nf - 1 - t } else { t } * nm + i;
                if flags[k] {
                    on = true;
                } else if score[k].is_nan() {
                    // Missing or not judged: the run carries over it.
                } else if on && score[k] > low {
                    flags[k] = true;
                } else {
                    on = false;
                }
            }
        }
    }
    flags
}

/// Marks the glitches of `seq` (see [`find_glitches`]) as missing; returns the count per
/// marker.
pub fn drop_glitches(seq: &mut MarkerSequence, threshold_m: f64, low_m: f64) -> Vec<usize> {
    let nm = seq.n_markers();
    let flags = find_glitches(seq, threshold_m, low_m);
    let mut count = vec![0; nm];
    for (k, _) in flags.iter().enumerate().filter(|(_, g)| **g) {
        seq.positions[k] = [f64::NAN; 3];
        count[k % nm] += 1;
    }
    count
}
