//! Skinned GLB export for the LBS baseline: an armature of the rig's bones, the rest mesh bound
//! to it with at most four influences per vertex, and the pose sequence as per-bone
//! rotation/translation animation, so that the result retargets in DCC tools.
//!
//! # Layout
//! * Axes as in [`crate::glb`]: a point `x` of panoman is `C x` in glTF with
//!   `C = [[1,0,0],[0,0,1],[0,−1,0]]` (`(x, y, z) ↦ (x, z, −y)`).
//! * **Joints**: one node per bone (`Bone::name`), parented like the rig (parents precede
//!   children). The root bone's local transform is `C · W₀`, every other bone's is
//!   `W_parent⁻¹ · W_c` (rotation + translation; `C` cancels), with `W_c` the bone's world
//!   frame (rest frame `P_c` = rotation of the bone + its head). The root joint is a scene
//!   root, so is the node `body` carrying the mesh and the skin (skinned meshes must not be
//!   transformed).
//! * **Skin**: `inverseBindMatrices` = `(C P_c)⁻¹` (float MAT4, column-major), `skeleton` =
//!   the root joint. `JOINTS_0` (unsigned short VEC4) and `WEIGHTS_0` (float VEC4): the four
//!   largest weights of each vertex, renormalised to sum 1 (in `f32`); unused slots are joint
//!   0 with weight 0. Vertices with more than four influences therefore deform slightly
//!   differently from the rig (the rig's own LBS uses all of them).
//! * **Animation** `pose`: per bone a `rotation` channel (unit quaternions, sign-continuous
//!   over time) and a `translation` channel, input the frame times `i / fps`, `LINEAR`.
//!   Frame 0 is the first pose, not the rest pose; the rest pose is the joints' node
//!   transforms (the bind pose).

use serde_json::{Value, json};

use panoman_human::rig::Affine;

use crate::error::{InterchangeError, Result};
use crate::glb::{
    ARRAY_BUFFER, Builder, FLOAT, UNSIGNED_SHORT, glb_container, to_gltf, vertex_normals,
};

type V3 = [f64; 3];
type M3 = [[f64; 3]; 3];

/// The rig of a skinned export.
#[derive(Clone, Debug)]
pub struct Armature {
    /// Bone names (node names), in rig order.
    pub names: Vec<String>,
    /// Parent of each bone; parents precede children; bone 0 is the only root.
    pub parents: Vec<Option<usize>>,
    /// Rest world frame `P_c` of each bone (rotation + head, panoman axes, metres).
    pub rest: Vec<Affine>,
}

/// The mesh of a skinned export.
#[derive(Clone, Debug)]
pub struct SkinnedMesh {
    /// Rest vertex positions (bind pose, panoman axes, metres).
    pub rest_positions: Vec<V3>,
    /// Triangles.
    pub faces: Vec<[u32; 3]>,
    /// Per vertex its `(bone, weight)` influences (any number, weights ≥ 0, not all 0).
    pub weights: Vec<Vec<(usize, f64)>>,
}

/// The skinned GLB: the mesh bound to the armature, animated by `poses[f][c]`, the world frame
/// `W_c` of bone `c` at frame `f` (rigid), at `fps` frames per second (see the module docs).
///
/// # Errors
/// [`InterchangeError::Invalid`] for inconsistent sizes, a second root, a parent after its
/// child, non-rigid or non-finite frames, bad weights, no poses or a bad frame rate.
pub fn skinned_glb(
    arm: &Armature,
    mesh: &SkinnedMesh,
    poses: &[Vec<Affine>],
    fps: f64,
) -> Result<Vec<u8>> {
    check(arm, mesh, poses, fps)?;
    let n_bones = arm.names.len();
    let n = mesh.rest_positions.len();
    let mut b = Builder::default();
    let pos: Vec<[f32; 3]> = mesh.rest_positions.iter().map(|&p| to_gltf(p)).collect();
    let nor = vertex_normals(&mesh.rest_positions, &mesh.faces);
    let p_acc = b.vec3(&pos, Some(ARRAY_BUFFER), true);
    let n_acc = b.vec3(&nor, Some(ARRAY_BUFFER), false);
    let (joints, weights) = top4(&mesh.weights);
    let jb: Vec<u8> = joints
        .iter()
        .flatten()
        .flat_map(|j| j.to_le_bytes())
        .collect();
    let wb: Vec<u8> = weights
        .iter()
        .flatten()
        .flat_map(|w| w.to_le_bytes())
        .collect();
    let j_acc = b.raw(&jb, UNSIGNED_SHORT, n, "VEC4", Some(ARRAY_BUFFER));
    let w_acc = b.raw(&wb, FLOAT, n, "VEC4", Some(ARRAY_BUFFER));
    let i_acc = b.indices(&mesh.faces);

    // Joint nodes: index 1 + c (node 0 is the mesh).
    let c_mat: M3 = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]];
    let conv = Affine::new(c_mat, [0.0; 3]);
    let local_of = |world: &[Affine], c: usize| -> Affine {
        match arm.parents[c] {
            None => conv.compose(&world[c]),
            Some(p) => world[p].inverse_rigid().compose(&world[c]),
        }
    };
    let mut nodes = vec![json!({"name": "body", "mesh": 0, "skin": 0})];
    for c in 0..n_bones {
        let l = local_of(&arm.rest, c);
        let children: Vec<usize> = (0..n_bones)
            .filter(|&k| arm.parents[k] == Some(c))
            .map(|k| k + 1)
            .collect();
        let mut node = json!({
            "name": arm.names[c],
            "translation": l.t.map(|x| f64::from(x as f32)),
            "rotation": quat(&l.m).map(f64::from),
        });
        if !children.is_empty() {
            node["children"] = json!(children);
        }
        nodes.push(node);
    }
    let ibm: Vec<u8> = arm
        .rest
        .iter()
        .flat_map(|p| mat4_col_major(&conv.compose(p).inverse_rigid()))
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let ibm_acc = b.raw(&ibm, FLOAT, n_bones, "MAT4", None);

    let n_frames = poses.len();
    let times: Vec<f32> = (0..n_frames).map(|i| (i as f64 / fps) as f32).collect();
    let t_acc = b.scalars(&times, true);
    let mut samplers = Vec::new();
    let mut channels = Vec::new();
    for c in 0..n_bones {
        let locals: Vec<Affine> = poses.iter().map(|w| local_of(w, c)).collect();
        let mut q: Vec<[f32; 4]> = Vec::with_capacity(n_frames);
        for l in &locals {
            let mut r = quat(&l.m);
            if let Some(prev) = q.last() {
                let dot: f32 = (0..4).map(|k| prev[k] * r[k]).sum();
                if dot < 0.0 {
                    r = r.map(|x| -x);
                }
            }
            q.push(r);
        }
        let qb: Vec<u8> = q.iter().flatten().flat_map(|x| x.to_le_bytes()).collect();
        let q_acc = b.raw(&qb, FLOAT, n_frames, "VEC4", None);
        let t: Vec<[f32; 3]> = locals.iter().map(|l| l.t.map(|x| x as f32)).collect();
        let tr_acc = b.vec3(&t, None, false);
        for (acc, path) in [(q_acc, "rotation"), (tr_acc, "translation")] {
            samplers.push(json!({"input": t_acc, "output": acc, "interpolation": "LINEAR"}));
            channels.push(
                json!({"sampler": samplers.len() - 1, "target": {"node": c + 1, "path": path}}),
            );
        }
    }
    let doc: Value = json!({
        "asset": {"version": "2.0", "generator": concat!("panoman-interchange ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"name": "panoman", "nodes": [0, 1]}],
        "nodes": nodes,
        "meshes": [{"name": "body", "primitives": [{
            "attributes": {"POSITION": p_acc, "NORMAL": n_acc, "JOINTS_0": j_acc, "WEIGHTS_0": w_acc},
            "indices": i_acc, "material": 0, "mode": 4}]}],
        "materials": [{"name": "skin", "pbrMetallicRoughness": {
            "baseColorFactor": [0.80, 0.62, 0.52, 1.0], "metallicFactor": 0.0, "roughnessFactor": 0.7}}],
        "skins": [{"name": "rig", "inverseBindMatrices": ibm_acc, "skeleton": 1,
                   "joints": (1..=n_bones).collect::<Vec<_>>()}],
        "animations": [{"name": "pose", "channels": channels, "samplers": samplers}],
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.bin.len()}],
    });
    glb_container(&doc, &b.bin)
}

/// Rejects inputs that would give an invalid file.
fn check(arm: &Armature, mesh: &SkinnedMesh, poses: &[Vec<Affine>], fps: f64) -> Result<()> {
    let bad = |w: String| Err(InterchangeError::Invalid(w));
    let nb = arm.names.len();
    if nb == 0 || nb > usize::from(u16::MAX) || arm.parents.len() != nb || arm.rest.len() != nb {
        return bad(format!(
            "armature: {nb} names, {} parents, {} rest frames (1 to 65,535 bones, one of each per bone)",
            arm.parents.len(),
            arm.rest.len()
        ));
    }
    for (c, p) in arm.parents.iter().enumerate() {
        match (c, p) {
            (0, None) => {}
            (0, Some(_)) => return bad("armature: bone 0 must be the root".into()),
            (_, None) => {
                return bad(format!(
                    "armature: bone {c} `{}` is a second root",
                    arm.names[c]
                ));
            }
            (_, Some(p)) if *p >= c => {
                return bad(format!(
                    "armature: bone {c}'s parent {p} does not precede it"
                ));
            }
            _ => {}
        }
    }
    let n = mesh.rest_positions.len();
    if n == 0 || mesh.faces.is_empty() || mesh.weights.len() != n {
        return bad(format!(
            "skinned mesh: {n} vertices, {} faces, {} weight rows",
            mesh.faces.len(),
            mesh.weights.len()
        ));
    }
    if mesh.faces.iter().flatten().any(|&v| v as usize >= n) {
        return bad("skinned mesh: a face indexes past the vertices".into());
    }
    if mesh.rest_positions.iter().flatten().any(|x| !x.is_finite()) {
        return bad("skinned mesh: non-finite rest position".into());
    }
    for (v, row) in mesh.weights.iter().enumerate() {
        if row
            .iter()
            .any(|&(j, w)| j >= nb || !w.is_finite() || w < 0.0)
            || !row.iter().any(|&(_, w)| w > 0.0)
        {
            return bad(format!(
                "skinned mesh: vertex {v} has invalid weights {row:?}"
            ));
        }
    }
    if poses.is_empty() {
        return bad("no poses to export".into());
    }
    if !(fps.is_finite() && fps > 0.0) {
        return bad(format!("frame rate must be > 0, got {fps}"));
    }
    for (f, w) in std::iter::once(&arm.rest).chain(poses).enumerate() {
        if w.len() != nb {
            return bad(format!(
                "pose {}: {} bone frames for {nb} bones",
                f as i64 - 1,
                w.len()
            ));
        }
        for (c, a) in w.iter().enumerate() {
            if !is_rigid(a) {
                return bad(format!(
                    "pose {}: bone `{}` has a non-rigid or non-finite frame",
                    f as i64 - 1,
                    arm.names[c]
                ));
            }
        }
    }
    Ok(())
}

fn is_rigid(a: &Affine) -> bool {
    let m = &a.m;
    if m.iter().flatten().chain(&a.t).any(|x| !x.is_finite()) {
        return false;
    }
    for i in 0..3 {
        for j in 0..3 {
            let d: f64 = (0..3).map(|k| m[k][i] * m[k][j]).sum();
            if (d - if i == j { 1.0 } else { 0.0 }).abs() > 1e-6 {
                return false;
            }
        }
    }
    let det = m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
        - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
        + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0]);
    det > 0.0
}

/// The four largest influences per vertex (repeated bones summed first), renormalised so
/// that the `f32` weights sum to 1 as closely as `f32` allows; unused slots are (0, 0).
fn top4(rows: &[Vec<(usize, f64)>]) -> (Vec<[u16; 4]>, Vec<[f32; 4]>) {
    let mut joints = Vec::with_capacity(rows.len());
    let mut weights = Vec::with_capacity(rows.len());
    for row in rows {
        let mut merged: Vec<(usize, f64)> = Vec::new();
        for &(j, w) in row {
            match merged.iter_mut().find(|(k, _)| *k == j) {
                Some(e) => e.1 += w,
                None => merged.push((j, w)),
            }
        }
        merged.retain(|&(_, w)| w > 0.0);
        merged.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        merged.truncate(4);
        let sum: f64 = merged.iter().map(|e| e.1).sum();
        let mut j = [0u16; 4];
        let mut w = [0f32; 4];
        for (k, &(b, x)) in merged.iter().enumerate() {
            j[k] = b as u16;
            w[k] = (x / sum) as f32;
        }
        // Put the f32 rounding residue on the largest weight.
        let s: f32 = w.iter().sum();
        w[0] += 1.0 - s;
        joints.push(j);
        weights.push(w);
    }
    (joints, weights)
}

/// Unit quaternion `[x, y, z, w]` (glTF's order) of a rotation matrix, as `f32`.
fn quat(m: &M3) -> [f32; 4] {
    let [w, x, y, z] = panoman_mesh::rotation::quaternion_of(m);
    [x, y, z, w].map(|c| c as f32)
}

/// A rigid transform as a column-major 4×4 `f32` matrix.
fn mat4_col_major(a: &Affine) -> [f32; 16] {
    let mut out = [0f32; 16];
    for col in 0..3 {
        for row in 0..3 {
            out[col * 4 + row] = a.m[row][col] as f32;
        }
    }
    for row in 0..3 {
        out[12 + row] = a.t[row] as f32;
    }
    out[15] = 1.0;
    out
}

/// The armature and skinned mesh of a generator identity on the generator's output topology
/// (13,718 vertices, Anny's quads split into triangles), for [`skinned_glb`].
///
/// # Errors
/// [`InterchangeError::Invalid`] if the generator's tables are inconsistent.
pub fn from_identity(
    identity: &panoman_human::generator::Identity<'_>,
) -> Result<(Armature, SkinnedMesh)> {
    let g = identity.generator();
    let arm = Armature {
        names: g.bone_names().to_vec(),
        parents: g.bone_parents().to_vec(),
        rest: identity.rest_frames().to_vec(),
    };
    let mut faces = Vec::new();
    for q in g.output_quads_base() {
        let idx: Option<Vec<u32>> = q
            .iter()
            .map(|&b| g.output_index_of_base(b).map(|i| i as u32))
            .collect();
        let idx = idx.ok_or_else(|| {
            InterchangeError::Invalid("an output face uses a non-output vertex".into())
        })?;
        for k in 1..idx.len().saturating_sub(1) {
            faces.push([idx[0], idx[k], idx[k + 1]]);
        }
    }
    let sw = g.skin_weights();
    let weights: Vec<Vec<(usize, f64)>> = (0..sw.len())
        .map(|v| {
            let (a, b) = (sw.offsets[v] as usize, sw.offsets[v + 1] as usize);
            (a..b)
                .map(|k| (usize::from(sw.bones[k]), sw.weights[k]))
                .collect()
        })
        .collect();
    let mesh = SkinnedMesh {
        rest_positions: identity.rest_vertices().to_vec(),
        faces,
        weights,
    };
    Ok((arm, mesh))
}

/// The `*.params.json` files of a folder (what `panoman track --baseline lbs` writes, one per
/// frame) in byte order of their names.
///
/// # Errors
/// The folder cannot be listed or holds no parameter files.
pub fn params_files(dir: &std::path::Path) -> Result<Vec<std::path::PathBuf>> {
    let entries = std::fs::read_dir(dir).map_err(|e| InterchangeError::io(dir, e))?;
    let mut files = Vec::new();
    for e in entries {
        let p = e.map_err(|e| InterchangeError::io(dir, e))?.path();
        let name = p
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        if name.ends_with(".params.json") && !name.starts_with('.') && p.is_file() {
            files.push(p);
        }
    }
    files.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    if files.is_empty() {
        return Err(InterchangeError::format(
            dir,
            "no *.params.json frames in this folder",
        ));
    }
    Ok(files)
}

/// A skinned GLB of a sequence of generator parameters (e.g. the LBS baseline's per-frame
/// fits): the armature and mesh of the first frame's identity, each frame's pose applied to
/// it at `fps`. Later frames' shapes are not used (a skinned armature has one identity);
/// the second value counts the frames whose shape differs from the first.
///
/// # Errors
/// No frames, a pose that does not fit the rig, or the errors of [`skinned_glb`].
pub fn lbs_sequence_glb(
    generator: &panoman_human::generator::Generator,
    frames: &[panoman_human::params::GeneratorParams],
    fps: f64,
) -> Result<(Vec<u8>, usize)> {
    let first = frames
        .first()
        .ok_or_else(|| InterchangeError::Invalid("no frames to export".into()))?;
    let id = generator.identity(&first.shape)?;
    let (arm, mesh) = from_identity(&id)?;
    let mut worlds = Vec::with_capacity(frames.len());
    for (f, p) in frames.iter().enumerate() {
        p.pose
            .validate(generator.bone_names())
            .map_err(|w| InterchangeError::Invalid(format!("frame {f}: {w}")))?;
        worlds.push(id.pose(&p.pose).world);
    }
    let differing = frames.iter().filter(|p| p.shape != first.shape).count();
    Ok((skinned_glb(&arm, &mesh, &worlds, fps)?, differing))
}
