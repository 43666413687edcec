//! Cuts the short excerpts under `tests/data/` from the real captures (see
//! `tests/data/README.md`): the first `N` frames of each file, with its frame count
//! rewritten, everything else byte-for-byte as in the original.
//!
//! `cargo run --release -p panoman-mocap --example cut_excerpts -- SRC_DIR OUT_DIR [N]`

use std::path::{Path, PathBuf};

use panoman_mocap::{MocapError, Result, c3d};

fn io(p: &Path) -> impl FnOnce(std::io::Error) -> MocapError + '_ {
    move |source| MocapError::Io {
        path: p.to_path_buf(),
        source,
    }
}

/// C3D: keep the header, the parameter section and the first `n` frames; rewrite the
/// header's last frame (word 5) and `POINT:FRAMES`.
fn cut_c3d(src: &Path, dst: &Path, n: usize) -> Result<()> {
    let bytes = std::fs::read(src).map_err(io(src))?;
    let c = c3d::parse_c3d(&bytes, src)?;
    let mut out = bytes[..c.data_start + n * c.frame_bytes].to_vec();
    let last = (c.markers.first_frame as usize + n - 1) as u16;
    let le = c.processor != c3d::Processor::Mips;
    let put = |out: &mut Vec<u8>, at: usize, v: u16| {
        let b = if le { v.to_le_bytes() } else { v.to_be_bytes() };
        out[at..at + 2].copy_from_slice(&b);
    };
    put(&mut out, 8, last);
    if let Some(p) = c.param("POINT", "FRAMES") {
        put(&mut out, p.data_offset, n as u16);
    }
    std::fs::write(dst, out).map_err(io(dst))
}

/// Text files: keep lines up to the data marker, then the first `n` data lines; `fix`
/// rewrites the header lines.
fn cut_text(
    src: &Path,
    dst: &Path,
    marker: &str,
    n: usize,
    fix: &dyn Fn(&str) -> String,
) -> Result<()> {
    let text = std::fs::read_to_string(src).map_err(io(src))?;
    let mut out = String::new();
    let mut data = None;
    for line in text.lines() {
        match data {
            None => {
                out.push_str(&fix(line));
                out.push('\n');
                if line.trim().starts_with(marker) {
                    data = Some(0);
                }
            }
            Some(k) if k < n => {
                out.push_str(line);
                out.push('\n');
                data = Some(k + 1);
            }
            Some(_) => break,
        }
    }
    std::fs::write(dst, out).map_err(io(dst))
}

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (src, out) = (PathBuf::from(&args[0]), PathBuf::from(&args[1]));
    let n: usize = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(40);
    std::fs::create_dir_all(&out).map_err(io(&out))?;
    cut_c3d(
        &src.join("nick_freeform_001.c3d"),
        &out.join("nick_freeform_001_head.c3d"),
        n,
    )?;
    let csm_fix = move |l: &str| {
        if l.starts_with("$LastFrame") {
            format!("$LastFrame {n}")
        } else {
            l.to_string()
        }
    };
    cut_text(
        &src.join("ThomasFechten.csm"),
        &out.join("ThomasFechten_head.csm"),
        "$Points",
        n,
        &csm_fix,
    )?;
    let bvh_fix = move |l: &str| {
        if l.starts_with("Frames:") {
            format!("Frames: {n}")
        } else {
            l.to_string()
        }
    };
    // The two header lines after MOTION are kept by `fix`, so cut after `Frame Time`.
    cut_text(
        &src.join("01_01.bvh"),
        &out.join("01_01_head.bvh"),
        "Frame Time",
        n,
        &bvh_fix,
    )?;
    for f in [
        "Nick01.vsk",
        "01_nn.bvh.source.txt",
        "DEBIAN_COPYRIGHT_assimp-testmodels.txt",
        "DEBIAN_COPYRIGHT_dart-doc.txt",
        "ThomasFechten.source.txt",
    ] {
        std::fs::copy(src.join(f), out.join(f)).map_err(io(&out.join(f)))?;
    }
    Ok(())
}
