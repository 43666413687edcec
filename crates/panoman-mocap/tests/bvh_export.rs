//! The rig's motion written as BVH reads back (our reader) with the rig's joint positions.
use std::path::Path;

use panoman_human::params::ShapeParams;
use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
use panoman_mocap::bvh_export::{posed_bone_heads, rig_motion_bvh};
use panoman_mocap::retarget::CmuRetarget;

#[test]
fn exported_bvh_reproduces_the_rig_joints() {
    let model = panoman::Model::load(panoman::training::small_model(None).unwrap()).unwrap();
    let g = model.rig().expect("embedded rig").generator.clone();
    let mut shape = ShapeParams::default();
    shape.phenotype.proportions = 0.7;
    let identity = g.identity(&shape).unwrap();
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&src).unwrap().scaled(CMU_UNIT_M);
    let rt = CmuRetarget::calibrate(&identity, &shape, &bvh, 0).unwrap();
    let poses: Vec<_> = (0..bvh.n_frames().min(12))
        .map(|f| rt.params(&bvh, f).pose)
        .collect();
    let out = rig_motion_bvh(&identity, &poses, 1.0 / 120.0).unwrap();
    assert_eq!(out.joints.len(), g.bone_names().len());
    let dir = std::env::temp_dir().join(format!("panoman-bvh-export-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("rig.bvh");
    out.write(&p).unwrap();
    let back = read_bvh(&p).unwrap();
    assert_eq!(back.n_frames(), poses.len());
    let mut worst = 0.0f64;
    let mut moved = 0.0f64;
    for (f, pose) in poses.iter().enumerate() {
        let rig = posed_bone_heads(&identity, pose);
        let ours = back.joint_positions(f);
        let first = back.joint_positions(0);
        for (j, name) in g.bone_names().iter().enumerate() {
            let k = back.joint_index(name).unwrap();
            let d = (0..3)
                .map(|i| (rig[j][i] - ours[k][i]).powi(2))
                .sum::<f64>()
                .sqrt();
            worst = worst.max(d);
            moved = moved.max(
                (0..3)
                    .map(|i| (ours[k][i] - first[k][i]).abs())
                    .fold(0.0, f64::max),
            );
        }
    }
    assert!(worst < 1e-6, "max joint difference {worst} m");
    assert!(moved > 0.05, "the clip moves ({moved} m)");
    assert!(rig_motion_bvh(&identity, &[], 0.1).is_err());
    let _ = std::fs::remove_dir_all(&dir);
}
