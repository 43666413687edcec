//! Retargeting of CMU BVH motion (the 31-joint skeleton of the CMU Graphics Lab captures,
//! e.g. `01_01.bvh`) to the generator's 163-bone rig ([`panoman_human::generator`]).
//!
//! # Method
//! 1. **Frames.** BVH is Y up with the CMU subject's left along +X, i.e. facing +Z; the
//!    project frame is Z up, facing −Y, left +X. `A = Y₀ · Rx(90°)`, where the yaw `Y₀`
//!    turns the calibration frame's hip vector (`LeftUpLeg − RightUpLeg`) onto +X.
//! 2. **Calibration (rest poses aligned).** At the calibration frame (frame 0, a T-pose),
//!    the rig's limb segments are swung, parents first, so that each segment's direction
//!    (e.g. head of `upperarm01.L` → head of `lowerarm01.L`) equals the mapped BVH segment's
//!    (`LeftArm → LeftForeArm`) under `A` ([`CMU_CALIBRATION`]). This gives world rotations
//!    `G⁰_c` of every rig bone in the BVH's T-pose; the BVH's own are `B⁰_j`.
//! 3. **Per frame.** A rig bone driven by a BVH joint ([`CMU_DRIVERS`]) gets the world
//!    rotation `G_c = A ΔB_j Aᵀ G⁰_c` with `ΔB_j = B_j B⁰_jᵀ` (the joint's world rotation
//!    change since the calibration frame); every other bone keeps its calibrated local
//!    rotation (follows its parent). Local deltas are `E_c = (G_p P_pᵀ R_c)ᵀ G_c` (rest
//!    rotations `R`), written as Euler XYZ degrees (`E = Rz·Ry·Rx`, the generator's
//!    convention); the root's `E_0 = G_0` (root Z rotation 0).
//! 4. **Root translation and scale.** The BVH is measured in metres; `s` (rig metres per
//!    BVH metre) is the similarity scale between the rig's calibrated joints and the BVH's at
//!    the calibration frame ([`CMU_EVAL_JOINTS`]). The rig point that corresponds to the BVH
//!    `Hips` joint follows `s · A · Hips(t)` (plus a constant that makes frame 0 coincide),
//!    which fixes the root translation given the root rotation.
//!
//! Bone-length differences between the subject and the rig's identity are not absorbed
//! (only the uniform `s`); they are what remains in [`retarget_error`].

use panoman_fit::shape_calibration::{LENGTH_KNOBS, fit_knobs, with_knobs};
use panoman_human::generator::Identity;
use panoman_human::params::{GeneratorParams, PoseParams, ShapeParams};
use panoman_mesh::align::nearest_rotation;
use panoman_mesh::geom::{
    IDENTITY, M3, V3, add, cross, dot, matmul, matvec, norm, normalize, scale, sub, transpose,
};
use panoman_mesh::rotation::{axis_angle, euler_xyz_deg_of};

use crate::bvh::{Bvh, Rigid};
use crate::error::{MocapError, Result};

/// Rig bone ← BVH joint whose world rotation change drives it (both sides). The spine is
/// matched by height above the hip joints: CMU `LowerBack` (≈ 0.10 m) ↔ `spine04`
/// (0.08 m), `Spine` (0.22 m) ↔ `spine02` (0.22 m), `Spine1` (0.33 m) ↔ `spine01`
/// (0.36 m); `spine05` follows the root (`Hips`). (Driving `spine05`/`spine03` instead
/// doubles the shoulder error.)
pub const CMU_DRIVERS: [(&str, &str); 33] = [
    ("root", "Hips"),
    ("spine04", "LowerBack"),
    ("spine02", "Spine"),
    ("spine01", "Spine1"),
    ("neck01", "Neck"),
    ("neck02", "Neck1"),
    ("head", "Head"),
    ("pelvis.L", "LHipJoint"),
    ("upperleg01.L", "LeftUpLeg"),
    ("lowerleg01.L", "LeftLeg"),
    ("foot.L", "LeftFoot"),
    ("toe1-1.L", "LeftToeBase"),
    ("toe2-1.L", "LeftToeBase"),
    ("toe3-1.L", "LeftToeBase"),
    ("toe4-1.L", "LeftToeBase"),
    ("toe5-1.L", "LeftToeBase"),
    ("clavicle.L", "LeftShoulder"),
    ("upperarm01.L", "LeftArm"),
    ("lowerarm01.L", "LeftForeArm"),
    ("wrist.L", "LeftHand"),
    ("pelvis.R", "RHipJoint"),
    ("upperleg01.R", "RightUpLeg"),
    ("lowerleg01.R", "RightLeg"),
    ("foot.R", "RightFoot"),
    ("toe1-1.R", "RightToeBase"),
    ("toe2-1.R", "RightToeBase"),
    ("toe3-1.R", "RightToeBase"),
    ("toe4-1.R", "RightToeBase"),
    ("toe5-1.R", "RightToeBase"),
    ("clavicle.R", "RightShoulder"),
    ("upperarm01.R", "RightArm"),
    ("lowerarm01.R", "RightForeArm"),
    ("wrist.R", "RightHand"),
];

/// Segments aligned at calibration: `(rig bone, rig bone at the segment's end, BVH joint,
/// BVH joint at the end)`; directions between heads / joint positions.
pub const CMU_CALIBRATION: [(&str, &str, &str, &str); 10] = [
    ("upperleg01.L", "lowerleg01.L", "LeftUpLeg", "LeftLeg"),
    ("lowerleg01.L", "foot.L", "LeftLeg", "LeftFoot"),
    ("foot.L", "toe2-1.L", "LeftFoot", "LeftToeBase"),
    ("upperarm01.L", "lowerarm01.L", "LeftArm", "LeftForeArm"),
    ("lowerarm01.L", "wrist.L", "LeftForeArm", "LeftHand"),
    ("upperleg01.R", "lowerleg01.R", "RightUpLeg", "RightLeg"),
    ("lowerleg01.R", "foot.R", "RightLeg", "RightFoot"),
    ("foot.R", "toe2-1.R", "RightFoot", "RightToeBase"),
    ("upperarm01.R", "lowerarm01.R", "RightArm", "RightForeArm"),
    ("lowerarm01.R", "wrist.R", "RightForeArm", "RightHand"),
];

/// Joints compared by [`retarget_error`]: `(BVH joint, rig bone whose head sits there)` —
/// hips, knees, ankles, balls of the feet, shoulders, elbows, wrists.
pub const CMU_EVAL_JOINTS: [(&str, &str); 14] = [
    ("LeftUpLeg", "upperleg01.L"),
    ("LeftLeg", "lowerleg01.L"),
    ("LeftFoot", "foot.L"),
    ("LeftToeBase", "toe2-1.L"),
    ("LeftArm", "upperarm01.L"),
    ("LeftForeArm", "lowerarm01.L"),
    ("LeftHand", "wrist.L"),
    ("RightUpLeg", "upperleg01.R"),
    ("RightLeg", "lowerleg01.R"),
    ("RightFoot", "foot.R"),
    ("RightToeBase", "toe2-1.R"),
    ("RightArm", "upperarm01.R"),
    ("RightForeArm", "lowerarm01.R"),
    ("RightHand", "wrist.R"),
];

/// A calibrated CMU → rig retarget for one identity (see the module docs).
#[derive(Clone, Debug)]
pub struct CmuRetarget {
    /// BVH world → rig world rotation `A`.
    pub bvh_to_rig: M3,
    /// Rig metres per BVH metre, `s`.
    pub scale: f64,
    /// The BVH frame used for calibration.
    pub calibration_frame: usize,
    shape: ShapeParams,
    parents: Vec<Option<usize>>,
    /// `R_pᵀ R_c` per bone (identity-free for the root).
    rest_local: Vec<M3>,
    /// Calibrated local deltas `E⁰_c`.
    calib_local: Vec<M3>,
    /// Calibrated world rotations `G⁰_c`.
    calib_world: Vec<M3>,
    /// Driving BVH joint per rig bone.
    driver: Vec<Option<usize>>,
    /// `B⁰_j`.
    bvh_calib: Vec<M3>,
    hips: usize,
    /// Rest root head `h_0`.
    h0: V3,
    /// The rig point matching BVH `Hips` at calibration (root-local offset from `h_0`).
    q_off: V3,
    /// `T = q − s A Hips⁰`.
    t_const: V3,
}

fn inv(what: String) -> MocapError {
    MocapError::Invalid { what }
}

/// Rig FK with rotation-only deltas: world rotations and head positions.
fn rig_fk(
    parents: &[Option<usize>],
    rest_local: &[M3],
    heads: &[V3],
    rest_rot: &[M3],
    local: &[M3],
    root_head: V3,
) -> (Vec<M3>, Vec<V3>) {
    let n = parents.len();
    let (mut g, mut p) = (vec![IDENTITY; n], vec![[0.0; 3]; n]);
    for c in 0..n {
        match parents[c] {
            None => {
                g[c] = local[c];
                p[c] = root_head;
            }
            Some(q) => {
                g[c] = matmul(&matmul(&g[q], &rest_local[c]), &local[c]);
                let off = matvec(&transpose(&rest_rot[q]), sub(heads[c], heads[q]));
                p[c] = add(p[q], matvec(&g[q], off));
            }
        }
    }
    (g, p)
}

/// The rotation taking unit `a` to unit `b` about `a × b` (identity if parallel).
fn swing(a: V3, b: V3) -> M3 {
    let ax = cross(a, b);
    let s = norm(ax);
    if s < 1e-12 {
        return IDENTITY;
    }
    axis_angle(ax, s.atan2(dot(a, b)))
}

impl CmuRetarget {
    /// Calibrates on frame `frame` (a T-pose) of `bvh`, given in metres (e.g.
    /// `bvh.scaled(CMU_UNIT_M)`), for `identity` of `shape`.
    ///
    /// # Errors
    /// [`MocapError::Invalid`] if a joint or bone of the mapping tables is missing, the
    /// frame is out of range, or a calibration segment has zero length.
    pub fn calibrate(
        identity: &Identity,
        shape: &ShapeParams,
        bvh: &Bvh,
        frame: usize,
    ) -> Result<CmuRetarget> {
        let g = identity.generator();
        let names = g.bone_names();
        let parents = g.bone_parents().to_vec();
        let bone = |n: &str| {
            names
                .iter()
                .position(|b| b == n)
                .ok_or_else(|| inv(format!("rig has no bone `{n}`")))
        };
        let joint = |n: &str| {
            bvh.joint_index(n)
                .ok_or_else(|| inv(format!("BVH has no joint `{n}`")))
        };
        if frame >= bvh.n_frames() {
            return Err(inv(format!(
                "calibration frame {frame} ≥ {} frames",
                bvh.n_frames()
            )));
        }
        let heads = identity.bone_heads();
        let rest_rot: Vec<M3> = identity.rest_frames().iter().map(|f| f.m).collect();
        let rest_local: Vec<M3> = (0..names.len())
            .map(|c| match parents[c] {
                None => IDENTITY,
                Some(p) => matmul(&transpose(&rest_rot[p]), &rest_rot[c]),
            })
            .collect();
        let bw = bvh.world_transforms(frame);
        let bp: Vec<V3> = bw.iter().map(|w| w.t).collect();
        // 1. Frames: A = Y0 · Rx(90°).
        let rx = [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]];
        let hip = matvec(&rx, sub(bp[joint("LeftUpLeg")?], bp[joint("RightUpLeg")?]));
        let yaw = -hip[1].atan2(hip[0]);
        let (sy, cy) = yaw.sin_cos();
        let a = matmul(&[[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]], &rx);
        // 2. Calibration: swing the limb segments, parents first (table order).
        let mut local = vec![IDENTITY; names.len()];
        // The trunk: swing `spine05` so that hip centre → shoulder centre matches.
        let (sp, ul, ur, al, ar) = (
            bone("spine05")?,
            bone("upperleg01.L")?,
            bone("upperleg01.R")?,
            bone("upperarm01.L")?,
            bone("upperarm01.R")?,
        );
        let (jl, jr, jal, jar) = (
            joint("LeftUpLeg")?,
            joint("RightUpLeg")?,
            joint("LeftArm")?,
            joint("RightArm")?,
        );
        let mid = |p: &[V3], a: usize, b: usize| scale(add(p[a], p[b]), 0.5);
        let (gw, pos) = rig_fk(&parents, &rest_local, heads, &rest_rot, &local, heads[0]);
        let d = sub(mid(&pos, al, ar), mid(&pos, ul, ur));
        let t = matvec(&a, sub(mid(&bp, jal, jar), mid(&bp, jl, jr)));
        let q = swing(normalize(d), normalize(t));
        let parent_g = matmul(&gw[parents[sp].unwrap_or(0)], &rest_local[sp]);
        local[sp] = matmul(&transpose(&parent_g), &matmul(&q, &gw[sp]));
        for (rc, re, bj, bk) in CMU_CALIBRATION {
            let (c, e, j, k) = (bone(rc)?, bone(re)?, joint(bj)?, joint(bk)?);
            let (gw, pos) = rig_fk(&parents, &rest_local, heads, &rest_rot, &local, heads[0]);
            let (d, t) = (sub(pos[e], pos[c]), matvec(&a, sub(bp[k], bp[j])));
            if norm(d) < 1e-9 || norm(t) < 1e-9 {
                return Err(inv(format!("zero-length calibration segment {rc}/{bj}")));
            }
            let q = swing(normalize(d), normalize(t));
            let parent_g = match parents[c] {
                None => IDENTITY,
                Some(p) => matmul(&gw[p], &rest_local[c]),
            };
            local[c] = matmul(&transpose(&parent_g), &matmul(&q, &gw[c]));
        }
        let (calib_world, pos) = rig_fk(&parents, &rest_local, heads, &rest_rot, &local, heads[0]);
        let mut driver = vec![None; names.len()];
        for (rb, bj) in CMU_DRIVERS {
            driver[bone(rb)?] = Some(joint(bj)?);
        }
        // 4. Scale from the evaluation joints at the calibration frame.
        let mut rig_pts = Vec::new();
        let mut bvh_pts = Vec::new();
        for (bj, rb) in CMU_EVAL_JOINTS {
            rig_pts.push(pos[bone(rb)?]);
            bvh_pts.push(matvec(&a, bp[joint(bj)?]));
        }
        let s = similarity_align(&bvh_pts, &rig_pts).scale;
        let hips = joint("Hips")?;
        let lu = pos[bone("upperleg01.L")?];
        let ru = pos[bone("upperleg01.R")?];
        let rig_c = scale(add(lu, ru), 0.5);
        let bvh_c = scale(add(bp[joint("LeftUpLeg")?], bp[joint("RightUpLeg")?]), 0.5);
        let q = add(rig_c, scale(matvec(&a, sub(bp[hips], bvh_c)), s));
        let q_off = matvec(&transpose(&calib_world[0]), sub(q, heads[0]));
        let t_const = sub(q, scale(matvec(&a, bp[hips]), s));
        Ok(CmuRetarget {
            bvh_to_rig: a,
            scale: s,
            calibration_frame: frame,
            shape: shape.clone(),
            parents,
            rest_local,
            calib_local: local,
            calib_world,
            driver,
            bvh_calib: bw.iter().map(|w| w.r).collect(),
            hips,
            h0: heads[0],
            q_off,
            t_const,
        })
    }

    /// The generator parameters of BVH frame `f` (the BVH in metres, as calibrated).
    ///
    /// # Panics
    /// If `f ≥ bvh.n_frames()` or `bvh` has a different hierarchy than at calibration.
    #[track_caller]
    pub fn params(&self, bvh: &Bvh, f: usize) -> GeneratorParams {
        let bw: Vec<Rigid> = bvh.world_transforms(f);
        let a = self.bvh_to_rig;
        let n = self.parents.len();
        let mut g = vec![IDENTITY; n];
        let mut euler = Vec::with_capacity(n);
        for c in 0..n {
            let parent_g = match self.parents[c] {
                None => IDENTITY,
                Some(p) => matmul(&g[p], &self.rest_local[c]),
            };
            let e = match self.driver[c] {
                Some(j) => {
                    let db = matmul(&bw[j].r, &transpose(&self.bvh_calib[j]));
                    g[c] = matmul(
                        &matmul(&matmul(&a, &db), &transpose(&a)),
                        &self.calib_world[c],
                    );
                    matmul(&transpose(&parent_g), &g[c])
                }
                None => {
                    g[c] = matmul(&parent_g, &self.calib_local[c]);
                    self.calib_local[c]
                }
            };
            euler.push(euler_xyz_deg_of(&e));
        }
        let hips = scale(matvec(&a, bw[self.hips].t), self.scale);
        let q = add(hips, self.t_const);
        let root_head = sub(q, matvec(&g[0], self.q_off));
        GeneratorParams {
            shape: self.shape.clone(),
            pose: PoseParams {
                euler_deg: euler,
                root_rotation_z_deg: 0.0,
                root_translation: sub(root_head, self.h0),
            },
        }
    }
}

/// A similarity `x ↦ scale · R x + t`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Similarity {
    /// Uniform scale.
    pub scale: f64,
    /// Rotation (row-major).
    pub r: M3,
    /// Translation.
    pub t: V3,
}

impl Similarity {
    /// Applies the similarity.
    pub fn apply(&self, x: V3) -> V3 {
        add(scale(matvec(&self.r, x), self.scale), self.t)
    }
}

/// The least-squares similarity `argmin Σ |s R a_i + t − b_i|²` (Umeyama): `R` from the
/// cross-covariance (Kabsch), `s = Σ (b_i − b̄)·R(a_i − ā) / Σ |a_i − ā|²`.
///
/// # Panics
/// If the slices differ in length.
pub fn similarity_align(a: &[V3], b: &[V3]) -> Similarity {
    assert_eq!(a.len(), b.len(), "one target per point");
    let n = a.len().max(1) as f64;
    let ca = scale(a.iter().fold([0.0; 3], |s, &x| add(s, x)), 1.0 / n);
    let cb = scale(b.iter().fold([0.0; 3], |s, &x| add(s, x)), 1.0 / n);
    let mut m = [[0.0; 3]; 3];
    let mut den = 0.0;
    for (x, y) in a.iter().zip(b) {
        let (da, db) = (sub(*x, ca), sub(*y, cb));
        for r in 0..3 {
            for c in 0..3 {
                m[r][c] += db[r] * da[c];
            }
        }
        den += dot(da, da);
    }
    let r = nearest_rotation(&m);
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| dot(sub(*y, cb), matvec(&r, sub(*x, ca))))
        .sum();
    let s = if den > 0.0 { num / den } else { 1.0 };
    Similarity {
        scale: s,
        r,
        t: sub(cb, scale(matvec(&r, ca), s)),
    }
}

/// Joint error of a retarget, after alignment: `rig[f][k]` and `bvh[f][k]` are the mapped
/// joints' positions per frame (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct RetargetError {
    /// Mean distance over frames and joints after one similarity for the whole sequence
    /// (rig → BVH), millimetres.
    pub global_mean_mm: f64,
    /// Largest such distance, millimetres.
    pub global_max_mm: f64,
    /// Mean after a separate similarity per frame, millimetres.
    pub per_frame_mean_mm: f64,
    /// Per joint, the mean after the global similarity, millimetres.
    pub per_joint_mm: Vec<f64>,
    /// The global similarity's scale (BVH metres per rig metre).
    pub global_scale: f64,
}

/// Compares mapped joint positions, see [`RetargetError`].
///
/// # Panics
/// If the shapes differ or there are no frames.
pub fn retarget_error(rig: &[Vec<V3>], bvh: &[Vec<V3>]) -> RetargetError {
    assert!(!rig.is_empty() && rig.len() == bvh.len(), "same frames");
    let k = rig[0].len();
    let flat = |v: &[Vec<V3>]| v.iter().flatten().copied().collect::<Vec<V3>>();
    let (ra, ba) = (flat(rig), flat(bvh));
    assert_eq!(ra.len(), ba.len(), "same joints per frame");
    let sim = similarity_align(&ra, &ba);
    let d: Vec<f64> = ra
        .iter()
        .zip(&ba)
        .map(|(x, y)| norm(sub(sim.apply(*x), *y)) * 1e3)
        .collect();
    let mut per_joint = vec![0.0; k];
    for (i, e) in d.iter().enumerate() {
        per_joint[i % k] += e / rig.len() as f64;
    }
    let mut pf = 0.0;
    for (r, b) in rig.iter().zip(bvh) {
        let s = similarity_align(r, b);
        pf += r
            .iter()
            .zip(b)
            .map(|(x, y)| norm(sub(s.apply(*x), *y)))
            .sum::<f64>()
            * 1e3;
    }
    RetargetError {
        global_mean_mm: d.iter().sum::<f64>() / d.len() as f64,
        global_max_mm: d.iter().copied().fold(0.0, f64::max),
        per_frame_mean_mm: pf / ra.len() as f64,
        per_joint_mm: per_joint,
        global_scale: sim.scale,
    }
}

pub use panoman_fit::shape_calibration::ShapeKnob;

/// The shape values [`fit_cmu_shape`] adjusts: the phenotype's proportions and the nine
/// length controls of [`LENGTH_KNOBS`] (limb and trunk lengths, shoulder and hip width, foot
/// size).
pub const CMU_SHAPE_KNOBS: [ShapeKnob; 10] = {
    // The phenotype's proportions, then panoman_fit's nine length controls.
    let mut k = [ShapeKnob::Phenotype("proportions"); 10];
    let mut i = 0;
    while i < LENGTH_KNOBS.len() {
        k[i + 1] = LENGTH_KNOBS[i];
        i += 1;
    }
    k
};

/// The result of [`fit_cmu_shape`].
#[derive(Clone, Debug)]
pub struct ShapeFit {
    /// The fitted shape (the base shape with [`CMU_SHAPE_KNOBS`] adjusted).
    pub shape: ShapeParams,
    /// Mean joint error over the fitting frames before the fit (one similarity), mm.
    pub before_mm: f64,
    /// The same after the fit, mm.
    pub after_mm: f64,
    /// Levenberg–Marquardt iterations taken.
    pub iterations: usize,
}

/// Positions of [`CMU_EVAL_JOINTS`] per frame: `(rig, bvh)`, each `[frames][14]`, metres.
pub type JointSets = (Vec<Vec<V3>>, Vec<Vec<V3>>);

/// Rig and BVH positions of [`CMU_EVAL_JOINTS`] on `frames`, for `shape` calibrated on
/// frame `calib`.
///
/// # Errors
/// Shape errors of the generator, or [`CmuRetarget::calibrate`]'s.
pub fn cmu_joint_sets(
    generator: &panoman_human::generator::Generator,
    shape: &ShapeParams,
    bvh: &Bvh,
    calib: usize,
    frames: &[usize],
) -> Result<JointSets> {
    let id = generator
        .identity(shape)
        .map_err(|e| inv(format!("identity: {e}")))?;
    let rt = CmuRetarget::calibrate(&id, shape, bvh, calib)?;
    let names = generator.bone_names();
    let mut rig_idx = Vec::new();
    let mut bvh_idx = Vec::new();
    for (j, b) in CMU_EVAL_JOINTS {
        rig_idx.push(
            names
                .iter()
                .position(|n| n == b)
                .ok_or_else(|| inv(format!("no bone `{b}`")))?,
        );
        bvh_idx.push(
            bvh.joint_index(j)
                .ok_or_else(|| inv(format!("no joint `{j}`")))?,
        );
    }
    let (mut rig, mut truth) = (Vec::new(), Vec::new());
    for &f in frames {
        let posed = id.pose(&rt.params(bvh, f).pose);
        rig.push(rig_idx.iter().map(|&b| posed.bone_heads[b]).collect());
        let bp = bvh.joint_positions(f);
        truth.push(bvh_idx.iter().map(|&j| bp[j]).collect());
    }
    Ok((rig, truth))
}

/// Residuals: aligned rig joints − BVH joints (metres) and the prior `√λ (v − v₀)`.
fn shape_residuals(
    generator: &panoman_human::generator::Generator,
    base: &ShapeParams,
    v: &[f64],
    bvh: &Bvh,
    frames: &[usize],
) -> Result<Vec<f64>> {
    let shape = with_knobs(base, &CMU_SHAPE_KNOBS, v);
    let (rig, truth) = cmu_joint_sets(generator, &shape, bvh, 0, frames)?;
    let (ra, ba): (Vec<V3>, Vec<V3>) = (rig.concat(), truth.concat());
    let sim = similarity_align(&ra, &ba);
    let mut r: Vec<f64> = ra
        .iter()
        .zip(&ba)
        .flat_map(|(x, y)| sub(sim.apply(*x), *y))
        .collect();
    // A weak pull to the base shape (1 unit of a knob costs as much as 5 mm on one joint).
    let w = 0.005;
    r.extend(
        CMU_SHAPE_KNOBS
            .iter()
            .zip(v)
            .map(|(k, x)| w * (x - k.get(base))),
    );
    Ok(r)
}

/// Fits [`CMU_SHAPE_KNOBS`] so that the retargeted rig's joints match the BVH's on
/// `frames` (after one similarity), by Levenberg–Marquardt with forward-difference
/// Jacobians and values clamped to their ranges; calibration on frame 0.
///
/// # Errors
/// As [`cmu_joint_sets`].
pub fn fit_cmu_shape(
    generator: &panoman_human::generator::Generator,
    base: &ShapeParams,
    bvh: &Bvh,
    frames: &[usize],
    max_iterations: usize,
) -> Result<ShapeFit> {
    let knobs = CMU_SHAPE_KNOBS;
    let v: Vec<f64> = knobs.iter().map(|k| k.get(base)).collect();
    let res = |v: &[f64]| shape_residuals(generator, base, v, bvh, frames);
    let n_pts = (frames.len() * CMU_EVAL_JOINTS.len()) as f64;
    let mean_mm = |r: &[f64]| {
        let m = frames.len() * CMU_EVAL_JOINTS.len();
        r[..3 * m]
            .chunks(3)
            .map(|c| norm([c[0], c[1], c[2]]))
            .sum::<f64>()
            / n_pts
            * 1e3
    };
    let before_mm = mean_mm(&res(&v)?);
    let fit = fit_knobs(&knobs, &v, max_iterations, res)?;
    Ok(ShapeFit {
        shape: with_knobs(base, &knobs, &fit.values),
        before_mm,
        after_mm: mean_mm(&fit.residuals),
        iterations: fit.iterations,
    })
}
