//! CMU → rig retarget: Euler conversion, similarity alignment, and on the committed BVH
//! excerpt (with the generator's assets, fetched on first use like the other crates' tests)
//! that every calibrated segment of the rig points exactly where the BVH's does.

use std::path::Path;

use panoman_human::generator::Generator;
use panoman_human::params::ShapeParams;
use panoman_mesh::geom::{dot, matvec, normalize, sub};
use panoman_mesh::rotation::euler_xyz_deg;
use panoman_mocap::bvh::{CMU_UNIT_M, read_bvh};
use panoman_mocap::retarget::{CMU_CALIBRATION, CmuRetarget, retarget_error, similarity_align};

#[test]
fn similarity_recovers_a_known_map() {
    let r = euler_xyz_deg([20.0, -35.0, 70.0]);
    let a: Vec<[f64; 3]> = (0..7)
        .map(|i| {
            let x = i as f64;
            [x.sin(), (2.0 * x).cos(), 0.3 * x]
        })
        .collect();
    let b: Vec<[f64; 3]> = a
        .iter()
        .map(|&p| {
            let q = matvec(&r, p);
            [1.7 * q[0] + 0.1, 1.7 * q[1] - 2.0, 1.7 * q[2] + 0.5]
        })
        .collect();
    let s = similarity_align(&a, &b);
    assert!((s.scale - 1.7).abs() < 1e-12);
    let e = retarget_error(&[a], &[b]);
    assert!(e.global_mean_mm < 1e-9 && e.per_frame_mean_mm < 1e-9);
    assert!((e.global_scale - 1.7).abs() < 1e-12);
}

#[test]
fn calibrated_segments_follow_the_bvh() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&path).unwrap().scaled(CMU_UNIT_M);
    let g = Generator::load_default().unwrap();
    let shape = ShapeParams::default();
    let id = g.identity(&shape).unwrap();
    let rt = CmuRetarget::calibrate(&id, &shape, &bvh, 0).unwrap();
    assert!((0.8..1.2).contains(&rt.scale), "{}", rt.scale);
    let names = g.bone_names();
    let bone = |n: &str| names.iter().position(|b| b == n).unwrap();
    for f in 0..bvh.n_frames() {
        let p = rt.params(&bvh, f);
        p.pose.validate(names).unwrap();
        let posed = id.pose(&p.pose);
        let bp = bvh.joint_positions(f);
        for (rc, re, bj, bk) in CMU_CALIBRATION {
            let d = normalize(sub(posed.bone_heads[bone(re)], posed.bone_heads[bone(rc)]));
            let (j, k) = (bvh.joint_index(bj).unwrap(), bvh.joint_index(bk).unwrap());
            let t = normalize(matvec(&rt.bvh_to_rig, sub(bp[k], bp[j])));
            // Unit vectors: 1 − cos θ ≈ θ²/2, so 1e-12 is an angle below 1.5e-6 rad.
            assert!(1.0 - dot(d, t) < 1e-12, "frame {f} {rc}: cos {}", dot(d, t));
        }
        // The BVH hips (scaled into the rig) stay where the rig's calibration put them:
        // the rig's hip centre moves with the BVH's.
        if f > 0 {
            let c =
                |p: &[[f64; 3]], l: usize, r: usize| [0, 1, 2].map(|k| 0.5 * (p[l][k] + p[r][k]));
            let rig_c = c(
                &posed.bone_heads,
                bone("upperleg01.L"),
                bone("upperleg01.R"),
            );
            let p0 = id.pose(&rt.params(&bvh, 0).pose);
            let rig_c0 = c(&p0.bone_heads, bone("upperleg01.L"), bone("upperleg01.R"));
            let (l, r) = (
                bvh.joint_index("LeftUpLeg").unwrap(),
                bvh.joint_index("RightUpLeg").unwrap(),
            );
            let b0 = bvh.joint_positions(0);
            let bm = matvec(&rt.bvh_to_rig, sub(c(&bp, l, r), c(&b0, l, r)));
            let rm = sub(rig_c, rig_c0);
            // Not exact: the rig's hip centre sits elsewhere relative to the root than the
            // BVH's; over 40 frames of slow motion the two displacements agree to 2 cm.
            for k in 0..3 {
                assert!(
                    (rm[k] - rt.scale * bm[k]).abs() < 0.02,
                    "frame {f}: {rm:?} vs {bm:?}"
                );
            }
        }
    }
}

#[test]
fn shape_fit_reduces_the_joint_error_and_respects_ranges() {
    use panoman_mocap::retarget::{CMU_SHAPE_KNOBS, ShapeKnob, fit_cmu_shape};
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/01_01_head.bvh");
    let bvh = read_bvh(&path).unwrap().scaled(CMU_UNIT_M);
    let g = Generator::load_default().unwrap();
    let frames = [0, 13, 26, 39];
    let fit = fit_cmu_shape(&g, &ShapeParams::default(), &bvh, &frames, 8).unwrap();
    // The default identity's proportions differ from the CMU subject's by several cm.
    assert!(fit.before_mm > 25.0, "{}", fit.before_mm);
    assert!(
        fit.after_mm < 0.6 * fit.before_mm,
        "{} → {}",
        fit.before_mm,
        fit.after_mm
    );
    for k in CMU_SHAPE_KNOBS {
        if let ShapeKnob::Changes(labels) = k {
            for l in labels {
                let v = fit.shape.local_changes.get(*l).copied().unwrap();
                assert!((-1.0..=1.0).contains(&v), "{l} = {v}");
            }
        }
    }
    fit.shape.validate().unwrap();
}
