//! glTF 2.0 binary (`.glb`) export of meshes, mesh sequences and keypoint/marker tracks.
//!
//! # Layout of the files written here
//! * **Axes and units.** glTF is Y-up, metres, with the asset's front facing +Z and its left
//!   at +X. panoman is Z-up, the character faces −Y, its left is +X; every point is written as
//!   `(x, y, z) ↦ (x, z, −y)` (a rotation of −90° about X), so the character stands up and
//!   faces the viewer of any glTF tool. No root transform is needed.
//! * **Mesh.** One node `body` with one mesh of one indexed triangle primitive: `POSITION`
//!   (float VEC3, with the `min`/`max` the specification requires), `NORMAL` (area-weighted
//!   vertex normals, unit length; a vertex in no triangle gets +Y), optional `COLOR_0` (float
//!   VEC3, e.g. a per-vertex error colouring), `indices` (unsigned int). One material
//!   (`skin`, metallic 0, roughness 0.7).
//! * **Sequences** are **morph targets**: the first frame is the base mesh, frame `k ≥ 1` is
//!   morph target `k − 1` holding the position and normal deltas to the base (names in
//!   `mesh.extras.targetNames`, `frame_00001`, …). One animation `sequence` has a single
//!   `weights` channel whose sampler's input is the frame times `i / fps` and whose output at
//!   frame `i` is the one-hot weight vector of target `i − 1` (all zero at frame 0). Morph
//!   targets are chosen over the alternatives because they are the only core-glTF way to move
//!   individual vertices: a node-per-frame "flip book" (scale or visibility animation) would
//!   store the same data plus an index buffer and normals per frame, and shows gaps or overlap
//!   under interpolation, while a weights channel is played, scrubbed and retimed by every
//!   glTF player (three.js, Blender, Babylon.js) and with `LINEAR` interpolation it blends
//!   consecutive frames linearly, i.e. it interpolates the vertices (exact at the frame
//!   times). `STEP` gives the frames unblended ([`Interpolation`]).
//! * **Markers** (keypoints): a node `markers` whose children `marker:<name>` carry a shared
//!   small octahedron mesh (material `marker`) at the keypoint's position; in a sequence each
//!   one has a `translation` channel in the same animation (a frame where the keypoint is
//!   missing holds the nearest earlier frame's position, or the first later one). Keypoints
//!   missing in every frame get no node.
//!
//! Everything is written into one binary buffer (the GLB `BIN` chunk), each buffer view
//! 4-byte aligned; vertex attributes and indices have their `target`s, animation data none.

use panoman_mesh::TriMesh;
use serde_json::{Value, json};

use crate::error::{InterchangeError, Result};

type V3 = [f64; 3];

/// How a sequence's animation interpolates between frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Interpolation {
    /// Linear blend of consecutive frames (vertex positions interpolated); exact at frame times.
    #[default]
    Linear,
    /// Each frame held until the next one.
    Step,
}

impl Interpolation {
    fn gltf_name(self) -> &'static str {
        match self {
            Interpolation::Linear => "LINEAR",
            Interpolation::Step => "STEP",
        }
    }
}

/// Named points over the frames of an export (keypoints, markers), in metres, panoman axes.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Markers {
    /// One name per marker (node names become `marker:<name>`).
    pub names: Vec<String>,
    /// `frames[f][k]`: marker `k` at frame `f`, `None` where it is missing. One row per mesh
    /// frame; each row has `names.len()` entries.
    pub frames: Vec<Vec<Option<V3>>>,
}

impl Markers {
    /// Markers named by the TC-133 keypoints given in any of `frames` (one keypoints file per
    /// mesh frame), in TC-133 order.
    pub fn from_keypoints(frames: &[panoman_human::keypoints::KeypointsFile]) -> Markers {
        let names = panoman_human::keypoints::keypoint_names();
        let used: std::collections::BTreeSet<usize> = frames
            .iter()
            .flat_map(|k| k.points.keys().copied())
            .collect();
        Markers {
            names: used.iter().map(|&i| names[i].clone()).collect(),
            frames: frames
                .iter()
                .map(|k| used.iter().map(|i| k.points.get(i).copied()).collect())
                .collect(),
        }
    }
}

/// Options of [`export_glb`].
#[derive(Clone, Debug)]
pub struct GlbOptions {
    /// Frame rate of a sequence (frames per second, > 0). Default 30.
    pub fps: f64,
    /// Interpolation of the sequence's animation. Default [`Interpolation::Linear`].
    pub interpolation: Interpolation,
    /// Optional per-vertex colour (linear RGB in [0, 1]) written as `COLOR_0`.
    pub colors: Option<Vec<[f32; 3]>>,
    /// Size of the marker octahedra, centre to vertex (metres). Default 0.01.
    pub marker_radius_m: f64,
    /// Name of the mesh and its node. Default `body`.
    pub name: String,
}

impl Default for GlbOptions {
    fn default() -> Self {
        GlbOptions {
            fps: 30.0,
            interpolation: Interpolation::Linear,
            colors: None,
            marker_radius_m: 0.01,
            name: "body".into(),
        }
    }
}

/// The GLB file of a single mesh (see the module documentation for the layout).
///
/// # Errors
/// [`InterchangeError::Invalid`] for an empty or invalid mesh (indices out of range,
/// non-finite coordinates) or invalid options.
pub fn mesh_glb(
    mesh: &TriMesh,
    markers: Option<&Markers>,
    options: &GlbOptions,
) -> Result<Vec<u8>> {
    export_glb(
        &mesh.faces,
        std::slice::from_ref(&mesh.positions),
        markers,
        options,
    )
}

/// The GLB file of a mesh sequence sharing one face list: one frame → a static mesh, several
/// → morph targets animated at `options.fps` (see the module documentation for the layout).
///
/// # Errors
/// [`InterchangeError::Invalid`] when there are no frames, frames differ in vertex count,
/// faces index past the vertices, a coordinate is not finite, the marker table does not
/// match the frames, or the options are out of range.
pub fn export_glb(
    faces: &[[u32; 3]],
    frames: &[Vec<V3>],
    markers: Option<&Markers>,
    options: &GlbOptions,
) -> Result<Vec<u8>> {
    check_input(faces, frames, markers, options)?;
    let n_frames = frames.len();
    let mut b = Builder::default();
    let base: Vec<[f32; 3]> = frames[0].iter().map(|&p| to_gltf(p)).collect();
    let base_normals = vertex_normals(&frames[0], faces);
    let mut attributes = serde_json::Map::new();
    attributes.insert(
        "POSITION".into(),
        b.vec3(&base, Some(ARRAY_BUFFER), true).into(),
    );
    attributes.insert(
        "NORMAL".into(),
        b.vec3(&base_normals, Some(ARRAY_BUFFER), false).into(),
    );
    if let Some(c) = &options.colors {
        attributes.insert(
            "COLOR_0".into(),
            b.vec3(c, Some(ARRAY_BUFFER), false).into(),
        );
    }
    let indices = b.indices(faces);
    let mut primitive = json!({
        "attributes": Value::Object(attributes),
        "indices": indices,
        "material": 0,
        "mode": 4,
    });
    let mut mesh = json!({"name": options.name, "primitives": []});
    let n_targets = n_frames - 1;
    if n_targets > 0 {
        let mut targets = Vec::with_capacity(n_targets);
        let mut names = Vec::with_capacity(n_targets);
        for (k, frame) in frames.iter().enumerate().skip(1) {
            let dp: Vec<[f32; 3]> = frame
                .iter()
                .zip(&frames[0])
                .map(|(&p, &q)| to_gltf([p[0] - q[0], p[1] - q[1], p[2] - q[2]]))
                .collect();
            let normals = vertex_normals(frame, faces);
            let dn: Vec<[f32; 3]> = normals
                .iter()
                .zip(&base_normals)
                .map(|(n, m)| [n[0] - m[0], n[1] - m[1], n[2] - m[2]])
                .collect();
            let pos = b.vec3(&dp, Some(ARRAY_BUFFER), true);
            let nor = b.vec3(&dn, Some(ARRAY_BUFFER), false);
            targets.push(json!({"POSITION": pos, "NORMAL": nor}));
            names.push(format!("frame_{k:05}"));
        }
        primitive["targets"] = Value::Array(targets);
        mesh["weights"] = Value::Array(vec![json!(0.0); n_targets]);
        mesh["extras"] = json!({ "targetNames": names });
    }
    mesh["primitives"] = Value::Array(vec![primitive]);
    let mut meshes = vec![mesh];
    let mut nodes = vec![json!({"name": options.name, "mesh": 0})];
    let mut materials = vec![json!({
        "name": "skin",
        "pbrMetallicRoughness": {
            "baseColorFactor": [0.80, 0.62, 0.52, 1.0],
            "metallicFactor": 0.0,
            "roughnessFactor": 0.7
        }
    })];
    let mut scene_nodes = vec![0usize];
    let mut channels = Vec::new();
    let mut samplers = Vec::new();
    let times = if n_frames > 1 {
        let t: Vec<f32> = (0..n_frames)
            .map(|i| (i as f64 / options.fps) as f32)
            .collect();
        Some(b.scalars(&t, true))
    } else {
        None
    };
    if let Some(times) = times {
        let mut w = vec![0f32; n_frames * n_targets];
        for i in 1..n_frames {
            w[i * n_targets + (i - 1)] = 1.0;
        }
        let out = b.scalars(&w, false);
        samplers.push(json!({"input": times, "output": out,
                             "interpolation": options.interpolation.gltf_name()}));
        channels.push(json!({"sampler": 0, "target": {"node": 0, "path": "weights"}}));
    }
    if let Some(m) = markers {
        let tracks = marker_tracks(m);
        if !tracks.is_empty() {
            let marker_mesh = marker_mesh(&mut b, options.marker_radius_m);
            meshes.push(marker_mesh);
            materials.push(json!({
                "name": "marker",
                "pbrMetallicRoughness": {
                    "baseColorFactor": [0.9, 0.1, 0.1, 1.0],
                    "metallicFactor": 0.0,
                    "roughnessFactor": 0.5
                }
            }));
            let parent = nodes.len();
            nodes.push(json!({"name": "markers", "children": []}));
            scene_nodes.push(parent);
            let mut children = Vec::new();
            for (k, track) in tracks {
                let node = nodes.len();
                children.push(node);
                let first = to_gltf(track[0]);
                nodes.push(json!({
                    "name": format!("marker:{}", m.names[k]),
                    "mesh": meshes.len() - 1,
                    "translation": first,
                }));
                if let Some(times) = times {
                    let pts: Vec<[f32; 3]> = track.iter().map(|&p| to_gltf(p)).collect();
                    let out = b.vec3(&pts, None, false);
                    samplers.push(json!({"input": times, "output": out,
                                         "interpolation": options.interpolation.gltf_name()}));
                    channels.push(json!({"sampler": samplers.len() - 1,
                                         "target": {"node": node, "path": "translation"}}));
                }
            }
            nodes[parent]["children"] = json!(children);
        }
    }
    let mut doc = json!({
        "asset": {"version": "2.0", "generator": concat!("panoman-interchange ", env!("CARGO_PKG_VERSION"))},
        "scene": 0,
        "scenes": [{"name": "panoman", "nodes": scene_nodes}],
        "nodes": nodes,
        "meshes": meshes,
        "materials": materials,
        "accessors": b.accessors,
        "bufferViews": b.views,
        "buffers": [{"byteLength": b.bin.len()}],
    });
    if !channels.is_empty() {
        doc["animations"] =
            json!([{"name": "sequence", "channels": channels, "samplers": samplers}]);
    }
    glb_container(&doc, &b.bin)
}

/// Rejects inputs that would give an invalid file.
fn check_input(
    faces: &[[u32; 3]],
    frames: &[Vec<V3>],
    markers: Option<&Markers>,
    options: &GlbOptions,
) -> Result<()> {
    let invalid = |w: String| Err(InterchangeError::Invalid(w));
    let Some(first) = frames.first() else {
        return invalid("no frames to export".into());
    };
    let n = first.len();
    if n == 0 || faces.is_empty() {
        return invalid("the mesh has no vertices or no faces".into());
    }
    if n > u32::MAX as usize {
        return invalid(format!("too many vertices: {n}"));
    }
    for (k, f) in frames.iter().enumerate() {
        if f.len() != n {
            return invalid(format!(
                "frame {k} has {} vertices, frame 0 has {n}",
                f.len()
            ));
        }
        if let Some((v, p)) = f
            .iter()
            .enumerate()
            .find(|(_, p)| p.iter().any(|c| !c.is_finite()))
        {
            return invalid(format!(
                "frame {k}, vertex {v}: non-finite coordinate {p:?}"
            ));
        }
    }
    if let Some((i, f)) = faces
        .iter()
        .enumerate()
        .find(|(_, f)| f.iter().any(|&v| v as usize >= n))
    {
        return invalid(format!("face {i} {f:?} indexes past the {n} vertices"));
    }
    if !(options.fps.is_finite() && options.fps > 0.0) {
        return invalid(format!("frame rate must be > 0, got {}", options.fps));
    }
    if !(options.marker_radius_m.is_finite() && options.marker_radius_m > 0.0) {
        return invalid(format!(
            "marker radius must be > 0, got {}",
            options.marker_radius_m
        ));
    }
    if let Some(c) = &options.colors {
        if c.len() != n {
            return invalid(format!("{} vertex colours for {n} vertices", c.len()));
        }
        if c.iter().flatten().any(|x| !(0.0..=1.0).contains(x)) {
            return invalid("vertex colours must lie in [0, 1]".into());
        }
    }
    if let Some(m) = markers {
        if m.frames.len() != frames.len() {
            return invalid(format!(
                "{} marker frames for {} mesh frames",
                m.frames.len(),
                frames.len()
            ));
        }
        for (f, row) in m.frames.iter().enumerate() {
            if row.len() != m.names.len() {
                return invalid(format!(
                    "marker frame {f} has {} entries for {} names",
                    row.len(),
                    m.names.len()
                ));
            }
            if row.iter().flatten().flatten().any(|c| !c.is_finite()) {
                return invalid(format!("marker frame {f}: non-finite coordinate"));
            }
        }
    }
    Ok(())
}

/// Per marker present in some frame: its position in every frame (gaps filled with the nearest
/// earlier frame's position, leading gaps with the first present one).
fn marker_tracks(m: &Markers) -> Vec<(usize, Vec<V3>)> {
    let mut out = Vec::new();
    for k in 0..m.names.len() {
        let Some(first) = m.frames.iter().find_map(|row| row[k]) else {
            continue;
        };
        let mut last = first;
        let track = m
            .frames
            .iter()
            .map(|row| {
                if let Some(p) = row[k] {
                    last = p;
                }
                last
            })
            .collect();
        out.push((k, track));
    }
    out
}

/// The shared marker mesh: an octahedron of the given radius with unit vertex normals.
fn marker_mesh(b: &mut Builder, r: f64) -> Value {
    let dirs: [[f32; 3]; 6] = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
    ];
    let pos: Vec<[f32; 3]> = dirs
        .iter()
        .map(|d| d.map(|c| (c as f64 * r) as f32))
        .collect();
    // Counter-clockwise seen from outside (outward normals).
    let faces: [[u32; 3]; 8] = [
        [0, 2, 4],
        [2, 1, 4],
        [1, 3, 4],
        [3, 0, 4],
        [2, 0, 5],
        [1, 2, 5],
        [3, 1, 5],
        [0, 3, 5],
    ];
    let p = b.vec3(&pos, Some(ARRAY_BUFFER), true);
    let n = b.vec3(&dirs, Some(ARRAY_BUFFER), false);
    let i = b.indices(&faces);
    json!({
        "name": "marker",
        "primitives": [{"attributes": {"POSITION": p, "NORMAL": n}, "indices": i, "material": 1, "mode": 4}]
    })
}

/// panoman (Z up, faces −Y) → glTF (Y up, faces +Z), as `f32`.
pub(crate) fn to_gltf(p: V3) -> [f32; 3] {
    [p[0] as f32, p[2] as f32, (-p[1]) as f32]
}

/// Area-weighted unit vertex normals in glTF axes; +Y for vertices with no (non-degenerate)
/// incident triangle.
pub(crate) fn vertex_normals(positions: &[V3], faces: &[[u32; 3]]) -> Vec<[f32; 3]> {
    panoman_mesh::measure::vertex_normals_of(faces, positions)
        .into_iter()
        .map(|n| {
            if n == [0.0; 3] || !n.iter().all(|c| c.is_finite()) {
                [0.0, 1.0, 0.0]
            } else {
                to_gltf(n)
            }
        })
        .collect()
}

pub(crate) const ARRAY_BUFFER: u32 = 34962;
const ELEMENT_ARRAY_BUFFER: u32 = 34963;
pub(crate) const FLOAT: u32 = 5126;
pub(crate) const UNSIGNED_SHORT: u32 = 5123;
const UNSIGNED_INT: u32 = 5125;

/// The binary buffer under construction with its buffer views and accessors.
#[derive(Default)]
pub(crate) struct Builder {
    pub(crate) bin: Vec<u8>,
    pub(crate) views: Vec<Value>,
    pub(crate) accessors: Vec<Value>,
}

impl Builder {
    /// Appends a 4-byte aligned buffer view; returns its index.
    pub(crate) fn view(&mut self, bytes: &[u8], target: Option<u32>) -> usize {
        while !self.bin.len().is_multiple_of(4) {
            self.bin.push(0);
        }
        let mut v = json!({"buffer": 0, "byteOffset": self.bin.len(), "byteLength": bytes.len()});
        if let Some(t) = target {
            v["target"] = t.into();
        }
        self.bin.extend_from_slice(bytes);
        self.views.push(v);
        self.views.len() - 1
    }

    /// A float VEC3 accessor (with exact `min`/`max` when asked); returns its index.
    pub(crate) fn vec3(&mut self, data: &[[f32; 3]], target: Option<u32>, minmax: bool) -> usize {
        let bytes: Vec<u8> = data
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let view = self.view(&bytes, target);
        let mut a = json!({"bufferView": view, "componentType": FLOAT, "count": data.len(), "type": "VEC3"});
        if minmax {
            let mut lo = [f32::INFINITY; 3];
            let mut hi = [f32::NEG_INFINITY; 3];
            for p in data {
                for c in 0..3 {
                    lo[c] = lo[c].min(p[c]);
                    hi[c] = hi[c].max(p[c]);
                }
            }
            a["min"] = json!(lo.map(f64::from));
            a["max"] = json!(hi.map(f64::from));
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// A float SCALAR accessor (animation data, no buffer-view target); returns its index.
    pub(crate) fn scalars(&mut self, data: &[f32], minmax: bool) -> usize {
        let bytes: Vec<u8> = data.iter().flat_map(|x| x.to_le_bytes()).collect();
        let view = self.view(&bytes, None);
        let mut a = json!({"bufferView": view, "componentType": FLOAT, "count": data.len(), "type": "SCALAR"});
        if minmax {
            let lo = data.iter().copied().fold(f32::INFINITY, f32::min);
            let hi = data.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            a["min"] = json!([f64::from(lo)]);
            a["max"] = json!([f64::from(hi)]);
        }
        self.accessors.push(a);
        self.accessors.len() - 1
    }

    /// An accessor of any type over raw little-endian `bytes` (no min/max); returns its index.
    pub(crate) fn raw(
        &mut self,
        bytes: &[u8],
        component: u32,
        count: usize,
        kind: &str,
        target: Option<u32>,
    ) -> usize {
        let view = self.view(bytes, target);
        self.accessors
            .push(json!({"bufferView": view, "componentType": component,
                                   "count": count, "type": kind}));
        self.accessors.len() - 1
    }

    /// An unsigned-int index accessor over the triangles; returns its index.
    pub(crate) fn indices(&mut self, faces: &[[u32; 3]]) -> usize {
        let bytes: Vec<u8> = faces
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let view = self.view(&bytes, Some(ELEMENT_ARRAY_BUFFER));
        self.accessors
            .push(json!({"bufferView": view, "componentType": UNSIGNED_INT,
                                   "count": faces.len() * 3, "type": "SCALAR"}));
        self.accessors.len() - 1
    }
}

/// The GLB container: 12-byte header, the JSON chunk (padded with spaces) and the BIN chunk
/// (padded with zeros), both 4-byte aligned.
pub(crate) fn glb_container(doc: &Value, bin: &[u8]) -> Result<Vec<u8>> {
    let mut json = serde_json::to_vec(doc).expect("serializing a serde_json::Value cannot fail");
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    if total > u32::MAX as usize {
        return Err(InterchangeError::Invalid(format!(
            "the GLB would be {total} bytes; the format's limit is 4 GiB (export fewer frames)"
        )));
    }
    let mut out = Vec::with_capacity(total);
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(&bin);
    Ok(out)
}

/// The JSON chunk and the BIN chunk of a GLB file (for tests and the viewer).
///
/// # Errors
/// [`InterchangeError::Invalid`] if `bytes` is not a well-formed GLB container.
pub fn split_glb(bytes: &[u8]) -> Result<(Value, &[u8])> {
    let bad = |w: &str| InterchangeError::Invalid(format!("not a GLB file: {w}"));
    let u32_at = |o: usize| -> Result<u32> {
        bytes
            .get(o..o + 4)
            .map(|s| u32::from_le_bytes([s[0], s[1], s[2], s[3]]))
            .ok_or_else(|| bad("truncated"))
    };
    if bytes.get(0..4) != Some(b"glTF") || u32_at(4)? != 2 {
        return Err(bad("no glTF 2 header"));
    }
    if u32_at(8)? as usize != bytes.len() {
        return Err(bad("length field differs from the file size"));
    }
    let jlen = u32_at(12)? as usize;
    if bytes.get(16..20) != Some(b"JSON") || 20 + jlen > bytes.len() {
        return Err(bad("missing JSON chunk"));
    }
    let doc: Value = serde_json::from_slice(&bytes[20..20 + jlen])
        .map_err(|e| bad(&format!("JSON chunk: {e}")))?;
    let o = 20 + jlen;
    if o == bytes.len() {
        return Ok((doc, &[]));
    }
    let blen = u32_at(o)? as usize;
    if bytes.get(o + 4..o + 8) != Some(b"BIN\0") || o + 8 + blen > bytes.len() {
        return Err(bad("malformed BIN chunk"));
    }
    Ok((doc, &bytes[o + 8..o + 8 + blen]))
}
