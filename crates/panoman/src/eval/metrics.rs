//! Per-vertex error statistics by body part, sample statistics, and the deterministic noise
//! of the keypoint experiments.
use panoman_human::regions::{Part, Regions};
use panoman_mesh::geom::{V3, norm, sub};
use serde::{Deserialize, Serialize};

use crate::model::Model;

/// Mean and max per-vertex error (mm) per part (body, face, hands) and over all vertices.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PartErrors {
    /// Mean over every vertex.
    pub all_mean: f64,
    /// Max over every vertex.
    pub all_max: f64,
    /// Mean over the body region.
    pub body_mean: f64,
    /// Max over the body region.
    pub body_max: f64,
    /// Mean over the face region.
    pub face_mean: f64,
    /// Max over the face region.
    pub face_max: f64,
    /// Mean over both hands.
    pub hands_mean: f64,
    /// Max over both hands.
    pub hands_max: f64,
}

/// The vertex groups errors are reported on (body, face, both hands).
#[derive(Clone, Debug)]
pub struct Groups {
    body: Vec<u32>,
    face: Vec<u32>,
    hands: Vec<u32>,
}

impl Groups {
    /// Body, face and both hands of `regions`.
    pub(crate) fn of(regions: &Regions) -> Groups {
        Groups {
            body: regions.vertices_of(Part::Body),
            face: regions.vertices_of(Part::Face),
            hands: {
                let mut h = regions.vertices_of(Part::LeftHand);
                h.extend(regions.vertices_of(Part::RightHand));
                h
            },
        }
    }
}

impl Groups {
    /// Body, face and both hands of a model's own vertex labelling ([`Model::regions`]; no
    /// asset tree needed).
    pub fn of_model(model: &Model) -> Groups {
        let mut g = Groups {
            body: Vec::new(),
            face: Vec::new(),
            hands: Vec::new(),
        };
        for (name, ids) in model.regions() {
            match name {
                "body" => g.body = ids,
                "face" => g.face = ids,
                _ => g.hands.extend(ids),
            }
        }
        g.hands.sort_unstable();
        g
    }

    /// Per-vertex errors (mm) of `x` against `truth` (both `(V, 3)` metres, the same
    /// topology) by part, see `part_errors`.
    pub fn errors(&self, x: &[V3], truth: &[V3]) -> PartErrors {
        part_errors(x, truth, self)
    }
}

/// Per-vertex errors (mm) of `x` against `truth`, by part (no alignment: both are in the
/// world frame).
pub(crate) fn part_errors(x: &[V3], truth: &[V3], g: &Groups) -> PartErrors {
    let d: Vec<f64> = x
        .iter()
        .zip(truth)
        .map(|(a, b)| 1e3 * norm(sub(*a, *b)))
        .collect();
    let stat = |vs: &[u32]| {
        let (mut s, mut m) = (0.0, 0.0f64);
        for &v in vs {
            s += d[v as usize];
            m = m.max(d[v as usize]);
        }
        (s / vs.len().max(1) as f64, m)
    };
    let all: f64 = d.iter().sum::<f64>() / d.len().max(1) as f64;
    let (bm, bx) = stat(&g.body);
    let (fm, fx) = stat(&g.face);
    let (hm, hx) = stat(&g.hands);
    PartErrors {
        all_mean: all,
        all_max: d.iter().cloned().fold(0.0, f64::max),
        body_mean: bm,
        body_max: bx,
        face_mean: fm,
        face_max: fx,
        hands_mean: hm,
        hands_max: hx,
    }
}

/// Means of the means and max of the maxima.
pub fn mean_of(xs: &[PartErrors]) -> PartErrors {
    let n = xs.len().max(1) as f64;
    let mut m = PartErrors::default();
    for x in xs {
        m.all_mean += x.all_mean / n;
        m.body_mean += x.body_mean / n;
        m.face_mean += x.face_mean / n;
        m.hands_mean += x.hands_mean / n;
        m.all_max = m.all_max.max(x.all_max);
        m.body_max = m.body_max.max(x.body_max);
        m.face_max = m.face_max.max(x.face_max);
        m.hands_max = m.hands_max.max(x.hands_max);
    }
    m
}

/// (median, min, max) of a sample; NaN for an empty one (see [`MedianMinMax::of`]).
pub(crate) fn median_min_max(xs: &[f64]) -> (f64, f64, f64) {
    let mut v = xs.to_vec();
    v.sort_by(|a, b| a.total_cmp(b));
    let n = v.len();
    if n == 0 {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let med = if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    };
    (med, v[0], v[n - 1])
}

pub(crate) fn to_v3(x: Vec<[f32; 3]>) -> Vec<V3> {
    x.iter()
        .map(|p| [p[0] as f64, p[1] as f64, p[2] as f64])
        .collect()
}

/// Deterministic Gaussian noise (xorshift + Box–Muller), for keypoint noise.
pub(crate) struct Noise(pub(crate) u64);

impl Noise {
    /// The generator of `panoman eval --seed seed`.
    pub(crate) fn for_seed(seed: u64) -> Noise {
        Noise(0x5eed ^ seed.wrapping_mul(0x9e37_79b9_7f4a_7c15) | 1)
    }

    pub(crate) fn next(&mut self) -> f64 {
        let mut u = || {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b) = (u().max(1e-300), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_min_max_of_even_and_empty_samples() {
        assert_eq!(median_min_max(&[3.0, 1.0, 2.0, 10.0]), (2.5, 1.0, 10.0));
        assert!(median_min_max(&[]).0.is_nan());
    }

    #[test]
    fn noise_is_deterministic_and_roughly_standard() {
        let (mut a, mut b) = (Noise::for_seed(7), Noise::for_seed(7));
        let xs: Vec<f64> = (0..4000).map(|_| a.next()).collect();
        assert!(xs.iter().all(|&x| x == b.next()));
        let mean = xs.iter().sum::<f64>() / xs.len() as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / xs.len() as f64;
        assert!(mean.abs() < 0.1 && (var - 1.0).abs() < 0.1, "{mean} {var}");
    }

    #[test]
    fn mean_of_averages_means_and_keeps_max() {
        let a = PartErrors {
            all_mean: 1.0,
            all_max: 5.0,
            ..Default::default()
        };
        let b = PartErrors {
            all_mean: 3.0,
            all_max: 2.0,
            ..Default::default()
        };
        let m = mean_of(&[a, b]);
        assert_eq!((m.all_mean, m.all_max), (2.0, 5.0));
    }
}
