//! Representation diagnostics for one registered mesh: RL/RA residual of the model's
//! least-squares encoding per part (body, face, left hand, right hand) next to the magnitude of
//! the mesh's own RL/RA, and the mesh error per part when `g` rebuilds from the model's RLA
//! everywhere or only on the body edges (truth elsewhere).
//!
//! `cargo run --release -p panoman-model --example repr_diagnostics -- M.safetensors mesh.obj rest.obj`
use panoman_mesh::{
    RestGeometry, Rla,
    align::rigid_align,
    geom::{norm, sub},
    io,
};
use panoman_model::model::{Evaluator, PanoManModel};
fn main() {
    let a: Vec<String> = std::env::args().collect();
    let model = PanoManModel::load(a[1].as_ref()).unwrap();
    let mesh = io::read_mesh(a[2].as_ref()).unwrap().positions;
    let rest = io::read_mesh(a[3].as_ref()).unwrap().positions;
    let mut ev = Evaluator::new(std::sync::Arc::new(model.clone())).unwrap();
    let p = ev.encode(&mesh, Some(&rest), false).unwrap();
    let topo = ev.topology().clone();
    let rg = RestGeometry::new(&topo, &rest).unwrap();
    let truth = Rla::compute(&topo, &rg, &mesh).unwrap();
    let fit = model.rla(&p, false);
    for part in 0..4u8 {
        let es: Vec<usize> = (0..topo.n_edges())
            .filter(|&e| model.edge_part[e] == part)
            .collect();
        let r = |a: &[f64], b: &[f64]| {
            (es.iter().map(|&e| (a[e] - b[e]).powi(2)).sum::<f64>() / es.len() as f64).sqrt()
        };
        let mag =
            |a: &[f64]| (es.iter().map(|&e| a[e].powi(2)).sum::<f64>() / es.len() as f64).sqrt();
        println!(
            "part {part}: {} edges, RL resid {:.4} (|RL| {:.4}), RA resid {:.4} (|RA| {:.4})",
            es.len(),
            r(&truth.rl, &fit.rl),
            mag(&truth.rl),
            r(&truth.ra, &fit.ra),
            mag(&truth.ra)
        );
    }
    // Model RLA on body edges, truth elsewhere.
    let mut mix = truth.clone();
    for e in 0..topo.n_edges() {
        if model.edge_part[e] == 0 {
            mix.rl[e] = fit.rl[e];
            mix.ra[e] = fit.ra[e];
        }
    }
    for (name, rla) in [
        ("model everywhere", fit.clone()),
        ("model on body edges only", mix),
    ] {
        let out = ev.reconstruct(&rest, &rla).unwrap();
        let m = rigid_align(&out, &mesh, None);
        let mut per = [0.0f64; 4];
        let mut cnt = [0usize; 4];
        let mut vpart = vec![0u8; mesh.len()];
        for (e, &[i, j]) in topo.edges.iter().enumerate() {
            for v in [i, j] {
                vpart[v as usize] = vpart[v as usize].max(model.edge_part[e]);
            }
        }
        for v in 0..mesh.len() {
            let d = norm(sub(m.apply(out[v]), mesh[v]));
            per[vpart[v] as usize] += d;
            cnt[vpart[v] as usize] += 1;
        }
        println!(
            "{name:<26}: mean error per part (body/face/lhand/rhand) mm: {:?}",
            (0..4)
                .map(|k| (1e3 * per[k] / cnt[k].max(1) as f64 * 10.0).round() / 10.0)
                .collect::<Vec<_>>()
        );
    }
}
