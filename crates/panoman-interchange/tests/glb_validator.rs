//! GLB exports checked by the Khronos glTF-Validator (npm `gltf-validator`, pinned in
//! `tools/node/package.json`): 0 errors and 0 warnings for a static mesh and for a 72-frame
//! animated sequence with markers; plus structural checks that do not need node.

mod common;

use panoman_interchange::glb::{self, GlbOptions, Interpolation, Markers};
use panoman_mesh::io::write_bytes_atomically;
use serde_json::Value;

fn markers(frames: &[Vec<[f64; 3]>]) -> Markers {
    let picks = [0usize, 1000, 5000, 9000, 13000];
    Markers {
        names: picks.iter().map(|v| format!("v{v}")).collect(),
        frames: frames
            .iter()
            .enumerate()
            .map(|(f, fr)| {
                picks
                    .iter()
                    .enumerate()
                    // Marker 1 is missing in every third frame, marker 4 in all of them.
                    .map(|(k, &v)| (k != 4 && !(k == 1 && f % 3 == 0)).then_some(fr[v]))
                    .collect()
            })
            .collect(),
    }
}

/// Validator output for the files: one JSON object per file.
fn validate(files: &[&std::path::Path]) -> Vec<Value> {
    let (ok, out, err) = common::run_node("validate.mjs", files);
    let reports: Vec<Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).expect("validator JSON line"))
        .collect();
    eprintln!("validator: {out}{err}");
    assert_eq!(
        reports.len(),
        files.len(),
        "one report per file; stderr: {err}"
    );
    assert!(ok, "validator reported problems: {out}");
    reports
}

#[test]
fn static_and_animated_exports_pass_the_khronos_validator() {
    if !common::node_ready("static_and_animated_exports_pass_the_khronos_validator") {
        return;
    }
    let dir = common::scratch("glb_validator");
    let mesh = common::template();
    let static_path = dir.join("static.glb");
    let colors: Vec<[f32; 3]> = (0..mesh.n_vertices())
        .map(|i| [(i % 7) as f32 / 6.0, 0.5, 1.0 - (i % 5) as f32 / 4.0])
        .collect();
    let opts = GlbOptions {
        colors: Some(colors),
        ..Default::default()
    };
    let bytes = glb::mesh_glb(mesh, None, &opts).unwrap();
    write_bytes_atomically(&static_path, &bytes).unwrap();

    let frames = common::clip(72);
    let m = markers(&frames);
    let anim_path = dir.join("clip72.glb");
    let opts = GlbOptions {
        fps: 24.0,
        ..Default::default()
    };
    let bytes = glb::export_glb(&mesh.faces, &frames, Some(&m), &opts).unwrap();
    write_bytes_atomically(&anim_path, &bytes).unwrap();
    let step_path = dir.join("clip72_step.glb");
    let opts = GlbOptions {
        interpolation: Interpolation::Step,
        ..Default::default()
    };
    let bytes = glb::export_glb(
        &mesh.faces,
        &frames[..5],
        Some(&markers(&frames[..5])),
        &opts,
    )
    .unwrap();
    write_bytes_atomically(&step_path, &bytes).unwrap();

    let reports = validate(&[&static_path, &anim_path, &step_path]);
    for r in &reports {
        assert_eq!(r["errors"], 0, "{r}");
        assert_eq!(r["warnings"], 0, "{r}");
    }
}

#[test]
fn validator_catches_a_broken_file() {
    // The check above must be able to fail: a file whose POSITION max is wrong is an error.
    if !common::node_ready("validator_catches_a_broken_file") {
        return;
    }
    let dir = common::scratch("glb_validator_broken");
    let mesh = common::template();
    let bytes = glb::mesh_glb(mesh, None, &GlbOptions::default()).unwrap();
    let (mut doc, bin) = glb::split_glb(&bytes).unwrap();
    doc["accessors"][0]["max"][0] = 123.0.into();
    let json = serde_json::to_vec(&doc).unwrap();
    let mut json = json;
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend_from_slice(b"glTF");
    out.extend_from_slice(&2u32.to_le_bytes());
    out.extend_from_slice(&(total as u32).to_le_bytes());
    out.extend_from_slice(&(json.len() as u32).to_le_bytes());
    out.extend_from_slice(b"JSON");
    out.extend_from_slice(&json);
    out.extend_from_slice(&(bin.len() as u32).to_le_bytes());
    out.extend_from_slice(b"BIN\0");
    out.extend_from_slice(bin);
    let path = dir.join("broken.glb");
    write_bytes_atomically(&path, &out).unwrap();
    let (ok, stdout, _) = common::run_node("validate.mjs", &[&path]);
    assert!(!ok, "validator accepted a wrong accessor max: {stdout}");
    let r: Value = serde_json::from_str(stdout.lines().next().unwrap()).unwrap();
    assert!(r["errors"].as_u64().unwrap() > 0, "{r}");
}

#[test]
fn animated_export_layout() {
    let mesh = common::template();
    let frames = common::clip(72);
    let bytes = glb::export_glb(
        &mesh.faces,
        &frames,
        Some(&markers(&frames)),
        &GlbOptions::default(),
    )
    .unwrap();
    let (doc, bin) = glb::split_glb(&bytes).unwrap();
    assert_eq!(
        doc["meshes"][0]["primitives"][0]["targets"]
            .as_array()
            .unwrap()
            .len(),
        71
    );
    let anim = &doc["animations"][0];
    // One weights channel + one translation channel per marker present somewhere (4 of 5).
    assert_eq!(anim["channels"].as_array().unwrap().len(), 1 + 4);
    let times = &doc["accessors"][anim["samplers"][0]["input"].as_u64().unwrap() as usize];
    assert_eq!(times["count"], 72);
    assert!((times["max"][0].as_f64().unwrap() - 71.0 / 30.0).abs() < 1e-6);
    // Frame 10's base + target 9 is frame 10 in glTF axes (x, z, −y), to f32 precision.
    let acc = |i: usize| &doc["accessors"][i];
    let read = |a: &Value, v: usize| -> [f32; 3] {
        let view = &doc["bufferViews"][a["bufferView"].as_u64().unwrap() as usize];
        let o = view["byteOffset"].as_u64().unwrap() as usize + 12 * v;
        let f = |k: usize| f32::from_le_bytes(bin[o + 4 * k..o + 4 * k + 4].try_into().unwrap());
        [f(0), f(1), f(2)]
    };
    let prim = &doc["meshes"][0]["primitives"][0];
    let base = acc(prim["attributes"]["POSITION"].as_u64().unwrap() as usize);
    let t9 = acc(prim["targets"][9]["POSITION"].as_u64().unwrap() as usize);
    for v in [0usize, 4321, 13000] {
        let p = frames[10][v];
        let (b, d) = (read(base, v), read(t9, v));
        let got = [b[0] + d[0], b[1] + d[1], b[2] + d[2]];
        let want = [p[0], p[2], -p[1]];
        for c in 0..3 {
            assert!(
                (got[c] as f64 - want[c]).abs() < 1e-5,
                "vertex {v}: {got:?} vs {want:?}"
            );
        }
    }
}

#[test]
fn mismatched_frames_are_rejected() {
    let mesh = common::template();
    let mut frames = common::clip(3);
    frames[2].pop();
    let e = glb::export_glb(&mesh.faces, &frames, None, &GlbOptions::default()).unwrap_err();
    assert!(e.to_string().contains("frame 2 has 13347 vertices"), "{e}");
    let e = glb::export_glb(&mesh.faces, &[], None, &GlbOptions::default()).unwrap_err();
    assert!(e.to_string().contains("no frames"), "{e}");
}
