//! `panoman render` end to end (the real binary): a valid PNG of the requested size whose
//! non-background coverage is plausible for a human body in each view, keypoint dots drawn
//! in their group colours, and one-line errors for bad inputs.

use panoman_human::template::full_template;
use panoman_mesh::io;
use std::path::{Path, PathBuf};

use crate::common;
use common::panoman;

const BACKGROUND: [u8; 3] = [236, 236, 236];

/// A fresh `<tmp>/panoman-test-render-<tag>-<pid>`, removed when the guard drops.
fn tmpdir(tag: &str) -> common::TempDir {
    common::TempDir::new(&format!("render-{tag}"))
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Decodes an 8-bit RGB PNG: (width, height, pixels).
fn decode(path: &Path) -> (u32, u32, Vec<[u8; 3]>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut reader = dec.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(info.color_type, png::ColorType::Rgb);
    assert_eq!(info.bit_depth, png::BitDepth::Eight);
    let px = buf[..info.buffer_size()]
        .chunks_exact(3)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    (info.width, info.height, px)
}

/// The default template written as OBJ (a real body: 13,348 vertices).
fn body(d: &Path) -> PathBuf {
    let a = panoman_human::assets::ensure_default().expect("assets");
    let t = full_template(&a).unwrap();
    let p = d.join("body.obj");
    io::write_mesh(&p, &t.mesh).unwrap();
    p
}

#[test]
fn renders_a_body_as_png_of_the_requested_size() {
    let d = tmpdir("body");
    let mesh = body(&d);
    for (view, lo, hi) in [
        ("front", 0.08, 0.35),
        ("side", 0.04, 0.25),
        ("back", 0.08, 0.35),
    ] {
        let out = d.join(format!("{view}.png"));
        let o = panoman(&[
            "render",
            s(&mesh),
            "--out",
            s(&out),
            "--view",
            view,
            "--width",
            "320",
            "--height",
            "400",
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let (w, h, px) = decode(&out);
        assert_eq!((w, h), (320, 400));
        assert_eq!(px[0], BACKGROUND);
        let covered = px.iter().filter(|&&p| p != BACKGROUND).count() as f64 / px.len() as f64;
        assert!(covered > lo && covered < hi, "{view}: coverage {covered}");
        // Front-lit skin, not back faces (which are drawn dark red).
        let dark_red = px
            .iter()
            .filter(|p| p[0] > 60 && (p[1] as u32) * 2 < p[0] as u32)
            .count();
        assert!(
            dark_red < px.len() / 1000,
            "{view}: {dark_red} back-face pixels"
        );
    }
    // Two meshes side by side with keypoints on the first.
    let kp = d.join("kp.json");
    std::fs::write(
        &kp,
        r#"{"units": "m", "keypoints": {"neck": [0, -0.05, 0.55], "face_30": [0, -0.12, 0.7],
            "lhand_00": [0.45, 0, 0], "rhand_00": [-0.45, 0, 0]}, "weights": {"neck": 1}}"#,
    )
    .unwrap();
    let out = d.join("two.png");
    let o = panoman(&[
        "render",
        s(&mesh),
        s(&mesh),
        "--out",
        s(&out),
        "--keypoints",
        s(&kp),
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let (w, h, px) = decode(&out);
    assert_eq!((w, h), (1120, 800));
    let count = |c: [u8; 3]| px.iter().filter(|&&p| p == c).count();
    for c in [[220, 40, 40], [30, 150, 60], [40, 90, 225], [240, 140, 0]] {
        assert!(count(c) > 0, "no pixels of keypoint colour {c:?}");
    }
    let half = |x0: u32| {
        (0..h)
            .flat_map(|y| (x0..x0 + w / 2).map(move |x| (x, y)))
            .filter(|&(x, y)| px[(y * w + x) as usize] != BACKGROUND)
            .count()
    };
    assert!(half(0) > 10_000 && half(w / 2) > 10_000);
    let _ = std::fs::remove_dir_all(&d);
}

#[test]
fn bad_inputs_are_one_line_errors() {
    let d = tmpdir("bad");
    let mesh = body(&d);
    let bad_kp = d.join("bad_kp.json");
    std::fs::write(&bad_kp, r#"{"keypoints": {"elbow": [0, 0, 0]}}"#).unwrap();
    let bad_mesh = d.join("bad_mesh.obj");
    std::fs::write(&bad_mesh, "v 0 0 0\nf 1 2 3\n").unwrap();
    let out = d.join("x.png");
    for (args, needle) in [
        (
            vec![
                "render",
                s(&mesh),
                "--out",
                s(&out),
                "--keypoints",
                s(&bad_kp),
            ],
            "bad_kp.json",
        ),
        (
            vec!["render", s(&bad_mesh), "--out", s(&out)],
            "bad_mesh.obj",
        ),
        (
            vec!["render", s(&d.join("none.obj")), "--out", s(&out)],
            "none.obj",
        ),
    ] {
        let o = panoman(&args);
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{err}");
        assert_eq!(err.trim_end().lines().count(), 1, "{err}");
        assert!(err.starts_with("error:") && err.contains(needle), "{err}");
        assert!(!out.exists());
    }
    let _ = std::fs::remove_dir_all(&d);
}
