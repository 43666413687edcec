//! A small software renderer for meshes and keypoints (used by `panoman render`, and meant for
//! the renders of `eval`, `fit` and the reports).
//!
//! * Orthographic camera, world Z up. [`View::Front`] looks along +Y at the character's front
//!   (the character faces −Y; its left, +X, is on the image's right), [`View::Side`] shows the
//!   character's left profile (camera on +X looking along −X), [`View::Back`] looks along −Y.
//! * Each [`Scene::add_mesh`] opens a *panel*; panels are laid out side by side with one shared
//!   scale and one shared vertical range (bodies of different heights compare directly).
//!   [`Scene::overlay_mesh`] and [`Scene::add_points`] draw into the current panel.
//! * Z-buffered triangle rasterization with per-pixel interpolated vertex normals: Lambert key
//!   and fill lights, ambient, a rim term and a faint specular highlight. Back faces are drawn
//!   darker and tinted red, so an inverted or open mesh shows at a glance.
//! * Antialiasing by `s × s` supersampling (default 2 × 2) and a box filter.
//! * Points (keypoints) are filled discs with a dark outline, drawn on top of everything.
//!
//! Example:
//! ```ignore
//! let img = Scene::new(800, 800)
//!     .add_mesh(&mesh, SKIN)
//!     .add_points(&keypoints, [220, 40, 40], 4.0)
//!     .render(View::Front);
//! img.save_png(Path::new("body.png"))?;
//! ```

// Part of the API is for commands that do not exist yet (error maps, overlays).
#![allow(dead_code)]

use anyhow::{Context, Result};
use panoman_mesh::TriMesh;
use panoman_mesh::geom::dot;
use panoman_mesh::measure::vertex_normals;
use std::path::Path;
use std::str::FromStr;

/// An sRGB colour, 8 bits per channel.
pub type Rgb = [u8; 3];

/// Default mesh colour (a neutral skin tone).
pub const SKIN: Rgb = [214, 178, 156];

/// Default background (light grey).
pub const BACKGROUND: Rgb = [236, 236, 236];

/// Mesh colours for several panels, in order (skin, blue-grey, sage, sand).
pub const PALETTE: [Rgb; 4] = [SKIN, [156, 174, 210], [168, 202, 160], [214, 196, 142]];

/// The camera direction.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum View {
    /// Looking along +Y at the character's front (its left on the image's right).
    #[default]
    Front,
    /// The character's left profile: camera on +X looking along −X (front to the image's left).
    Side,
    /// Looking along −Y at the character's back.
    Back,
}

impl View {
    /// The name used on the command line: `front`, `side` or `back`.
    pub fn name(self) -> &'static str {
        match self {
            View::Front => "front",
            View::Side => "side",
            View::Back => "back",
        }
    }

    /// Image right, image up and viewing direction (into the screen), in world coordinates.
    pub fn basis(self) -> ([f64; 3], [f64; 3], [f64; 3]) {
        let up = [0.0, 0.0, 1.0];
        match self {
            View::Front => ([1.0, 0.0, 0.0], up, [0.0, 1.0, 0.0]),
            View::Side => ([0.0, 1.0, 0.0], up, [-1.0, 0.0, 0.0]),
            View::Back => ([-1.0, 0.0, 0.0], up, [0.0, -1.0, 0.0]),
        }
    }
}

impl std::fmt::Display for View {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for View {
    type Err = String;

    /// Parses `front`, `side` or `back`.
    fn from_str(s: &str) -> std::result::Result<View, String> {
        match s {
            "front" => Ok(View::Front),
            "side" => Ok(View::Side),
            "back" => Ok(View::Back),
            _ => Err(format!(
                "unknown view `{s}` (expected `front`, `side` or `back`)"
            )),
        }
    }
}

/// An 8-bit RGB image, rows top to bottom.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height × 3` bytes, row-major, top row first.
    pub data: Vec<u8>,
}

impl RgbImage {
    /// An image filled with `color`.
    pub fn new(width: u32, height: u32, color: Rgb) -> RgbImage {
        let n = width as usize * height as usize;
        let mut data = Vec::with_capacity(3 * n);
        for _ in 0..n {
            data.extend_from_slice(&color);
        }
        RgbImage {
            width,
            height,
            data,
        }
    }

    /// The pixel at column `x`, row `y` (row 0 at the top).
    ///
    /// # Panics
    /// If the pixel is outside the image.
    pub fn pixel(&self, x: u32, y: u32) -> Rgb {
        assert!(x < self.width && y < self.height, "pixel outside the image");
        let i = 3 * (y as usize * self.width as usize + x as usize);
        [self.data[i], self.data[i + 1], self.data[i + 2]]
    }

    /// Number of pixels that differ from `color`.
    pub fn count_not(&self, color: Rgb) -> usize {
        self.data.chunks_exact(3).filter(|p| *p != color).count()
    }

    /// The image as PNG bytes (8-bit RGB).
    ///
    /// # Errors
    /// An encoder error (an empty image).
    pub fn encode_png(&self) -> Result<Vec<u8>> {
        let mut out = Vec::new();
        {
            let mut enc = png::Encoder::new(&mut out, self.width, self.height);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            enc.set_compression(png::Compression::Fast);
            let mut w = enc.write_header()?;
            w.write_image_data(&self.data)?;
            w.finish()?;
        }
        Ok(out)
    }

    /// Writes the image as PNG, atomically (a temporary file in the same directory, renamed).
    ///
    /// # Errors
    /// `<path>: <what>` for encoding or I/O failures.
    pub fn save_png(&self, path: &Path) -> Result<()> {
        check_png_path(path)?;
        let bytes = self
            .encode_png()
            .with_context(|| format!("{}: PNG encoding failed", path.display()))?;
        crate::util::write_atomic(path, &bytes)
    }
}

/// Images are written as PNG only: an output path must end in `.png` (case-insensitive), so
/// that no PNG bytes land under a `.jpg` (or other) name.
///
/// # Errors
/// One line naming the path.
pub fn check_png_path(path: &Path) -> Result<()> {
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase());
    match ext.as_deref() {
        Some("png") => Ok(()),
        Some(other) => anyhow::bail!(
            "{}: unsupported image extension '.{other}': images are written as PNG (.png)",
            path.display()
        ),
        None => anyhow::bail!(
            "{}: image path has no extension: images are written as PNG (.png)",
            path.display()
        ),
    }
}

/// A colour map for scalar maps (e.g. per-vertex errors): `t` clamped to [0, 1] goes from
/// blue (0) through white-ish green-yellow to red (1).
pub fn error_color(t: f64) -> Rgb {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        1.0
    };
    // Piecewise-linear through five anchors.
    const A: [[f64; 3]; 5] = [
        [48.0, 86.0, 200.0],
        [90.0, 180.0, 220.0],
        [235.0, 235.0, 200.0],
        [245.0, 170.0, 60.0],
        [200.0, 30.0, 30.0],
    ];
    let x = t * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    std::array::from_fn(|k| (A[i][k] + f * (A[i + 1][k] - A[i][k])).round() as u8)
}

#[derive(Clone, Debug)]
enum Coloring {
    Uniform(Rgb),
    PerVertex(Vec<Rgb>),
}

#[derive(Clone, Debug)]
struct MeshItem {
    positions: Vec<[f64; 3]>,
    faces: Vec<[u32; 3]>,
    normals: Vec<[f64; 3]>,
    coloring: Coloring,
}

#[derive(Clone, Debug)]
struct PointsItem {
    points: Vec<[f64; 3]>,
    color: Rgb,
    radius_px: f64,
}

#[derive(Clone, Debug, Default)]
struct Panel {
    meshes: Vec<MeshItem>,
    points: Vec<PointsItem>,
}

/// What to draw: panels of meshes and points (see the module docs).
#[derive(Clone, Debug)]
pub struct Scene {
    width: u32,
    height: u32,
    background: Rgb,
    supersample: u32,
    margin: f64,
    panels: Vec<Panel>,
}

impl Scene {
    /// An empty scene for a `width × height` image (light grey background, 2 × 2
    /// supersampling).
    pub fn new(width: u32, height: u32) -> Scene {
        Scene {
            width: width.max(1),
            height: height.max(1),
            background: BACKGROUND,
            supersample: 2,
            margin: 0.04,
            panels: Vec::new(),
        }
    }

    /// Sets the background colour.
    pub fn background(&mut self, color: Rgb) -> &mut Self {
        self.background = color;
        self
    }

    /// Sets the supersampling factor per axis (1 = no antialiasing; clamped to 1..=4).
    pub fn supersample(&mut self, s: u32) -> &mut Self {
        self.supersample = s.clamp(1, 4);
        self
    }

    /// Sets the empty border around the drawing, as a fraction of the image size (default
    /// 0.04, clamped to [0, 0.4]).
    pub fn margin(&mut self, m: f64) -> &mut Self {
        self.margin = if m.is_finite() {
            m.clamp(0.0, 0.4)
        } else {
            0.04
        };
        self
    }

    /// Number of panels so far.
    pub fn n_panels(&self) -> usize {
        self.panels.len()
    }

    fn mesh_item(mesh: &TriMesh, coloring: Coloring) -> MeshItem {
        MeshItem {
            positions: mesh.positions.clone(),
            faces: mesh.faces.clone(),
            normals: vertex_normals(mesh),
            coloring,
        }
    }

    /// Adds a mesh of one colour in a new panel.
    pub fn add_mesh(&mut self, mesh: &TriMesh, color: Rgb) -> &mut Self {
        self.panels.push(Panel::default());
        self.overlay_mesh(mesh, color)
    }

    /// Adds a mesh with one colour per vertex (interpolated over the triangles; e.g. an
    /// error map with [`error_color`]) in a new panel.
    ///
    /// # Panics
    /// If `colors.len()` is not the number of vertices.
    pub fn add_mesh_colored(&mut self, mesh: &TriMesh, colors: &[Rgb]) -> &mut Self {
        assert_eq!(colors.len(), mesh.n_vertices(), "one colour per vertex");
        self.panels.push(Panel::default());
        let item = Scene::mesh_item(mesh, Coloring::PerVertex(colors.to_vec()));
        self.current().meshes.push(item);
        self
    }

    /// Adds a mesh of one colour to the current panel (a new panel if there is none), e.g. to
    /// overlay a fitted mesh on a target.
    pub fn overlay_mesh(&mut self, mesh: &TriMesh, color: Rgb) -> &mut Self {
        let item = Scene::mesh_item(mesh, Coloring::Uniform(color));
        self.current().meshes.push(item);
        self
    }

    /// Adds points (world coordinates) drawn as filled discs of `radius_px` output pixels on
    /// top of the current panel (a new panel if there is none). Non-finite points are skipped.
    pub fn add_points(&mut self, points: &[[f64; 3]], color: Rgb, radius_px: f64) -> &mut Self {
        let item = PointsItem {
            points: points.to_vec(),
            color,
            radius_px: if radius_px.is_finite() {
                radius_px.max(0.5)
            } else {
                3.0
            },
        };
        self.current().points.push(item);
        self
    }

    fn current(&mut self) -> &mut Panel {
        if self.panels.is_empty() {
            self.panels.push(Panel::default());
        }
        self.panels.last_mut().expect("a panel")
    }

    /// Renders the scene from `view`.
    pub fn render(&self, view: View) -> RgbImage {
        let s = self.supersample;
        let (w, h) = (self.width * s, self.height * s);
        let mut fb = Framebuffer::new(w as usize, h as usize, self.background);
        let (r, u, f) = view.basis();
        let proj = |p: [f64; 3]| (dot(p, r), dot(p, u));
        let layout = Layout::new(self, view, w as f64, h as f64);
        for (panel, place) in self.panels.iter().zip(&layout.panels) {
            let to_px = |p: [f64; 3]| {
                let (x, y) = proj(p);
                let px = place.x0 + layout.scale * (x - place.sx0);
                let py = layout.cy - layout.scale * (y - layout.sy_mid);
                [px, py, dot(p, f)]
            };
            for m in &panel.meshes {
                let screen: Vec<[f64; 3]> = m.positions.iter().map(|&p| to_px(p)).collect();
                let normals: Vec<[f64; 3]> = m
                    .normals
                    .iter()
                    .map(|&n| [dot(n, r), dot(n, u), -dot(n, f)])
                    .collect();
                fb.draw_mesh(m, &screen, &normals);
            }
        }
        for (panel, place) in self.panels.iter().zip(&layout.panels) {
            for pts in &panel.points {
                for &p in &pts.points {
                    if !p.iter().all(|c| c.is_finite()) {
                        continue;
                    }
                    let (x, y) = proj(p);
                    let px = place.x0 + layout.scale * (x - place.sx0);
                    let py = layout.cy - layout.scale * (y - layout.sy_mid);
                    fb.draw_disc(px, py, pts.radius_px * s as f64, pts.color);
                }
            }
        }
        fb.downsample(s as usize, self.width, self.height)
    }
}

/// Where each panel goes: a shared scale and vertical range, per-panel horizontal offsets.
struct Layout {
    scale: f64,
    cy: f64,
    sy_mid: f64,
    panels: Vec<PanelPlace>,
}

struct PanelPlace {
    /// Leftmost image x of the panel and the projected x it corresponds to.
    x0: f64,
    sx0: f64,
}

impl Layout {
    fn new(scene: &Scene, view: View, w: f64, h: f64) -> Layout {
        let (r, u, _) = view.basis();
        let mut extents = Vec::with_capacity(scene.panels.len());
        let (mut y_lo, mut y_hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for panel in &scene.panels {
            let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
            let all = panel
                .meshes
                .iter()
                .flat_map(|m| m.positions.iter())
                .chain(panel.points.iter().flat_map(|p| p.points.iter()));
            for &p in all {
                let (x, y) = (dot(p, r), dot(p, u));
                if x.is_finite() && y.is_finite() {
                    lo = lo.min(x);
                    hi = hi.max(x);
                    y_lo = y_lo.min(y);
                    y_hi = y_hi.max(y);
                }
            }
            if lo > hi {
                (lo, hi) = (0.0, 0.0);
            }
            extents.push((lo, hi));
        }
        if y_lo > y_hi {
            (y_lo, y_hi) = (0.0, 0.0);
        }
        let height = (y_hi - y_lo).max(1e-9);
        let widths: Vec<f64> = extents.iter().map(|(a, b)| (b - a).max(1e-9)).collect();
        let n = widths.len().max(1) as f64;
        let mean_w = widths.iter().sum::<f64>() / n;
        let gap = 0.15 * mean_w.max(0.1 * height);
        let total = widths.iter().sum::<f64>() + gap * (n - 1.0);
        let m = scene.margin;
        let scale = ((w * (1.0 - 2.0 * m)) / total).min((h * (1.0 - 2.0 * m)) / height);
        let mut x = 0.5 * (w - scale * total);
        let mut panels = Vec::with_capacity(widths.len());
        for (&(lo, _), wi) in extents.iter().zip(&widths) {
            panels.push(PanelPlace { x0: x, sx0: lo });
            x += scale * (wi + gap);
        }
        Layout {
            scale,
            cy: 0.5 * h,
            sy_mid: 0.5 * (y_lo + y_hi),
            panels,
        }
    }
}

/// Supersampled colour (linear floats) and depth buffers.
struct Framebuffer {
    w: usize,
    h: usize,
    color: Vec<[f32; 3]>,
    depth: Vec<f32>,
}

/// Key light, fill light (view space: x right, y up, z toward the viewer), ambient, rim,
/// specular.
const KEY: [f64; 3] = [-0.42, 0.52, 0.74];
const FILL: [f64; 3] = [0.62, 0.05, 0.78];
const K_KEY: f64 = 0.68;
const K_FILL: f64 = 0.22;
const K_AMBIENT: f64 = 0.2;
const K_RIM: f64 = 0.22;
const K_SPEC: f64 = 0.07;

impl Framebuffer {
    fn new(w: usize, h: usize, bg: Rgb) -> Framebuffer {
        let c = bg.map(|v| v as f32 / 255.0);
        Framebuffer {
            w,
            h,
            color: vec![c; w * h],
            depth: vec![f32::INFINITY; w * h],
        }
    }

    /// Rasterizes a mesh: `screen` = (pixel x, pixel y, depth) per vertex, `normals` in view
    /// space (x right, y up, z toward the viewer).
    fn draw_mesh(&mut self, m: &MeshItem, screen: &[[f64; 3]], normals: &[[f64; 3]]) {
        let key = normalize(KEY);
        let fill = normalize(FILL);
        let half = normalize([key[0], key[1], key[2] + 1.0]);
        for face in &m.faces {
            let [i0, i1, i2] = face.map(|i| i as usize);
            if i0 >= screen.len() || i1 >= screen.len() || i2 >= screen.len() {
                continue;
            }
            let (a, b, c) = (screen[i0], screen[i1], screen[i2]);
            if ![a, b, c].iter().flatten().all(|v| v.is_finite()) {
                continue;
            }
            // Signed doubled area in image coordinates (y down): > 0 ⇔ the triangle is
            // counter-clockwise as seen by the viewer, i.e. front-facing.
            let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            if area.abs() < 1e-12 {
                continue;
            }
            let front = area < 0.0;
            let x_lo = (a[0].min(b[0]).min(c[0]).floor().max(0.0)) as usize;
            let y_lo = (a[1].min(b[1]).min(c[1]).floor().max(0.0)) as usize;
            let x_hi = (a[0].max(b[0]).max(c[0]).ceil()).min(self.w as f64 - 1.0);
            let y_hi = (a[1].max(b[1]).max(c[1]).ceil()).min(self.h as f64 - 1.0);
            if x_hi < 0.0 || y_hi < 0.0 {
                continue;
            }
            let (x_hi, y_hi) = (x_hi as usize, y_hi as usize);
            let inv = 1.0 / area;
            let cols = match &m.coloring {
                Coloring::Uniform(c) => [*c; 3],
                Coloring::PerVertex(v) => [v[i0], v[i1], v[i2]],
            }
            .map(|c| c.map(|v| v as f64 / 255.0));
            let ns = [normals[i0], normals[i1], normals[i2]];
            for y in y_lo..=y_hi {
                let py = y as f64 + 0.5;
                for x in x_lo..=x_hi {
                    let px = x as f64 + 0.5;
                    let w0 = ((b[0] - px) * (c[1] - py) - (b[1] - py) * (c[0] - px)) * inv;
                    let w1 = ((c[0] - px) * (a[1] - py) - (c[1] - py) * (a[0] - px)) * inv;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = (w0 * a[2] + w1 * b[2] + w2 * c[2]) as f32;
                    let k = y * self.w + x;
                    if z >= self.depth[k] {
                        continue;
                    }
                    self.depth[k] = z;
                    let mut n = [0.0; 3];
                    let mut base = [0.0; 3];
                    for j in 0..3 {
                        n[j] = w0 * ns[0][j] + w1 * ns[1][j] + w2 * ns[2][j];
                        base[j] = w0 * cols[0][j] + w1 * cols[1][j] + w2 * cols[2][j];
                    }
                    let mut n = normalize(n);
                    if !front {
                        n = [-n[0], -n[1], -n[2]];
                    }
                    let nz = n[2].clamp(0.0, 1.0);
                    let lambert = K_KEY * dot(n, key).max(0.0) + K_FILL * dot(n, fill).max(0.0);
                    let rim = K_RIM * (1.0 - nz).powi(3);
                    let spec = K_SPEC * dot(n, half).max(0.0).powi(24);
                    let mut out = [0.0f32; 3];
                    for j in 0..3 {
                        let mut v = base[j] * (K_AMBIENT + lambert) + rim + spec;
                        if !front {
                            // Back faces: darker, reddish.
                            v *= if j == 0 { 0.75 } else { 0.35 };
                        }
                        out[j] = v.clamp(0.0, 1.0) as f32;
                    }
                    self.color[k] = out;
                }
            }
        }
    }

    /// A filled disc with a dark outline (antialiased by the supersampling).
    fn draw_disc(&mut self, cx: f64, cy: f64, radius: f64, color: Rgb) {
        let fill = color.map(|v| v as f32 / 255.0);
        let edge = fill.map(|v| v * 0.3);
        let inner = radius - (0.18 * radius).max(1.0);
        let x_lo = (cx - radius).floor().max(0.0) as usize;
        let y_lo = (cy - radius).floor().max(0.0) as usize;
        let x_hi = (cx + radius).ceil().min(self.w as f64 - 1.0);
        let y_hi = (cy + radius).ceil().min(self.h as f64 - 1.0);
        if x_hi < 0.0 || y_hi < 0.0 {
            return;
        }
        for y in y_lo..=y_hi as usize {
            for x in x_lo..=x_hi as usize {
                let (dx, dy) = (x as f64 + 0.5 - cx, y as f64 + 0.5 - cy);
                let d = (dx * dx + dy * dy).sqrt();
                if d <= radius {
                    self.color[y * self.w + x] = if d <= inner { fill } else { edge };
                }
            }
        }
    }

    /// Box-filters `s × s` blocks into an 8-bit image.
    fn downsample(&self, s: usize, width: u32, height: u32) -> RgbImage {
        let (wo, ho) = (width as usize, height as usize);
        let mut data = Vec::with_capacity(3 * wo * ho);
        let norm = 1.0 / (s * s) as f32;
        for y in 0..ho {
            for x in 0..wo {
                let mut acc = [0.0f32; 3];
                for dy in 0..s {
                    let row = (y * s + dy) * self.w;
                    for dx in 0..s {
                        let c = self.color[row + x * s + dx];
                        for j in 0..3 {
                            acc[j] += c[j];
                        }
                    }
                }
                for a in acc {
                    data.push((a * norm * 255.0).round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        RgbImage {
            width,
            height,
            data,
        }
    }
}

#[inline]
fn normalize(a: [f64; 3]) -> [f64; 3] {
    let n = dot(a, a).sqrt();
    if n > 0.0 && n.is_finite() {
        [a[0] / n, a[1] / n, a[2] / n]
    } else {
        [0.0, 0.0, 1.0]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An axis-aligned cube `[-0.5, 0.5]³`, outward-facing triangles.
    fn cube() -> TriMesh {
        let p: Vec<[f64; 3]> = (0..8)
            .map(|i| {
                [
                    if i & 1 == 0 { -0.5 } else { 0.5 },
                    if i & 2 == 0 { -0.5 } else { 0.5 },
                    if i & 4 == 0 { -0.5 } else { 0.5 },
                ]
            })
            .collect();
        let quads = [
            [0, 2, 3, 1],
            [4, 5, 7, 6],
            [0, 1, 5, 4],
            [2, 6, 7, 3],
            [0, 4, 6, 2],
            [1, 3, 7, 5],
        ];
        let mut f = Vec::new();
        for q in quads {
            f.push([q[0], q[1], q[2]]);
            f.push([q[0], q[2], q[3]]);
        }
        TriMesh::new(p, f)
    }

    #[test]
    fn cube_covers_the_middle_and_is_front_lit() {
        let m = cube();
        assert!(panoman_mesh::measure::enclosed_volume(&m) > 0.0);
        let img = Scene::new(100, 100).add_mesh(&m, SKIN).render(View::Front);
        assert_eq!((img.width, img.height, img.data.len()), (100, 100, 30000));
        assert_eq!(img.pixel(0, 0), BACKGROUND);
        let c = img.pixel(50, 50);
        assert_ne!(c, BACKGROUND);
        // Front-facing: not the dark red back-face tint.
        assert!(c[1] > 100 && c[2] > 80, "{c:?}");
        let covered = img.count_not(BACKGROUND) as f64 / 1e4;
        assert!(covered > 0.8 && covered < 0.95, "{covered}");
    }

    #[test]
    fn inverted_mesh_shows_back_faces() {
        let mut m = cube();
        for f in &mut m.faces {
            f.swap(1, 2);
        }
        let img = Scene::new(64, 64).add_mesh(&m, SKIN).render(View::Side);
        let c = img.pixel(32, 32);
        assert!(c[0] > 2 * c[1], "{c:?}");
    }

    #[test]
    fn panels_points_and_png() {
        let m = cube();
        let mut moved = m.clone();
        for p in &mut moved.positions {
            p[2] *= 2.0;
        }
        let mut scene = Scene::new(200, 100);
        scene
            .add_mesh(&m, SKIN)
            .add_points(&[[0.0, -0.5, 0.0]], [220, 40, 40], 4.0)
            .add_mesh_colored(&moved, &[error_color(0.9); 8]);
        assert_eq!(scene.n_panels(), 2);
        let img = scene.render(View::Front);
        let bytes = img.encode_png().unwrap();
        assert_eq!(&bytes[1..4], b"PNG");
        // Two panels: the left one is shorter (shared scale), the point sits on it.
        let col = |x: u32| (0..100).filter(|&y| img.pixel(x, y) != BACKGROUND).count();
        let left = (0..100).map(col).max().unwrap();
        let right = (100..200).map(col).max().unwrap();
        assert!(left < right, "{left} {right}");
        let centre_left = (0..100)
            .flat_map(|x| (0..100).map(move |y| (x, y)))
            .filter(|&(x, y)| img.pixel(x, y)[0] > 180 && img.pixel(x, y)[1] < 90)
            .count();
        assert!(centre_left > 10, "{centre_left}");
        assert_eq!(error_color(0.0), [48, 86, 200]);
        assert_eq!(error_color(2.0), [200, 30, 30]);
    }
}
