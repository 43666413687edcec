//! `panoman::eval::run_all` on a small dataset and the model trained on it: every experiment
//! reports, the progress names each one, and the figures depend only on the seed.
use panoman::eval::{EvalConfig, EvalPreset, EvalProgress, EvalSummary, run_all};
use panoman_human::assets;
use panoman_human::dataset::SynthConfig;
use panoman_model::train::TrainConfig;

/// The summary without its timings (the only numbers that change from run to run).
fn without_timings(s: &EvalSummary) -> serde_json::Value {
    let mut v = serde_json::to_value(s).unwrap();
    v["meta"]["seconds"] = 0.into();
    v["timing"] = serde_json::Value::Null;
    for k in ["first_frame_s", "warm_s"] {
        v["clip"][k] = serde_json::Value::Null;
    }
    for k in ["cold_fit_median_s", "warm_frame_median_s"] {
        v["headline"][k] = serde_json::Value::Null;
    }
    if let Some(cases) = v["stress"]["cases"].as_array_mut() {
        for c in cases {
            c["seconds"] = serde_json::Value::Null;
        }
    }
    v
}

#[test]
fn small_evaluation_reports_every_experiment_and_repeats_exactly() {
    let dir = std::env::temp_dir().join(format!("panoman-eval-lib-{}", std::process::id()));
    let data = dir.join("H");
    let model = dir.join("M.safetensors");
    let assets = assets::ensure_default().unwrap();
    let mut synth = SynthConfig::preset("small").unwrap();
    synth.seed = 3;
    panoman::training::synthesize(&assets, &synth, &data, &mut |_, _| {}).unwrap();
    let trained = panoman::training::train(
        &assets,
        &data,
        &TrainConfig::preset("small").unwrap(),
        &mut |_| {},
    )
    .unwrap();
    trained.output.model.save(&model).unwrap();

    let mut preset = EvalPreset::small();
    preset.clip_frames = 3;
    preset.twist_angles = vec![0.0, 150.0, 180.0];
    let cfg = EvalConfig {
        stress_without_feet: false,
        stress_representation: false,
        model: model.clone(),
        data: data.clone(),
        preset,
        seed: 5,
    };
    let mut experiments = Vec::new();
    let mut steps = 0usize;
    let out = run_all(&cfg, &assets, &mut |p| match p {
        EvalProgress::Experiment(name) => experiments.push(name.to_string()),
        EvalProgress::Step { done, total } => {
            assert!(done >= 1 && done <= total);
            steps += 1;
        }
        EvalProgress::Detail(_) => {}
    })
    .unwrap();
    assert_eq!(experiments.len(), 7, "{experiments:?}");
    assert!(steps >= 2 * 2 + 3, "{steps} steps");

    let s = &out.summary;
    assert_eq!(s.fit_held_out.people, 2);
    assert_eq!(s.clip.frames, 3);
    assert_eq!(out.clip_frames.len(), 3);
    assert!(out.meshes.fit_example.is_some() && out.meshes.error_map.is_some());
    // Forearm renders at the preset's angles among 90°, 150°, 180°.
    let angles: Vec<f64> = out
        .meshes
        .twist_forearm
        .iter()
        .map(|r| r.angle_deg)
        .collect();
    assert_eq!(angles, [150.0, 180.0]);
    for e in [s.fit_held_out.exact.panoman, s.fit_held_out.exact.lbs] {
        assert!(e.all_mean.is_finite() && e.all_mean > 0.0 && e.all_mean < 100.0);
    }
    assert_eq!(s.twist.limbs.len(), 4);
    assert!(s.twist.limbs.iter().all(|l| l.rows.len() == 3));
    assert!(
        s.headline
            .forearm_twist_120_170_min_radius_ratio_panoman
            .is_some()
    );
    assert_eq!(s.timing.stages["total"].runs, 2);
    assert_eq!(
        s.headline.fit_exact_mean_mm.panoman,
        s.fit_held_out.exact.panoman.all_mean
    );
    assert_eq!(s.meta.preset, "small");
    // The stress set: one case of each kind, each fitted and measured; the twist case has its
    // forearm and shoulder measures; every case is rendered.
    let kinds: Vec<&str> = s.stress.cases.iter().map(|c| c.kind.as_str()).collect();
    assert_eq!(
        kinds,
        [
            "composite",
            "whole-body",
            "extreme shape",
            "twist",
            "posture",
            "contact"
        ],
        "{kinds:?}"
    );
    for c in &s.stress.cases {
        assert!(
            c.errors.panoman.all_mean.is_finite() && c.errors.lbs.all_mean > 0.0,
            "{c:?}"
        );
        assert!(c.shell_steps_tried > 0 && c.shell_steps_accepted <= c.shell_steps_tried);
        assert_eq!(c.converged, c.reason.is_none());
        // The six regions partition the vertices, so the mean over all vertices is a
        // weighted mean of the region means and lies between the smallest and the largest.
        for (r, all) in [
            (c.regions.panoman.values(), c.errors.panoman.all_mean),
            (c.regions.lbs.values(), c.errors.lbs.all_mean),
        ] {
            assert!(r.iter().all(|x| x.is_finite() && *x >= 0.0), "{r:?}");
            let (lo, hi) = r
                .iter()
                .fold((f64::INFINITY, 0.0f64), |(a, b), &x| (a.min(x), b.max(x)));
            assert!(lo - 1e-9 <= all && all <= hi + 1e-9, "{all} outside {r:?}");
        }
    }
    let tw = s.stress.cases[3].twist.expect("twist measures");
    assert!(tw.min_radius_ratio.panoman > 0.0 && tw.shoulder_mean_mm.lbs.is_finite());
    assert_eq!(out.meshes.stress.len(), s.stress.cases.len());
    assert!(s.stress.cases.iter().any(|c| c.name == s.stress.worst_case));
    // Round trip through the JSON layout.
    let text = serde_json::to_string(s).unwrap();
    let back: EvalSummary = serde_json::from_str(&text).unwrap();
    assert_eq!(serde_json::to_string(&back).unwrap(), text);

    // Same model, data, preset and seed: the same figures.
    let again = run_all(&cfg, &assets, &mut |_| {}).unwrap();
    assert_eq!(without_timings(&again.summary), without_timings(s));
    let _ = std::fs::remove_dir_all(&dir);
}
