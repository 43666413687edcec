//! Prints the JSON chunk of a tiny animated GLB (a tetrahedron over 3 frames with one marker):
//! the example of the layout in `docs/formats-interchange.md`.
//! Run: `cargo run --release -p panoman-interchange --example glb_layout`.

use panoman_interchange::glb::{self, GlbOptions, Markers};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let faces = vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]];
    let frames: Vec<Vec<[f64; 3]>> = (0..3)
        .map(|f| {
            let z = 0.1 * f as f64;
            vec![
                [0.0, 0.0, z],
                [1.0, 0.0, z],
                [0.0, 1.0, z],
                [0.0, 0.0, 1.0 + z],
            ]
        })
        .collect();
    let markers = Markers {
        names: vec!["nose".into()],
        frames: frames.iter().map(|f| vec![Some(f[3])]).collect(),
    };
    let bytes = glb::export_glb(&faces, &frames, Some(&markers), &GlbOptions::default())?;
    let (doc, bin) = glb::split_glb(&bytes)?;
    println!("{}", serde_json::to_string_pretty(&doc)?);
    eprintln!(
        "{} bytes in all, BIN chunk {} bytes",
        bytes.len(),
        bin.len()
    );
    Ok(())
}
