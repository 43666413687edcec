//! The offline viewer: its HTML is self-contained (no network URLs), and in headless Chromium
//! (Debian's `chromium`) it loads without console errors, draws a non-blank canvas, and moving
//! the frame slider changes the rendered image.

mod common;

use std::process::Command;

use panoman_interchange::glb::{self, GlbOptions, Markers};
use panoman_interchange::viewer::{self, ThreeAssets, VertexErrors, ViewOptions};
use panoman_mesh::io::write_bytes_atomically;
use serde_json::Value;

/// A 24-frame clip with 3 markers and errors against the undeformed template.
fn page() -> String {
    let mesh = common::template();
    let frames = common::clip(24);
    let picks = [500usize, 6000, 12000];
    let markers = Markers {
        names: picks.iter().map(|v| format!("v{v}")).collect(),
        frames: frames
            .iter()
            .map(|f| picks.iter().map(|&v| Some(f[v])).collect())
            .collect(),
    };
    let bytes =
        glb::export_glb(&mesh.faces, &frames, Some(&markers), &GlbOptions::default()).unwrap();
    let truth = vec![mesh.positions.clone(); frames.len()];
    let errors = viewer::vertex_errors(&frames, &truth).unwrap();
    let three = ThreeAssets::load_or_fetch().expect("three.js (npm pack on first use)");
    let options = ViewOptions {
        title: Some("panoman viewer test".into()),
        errors: Some(VertexErrors {
            per_frame: errors,
            max_m: 0.2,
        }),
    };
    viewer::view_html(&bytes, &three, &options).unwrap()
}

fn chromium_ready() -> bool {
    let required = std::env::var("PANOMAN_NODE_TESTS").is_ok_and(|v| v == "1");
    let bin = std::env::var("CHROMIUM").unwrap_or_else(|_| "chromium".into());
    let ok = Command::new(&bin)
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    if !ok {
        if required {
            panic!("PANOMAN_NODE_TESTS=1 but `{bin}` is not runnable (apt-get install chromium)");
        }
        eprintln!(
            "\n*** SKIPPED viewer browser test: `{bin}` not found (set PANOMAN_NODE_TESTS=1 to make this an error) ***\n"
        );
    }
    ok
}

#[test]
fn viewer_page_is_self_contained() {
    if !common::node_ready("viewer_page_is_self_contained") {
        return; // three.js comes from `npm pack`
    }
    let html = page();
    assert!(html.contains("<script type=\"importmap\">"));
    for forbidden in ["http://", "https://", "src=\"", "@GLB@", "@CONFIG@"] {
        // three.js sources mention URLs in comments; they are inside base64 data URLs, so the
        // page text itself must hold none.
        assert!(!html.contains(forbidden), "page contains {forbidden}");
    }
    // Errors of the wrong shape are rejected.
    let mesh = common::template();
    let bytes = glb::mesh_glb(mesh, None, &GlbOptions::default()).unwrap();
    let three = ThreeAssets::load_or_fetch().unwrap();
    let bad = ViewOptions {
        title: None,
        errors: Some(VertexErrors {
            per_frame: vec![vec![0.0; 10]],
            max_m: 0.01,
        }),
    };
    let e = viewer::view_html(&bytes, &three, &bad)
        .unwrap_err()
        .to_string();
    assert!(e.contains("10 errors for 13348 vertices"), "{e}");
}

#[test]
fn viewer_renders_and_scrubs_in_headless_chromium() {
    if !common::node_ready("viewer_renders_and_scrubs_in_headless_chromium") || !chromium_ready() {
        return;
    }
    let dir = common::scratch("viewer_browser");
    let html_path = dir.join("view.html");
    write_bytes_atomically(&html_path, page().as_bytes()).unwrap();
    let shot = dir.join("viewer.png");
    let (ok, out, err) = common::run_node(
        "browser_check.mjs",
        &[&html_path, &shot, std::path::Path::new("6")],
    );
    eprintln!("browser check: {out}{err}");
    let r: Value =
        serde_json::from_str(out.lines().last().unwrap_or("null")).unwrap_or(Value::Null);
    assert!(
        r.is_object(),
        "no result from the browser check: {out} {err}"
    );
    assert_eq!(r["consoleErrors"].as_array().map(Vec::len), Some(0), "{r}");
    assert!(
        r["nonBlankFraction"].as_f64().unwrap() > 0.01,
        "blank canvas: {r}"
    );
    assert!(
        r["scrubChangedFraction"].as_f64().unwrap() > 0.002,
        "scrubbing did not change the image: {r}"
    );
    assert_eq!(r["frameShown"], 6, "{r}");
    assert!(
        r["markerToggleChangedFraction"].as_f64().unwrap() > 0.0,
        "the keypoint toggle changed nothing: {r}"
    );
    assert!(ok, "browser check failed: {out} {err}");
    let png = std::fs::read(&shot).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    if let Some(dest) = std::env::var_os("PANOMAN_VIEWER_SCREENSHOT") {
        std::fs::copy(&shot, dest).unwrap();
    }
}
