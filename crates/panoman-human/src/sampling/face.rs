//! Facial expressions: face units, jaw and gaze (docs/design/rig-and-ik.md §3.1).

use super::*;

/// The eight `eyeLook*` units (gaze by blendshape).
pub const EYE_LOOK_UNITS: [&str; 8] = [
    "eyeLookDownLeft",
    "eyeLookDownRight",
    "eyeLookInLeft",
    "eyeLookInRight",
    "eyeLookOutLeft",
    "eyeLookOutRight",
    "eyeLookUpLeft",
    "eyeLookUpRight",
];

/// Mutually exclusive unit pairs (opposite motions): never both active.
pub const EXCLUSIVE_UNITS: [(&str, &str); 2] =
    [("jawLeft", "jawRight"), ("mouthLeft", "mouthRight")];

/// The mirror unit of a `…Left`/`…Right` unit (`None` for central units and for the
/// exclusive pairs).
pub fn mirror_unit(unit: &str) -> Option<&'static str> {
    if EXCLUSIVE_UNITS
        .iter()
        .any(|(a, b)| *a == unit || *b == unit)
    {
        return None;
    }
    let m = if let Some(b) = unit.strip_suffix("Left") {
        format!("{b}Right")
    } else if let Some(b) = unit.strip_suffix("Right") {
        format!("{b}Left")
    } else {
        return None;
    };
    face_unit_index(&m).map(|k| FACE_UNITS[k])
}

/// A facial expression: face-unit values (docs/design/assets.md §5.4) and the jaw/eye bone angles.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Expression {
    /// Unit values in [`FACE_UNITS`] order, each in [0, 1].
    pub units: [f64; 52],
    /// Jaw `[x, y, z]` degrees (x = open).
    pub jaw: [f64; 3],
    /// Gaze `[x, y, z]` degrees, the same on both eyes (x = up, z = toward +x).
    pub eyes: [f64; 3],
}

impl Expression {
    /// Writes the jaw and eye angles into the face slots of `theta`.
    pub fn write_theta(&self, theta: &mut Theta) {
        theta.deg[FACE_SLOT] = self.jaw;
        theta.deg[FACE_SLOT + 1] = self.eyes;
        theta.deg[FACE_SLOT + 2] = self.eyes;
    }
}

/// Sparse facial expressions avoiding docs/design/rig-and-ik.md §3.2's double counting.
///
/// 1. Gaze: with p = 0.5 by the *eye bones* — x `TN(0, 8; ±20)`, z `TN(0, 12; ±30)`, the
///    same on both eyes, and no `eyeLook*` unit; else by *units* with p = 0.5 — horizontal
///    `h ~ TN(0, 0.5; ±1)` (h > 0 looks toward +x: eyeLookOutLeft = eyeLookInRight = h; h < 0:
///    eyeLookInLeft = eyeLookOutRight = |h|) and vertical `v ~ TN(0, 0.4; ±1)` (Up or Down
///    on both eyes), each axis active with p = 0.6; else no gaze.
/// 2. `k ~ U{1, …, 6}` distinct units drawn uniformly from the 43 units other than
///    `eyeLook*` and mouthClose, each `~ U(0.1, 1)`; a second unit of an
///    [`EXCLUSIVE_UNITS`] pair is dropped. A unit with a mirror ([`mirror_unit`]) gets its
///    mirror set to the same value with p = 0.5 (symmetric), to an independent `U(0.1, 1)`
///    with p = 0.2, else stays one-sided (unless the mirror was drawn itself).
/// 3. If jawOpen > 0: mouthClose `~ U(0, jawOpen)` with p = 0.3 (ARKit: used with jawOpen).
/// 4. Jaw bone with p = 0.4: x `~ U(0, 22)·(1 − jawOpen)` (a large jawOpen leaves little
///    rotation), y `TN(0, 1.5; ±3)`, z `TN(0, 2; ±4)`; else at rest.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ExpressionSampler;

impl ExpressionSampler {
    /// Draws one expression (see the type docs).
    pub fn sample(&self, rng: &mut impl RngCore) -> Expression {
        let mut units = [0.0; 52];
        let mut eyes = [0.0; 3];
        let idx = |u: &str| face_unit_index(u).expect("face unit");
        let gaze = uniform(rng);
        if gaze < 0.5 {
            eyes = [
                truncated_normal(rng, 0.0, 8.0, -20.0, 20.0),
                0.0,
                truncated_normal(rng, 0.0, 12.0, -30.0, 30.0),
            ];
        } else if gaze < 0.75 {
            let h = truncated_normal(rng, 0.0, 0.5, -1.0, 1.0);
            let v = truncated_normal(rng, 0.0, 0.4, -1.0, 1.0);
            if uniform(rng) < 0.6 {
                let (a, b) = if h > 0.0 {
                    ("eyeLookOutLeft", "eyeLookInRight")
                } else {
                    ("eyeLookInLeft", "eyeLookOutRight")
                };
                units[idx(a)] = h.abs();
                units[idx(b)] = h.abs();
            }
            if uniform(rng) < 0.6 {
                let (a, b) = if v > 0.0 {
                    ("eyeLookUpLeft", "eyeLookUpRight")
                } else {
                    ("eyeLookDownLeft", "eyeLookDownRight")
                };
                units[idx(a)] = v.abs();
                units[idx(b)] = v.abs();
            }
        }
        let mut pool: Vec<usize> = (0..52)
            .filter(|&k| !EYE_LOOK_UNITS.contains(&FACE_UNITS[k]) && FACE_UNITS[k] != "mouthClose")
            .collect();
        let k = 1 + (uniform(rng) * 6.0) as usize;
        let mut chosen = Vec::with_capacity(6);
        for _ in 0..k.min(6) {
            let j = (uniform(rng) * pool.len() as f64) as usize;
            chosen.push(pool.swap_remove(j.min(pool.len() - 1)));
        }
        for &u in &chosen {
            let name = FACE_UNITS[u];
            let v = uniform_in(rng, 0.1, 1.0);
            let excluded = EXCLUSIVE_UNITS.iter().any(|&(a, b)| {
                (name == a && units[idx(b)] > 0.0) || (name == b && units[idx(a)] > 0.0)
            });
            if excluded {
                continue;
            }
            units[u] = v;
            if let Some(m) = mirror_unit(name) {
                let mi = idx(m);
                let p = uniform(rng);
                let mv = uniform_in(rng, 0.1, 1.0);
                if !chosen.contains(&mi) {
                    if p < 0.5 {
                        units[mi] = v;
                    } else if p < 0.7 {
                        units[mi] = mv;
                    }
                }
            }
        }
        let jaw_open = units[idx("jawOpen")];
        if jaw_open > 0.0 && uniform(rng) < 0.3 {
            units[idx("mouthClose")] = uniform_in(rng, 0.0, jaw_open);
        }
        let mut jaw = [0.0; 3];
        if uniform(rng) < 0.4 {
            jaw = [
                uniform_in(rng, 0.0, 22.0) * (1.0 - jaw_open),
                truncated_normal(rng, 0.0, 1.5, -3.0, 3.0),
                truncated_normal(rng, 0.0, 2.0, -4.0, 4.0),
            ];
        }
        for u in &mut units {
            *u = u.clamp(0.0, 1.0);
        }
        Expression { units, jaw, eyes }
    }
}
