//! Profiling aid: tracks the eval's held-out clip (seed, frames) and prints per-stage warm
//! times and the mean vertex error.
//! `cargo run --release -p panoman --example track_profile -- MODEL [FRAMES] [SEED]`
use panoman::{FitRequest, IkStart, Method, Model, Targets, Tracker};
use panoman_human::clip::{Clip, ClipConfig};
use std::collections::BTreeMap;

fn main() -> panoman::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let model = Model::load(&args[1])?;
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(72);
    let seed: u64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(0);
    let rig = model.inner().rig.as_ref().unwrap();
    let clip = Clip::generate(&ClipConfig {
        seed,
        n_frames: n,
        n_keyframes: 5,
    })
    .unwrap();
    let (_, truths) = clip
        .meshes(&rig.generator, &rig.map, model.output_topology()?)
        .unwrap();
    let mut tracker = Tracker::new(
        &model,
        FitRequest {
            method: Method::PanoMan,
            ..Default::default()
        },
        IkStart::Warm,
    )?;
    let mut stages: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut errs = Vec::new();
    let mut totals = Vec::new();
    for (f, truth) in truths.iter().enumerate() {
        let out = tracker.track(&Targets::from_keypoints(&model.keypoints(truth)?))?;
        let e: f64 = out
            .vertices
            .iter()
            .zip(truth)
            .map(|(a, b)| panoman_mesh::geom::norm(panoman_mesh::geom::sub(*a, *b)))
            .sum::<f64>();
        errs.push(1e3 * e / truth.len() as f64);
        if f > 0 {
            totals.push(out.report.total_seconds);
            let v = serde_json::to_value(&out.report).unwrap();
            if let Some(st) = v["stages"].as_array() {
                for s in st {
                    stages
                        .entry(s["name"].as_str().unwrap_or("?").to_string())
                        .or_default()
                        .push(s["seconds"].as_f64().unwrap_or(0.0));
                }
            }
            if let Some(x) = v["ik"]["seconds"].as_f64() {
                stages.entry("ik".into()).or_default().push(x);
            }
            stages
                .entry("fit_seconds".into())
                .or_default()
                .push(out.report.fit_seconds);
        }
    }
    let med = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    println!(
        "frames {n}, mean err {:.3} mm, warm total median {:.1} ms",
        errs.iter().sum::<f64>() / n as f64,
        1e3 * med(&mut totals)
    );
    for (k, mut v) in stages {
        println!("  {k:<24} {:.1} ms", 1e3 * med(&mut v));
    }
    Ok(())
}
