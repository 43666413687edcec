//! Sequence benchmark (issue acceptance: warm-started tracking time per frame).
//!
//! ```sh
//! cargo run --release -p panoman-fit --example track_bench -- MODEL [N_FRAMES] [SEED]
//! ```
//!
//! Generates a held-out motion clip ([`panoman_human::clip`], 4 keyframes, body + expressions +
//! gestures on a random identity), tracks it from the exact TC-133 keypoints of every frame with
//! [`Tracking`] (cold first frame, warm-started frames after it), and prints the median, min and
//! max time per stage over the warm frames, and the mean per-vertex error (mm) of PanoMan and of
//! the warm-started LBS rig (IK alone) against the truth.
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Constraints, FrameSolver, LbsRig, Tracking};
use panoman_human::clip::{Clip, ClipConfig};
use panoman_human::keypoints::KeypointsFile;
use panoman_mesh::geom::{V3, norm, sub};
use panoman_model::model::PanoManModel;
use std::collections::BTreeMap;

fn mean_mm(a: &[V3], b: &[V3]) -> f64 {
    a.iter().zip(b).map(|(p, q)| norm(sub(*p, *q))).sum::<f64>() / a.len() as f64 * 1e3
}

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let Some(model_path) = a.get(1) else {
        eprintln!("usage: track_bench MODEL [N_FRAMES] [SEED]");
        std::process::exit(2);
    };
    let n_frames: usize = a.get(2).map_or(24, |s| s.parse().expect("N_FRAMES"));
    let seed: u64 = a.get(3).map_or(7, |s| s.parse().expect("SEED"));
    let model = PanoManModel::load(model_path.as_ref()).expect("model");
    let assets = panoman_human::assets::ensure_default().expect("assets");
    let mut solver = FrameSolver::new(
        std::sync::Arc::new(model.clone()),
        LbsRig::load(&assets, &model).expect("rig"),
    )
    .expect("solver");
    let rig = solver.rig();
    let clip = Clip::generate(&ClipConfig {
        seed,
        n_frames,
        n_keyframes: 4,
    })
    .expect("clip");
    let (_, frames) = clip
        .meshes(&rig.generator, &rig.map, rig.topology)
        .expect("clip meshes");
    let mut seq = Tracking::default();
    let mut lbs_state: Option<IkState> = None;
    let mut times: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let (mut e_pm, mut e_lbs) = (Vec::new(), Vec::new());
    for (f, truth) in frames.iter().enumerate() {
        let c =
            Constraints::from_keypoints(KeypointsFile::from_all(&model.keypoints.evaluate(truth)));
        let (ikr, fit) = seq.fit_next(&mut solver, &c).expect("fit");
        let lbs = solver
            .ik_fit(
                &c,
                &IkConfig {
                    initial_state: lbs_state.take(),
                    ..IkConfig::default()
                },
            )
            .expect("LBS");
        lbs_state = Some(lbs.state.clone());
        e_pm.push(mean_mm(&fit.vertices, truth));
        e_lbs.push(mean_mm(&lbs.posed, truth));
        if f == 0 {
            println!(
                "cold frame: {:.0} ms",
                (ikr.seconds + fit.report.seconds) * 1e3
            );
            continue;
        }
        times.entry("ik".into()).or_default().push(ikr.seconds);
        for s in &fit.report.stages {
            times.entry(s.name.clone()).or_default().push(s.seconds);
        }
        times
            .entry("total".into())
            .or_default()
            .push(ikr.seconds + fit.report.seconds);
    }
    println!("{} warm frames, full template:", frames.len() - 1);
    for (k, v) in &mut times {
        v.sort_by(f64::total_cmp);
        println!(
            "  {k:>10}: median {:6.1} ms   min {:6.1}   max {:6.1}",
            v[v.len() / 2] * 1e3,
            v[0] * 1e3,
            v[v.len() - 1] * 1e3
        );
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    println!(
        "mean per-vertex error: PanoMan {:.2} mm, LBS {:.2} mm",
        mean(&e_pm),
        mean(&e_lbs)
    );
}
