//! The posable bones, their angle ranges and a pose [`Theta`] over them
//! (docs/design/rig-and-ik.md §3.3).

use super::*;

/// Body bones sampled for body poses (docs/design/rig-and-ik.md §3.2), `[33]`.
pub const BODY_BONES: [&str; 33] = [
    "spine05",
    "spine04",
    "spine03",
    "spine02",
    "spine01",
    "neck01",
    "neck02",
    "neck03",
    "head",
    "clavicle.L",
    "clavicle.R",
    "shoulder01.L",
    "shoulder01.R",
    "upperarm01.L",
    "upperarm01.R",
    "upperarm02.L",
    "upperarm02.R",
    "lowerarm01.L",
    "lowerarm01.R",
    "lowerarm02.L",
    "lowerarm02.R",
    "wrist.L",
    "wrist.R",
    "upperleg01.L",
    "upperleg01.R",
    "upperleg02.L",
    "upperleg02.R",
    "lowerleg01.L",
    "lowerleg01.R",
    "lowerleg02.L",
    "lowerleg02.R",
    "foot.L",
    "foot.R",
];

/// The 19 hand bones of one hand without side suffix (docs/design/rig-and-ik.md §3.2): thumb, metacarpals (cupping),
/// index, middle, ring, little.
pub const HAND_BONES: [&str; 19] = [
    "finger1-1",
    "finger1-2",
    "finger1-3",
    "metacarpal1",
    "metacarpal2",
    "metacarpal3",
    "metacarpal4",
    "finger2-1",
    "finger2-2",
    "finger2-3",
    "finger3-1",
    "finger3-2",
    "finger3-3",
    "finger4-1",
    "finger4-2",
    "finger4-3",
    "finger5-1",
    "finger5-2",
    "finger5-3",
];

/// Face bones (docs/design/rig-and-ik.md §3.2): the jaw and the two eyes (gaze).
pub const FACE_BONES: [&str; 3] = ["jaw", "eye.L", "eye.R"];

/// Number of posable bones: 33 body + 2 × 19 hand + 3 face.
pub const N_POSABLE: usize = 74;
/// First [`posable_bones`] slot of the left hand (19 slots `HAND_BONES` + `.L`).
pub const LEFT_HAND_SLOT: usize = 33;
/// First slot of the right hand (19 slots `HAND_BONES` + `.R`).
pub const RIGHT_HAND_SLOT: usize = 52;
/// First slot of the face bones (jaw, eye.L, eye.R).
pub const FACE_SLOT: usize = 71;

/// The posable bones in [`Theta`] (and dataset `theta`) order: [`BODY_BONES`], the left
/// hand's [`HAND_BONES`] with `.L`, the right hand's with `.R`, then [`FACE_BONES`].
pub fn posable_bones() -> Vec<String> {
    let mut v: Vec<String> = BODY_BONES.iter().map(|s| s.to_string()).collect();
    for side in ["L", "R"] {
        v.extend(HAND_BONES.iter().map(|b| format!("{b}.{side}")));
    }
    v.extend(FACE_BONES.iter().map(|s| s.to_string()));
    v
}

/// Twist limits (degrees, Y) of the `*02` limb bones, chosen from the measured volume loss
/// of the LBS skin (the example `sampling_measurements twist`; default and adult identity).
///
/// LBS twist shrinks the limb where the `*01`/`*02` weights blend (the "candy wrapper"); the
/// worst cross-section radius loss grows like `1 − cos(θ/2)`: about −1.5 % at 20°, −3.1 to
/// −3.8 % at 30°, −7 to −7.6 % at 45°, −12 to −13 % at 60°, −27 to −29 % at 90°, for all
/// four bones (segment volume of revolution −3 % at 30°, −7 % at 45°). The whole-body
/// enclosed volume changes by −0.04 % (forearm) to −0.45 % (thigh) at 30°. The limit keeps the
/// worst radius loss within ≈ 3.5 %: ±30° for the arm bones (docs/design/rig-and-ik.md §3.3 allowed ±45° for
/// lowerarm02: −7.5 % radius), and docs/design/rig-and-ik.md §3.3's own tighter ±15° / ±10° for the legs (−0.9 % /
/// −0.4 %). Samples are `TN(0, L/2; ±L)`, so most twists are well inside.
pub const TWIST_LIMIT_DEG: [(&str, f64); 4] = [
    ("upperarm02", 30.0),
    ("lowerarm02", 30.0),
    ("upperleg02", 15.0),
    ("lowerleg02", 10.0),
];

/// [`bone_range`] of every posable bone, in theta order.
pub fn posable_ranges() -> &'static [[[f64; 2]; 3]] {
    static R: std::sync::OnceLock<Vec<[[f64; 2]; 3]>> = std::sync::OnceLock::new();
    R.get_or_init(|| {
        posable_bones()
            .iter()
            .map(|b| bone_range(b).expect("posable bones have ranges"))
            .collect()
    })
}

pub(super) fn twist_limit(bone: &str) -> f64 {
    TWIST_LIMIT_DEG
        .iter()
        .find(|(b, _)| *b == bone)
        .map_or(0.0, |(_, l)| *l)
}

/// Allowed range `[[x_lo, x_hi], [y_lo, y_hi], [z_lo, z_hi]]` (degrees) of a posable bone
/// in its *own* frame: docs/design/rig-and-ik.md §3.3 for left-side and central bones; right-side bones get the mirror
/// `(x, −y, −z)` of the left range; eyes share one range. The `*02` twists use
/// [`TWIST_LIMIT_DEG`]. `None` for a bone that is not posable.
pub fn bone_range(bone: &str) -> Option<[[f64; 2]; 3]> {
    let (base, right) = match bone.strip_suffix(".R") {
        Some(b) => (b, true),
        None => (bone.strip_suffix(".L").unwrap_or(bone), false),
    };
    let r = |x: [f64; 2], y: [f64; 2], z: [f64; 2]| Some([x, y, z]);
    let left = match base {
        "spine05" | "spine04" | "spine03" => r([-8., 12.], [-8., 8.], [-6., 6.]),
        "spine02" | "spine01" => r([-6., 10.], [-8., 8.], [-6., 6.]),
        "neck01" | "neck02" | "neck03" => r([-10., 15.], [-15., 15.], [-10., 10.]),
        "head" => r([-15., 20.], [-20., 20.], [-12., 12.]),
        "clavicle" => r([-8., 12.], [-5., 5.], [-8., 15.]),
        "shoulder01" => r([-8., 8.], [-5., 5.], [-8., 12.]),
        "upperarm01" => r([-40., 90.], [-45., 45.], [-40., 90.]),
        "lowerarm01" => r([-35., 95.], [-20., 20.], [0., 0.]),
        "upperarm02" | "lowerarm02" | "upperleg02" | "lowerleg02" => {
            let t = twist_limit(base);
            r([0., 0.], [-t, t], [0., 0.])
        }
        "wrist" => r([-20., 20.], [-10., 10.], [-60., 50.]),
        "upperleg01" => r([-90., 25.], [-30., 30.], [-35., 15.]),
        "lowerleg01" => r([0., 120.], [-8., 8.], [0., 0.]),
        "foot" => r([-20., 40.], [-10., 10.], [-15., 15.]),
        "finger1-1" => r([-15., 35.], [-15., 15.], [-25., 25.]),
        "finger1-2" => r([0., 55.], [0., 0.], [-5., 5.]),
        "finger1-3" => r([-5., 75.], [0., 0.], [0., 0.]),
        "metacarpal1" | "metacarpal2" => r([0., 6.], [0., 0.], [-3., 3.]),
        "metacarpal3" => r([0., 8.], [0., 0.], [-3., 3.]),
        "metacarpal4" => r([0., 10.], [0., 0.], [-3., 3.]),
        "finger2-1" | "finger3-1" | "finger4-1" | "finger5-1" => {
            r([-15., 85.], [0., 0.], [-12., 12.])
        }
        "finger2-2" | "finger3-2" | "finger4-2" | "finger5-2" => r([0., 100.], [0., 0.], [0., 0.]),
        "finger2-3" | "finger3-3" | "finger4-3" | "finger5-3" => r([0., 70.], [0., 0.], [0., 0.]),
        "jaw" => r([0., 22.], [-3., 3.], [-4., 4.]),
        "eye" => return Some([[-20., 20.], [0., 0.], [-30., 30.]]),
        _ => None,
    }?;
    if right {
        let [x, y, z] = left;
        Some([x, [-y[1], -y[0]], [-z[1], -z[0]]])
    } else {
        Some(left)
    }
}

// ---------------------------------------------------------------------------------------------
// Theta.

/// A pose of the [`POSABLE_BONES`](posable_bones): `deg[k] = [x, y, z]` local Euler angles in
/// degrees of bone `k` in its own frame (`R = Rz(z)·Ry(y)·Rx(x)`), zero = rest.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Theta {
    /// Euler angles in degrees, `[N_POSABLE]`.
    pub deg: [[f64; 3]; N_POSABLE],
}

impl Default for Theta {
    /// The rest pose (all zero).
    fn default() -> Self {
        Theta {
            deg: [[0.0; 3]; N_POSABLE],
        }
    }
}

impl Theta {
    /// The angles in radians as `f32`, flattened bone-major: `[x₀, y₀, z₀, x₁, …]`
    /// (`3 · N_POSABLE` values), the dataset's `theta` row.
    pub fn to_radians_f32(&self) -> Vec<f32> {
        self.deg
            .iter()
            .flat_map(|e| e.map(|a| a.to_radians() as f32))
            .collect()
    }

    /// Clamps every angle into [`bone_range`].
    pub fn clamp_to_ranges(&mut self) {
        for (e, r) in self.deg.iter_mut().zip(posable_ranges()) {
            for (v, lim) in e.iter_mut().zip(r) {
                *v = v.clamp(lim[0], lim[1]);
            }
        }
    }

    /// True if every angle is finite and lies in [`bone_range`] (within `tol` degrees).
    pub fn in_ranges(&self, tol: f64) -> bool {
        self.deg.iter().zip(posable_ranges()).all(|(e, r)| {
            e.iter()
                .zip(r)
                .all(|(v, lim)| v.is_finite() && *v >= lim[0] - tol && *v <= lim[1] + tol)
        })
    }

    /// Sets slot `k` from angles in the left-side convention: the right side stores the
    /// mirror `(x, −y, −z)` (docs/design/rig-and-ik.md §3.1).
    pub(super) fn set_lr(&mut self, k: usize, right: bool, e: [f64; 3]) {
        self.deg[k] = if right { [e[0], -e[1], -e[2]] } else { e };
    }
}

/// Rig index of each posable bone, to turn a [`Theta`] into [`PoseParams`].
#[derive(Clone, Debug)]
pub struct BoneMap {
    names: Vec<String>,
    rig_index: Vec<usize>,
    n_bones: usize,
}

impl BoneMap {
    /// Looks the [`posable_bones`] up in the rig's bone names (e.g.
    /// [`crate::generator::Generator::bone_names`]).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] naming a posable bone the rig lacks.
    pub fn new(rig_bone_names: &[String]) -> Result<BoneMap> {
        let names = posable_bones();
        let rig_index = names
            .iter()
            .map(|n| {
                rig_bone_names.iter().position(|b| b == n).ok_or_else(|| {
                    HumanError::Invalid(format!("the rig has no bone `{n}` (posable bone)"))
                })
            })
            .collect::<Result<Vec<usize>>>()?;
        Ok(BoneMap {
            names,
            rig_index,
            n_bones: rig_bone_names.len(),
        })
    }

    /// The posable bone names (theta order).
    pub fn names(&self) -> &[String] {
        &self.names
    }

    /// Rig index of each posable bone.
    pub fn rig_index(&self) -> &[usize] {
        &self.rig_index
    }

    /// The generator pose of a theta: angles at the posable bones, zero elsewhere, no root
    /// rotation or translation.
    pub fn pose_params(&self, theta: &Theta) -> PoseParams {
        let mut euler_deg = vec![[0.0; 3]; self.n_bones];
        for (k, &c) in self.rig_index.iter().enumerate() {
            euler_deg[c] = theta.deg[k];
        }
        PoseParams {
            euler_deg,
            root_rotation_z_deg: 0.0,
            root_translation: [0.0; 3],
        }
    }
}

pub(super) fn slot(bone: &str) -> usize {
    BODY_BONES
        .iter()
        .position(|&b| b == bone)
        .expect("body bone")
}
