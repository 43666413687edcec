//! Retargets a CMU BVH (e.g. `01_01.bvh`, frame 0 a T-pose) to the generator's rig and
//! measures the rig's joint positions (posed bone heads) against the BVH's own forward
//! kinematics after a similarity alignment (see `panoman_mocap::retarget`).
//!
//! `cargo run --release -p panoman-mocap --example retarget_cmu -- PATH/01_01.bvh [STRIDE]`

use std::path::PathBuf;

use panoman_human::generator::Generator;
use panoman_human::params::ShapeParams;
use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
use panoman_mocap::retarget::{CMU_EVAL_JOINTS, CmuRetarget, retarget_error};

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
    let shape = ShapeParams::default();
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
    if std::env::var_os("RETARGET_DEBUG").is_some() {
        for k in (0..rig.len()).step_by((rig.len() / 20).max(1)) {
            let ek = retarget_error(&rig[k..k + 1], &truth[k..k + 1]);
            println!(
                "  frame {:5}: {:6.1} mm {:?}",
                k * stride,
                ek.global_mean_mm,
                ek.per_joint_mm
                    .iter()
                    .map(|x| x.round())
                    .collect::<Vec<_>>()
            );
        }
    }
    if std::env::var_os("RETARGET_DEBUG").is_some() {
        use panoman_mocap::retarget::CMU_CALIBRATION;
        let t0 = std::time::Instant::now();
        let _ = generator.identity(&shape)?;
        println!("identity in {:.3} s", t0.elapsed().as_secs_f64());
        for f in [0usize, 500, 1000, 2000] {
            let posed = identity.pose(&rt.params(&bvh, f).pose);
            let bp = bvh.joint_positions(f);
            let mut worst = 0.0f64;
            for (rc, re, bj, bk) in CMU_CALIBRATION {
                let c = names.iter().position(|n| n == rc).unwrap();
                let e = names.iter().position(|n| n == re).unwrap();
                let d = panoman_mesh::geom::normalize(panoman_mesh::geom::sub(
                    posed.bone_heads[e],
                    posed.bone_heads[c],
                ));
                let t = panoman_mesh::geom::sub(
                    bp[bvh.joint_index(bk).unwrap()],
                    bp[bvh.joint_index(bj).unwrap()],
                );
                let t =
                    panoman_mesh::geom::normalize(panoman_mesh::geom::matvec(&rt.bvh_to_rig, t));
                worst = worst.max(
                    panoman_mesh::geom::dot(d, t)
                        .clamp(-1.0, 1.0)
                        .acos()
                        .to_degrees(),
                );
            }
            println!("  frame {f}: worst segment direction error {worst:.4}°");
        }
    }
    let e = retarget_error(&rig, &truth);
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
