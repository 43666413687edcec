//! Prints a summary of a motion-capture file (`.c3d`, `.csm`, `.vsk`, `.bvh`).
//!
//! `cargo run --release -p panoman-mocap --example mocap_info -- FILE...`

use std::path::Path;

use panoman_mocap::markers::MarkerSequence;
use panoman_mocap::{Result, bvh, c3d, csm, vsk};

fn summary(m: &MarkerSequence) {
    println!(
        "  {} markers, {} frames at {} Hz (first frame {}), unit {}, up {:?} ({:?})",
        m.n_markers(),
        m.n_frames(),
        m.rate_hz,
        m.first_frame,
        m.source_unit,
        m.up_axis,
        m.up_source
    );
    println!(
        "  missing {} of {} samples = {:.3} %",
        m.n_missing(),
        m.positions.len(),
        100.0 * m.missing_fraction()
    );
    println!("  names: {}", m.names.join(" "));
    if let Some(f) = (0..m.n_frames()).find(|&f| m.get(f, 0).is_some()) {
        println!(
            "  first sample of {}: frame {f} {:?} m",
            m.names[0],
            m.get(f, 0)
        );
    }
}

fn show(p: &Path) -> Result<()> {
    println!("{}:", p.display());
    match p
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("c3d") => {
            let c = c3d::read_c3d(p)?;
            println!(
                "  processor {:?}, storage {:?}, analog words/frame {}, data at byte {}, {} bytes/frame",
                c.processor, c.storage, c.analog_words_per_frame, c.data_start, c.frame_bytes
            );
            for q in &c.parameters {
                let v = match &q.data {
                    c3d::ParamData::Char(_) => {
                        format!("{:?}", q.strings().iter().take(4).collect::<Vec<_>>())
                    }
                    d => format!("{:.60}", format!("{d:?}")),
                };
                println!("  {}:{} {:?} {v}", q.group, q.name, q.dims);
            }
            summary(&c.markers);
        }
        Some("csm") => {
            let (m, info) = csm::read_csm(p)?;
            println!("  header {:?}", info.header);
            summary(&m);
        }
        Some("vsk") => {
            let v = vsk::read_vsk(p)?;
            println!(
                "  {} parameters, {} segments, {} markers, {} sticks",
                v.parameters.len(),
                v.segments.len(),
                v.markers.len(),
                v.sticks.len()
            );
            for s in &v.segments {
                let parent = s.parent.map(|i| v.segments[i].name.as_str()).unwrap_or("-");
                println!(
                    "  segment {} <- {parent} {:?} {}",
                    s.name, s.position, s.joint
                );
            }
        }
        Some("bvh") => {
            let b = bvh::read_bvh(p)?;
            println!(
                "  {} joints, {} channels, {} frames at {:.3} Hz",
                b.joints.len(),
                b.n_channels(),
                b.n_frames(),
                b.rate_hz()
            );
            let names: Vec<&str> = b.joints.iter().map(|j| j.name.as_str()).collect();
            println!("  joints: {}", names.join(" "));
        }
        _ => println!("  unknown extension"),
    }
    Ok(())
}

fn main() {
    let mut failed = false;
    for a in std::env::args().skip(1) {
        if let Err(e) = show(Path::new(&a)) {
            eprintln!("error: {e}");
            failed = true;
        }
    }
    std::process::exit(i32::from(failed));
}
