//! `Tracker::checkpoint` / `Tracker::restore`: a tracker restored from a checkpoint taken
//! after frame k fits frames k+1… bit-identically to the tracker that never stopped (PanoMan
//! and the LBS baseline), and damaged or mismatched checkpoints are refused.
use panoman::{FitRequest, Generator, IkStart, Method, Model, Targets, Tracker};

fn clip(model: &Model, n: usize) -> Vec<Targets> {
    let g = Generator::from_model(model).unwrap();
    (0..n)
        .map(|f| {
            let u = f as f64 / (n - 1) as f64;
            let p = g
                .parse_params(&format!(
                    r#"{{"pose_euler_xyz_deg": {{"upperarm01.R": [0, 0, {:.4}]}},
                        "root_rotation_z_deg": {:.4}}}"#,
                    50.0 * u,
                    20.0 * u
                ))
                .unwrap();
            let mesh = g.generate(&p, model.output_topology().unwrap()).unwrap();
            Targets::from_keypoints(&model.keypoints(&mesh).unwrap())
        })
        .collect()
}

#[test]
fn restored_tracker_continues_bit_identically() {
    let model = Model::load(panoman::training::small_model(None).unwrap()).unwrap();
    let frames = clip(&model, 8);
    for method in [Method::PanoMan, Method::Lbs] {
        let req = FitRequest {
            method,
            ..Default::default()
        };
        let mut full = Tracker::new(&model, req.clone(), IkStart::Warm).unwrap();
        let mut cut = Tracker::new(&model, req.clone(), IkStart::Warm).unwrap();
        let mut bytes = Vec::new();
        for (f, t) in frames.iter().enumerate() {
            let a = full.track(t).unwrap();
            if f < 3 {
                cut.track(t).unwrap();
                bytes = cut.checkpoint();
                continue;
            }
            if f == 3 {
                cut = Tracker::new(&model, req.clone(), IkStart::Warm).unwrap();
                cut.restore(&bytes).unwrap();
                assert_eq!(cut.frames(), 3);
            }
            let b = cut.track(t).unwrap();
            assert_eq!(a.vertices, b.vertices, "{method:?} frame {f}");
            assert_eq!(a.params, b.params, "{method:?} frame {f}");
        }
        // Damaged (one bit), truncated, or another IK start / method: refused, unchanged.
        let mut fresh = Tracker::new(&model, req.clone(), IkStart::Warm).unwrap();
        let mut bad = bytes.clone();
        bad[40] ^= 1;
        assert!(
            fresh
                .restore(&bad)
                .unwrap_err()
                .to_string()
                .contains("checksum")
        );
        assert!(fresh.restore(&bytes[..bytes.len() / 2]).is_err());
        assert_eq!(fresh.frames(), 0);
        let mut cold = Tracker::new(&model, req.clone(), IkStart::Cold).unwrap();
        assert!(
            cold.restore(&bytes)
                .unwrap_err()
                .to_string()
                .contains("--cold")
        );
    }
}
