//! Marker solving on the committed 40-frame excerpts with the small model (both methods end
//! to end), the shipped marker sets, and bad input.
use std::path::{Path, PathBuf};

use panoman::Method;
use panoman_fit::ik::IkState;
use panoman_human::params::ShapeParams;
use panoman_mocap::c3d::{C3dWriteOptions, write_c3d};
use panoman_mocap::marker_map::surface_point;
use panoman_mocap::marker_map::{default_set_for, default_sets};
use panoman_mocap::solve::{MarkerSolver, SolveOptions};
use panoman_mocap::solve_run::{
    SolveRequest, initial_map, load_capture, parse_frames, solve_capture, write_solve,
};

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn model() -> panoman::Model {
    panoman::Model::load(panoman::training::small_model(None).expect("small model")).expect("loads")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("panoman-mocap-solve-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn request(markers: PathBuf, frames: &str, method: Method, folds: usize) -> SolveRequest {
    SolveRequest {
        markers,
        vsk: None,
        marker_map: None,
        frames: parse_frames(frames).expect("frames"),
        up: None,
        options: SolveOptions {
            method,
            calibration_frames: 8,
            held_out_folds: folds,
            held_out_step: 8,
            ..SolveOptions::default()
        },
    }
}

#[test]
fn shipped_sets_place_every_marker_on_the_small_template() {
    let m = model();
    let solver = MarkerSolver::new(&m, SolveOptions::default()).expect("solver");
    let sets = default_sets();
    assert_eq!(sets.len(), 2);
    assert_eq!(sets[0].markers.len(), 53);
    assert_eq!(sets[1].markers.len(), 43);
    for s in &sets {
        let map = s.place(solver.template(), None, None).expect("placed");
        assert_eq!(map.markers.len(), s.markers.len());
        let rest = &solver.template().vertices;
        let pts = solver.model_markers(&map, rest);
        // Markers sit outside the surface by their offset: left markers on +X, right on −X.
        for (pm, p) in map.markers.iter().zip(&pts) {
            let b = pm.barycentric;
            assert!((b[0] + b[1] + b[2] - 1.0).abs() < 1e-9 && b.iter().all(|x| *x >= -1e-9));
            if pm.name.starts_with('L') && pm.name != "LFHD" && pm.name != "LBHD" {
                assert!(p[0] > 0.0, "{} at {p:?}", pm.name);
            }
            if pm.name.starts_with('R') && !["RBAC", "RFHD", "RBHD"].contains(&pm.name.as_str()) {
                assert!(p[0] < 0.0, "{} at {p:?}", pm.name);
            }
        }
        let head = pts[map.markers.iter().position(|m| m.name == "LFHD").unwrap()];
        let toe = pts[map.markers.iter().position(|m| m.name == "LTOE").unwrap()];
        assert!(head[2] - toe[2] > 1.3, "head {head:?} toe {toe:?}");
    }
}

#[test]
fn lbs_solves_the_c3d_excerpt_with_held_out_error() {
    let m = model();
    let req = request(data("nick_freeform_001_head.c3d"), "0:40", Method::Lbs, 5);
    let out = solve_capture(&m, &req).expect("solve");
    let r = &out.report;
    assert_eq!(r.n_frames, 40);
    assert_eq!(r.marker_set, "cmu53");
    assert!(r.mean_residual_mm < 12.0, "{}", r.mean_residual_mm);
    let h = r.held_out_marker_error_mm.as_ref().expect("held out");
    assert!(
        h.mean.is_finite() && h.mean > r.mean_residual_mm && h.mean < 40.0,
        "{}",
        h.mean
    );
    assert!(h.per_marker.len() >= 50);
    assert!(h.method.contains("5-fold"));
    // Every 8th of the 40 frames, less those the calibration used (8, spread over the 40).
    assert!(h.method.contains("every 8-th solved frame"), "{}", h.method);
    assert!((1..=5).contains(&h.frames), "{}", h.frames);
    assert!(h.mean_inliers.is_finite() && h.observations[1] <= h.observations[0]);
    // The hands' and toes' markers are alone on their bones: unobservable once held out,
    // in `mean_all` but not in `mean`; the torso's are observable.
    assert!(h.observations[0] < h.observations[2] && h.mean_all.is_finite());
    for name in ["LIHAND", "ROHAND", "LTOE"] {
        assert!(
            h.unobservable.iter().any(|u| u == name),
            "{name}: {:?}",
            h.unobservable
        );
    }
    for name in ["STRN", "LFHD", "LKNE", "LELB"] {
        assert!(!h.unobservable.iter().any(|u| u == name), "{name}");
    }
    assert!(r.times.contains_key("tracking_warm_ik_ms_per_frame"));
    let dir = tmp("lbs");
    write_solve(&dir, &out, m.faces()).expect("written");
    let rep: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("report.json")).unwrap()).unwrap();
    for key in [
        "frames",
        "mean_residual_mm",
        "outliers",
        "times",
        "calibration",
        "per_marker_residual_mm",
    ] {
        assert!(rep.get(key).is_some(), "report.json lacks {key}");
    }
    assert!(rep["held_out_marker_error_mm"]["mean"].as_f64().unwrap() > 0.0);
    assert_eq!(rep["method"], "lbs");
    assert!(rep["times"]["calibration_s"].as_f64().unwrap() > 0.0);
    assert!(dir.join("mesh_00039.obj").is_file() && dir.join("params_00039.json").is_file());
    let map: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("marker_map.json")).unwrap()).unwrap();
    assert_eq!(map["topology"], "small");
    assert_eq!(map["markers"].as_array().unwrap().len(), 53);
    // The pose-dependent placements: one entry per marker that has one, its features named
    // by bone and axis, one slope (3-vector, m/rad) per feature.
    let pp: serde_json::Value =
        serde_json::from_slice(&std::fs::read(dir.join("pose_placement.json")).unwrap()).unwrap();
    let pp = pp.as_array().unwrap();
    assert_eq!(
        pp.len(),
        out.calibration.pose_placement.iter().flatten().count()
    );
    assert!(!pp.is_empty());
    for e in pp {
        let n = e["features"].as_array().unwrap().len();
        assert!(n >= 3 && n % 3 == 0, "{e}");
        assert_eq!(e["slopes_m_per_rad"].as_array().unwrap().len(), n);
        assert_eq!(e["mean_rad"].as_array().unwrap().len(), n);
    }
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn panoman_solves_the_csm_excerpt() {
    let m = model();
    let req = request(data("ThomasFechten_head.csm"), "0:40:2", Method::PanoMan, 3);
    let out = solve_capture(&m, &req).expect("solve");
    let r = &out.report;
    assert_eq!(r.n_frames, 20);
    assert_eq!(r.marker_set, "plugin_gait43");
    assert!(out.frames.iter().all(|f| f.params.is_some()));
    // RANK is mislabelled in these frames (≈ 0.2 m off): it is the outlier.
    assert!(r.outliers >= 20, "{}", r.outliers);
    assert!(r.per_marker_residual_mm["RANK"] > 100.0);
    let others: Vec<f64> = r
        .per_marker_residual_mm
        .iter()
        .filter(|(k, _)| k.as_str() != "RANK")
        .map(|(_, v)| *v)
        .collect();
    let mean = others.iter().sum::<f64>() / others.len() as f64;
    assert!(mean < 12.0, "{mean}");
    let h = r.held_out_marker_error_mm.as_ref().expect("held out");
    assert!(h.mean.is_finite() && h.folds == 3);
    for stage in ["ik", "shell_init", "shell_keypoints", "shell_params"] {
        let key = format!("tracking_warm_{stage}_ms_per_frame");
        assert!(r.times.contains_key(&key), "{key}: {:?}", r.times.keys());
    }
}

#[test]
fn unknown_marker_names_are_listed() {
    let names: Vec<String> = ["LFHD", "RFHD", "FOO1", "BAR2"]
        .iter()
        .map(|s| s.to_string())
        .collect();
    let e = default_set_for(&names).unwrap_err().to_string();
    assert!(
        e.contains("FOO1") && e.contains("BAR2") && !e.contains("LFHD,"),
        "{e}"
    );
    // The same through the solve of a file.
    let mut seq = load_capture(&data("nick_freeform_001_head.c3d"), None).unwrap();
    seq.names[3] = "XYZW".into();
    let dir = tmp("unknown");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("renamed.c3d");
    std::fs::write(&p, write_c3d(&seq, &C3dWriteOptions::default()).unwrap()).unwrap();
    let e = solve_capture(&model(), &request(p, "0:4", Method::Lbs, 0))
        .unwrap_err()
        .to_string();
    assert!(e.contains("XYZW") && e.contains("--marker-map"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn nan_frames_are_missing_markers() {
    let mut seq = load_capture(&data("nick_freeform_001_head.c3d"), None).unwrap();
    let nm = seq.n_markers();
    for f in 4..7 {
        for i in 0..nm {
            seq.positions[f * nm + i] = [f64::NAN; 3];
        }
    }
    for f in 0..12 {
        seq.positions[f * nm + (f % nm)] = [f64::NAN; 3];
    }
    let dir = tmp("nan");
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("gaps.c3d");
    std::fs::write(&p, write_c3d(&seq, &C3dWriteOptions::default()).unwrap()).unwrap();
    let out = solve_capture(&model(), &request(p, "0:12", Method::Lbs, 0)).expect("solve");
    assert_eq!(out.frames.len(), 12);
    for f in 4..7 {
        assert_eq!(out.report.frames[f].markers, 0);
        assert!(out.report.frames[f].mean_mm.is_nan());
    }
    assert!(out.report.frames[8].markers >= nm - 3);
    assert!(out.report.mean_residual_mm < 15.0);
    assert!(
        out.frames
            .iter()
            .all(|s| s.vertices.iter().flatten().all(|c| c.is_finite()))
    );
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn frame_ranges_parse() {
    assert_eq!(parse_frames("0:400:2").unwrap(), (0, Some(400), 2));
    assert_eq!(parse_frames("10:").unwrap(), (10, None, 1));
    assert_eq!(parse_frames("7").unwrap(), (7, Some(8), 1));
    assert!(parse_frames("5:3").is_err());
    assert!(parse_frames("0:10:0").is_err());
    assert!(parse_frames("a:b").is_err());
}

#[test]
fn marker_patches_are_gaussian_discs_around_the_surface_points() {
    use panoman_mocap::marker_map::{MarkerMap, PlacedMarker};
    use panoman_mocap::solve::marker_patches;
    // A 21 × 21 grid of 1 cm in the plane z = 0, two triangles per cell.
    let n = 21usize;
    let rest: Vec<[f64; 3]> = (0..n * n)
        .map(|k| [(k % n) as f64 * 0.01, (k / n) as f64 * 0.01, 0.0])
        .collect();
    let mut faces = Vec::new();
    for j in 0..n - 1 {
        for i in 0..n - 1 {
            let a = (j * n + i) as u32;
            faces.push([a, a + 1, a + n as u32]);
            faces.push([a + 1, a + n as u32 + 1, a + n as u32]);
        }
    }
    let map = MarkerMap {
        set: "test".into(),
        topology: "grid".into(),
        n_vertices: rest.len(),
        markers: vec![PlacedMarker {
            name: "M".into(),
            triangle: 2 * (10 * (n - 1) + 10) as u32,
            barycentric: [1.0, 0.0, 0.0],
            offset_m: 0.01,
            bone: "root".into(),
        }],
    };
    let p = surface_point(&faces, &rest, map.markers[0].triangle, [1.0, 0.0, 0.0]);
    assert_eq!(p, [0.1, 0.1, 0.0]);
    let sigma = 0.03;
    let patch = &marker_patches(&faces, &map, &rest, sigma)[0];
    // Every vertex within 2σ = 6 cm, none beyond, each weighted exp(−d²/2σ²).
    let inside = rest
        .iter()
        .filter(|q| (q[0] - 0.1).hypot(q[1] - 0.1) < 2.0 * sigma)
        .count();
    assert_eq!(patch.len(), inside);
    for &(v, g) in patch {
        let q = rest[v as usize];
        let d = (q[0] - 0.1).hypot(q[1] - 0.1);
        assert!(d < 2.0 * sigma);
        assert!((g - (-0.5 * d * d / (sigma * sigma)).exp()).abs() < 1e-12);
    }
    assert!(marker_patches(&faces, &map, &rest, 0.0)[0].is_empty());
}

#[test]
fn ridge_fit_recovers_a_linear_placement_and_shrinks_it() {
    use panoman_mocap::solve::ridge_fit;
    // y = y0 + B x on two features, unequal weights.
    let b = [[0.03, -0.01, 0.02], [0.0, 0.05, -0.04]];
    let y0 = [0.1, 0.2, 0.3];
    let samples: Vec<(Vec<f64>, [f64; 3], f64)> = (0..12)
        .map(|k| {
            let x = vec![(k as f64 * 0.7).sin(), (k as f64 * 1.3).cos() * 0.5];
            let y: [f64; 3] = std::array::from_fn(|c| y0[c] + b[0][c] * x[0] + b[1][c] * x[1]);
            (x, y, 1.0 + (k % 3) as f64)
        })
        .collect();
    let (mean, slopes) = ridge_fit(&samples, 0.0).expect("fit");
    let wsum: f64 = samples.iter().map(|s| s.2).sum();
    let m0: f64 = samples.iter().map(|s| s.2 * s.0[0]).sum::<f64>() / wsum;
    assert!((mean[0] - m0).abs() < 1e-12);
    for k in 0..2 {
        for c in 0..3 {
            assert!((slopes[k][c] - b[k][c]).abs() < 1e-10, "{slopes:?}");
        }
    }
    // A ridge shrinks the slopes toward 0 (‖B_λ‖ decreases with λ).
    let norm = |s: &[[f64; 3]]| s.iter().flatten().map(|v| v * v).sum::<f64>();
    let s1 = ridge_fit(&samples, 0.01).expect("fit").1;
    let s2 = ridge_fit(&samples, 1.0).expect("fit").1;
    assert!(norm(&s2) < norm(&s1) && norm(&s1) < norm(&slopes));
    // A feature that never varies: singular without a ridge, slope 0 with one.
    let flat: Vec<_> = samples
        .iter()
        .map(|(x, y, w)| (vec![x[0], 0.25], *y, *w))
        .collect();
    assert!(ridge_fit(&flat, 0.0).is_none());
    assert_eq!(ridge_fit(&flat, 0.1).expect("fit").1[1], [0.0; 3]);
    assert!(ridge_fit(&[], 0.1).is_none());
}

/// The pose-dependent placement can only follow the markers closer where they slide (slopes
/// 0 give the fixed placement; the IRLS alternation makes this an expectation, about
/// 8.4 vs 8.6 mm here, not a theorem); placed for a marker's mean pose it sits at its fixed
/// surface point, and a pose away from the mean moves it.
#[test]
fn pose_dependent_placement_follows_the_markers_closer() {
    let m = model();
    let seq = load_capture(&data("ThomasFechten_head.csm"), None).expect("capture");
    let names = &seq.names;
    let frames: Vec<usize> = (0..seq.n_frames()).collect();
    let active = vec![true; names.len()];
    let calibrate = |ridge: f64| {
        let solver = MarkerSolver::new(
            &m,
            SolveOptions {
                method: Method::Lbs,
                calibration_frames: 40,
                calibration_rounds: 6,
                pose_placement_ridge: ridge,
                ..SolveOptions::default()
            },
        )
        .expect("solver");
        let map = initial_map(&solver, names, None, None).expect("placed");
        let cal = solver
            .calibrate(&seq, &frames, &map, &active)
            .expect("calibrated");
        (solver, cal)
    };
    let (_, fixed) = calibrate(0.0);
    let (solver, posed) = calibrate(0.05);
    assert!(fixed.pose_placement.iter().all(Option::is_none));
    let n_posed = posed.pose_placement.iter().flatten().count();
    assert!(n_posed >= names.len() / 2, "{n_posed} of {}", names.len());
    assert!(
        posed.mean_residual_mm < fixed.mean_residual_mm,
        "{} vs {}",
        posed.mean_residual_mm,
        fixed.mean_residual_mm
    );
    let faces = &solver.template().faces;
    let (pps, rest) = posed.placement().expect("pose-dependent");
    let mut moved = 0;
    for (i, pp) in pps.iter().enumerate() {
        let Some(pp) = pp else { continue };
        let name = &posed.map.markers[i].name;
        let mut st = IkState::rest(solver.bone_names().len(), &ShapeParams::default());
        for (&(b, a), mu) in pp.features.iter().zip(&pp.mean) {
            st.angles[b][a] = *mu;
        }
        assert_eq!(pp.rest_point(&st.angles), pp.at_mean, "{name}");
        let at = |st: &IkState| {
            let m = &solver.posed_map(&posed.map, pps, rest, st).markers[i];
            surface_point(faces, rest, m.triangle, m.barycentric)
        };
        let p = at(&st);
        let d = (0..3).map(|c| (p[c] - pp.at_mean[c]).powi(2)).sum::<f64>();
        assert!(d.sqrt() < 1e-9, "{name}: {p:?} vs {:?}", pp.at_mean);
        for &(b, a) in &pp.features {
            st.angles[b][a] += 0.5;
        }
        let q = at(&st);
        if (0..3).map(|c| (q[c] - p[c]).powi(2)).sum::<f64>() > 1e-6 {
            moved += 1;
        }
    }
    assert!(moved > 0);
}
