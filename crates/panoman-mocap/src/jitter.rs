//! Jitter of a solved sequence: the mean acceleration of its points, beside the observed
//! markers' own (issue 13's evaluation: "jitter (mean vertex acceleration against the
//! markers' own)").
//!
//! For point sets `x_t` sampled every `dt` seconds, the acceleration of point `i` at an
//! interior frame is the second difference `a = (x_{t+1} − 2 x_t + x_{t−1}) / dt²` (m/s²). A
//! solve that adds no noise of its own moves its mesh about as smoothly as the markers move
//! (their acceleration includes the capture's noise and the soft tissue); a per-frame solve
//! that flips between nearby minima shows as a mesh acceleration well above the markers'.

use panoman_mesh::geom::{V3, norm};

/// Mean of `|x_{t+1} − 2 x_t + x_{t−1}| / dt²` (m/s²) over every interior frame `t` of
/// `frames` (each `[n]` points, one sequence sampled every `dt` s) and every point that is
/// finite in all three frames; `None` with fewer than three frames, no such point, point
/// sets of different sizes or a `dt` that is not positive.
pub fn mean_acceleration(frames: &[&[V3]], dt: f64) -> Option<f64> {
    if frames.len() < 3 || !(dt > 0.0 && dt.is_finite()) {
        return None;
    }
    let n = frames[0].len();
    if frames.iter().any(|f| f.len() != n) {
        return None;
    }
    let finite = |p: &V3| p.iter().all(|c| c.is_finite());
    let (mut sum, mut count) = (0.0, 0usize);
    for w in frames.windows(3) {
        for ((a, b), c) in w[0].iter().zip(w[1]).zip(w[2]) {
            if finite(a) && finite(b) && finite(c) {
                let d = [
                    c[0] - 2.0 * b[0] + a[0],
                    c[1] - 2.0 * b[1] + a[1],
                    c[2] - 2.0 * b[2] + a[2],
                ];
                sum += norm(d);
                count += 1;
            }
        }
    }
    (count > 0).then(|| sum / count as f64 / (dt * dt))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_parabola_has_its_constant_acceleration() {
        // x(t) = ½ a t² along x with a = 3 m/s², sampled at 120 Hz; a missing point is skipped.
        let dt = 1.0 / 120.0;
        let pts: Vec<Vec<V3>> = (0..10)
            .map(|k| {
                let t = k as f64 * dt;
                let missing = if k == 4 { f64::NAN } else { 0.0 };
                vec![[1.5 * t * t, 0.0, 1.0], [missing, 2.0, 0.0]]
            })
            .collect();
        let refs: Vec<&[V3]> = pts.iter().map(Vec::as_slice).collect();
        let a = mean_acceleration(&refs, dt).unwrap();
        // Point 0: 8 windows of 3.0; point 1 (at rest) in the 5 windows without frame 4: 0.
        let want = 8.0 * 3.0 / 13.0;
        assert!((a - want).abs() < 1e-9, "{a} vs {want}");
        assert!(mean_acceleration(&refs[..2], dt).is_none());
        assert!(mean_acceleration(&refs, 0.0).is_none());
    }
}
