//! Limb cross-section measures for the twist study (paper Fig. 1, 13): how far skinning
//! collapses a twisted limb, and whether a fit keeps it.
//!
//! A limb segment runs from joint `a` to joint `b` (e.g. the elbow and wrist keypoints). Its
//! vertices are those of the rest mesh whose projection parameter `t = (x − a)·(b − a)/|b − a|²`
//! lies in `[t0, t1]` and whose distance to the axis is below `r_max`. Slices are equal
//! intervals of the rest `t`; the *radius ratio* of a slice is the median over its vertices of
//! the posed distance to the posed axis divided by the median rest distance to the rest axis.
use panoman_mesh::geom::{V3, dot, norm, sub};
use panoman_mesh::stats::median;

/// Vertices of a limb segment with their rest parameter `t` (module docs).
#[derive(Clone, Debug)]
pub struct LimbSegment {
    /// `(vertex, t)`.
    pub vertices: Vec<(u32, f64)>,
    /// Slice boundaries in `t` (n + 1 values).
    pub bounds: Vec<f64>,
}

/// Distance of `x` to the line through `a` along the unit `d`, and the parameter of `x` on
/// the segment `a + t(b − a)`.
fn axis_coords(x: V3, a: V3, b: V3) -> (f64, f64) {
    let ab = sub(b, a);
    let l2 = dot(ab, ab).max(1e-300);
    let t = dot(sub(x, a), ab) / l2;
    let foot = [a[0] + t * ab[0], a[1] + t * ab[1], a[2] + t * ab[2]];
    (norm(sub(x, foot)), t)
}

impl LimbSegment {
    /// The segment's vertices on `rest` between joints `a`, `b`, `t ∈ [t0, t1]`, radius below
    /// `r_max`, cut into `n_slices` equal slices.
    pub fn new(rest: &[V3], a: V3, b: V3, t0: f64, t1: f64, r_max: f64, n_slices: usize) -> Self {
        let vertices = rest
            .iter()
            .enumerate()
            .filter_map(|(v, &x)| {
                let (r, t) = axis_coords(x, a, b);
                (t >= t0 && t <= t1 && r < r_max).then_some((v as u32, t))
            })
            .collect();
        let n = n_slices.max(1);
        let bounds = (0..=n)
            .map(|k| t0 + (t1 - t0) * k as f64 / n as f64)
            .collect();
        LimbSegment { vertices, bounds }
    }

    /// Radius ratio per slice (posed over rest, module docs); NaN for an empty slice.
    pub fn radius_ratios(
        &self,
        rest: &[V3],
        rest_axis: (V3, V3),
        posed: &[V3],
        posed_axis: (V3, V3),
    ) -> Vec<f64> {
        let n = self.bounds.len() - 1;
        let mut rr: Vec<Vec<f64>> = vec![Vec::new(); n];
        let mut pr: Vec<Vec<f64>> = vec![Vec::new(); n];
        for &(v, t) in &self.vertices {
            let k = self.bounds[1..]
                .iter()
                .position(|&b| t <= b)
                .unwrap_or(n - 1);
            rr[k].push(axis_coords(rest[v as usize], rest_axis.0, rest_axis.1).0);
            pr[k].push(axis_coords(posed[v as usize], posed_axis.0, posed_axis.1).0);
        }
        (0..n)
            .map(|k| {
                let (a, b) = (median(&mut rr[k]), median(&mut pr[k]));
                if a > 0.0 { b / a } else { f64::NAN }
            })
            .collect()
    }
}
