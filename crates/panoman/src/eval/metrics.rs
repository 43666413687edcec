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

/// The six regions of the whole-body report: feet, legs, torso, arms, hands, face.
pub const REGION_NAMES: [&str; 6] = ["feet", "legs", "torso", "arms", "hands", "face"];

/// Mean per-vertex error (mm) per region of [`REGION_NAMES`], in that order.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RegionErrors {
    /// Feet: vertices skinned mostly by `foot` or a toe bone.
    pub feet: f64,
    /// Legs: mostly `upperleg*` / `lowerleg*`.
    pub legs: f64,
    /// Torso: the rest of the body part (root, pelvis, spine, clavicles, shoulders, neck).
    pub torso: f64,
    /// Arms: mostly `upperarm*` / `lowerarm*` (the hands' own vertices excluded).
    pub arms: f64,
    /// Both hands (the hand parts).
    pub hands: f64,
    /// The face part.
    pub face: f64,
}

impl RegionErrors {
    /// The values in [`REGION_NAMES`] order.
    pub fn values(&self) -> [f64; 6] {
        [
            self.feet, self.legs, self.torso, self.arms, self.hands, self.face,
        ]
    }
}

/// The vertices of each region of [`REGION_NAMES`] on a model's topology.
#[derive(Clone, Debug)]
pub struct BodyRegions {
    /// Per region, its vertex ids (ascending).
    pub vertices: [Vec<u32>; 6],
}

impl BodyRegions {
    /// Regions of `topology`'s vertices: hands and face from `regions`' parts; a body-part
    /// vertex goes to the region of the bone that skins it most (the generator's skin weights
    /// carried onto the topology through `map` as one-hot region indicators, the largest
    /// winning).
    pub(crate) fn of_rig(
        generator: &panoman_human::generator::Generator,
        map: &panoman_human::outputs::TopologyMap,
        topology: panoman_human::outputs::OutputTopology,
        regions: &Regions,
    ) -> BodyRegions {
        let names = generator.bone_names();
        let region_of_bone = |b: usize| -> usize {
            let n = names[b].as_str();
            if n.starts_with("foot") || n.starts_with("toe") {
                0
            } else if n.starts_with("upperleg") || n.starts_with("lowerleg") {
                1
            } else if n.starts_with("upperarm") || n.starts_with("lowerarm") {
                3
            } else {
                2
            }
        };
        let skin = generator.skin_weights();
        let n_anny = skin.offsets.len() - 1;
        // One-hot indicators of feet / legs / torso and of arms (two 3-vectors per vertex).
        let (mut a, mut b) = (vec![[0.0; 3]; n_anny], vec![[0.0; 3]; n_anny]);
        for k in 0..n_anny {
            let row = skin.offsets[k] as usize..skin.offsets[k + 1] as usize;
            let best = row
                .max_by(|&i, &j| skin.weights[i].total_cmp(&skin.weights[j]))
                .map_or(2, |i| region_of_bone(skin.bones[i] as usize));
            if best < 3 {
                a[k][best] = 1.0;
            } else {
                b[k][0] = 1.0;
            }
        }
        let (a, b) = (map.map(topology, &a), map.map(topology, &b));
        let mut vertices: [Vec<u32>; 6] = Default::default();
        for (v, part) in regions.vertex_part.iter().enumerate() {
            let r = match part {
                Part::LeftHand | Part::RightHand => 4,
                Part::Face => 5,
                Part::Body => {
                    let w = [a[v][0], a[v][1], a[v][2], b[v][0]];
                    (0..4).max_by(|&i, &j| w[i].total_cmp(&w[j])).unwrap_or(2)
                }
            };
            vertices[r].push(v as u32);
        }
        BodyRegions { vertices }
    }

    /// Mean per-vertex error (mm) of `x` against `truth` per region.
    pub fn errors(&self, x: &[V3], truth: &[V3]) -> RegionErrors {
        let m = |vs: &[u32]| {
            1e3 * vs
                .iter()
                .map(|&v| norm(sub(x[v as usize], truth[v as usize])))
                .sum::<f64>()
                / vs.len().max(1) as f64
        };
        let v = &self.vertices;
        RegionErrors {
            feet: m(&v[0]),
            legs: m(&v[1]),
            torso: m(&v[2]),
            arms: m(&v[3]),
            hands: m(&v[4]),
            face: m(&v[5]),
        }
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
