//! `panoman synth`: the synthetic training data H (rest rows, body poses, expressions, hand
//! gestures) as `dataset.safetensors` + `dataset.json` (docs/formats.md), with an optional
//! contact sheet of random rows.

use anyhow::{Result, anyhow, bail};
use clap::Args;
use panoman_human::dataset::{
    self, Dataset, KIND_BODY, KIND_FACE, KIND_HAND, KIND_NAMES, KIND_REST, SynthConfig,
};
use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::{OutputTopology, TopologyMap};
use panoman_human::sampling::{stream_rng, uniform};
use panoman_human::template::{full_template, small_template};
use panoman_mesh::TriMesh;
use std::path::PathBuf;
use std::time::Instant;

use crate::render::{RgbImage, SKIN, Scene, View};

/// Arguments of `panoman synth`.
///
/// Example: `panoman synth --preset small --out data/` writes 12 identities with 40 body
/// poses, 40 expressions and 40 hand gestures on the small topology in a few seconds;
/// `--preset default` writes 250 identities and 8,000 posed rows on the full template.
#[derive(Args, Debug)]
#[command(after_help = "Examples:\n  \
    panoman synth --preset small --out data-small/ --preview data-small/preview.png\n  \
    panoman synth --preset default --seed 7 --out data/\n  \
    panoman synth --preset small --topology full --identities 4 --body 8 --face 8 --hand 8 --out tiny/\n\n\
    Presets: small = 12 identities, 40 rows per kind, small topology (1,229 vertices);\n  \
    default = 250 identities, 4,000 body / 2,000 face / 2,000 hand rows, full topology\n  \
    (13,348 vertices, about 1.3 GB). Same seed and options give byte-identical files\n  \
    whatever the number of threads (RAYON_NUM_THREADS).")]
pub struct SynthArgs {
    /// Size preset: `small` (CI-sized) or `default`.
    #[arg(long, default_value = "default")]
    pub preset: String,
    /// Seed of every random draw.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Topology of the rows: `full` (13,348 vertices) or `small` (1,229); default from the
    /// preset (small → small, default → full).
    #[arg(long)]
    pub topology: Option<OutputTopology>,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write a contact sheet (PNG) of random rows: one row of cells per kind (rest,
    /// body, face close-ups, hand close-ups).
    #[arg(long)]
    pub preview: Option<PathBuf>,
    /// Override the preset's number of identities.
    #[arg(long)]
    pub identities: Option<usize>,
    /// Override the preset's number of body-pose rows.
    #[arg(long)]
    pub body: Option<usize>,
    /// Override the preset's number of expression rows.
    #[arg(long)]
    pub face: Option<usize>,
    /// Override the preset's number of hand-gesture rows.
    #[arg(long)]
    pub hand: Option<usize>,
    /// Asset directory (default: $PANOMAN_ASSETS, else the user cache directory).
    #[arg(long)]
    pub assets: Option<PathBuf>,
}

/// Runs `panoman synth`.
pub fn run(a: SynthArgs) -> Result<()> {
    let t0 = Instant::now();
    let mut config = SynthConfig::preset(&a.preset)?;
    config.seed = a.seed;
    if let Some(t) = a.topology {
        if t == OutputTopology::Anny {
            bail!("--topology: datasets use `full` or `small`, not `anny`");
        }
        config.topology = t;
    }
    config.n_identities = a.identities.unwrap_or(config.n_identities);
    config.n_body = a.body.unwrap_or(config.n_body);
    config.n_face = a.face.unwrap_or(config.n_face);
    config.n_hand = a.hand.unwrap_or(config.n_hand);

    let assets = crate::util::open_assets(a.assets.as_deref())?;
    // Breast and local-change targets are not used (cupsize = firmness = 0.5, no changes).
    let opts = GeneratorOptions {
        breast: false,
        local_changes: false,
    };
    let generator = Generator::load(&assets, opts)?;
    let full = full_template(&assets)?;
    let small = small_template(&assets, &full)?;
    let map = TopologyMap::new(&generator, &full, &small)?;
    let load_s = t0.elapsed().as_secs_f64();

    let pb = indicatif::ProgressBar::new(config.n_rows() as u64);
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} synth [{bar:40}] {pos}/{len} rows  {per_sec}  eta {eta}",
        )
        .map_err(|e| anyhow!("progress style: {e}"))?
        .progress_chars("=> "),
    );
    let summary = dataset::synthesize(&generator, &map, &config, &a.out, &mut |done, _| {
        pb.set_position(done as u64)
    })
    .map_err(|e| anyhow!("{e}"))?;
    pb.finish_and_clear();

    let c = summary.counts;
    println!(
        "{}: {} rows ({} rest, {} body, {} face, {} hand) of {} identities ({} held out), \
         {} topology ({} vertices)",
        a.out.display(),
        summary.n_rows,
        c[0],
        c[1],
        c[2],
        c[3],
        config.n_identities,
        summary.n_held_out,
        config.topology,
        summary.n_vertices
    );
    println!(
        "  {:.1} MB in {:.1} s ({:.0} rows/s; assets and templates loaded in {:.1} s), seed {}",
        summary.bytes as f64 / 1e6,
        summary.seconds,
        summary.n_rows as f64 / summary.seconds.max(1e-9),
        load_s,
        config.seed
    );
    if let Some(png) = &a.preview {
        let t = Instant::now();
        let ds = Dataset::open(&a.out)?;
        let img = contact_sheet(&ds, &generator, &map, config.topology, config.seed)?;
        img.save_png(png)?;
        println!(
            "  preview {} ({}×{} px, {:.1} s)",
            png.display(),
            img.width,
            img.height,
            t.elapsed().as_secs_f64()
        );
    }
    Ok(())
}

/// Columns of the contact sheet.
const COLUMNS: usize = 6;
/// Cell size in pixels (width, height) per kind.
const CELL: [(u32, u32); 4] = [(220, 360), (220, 360), (220, 240), (220, 240)];

/// The contact sheet: one line per kind (rest, body, face, hand), `COLUMNS` random rows each
/// (drawn from `stream_rng(seed, 4, kind)`); bodies whole (front view), faces cropped to the
/// head, hands cropped to one hand (left and right alternating).
fn contact_sheet(
    ds: &Dataset,
    generator: &Generator,
    map: &TopologyMap,
    topology: OutputTopology,
    seed: u64,
) -> Result<RgbImage> {
    let faces = map.faces(topology);
    let part = vertex_parts(generator, map, topology);
    let width = CELL.iter().map(|c| c.0).max().unwrap_or(220) * COLUMNS as u32;
    let height: u32 = CELL.iter().map(|c| c.1).sum();
    let mut sheet = RgbImage::new(width, height, [255, 255, 255]);
    let mut y0 = 0;
    for kind in [KIND_REST, KIND_BODY, KIND_FACE, KIND_HAND] {
        let rows: Vec<usize> = (0..ds.n_rows).filter(|&r| ds.kind[r] == kind).collect();
        let (cw, ch) = CELL[kind as usize];
        let mut rng = stream_rng(seed, 4, kind as u64);
        // A partial Fisher–Yates shuffle: distinct random rows.
        let mut rows = rows;
        for col in 0..COLUMNS.min(rows.len()) {
            let j = col
                + ((uniform(&mut rng) * (rows.len() - col) as f64) as usize)
                    .min(rows.len() - col - 1);
            rows.swap(col, j);
            let row = rows[col];
            let v: Vec<[f64; 3]> = ds.vertices(row)?.iter().map(|p| p.map(f64::from)).collect();
            let mesh = TriMesh::new(v, faces.to_vec());
            let (mesh, view) = match kind {
                KIND_FACE => (crop(&mesh, &part, |p| p == Part::Head), View::Front),
                KIND_HAND => {
                    let side = if col % 2 == 0 {
                        Part::LeftHand
                    } else {
                        Part::RightHand
                    };
                    (crop(&mesh, &part, |p| p == side), View::Side)
                }
                _ => (mesh, View::Front),
            };
            if mesh.faces.is_empty() {
                bail!(
                    "{}: row {row} ({}) has nothing to draw",
                    ds.dir.display(),
                    KIND_NAMES[kind as usize]
                );
            }
            let cell = Scene::new(cw, ch).add_mesh(&mesh, SKIN).render(view);
            blit(&mut sheet, &cell, col as u32 * cw, y0);
        }
        y0 += ch;
    }
    Ok(sheet)
}

/// Coarse parts for cropping the preview.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Part {
    Head,
    LeftHand,
    RightHand,
    Other,
}

/// Part of each vertex of `topology` by its dominant skinning bone: the head bone and its
/// descendants (jaw, eyes, face bones), `wrist.L`/`wrist.R` and their descendants (hands).
fn vertex_parts(generator: &Generator, map: &TopologyMap, topology: OutputTopology) -> Vec<Part> {
    let names = generator.bone_names();
    let parents = generator.bone_parents();
    let below = |c: usize, root: &str| {
        let mut b = Some(c);
        while let Some(k) = b {
            if names[k] == root {
                return true;
            }
            b = parents[k];
        }
        false
    };
    let bone_part: Vec<Part> = (0..names.len())
        .map(|c| {
            if below(c, "head") {
                Part::Head
            } else if below(c, "wrist.L") {
                Part::LeftHand
            } else if below(c, "wrist.R") {
                Part::RightHand
            } else {
                Part::Other
            }
        })
        .collect();
    let sw = generator.skin_weights();
    let anny_part = |k: usize| {
        let (a, b) = (sw.offsets[k] as usize, sw.offsets[k + 1] as usize);
        (a..b)
            .max_by(|&i, &j| sw.weights[i].total_cmp(&sw.weights[j]))
            .map_or(Part::Other, |i| bone_part[sw.bones[i] as usize])
    };
    match topology {
        OutputTopology::Small => map
            .small_binding()
            .iter()
            .map(|b| {
                let m = (0..3)
                    .max_by(|&i, &j| b.bary[i].total_cmp(&b.bary[j]))
                    .unwrap_or(0);
                anny_part(b.tri[m] as usize)
            })
            .collect(),
        OutputTopology::Full => map
            .full_from_anny()
            .iter()
            .map(|&k| anny_part(k as usize))
            .collect(),
        OutputTopology::Anny => (0..map.n_anny_vertices()).map(anny_part).collect(),
    }
}

/// The triangles whose three vertices satisfy `keep`, with the used vertices only.
fn crop(mesh: &TriMesh, part: &[Part], keep: impl Fn(Part) -> bool) -> TriMesh {
    let mut new_id = vec![u32::MAX; mesh.positions.len()];
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for f in &mesh.faces {
        if f.iter().all(|&v| keep(part[v as usize])) {
            faces.push(f.map(|v| {
                let v = v as usize;
                if new_id[v] == u32::MAX {
                    new_id[v] = positions.len() as u32;
                    positions.push(mesh.positions[v]);
                }
                new_id[v]
            }));
        }
    }
    TriMesh::new(positions, faces)
}

/// Copies `cell` into `sheet` at `(x0, y0)` (clipped).
fn blit(sheet: &mut RgbImage, cell: &RgbImage, x0: u32, y0: u32) {
    for y in 0..cell.height.min(sheet.height.saturating_sub(y0)) {
        for x in 0..cell.width.min(sheet.width.saturating_sub(x0)) {
            let s = 3 * (y as usize * cell.width as usize + x as usize);
            let d = 3 * ((y0 + y) as usize * sheet.width as usize + (x0 + x) as usize);
            sheet.data[d..d + 3].copy_from_slice(&cell.data[s..s + 3]);
        }
    }
}
