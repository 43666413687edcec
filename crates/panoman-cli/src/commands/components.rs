//! `panoman components`: draw sparse localized components on the mesh (the paper's Fig. 8).

use crate::render::{Rgb, SKIN, Scene, View, error_color};
use anyhow::{Result, bail};
use clap::Args;
use panoman_mesh::TriMesh;
use panoman_model::model::{BLOCK_NAMES, PanoManModel};
use std::path::PathBuf;

/// Arguments of `panoman components`.
#[derive(Args, Debug)]
#[command(
    after_help = "Examples:\n  panoman components --model M.safetensors --block body_a --count 6 --out body_a.png\n  panoman components --model M.safetensors --block face_l --view front --out face_l.png"
)]
pub struct ComponentsArgs {
    /// Model file.
    #[arg(long)]
    pub model: PathBuf,
    /// Block: body_l, face_l, hands_l, body_a, face_a or hands_a.
    #[arg(long, default_value = "body_a")]
    pub block: String,
    /// How many components to draw (the most energetic first).
    #[arg(long, default_value_t = 6)]
    pub count: usize,
    /// First component to draw.
    #[arg(long, default_value_t = 0)]
    pub first: usize,
    /// View direction.
    #[arg(long, default_value = "front")]
    pub view: View,
    /// Output PNG.
    #[arg(long)]
    pub out: PathBuf,
}

/// Per-vertex magnitude of one component: the largest |C_k,e| over the vertex's edges.
fn vertex_magnitude(model: &PanoManModel, edges: &[[u32; 2]], b: usize, k: usize) -> Vec<f64> {
    let block = &model.blocks[b];
    let mut v = vec![0.0f64; model.n_vertices];
    let (cols, vals) = block.components.row(k);
    for (&j, &c) in cols.iter().zip(vals) {
        let [a, bb] = edges[block.columns[j as usize] as usize];
        for x in [a, bb] {
            v[x as usize] = v[x as usize].max((c as f64).abs());
        }
    }
    v
}

/// Runs `panoman components`.
pub fn run(a: ComponentsArgs) -> Result<()> {
    let model = PanoManModel::load(&a.model)?;
    let Some(b) = BLOCK_NAMES.iter().position(|n| *n == a.block) else {
        bail!(
            "unknown block '{}' (known: {})",
            a.block,
            BLOCK_NAMES.join(", ")
        );
    };
    if a.count == 0 {
        bail!("--count must be at least 1");
    }
    let k_total = model.blocks[b].n_components();
    if a.first >= k_total {
        bail!(
            "{}: block {} has {k_total} components",
            a.model.display(),
            a.block
        );
    }
    let topo = panoman_mesh::Topology::build(model.n_vertices, &model.faces)?;
    let rest = model.rest_shape(&[]);
    // Face and hand blocks: crop to the block's region (hands: the left hand) so the
    // components are visible.
    let faces = if b % 3 == 0 {
        model.faces.clone()
    } else {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for &e in &model.blocks[b].columns {
            for v in topo.edges[e as usize] {
                let p = rest[v as usize];
                if b % 3 == 2 && p[0] < 0.0 {
                    continue;
                }
                for c in 0..3 {
                    lo[c] = lo[c].min(p[c]);
                    hi[c] = hi[c].max(p[c]);
                }
            }
        }
        let pad: Vec<f64> = (0..3).map(|c| 0.08 * (hi[c] - lo[c])).collect();
        let inside = |v: u32| {
            (0..3).all(|c| (lo[c] - pad[c]..=hi[c] + pad[c]).contains(&rest[v as usize][c]))
        };
        model
            .faces
            .iter()
            .copied()
            .filter(|f| f.iter().all(|&v| inside(v)))
            .collect()
    };
    // Keep only referenced vertices (the renderer frames every position it is given).
    let mut map = vec![u32::MAX; rest.len()];
    let mut keep = Vec::new();
    for f in &faces {
        for &v in f {
            if map[v as usize] == u32::MAX {
                map[v as usize] = keep.len() as u32;
                keep.push(v);
            }
        }
    }
    let faces: Vec<[u32; 3]> = faces.iter().map(|f| f.map(|v| map[v as usize])).collect();
    let mesh = TriMesh::new(keep.iter().map(|&v| rest[v as usize]).collect(), faces);
    let ks: Vec<usize> = (a.first..(a.first + a.count).min(k_total)).collect();
    let (w, h) = if b % 3 == 0 { (360, 720) } else { (420, 420) };
    let mut scene = Scene::new(w * ks.len() as u32, h);
    let mut supports = Vec::new();
    for &k in &ks {
        let mag = vertex_magnitude(&model, &topo.edges, b, k);
        let max = mag.iter().copied().fold(0.0, f64::max).max(1e-30);
        let colors: Vec<Rgb> = keep
            .iter()
            .map(|&v| mag[v as usize])
            .collect::<Vec<_>>()
            .iter()
            .map(|&m| {
                // Values below 2 % of the peak are drawn as skin: the ℓ1 penalty leaves a dust
                // of tiny weights inside the support radius that carries no visible energy.
                if m > 0.02 * max {
                    error_color(0.15 + 0.85 * (m / max))
                } else {
                    SKIN
                }
            })
            .collect();
        scene.add_mesh_colored(&mesh, &colors);
        supports.push(
            model.blocks[b].components.row(k).0.len() as f64 / model.blocks[b].columns.len() as f64,
        );
    }
    scene.render(a.view).save_png(&a.out)?;
    println!(
        "{}: {} components {}..{} of {} ({} of {}), support {} of the block's edges",
        a.out.display(),
        ks.len(),
        ks[0],
        ks[ks.len() - 1],
        a.block,
        k_total,
        a.model.display(),
        supports
            .iter()
            .map(|s| format!("{:.1} %", 100.0 * s))
            .collect::<Vec<_>>()
            .join(", ")
    );
    Ok(())
}
