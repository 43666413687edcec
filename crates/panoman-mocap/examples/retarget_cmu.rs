//! Retargets a CMU BVH (e.g. `01_01.bvh`, frame 0 a T-pose) to the generator's rig and
//! measures the rig's joint positions (posed bone heads) against the BVH's own forward
//! kinematics after a similarity alignment (see `panoman_mocap::retarget`).
//!
//! `cargo run --release -p panoman-mocap --example retarget_cmu -- PATH/01_01.bvh [STRIDE]`
//!
//! The identity's shape is first fitted to the clip (24 frames spread over it, see
//! `fit_cmu_shape`); set `RETARGET_NO_SHAPE=1` to keep the default identity (uniform scale
//! only).

use std::path::PathBuf;

use panoman_human::generator::Generator;
use panoman_human::params::ShapeParams;
use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
use panoman_mocap::retarget::{CMU_EVAL_JOINTS, CmuRetarget, fit_cmu_shape, retarget_error};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().ok_or("usage: retarget_cmu BVH [STRIDE]")?);
    let stride: usize = args
        .next()
        .map(|s| s.parse())
        .transpose()?
        .unwrap_or(1)
        .max(1);
    let bvh = read_bvh(&path)?.scaled(CMU_UNIT_M);
    let generator = Generator::load_default()?;
    let mut shape = ShapeParams::default();
    let mut fit_frames: Vec<usize> = Vec::new();
    if std::env::var_os("RETARGET_NO_SHAPE").is_none() {
        // Shape fit on 24 frames spread over the clip (frame 0 among them).
        let n = bvh.n_frames();
        fit_frames = (0..24).map(|k| k * (n - 1) / 23).collect();
        let t = std::time::Instant::now();
        let fit = fit_cmu_shape(&generator, &shape, &bvh, &fit_frames, 30)?;
        println!(
            "shape fit on {} frames: {:.1} → {:.1} mm in {} iterations, {:.1} s; {:?} {:?}",
            fit_frames.len(),
            fit.before_mm,
            fit.after_mm,
            fit.iterations,
            t.elapsed().as_secs_f64(),
            fit.shape.phenotype.get("proportions"),
            fit.shape.local_changes
        );
        shape = fit.shape;
    }
    let identity = generator.identity(&shape)?;
    let rt = CmuRetarget::calibrate(&identity, &shape, &bvh, 0)?;
    println!(
        "{}: {} frames, rig scale s = {:.4}",
        path.display(),
        bvh.n_frames(),
        rt.scale
    );
    let names = generator.bone_names();
    let rig_idx: Vec<usize> = CMU_EVAL_JOINTS
        .iter()
        .map(|(_, b)| names.iter().position(|n| n == b).ok_or("bone"))
        .collect::<Result<_, _>>()?;
    let bvh_idx: Vec<usize> = CMU_EVAL_JOINTS
        .iter()
        .map(|(j, _)| bvh.joint_index(j).ok_or("joint"))
        .collect::<Result<_, _>>()?;
    let (mut rig, mut truth) = (Vec::new(), Vec::new());
    let t = std::time::Instant::now();
    for f in (0..bvh.n_frames()).step_by(stride) {
        let p = rt.params(&bvh, f);
        p.pose.validate(names)?;
        let posed = identity.pose(&p.pose);
        rig.push(rig_idx.iter().map(|&b| posed.bone_heads[b]).collect());
        let bp = bvh.joint_positions(f);
        truth.push(bvh_idx.iter().map(|&j| bp[j]).collect());
    }
    let e0 = retarget_error(&rig[..1], &truth[..1]);
    println!(
        "calibration frame: mean {:.1} mm after its similarity",
        e0.global_mean_mm
    );
    let e = retarget_error(&rig, &truth);
    if !fit_frames.is_empty() {
        // The frames the shape was not fitted on.
        let keep: Vec<usize> = (0..rig.len())
            .filter(|k| !fit_frames.contains(&(k * stride)))
            .collect();
        let pick = |v: &[Vec<[f64; 3]>]| keep.iter().map(|&k| v[k].clone()).collect::<Vec<_>>();
        let h = retarget_error(&pick(&rig), &pick(&truth));
        println!(
            "on the {} frames not used by the shape fit: mean {:.1} mm (one similarity), {:.1} mm (per frame)",
            keep.len(),
            h.global_mean_mm,
            h.per_frame_mean_mm
        );
    }
    println!(
        "{} frames retargeted and posed in {:.1} s",
        rig.len(),
        t.elapsed().as_secs_f64()
    );
    println!(
        "joint error after one similarity for the clip: mean {:.1} mm, max {:.1} mm (scale {:.4}); per-frame similarity: mean {:.1} mm",
        e.global_mean_mm, e.global_max_mm, e.global_scale, e.per_frame_mean_mm
    );
    for ((j, b), m) in CMU_EVAL_JOINTS.iter().zip(&e.per_joint_mm) {
        println!("  {j:>13} ↔ {b:<13} {m:6.1} mm");
    }
    Ok(())
}
