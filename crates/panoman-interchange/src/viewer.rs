//! A self-contained, offline HTML viewer around a GLB file.
//!
//! [`view_html`] writes one HTML file holding the GLB (base64), three.js and its
//! `OrbitControls` and `GLTFLoader` (from `examples/jsm`, with `BufferGeometryUtils` which the
//! loader imports) as `data:` URLs in an import map, and a small script: orbit controls,
//! play/pause and a frame slider for sequences, a toggle for the `markers` node, and, when
//! per-vertex errors are given, an error colouring (0 blue → `max` red) that follows the
//! frame. Nothing is loaded from the network when the page is opened.
//!
//! three.js is [`THREE_VERSION`] from the npm registry: [`ThreeAssets::load_or_fetch`] runs
//! `npm pack three@<version>` once into the cache directory ([`cache_dir`]), checks the
//! tarball's SHA-256 against [`THREE_TGZ_SHA256`] every time it is used, and reads the four
//! modules out of it. Nothing of three.js is committed.
//!
//! The page exposes `window.panomanViewer` (`ready`, `nFrames`, `setFrame(i)`, `frame()`,
//! `pixels()`) for the browser test.

use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::Command;

use serde_json::json;
use sha2::{Digest, Sha256};

use crate::error::{InterchangeError, Result};
use crate::glb::split_glb;

/// The pinned three.js version.
pub const THREE_VERSION: &str = "0.170.0";
/// SHA-256 of `three-0.170.0.tgz` as served by the npm registry (`npm pack three@0.170.0`).
pub const THREE_TGZ_SHA256: &str =
    "4a608a355dcaba72e0e5383cdc814303f5b6060b43c238cdf6932dceb699238d";

/// The three.js modules the viewer inlines (JavaScript source text).
#[derive(Clone, Debug)]
pub struct ThreeAssets {
    /// `build/three.module.min.js`.
    pub three: String,
    /// `examples/jsm/controls/OrbitControls.js`.
    pub orbit_controls: String,
    /// `examples/jsm/loaders/GLTFLoader.js`.
    pub gltf_loader: String,
    /// `examples/jsm/utils/BufferGeometryUtils.js`.
    pub buffer_geometry_utils: String,
}

const MODULE_PATHS: [&str; 4] = [
    "package/build/three.module.min.js",
    "package/examples/jsm/controls/OrbitControls.js",
    "package/examples/jsm/loaders/GLTFLoader.js",
    "package/examples/jsm/utils/BufferGeometryUtils.js",
];

/// The three.js cache directory: `$PANOMAN_THREE_DIR` if set, else
/// `$XDG_CACHE_HOME/panoman/three-<version>`, else `$HOME/.cache/panoman/three-<version>`
/// (else the same below the system temporary directory).
pub fn cache_dir() -> PathBuf {
    panoman_human::assets::user_cache_dir("PANOMAN_THREE_DIR", &format!("three-{THREE_VERSION}"))
}

impl ThreeAssets {
    /// The modules from the cached tarball in [`cache_dir`], running `npm pack` first when it
    /// is missing.
    ///
    /// # Errors
    /// npm missing or failing, a digest other than [`THREE_TGZ_SHA256`], a tarball without
    /// the modules.
    pub fn load_or_fetch() -> Result<ThreeAssets> {
        let dir = cache_dir();
        let tgz = dir.join(format!("three-{THREE_VERSION}.tgz"));
        if !tgz.is_file() {
            fetch(&dir, &tgz)?;
        }
        ThreeAssets::from_tarball(&tgz)
    }

    /// The modules from a `three-<version>.tgz` file, after checking its SHA-256.
    ///
    /// # Errors
    /// I/O errors, a digest mismatch, a malformed tarball or missing modules (naming the file).
    pub fn from_tarball(tgz: &Path) -> Result<ThreeAssets> {
        let bytes = std::fs::read(tgz).map_err(|e| InterchangeError::io(tgz, e))?;
        let digest = hex(&Sha256::digest(&bytes));
        if digest != THREE_TGZ_SHA256 {
            return Err(InterchangeError::format(
                tgz,
                format!(
                    "sha256 mismatch: expected {THREE_TGZ_SHA256}, got {digest} (delete it to fetch again)"
                ),
            ));
        }
        let mut tar = Vec::new();
        flate2::read::GzDecoder::new(&bytes[..])
            .read_to_end(&mut tar)
            .map_err(|e| InterchangeError::format(tgz, format!("gzip: {e}")))?;
        let mut found: [Option<String>; 4] = Default::default();
        for (name, data) in tar_entries(&tar).map_err(|w| InterchangeError::format(tgz, w))? {
            if let Some(k) = MODULE_PATHS.iter().position(|p| *p == name) {
                let text = String::from_utf8(data.to_vec())
                    .map_err(|_| InterchangeError::format(tgz, format!("{name}: not UTF-8")))?;
                found[k] = Some(text);
            }
        }
        let mut take = |k: usize| {
            found[k].take().ok_or_else(|| {
                InterchangeError::format(tgz, format!("no {} in the tarball", MODULE_PATHS[k]))
            })
        };
        Ok(ThreeAssets {
            three: take(0)?,
            orbit_controls: take(1)?,
            gltf_loader: take(2)?,
            buffer_geometry_utils: take(3)?,
        })
    }
}

/// `npm pack three@<version>` into a fresh temporary folder of `dir`, then checked and moved
/// onto `tgz`.
fn fetch(dir: &Path, tgz: &Path) -> Result<()> {
    std::fs::create_dir_all(dir).map_err(|e| InterchangeError::io(dir, e))?;
    static COUNTER: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = COUNTER.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let tmp = dir.join(format!(".fetch-{}-{n}", std::process::id()));
    let _ = std::fs::remove_dir_all(&tmp);
    std::fs::create_dir_all(&tmp).map_err(|e| InterchangeError::io(&tmp, e))?;
    let spec = format!("three@{THREE_VERSION}");
    let out = Command::new("npm")
        .args(["pack", "--silent", &spec, "--pack-destination"])
        .arg(&tmp)
        .current_dir(&tmp)
        .output();
    let result = (|| {
        let out = out.map_err(|e| InterchangeError::Tool {
            what: format!("cannot run npm ({e}): it is needed once to fetch {spec} for the viewer"),
        })?;
        if !out.status.success() {
            return Err(InterchangeError::Tool {
                what: format!(
                    "npm pack {spec} failed: {}",
                    String::from_utf8_lossy(&out.stderr).trim()
                ),
            });
        }
        let got = tmp.join(format!("three-{THREE_VERSION}.tgz"));
        ThreeAssets::from_tarball(&got)?;
        std::fs::rename(&got, tgz).map_err(|e| InterchangeError::io(tgz, e))
    })();
    let _ = std::fs::remove_dir_all(&tmp);
    result
}

/// The regular files of a (ustar / pax) tar archive: (path, contents).
fn tar_entries(tar: &[u8]) -> std::result::Result<Vec<(String, &[u8])>, String> {
    let mut out = Vec::new();
    let mut o = 0;
    let mut pax_path: Option<String> = None;
    while o + 512 <= tar.len() {
        let h = &tar[o..o + 512];
        if h.iter().all(|&b| b == 0) {
            break;
        }
        let field = |a: usize, b: usize| {
            let s = &h[a..b];
            let end = s.iter().position(|&c| c == 0).unwrap_or(s.len());
            String::from_utf8_lossy(&s[..end]).into_owned()
        };
        let size_text = field(124, 136);
        let size = usize::from_str_radix(size_text.trim(), 8)
            .map_err(|_| format!("tar: bad size field `{size_text}` at byte {o}"))?;
        let data_start = o + 512;
        let data = tar
            .get(data_start..data_start + size)
            .ok_or_else(|| format!("tar: truncated entry at byte {o}"))?;
        let kind = h[156];
        let mut name = field(0, 100);
        if &h[257..262] == b"ustar" {
            let prefix = field(345, 500);
            if !prefix.is_empty() {
                name = format!("{prefix}/{name}");
            }
        }
        match kind {
            b'x' => {
                // pax extended header: "<len> path=<value>\n" records.
                let text = String::from_utf8_lossy(data);
                pax_path = text
                    .lines()
                    .find_map(|l| l.split_once(" path=").map(|(_, v)| v.to_string()));
            }
            b'0' | 0 => {
                out.push((pax_path.take().unwrap_or(name), data));
            }
            _ => pax_path = None,
        }
        o = data_start + size.div_ceil(512) * 512;
    }
    Ok(out)
}

/// Per-vertex errors to colour, one row per frame of the GLB (metres).
#[derive(Clone, Debug, PartialEq)]
pub struct VertexErrors {
    /// `per_frame[f][v]`: error of vertex `v` at frame `f` (metres, ≥ 0).
    pub per_frame: Vec<Vec<f32>>,
    /// The error shown in full red (metres, > 0); smaller errors blend from blue.
    pub max_m: f64,
}

/// Per-vertex Euclidean distances between result and ground-truth frames.
///
/// # Errors
/// [`InterchangeError::Invalid`] when the frame or vertex counts differ.
pub fn vertex_errors(result: &[Vec<[f64; 3]>], truth: &[Vec<[f64; 3]>]) -> Result<Vec<Vec<f32>>> {
    if result.len() != truth.len() {
        return Err(InterchangeError::Invalid(format!(
            "{} result frames but {} ground-truth frames",
            result.len(),
            truth.len()
        )));
    }
    result
        .iter()
        .zip(truth)
        .enumerate()
        .map(|(f, (r, t))| {
            if r.len() != t.len() {
                return Err(InterchangeError::Invalid(format!(
                    "frame {f}: {} result vertices but {} ground-truth vertices",
                    r.len(),
                    t.len()
                )));
            }
            Ok(r.iter()
                .zip(t)
                .map(|(p, q)| {
                    let d = [p[0] - q[0], p[1] - q[1], p[2] - q[2]];
                    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() as f32
                })
                .collect())
        })
        .collect()
}

/// Options of [`view_html`].
#[derive(Clone, Debug, Default)]
pub struct ViewOptions {
    /// The page title (default "panoman viewer").
    pub title: Option<String>,
    /// Per-vertex errors for the error colouring (toggle shown only when given).
    pub errors: Option<VertexErrors>,
}

/// The viewer page for a GLB written by [`crate::glb`] (any GLB with one animation works; the
/// frame count is read from the first animation sampler, the vertex count from the first
/// mesh's `POSITION`).
///
/// # Errors
/// [`InterchangeError::Invalid`] for a malformed GLB, or errors whose frame or vertex counts do
/// not match it.
pub fn view_html(glb: &[u8], three: &ThreeAssets, options: &ViewOptions) -> Result<String> {
    let (doc, _) = split_glb(glb)?;
    let n_frames = doc["animations"][0]["samplers"][0]["input"]
        .as_u64()
        .and_then(|a| doc["accessors"][a as usize]["count"].as_u64())
        .unwrap_or(1) as usize;
    let duration = doc["animations"][0]["samplers"][0]["input"]
        .as_u64()
        .and_then(|a| doc["accessors"][a as usize]["max"][0].as_f64())
        .unwrap_or(0.0);
    let fps = if n_frames > 1 && duration > 0.0 {
        (n_frames - 1) as f64 / duration
    } else {
        30.0
    };
    let n_vertices = doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]
        .as_u64()
        .and_then(|a| doc["accessors"][a as usize]["count"].as_u64())
        .ok_or_else(|| InterchangeError::Invalid("the GLB has no mesh with POSITION".into()))?
        as usize;
    let has_markers = doc["nodes"]
        .as_array()
        .is_some_and(|n| n.iter().any(|n| n["name"] == "markers"));
    let mut error_b64 = String::new();
    let mut error_max = 0.0;
    if let Some(e) = &options.errors {
        if e.per_frame.len() != n_frames {
            return Err(InterchangeError::Invalid(format!(
                "{} frames of errors for a GLB of {n_frames} frames",
                e.per_frame.len()
            )));
        }
        if let Some((f, row)) = e
            .per_frame
            .iter()
            .enumerate()
            .find(|(_, r)| r.len() != n_vertices)
        {
            return Err(InterchangeError::Invalid(format!(
                "frame {f}: {} errors for {n_vertices} vertices",
                row.len()
            )));
        }
        if !(e.max_m.is_finite() && e.max_m > 0.0) {
            return Err(InterchangeError::Invalid(format!(
                "error scale must be > 0, got {}",
                e.max_m
            )));
        }
        let bytes: Vec<u8> = e
            .per_frame
            .iter()
            .flatten()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        error_b64 = base64(&bytes);
        error_max = e.max_m;
    }
    let config = json!({
        "nFrames": n_frames,
        "fps": fps,
        "nVertices": n_vertices,
        "hasMarkers": has_markers,
        "hasErrors": options.errors.is_some(),
        "errorMax": error_max,
    });
    let data_url = |src: &str| format!("data:text/javascript;base64,{}", base64(src.as_bytes()));
    let loader = three.gltf_loader.replace(
        "'../utils/BufferGeometryUtils.js'",
        "'three/addons/utils/BufferGeometryUtils.js'",
    );
    let import_map = json!({"imports": {
        "three": data_url(&three.three),
        "three/addons/controls/OrbitControls.js": data_url(&three.orbit_controls),
        "three/addons/loaders/GLTFLoader.js": data_url(&loader),
        "three/addons/utils/BufferGeometryUtils.js": data_url(&three.buffer_geometry_utils),
    }});
    let title = html_escape(options.title.as_deref().unwrap_or("panoman viewer"));
    Ok(TEMPLATE
        .replace("@TITLE@", &title)
        .replace("@IMPORTMAP@", &import_map.to_string())
        .replace("@CONFIG@", &config.to_string())
        .replace("@ERRORS@", &error_b64)
        .replace("@GLB@", &base64(glb)))
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Standard base64 with padding.
pub fn base64(bytes: &[u8]) -> String {
    const A: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
    let mut out = String::with_capacity(bytes.len().div_ceil(3) * 4);
    for c in bytes.chunks(3) {
        let b = [c[0], *c.get(1).unwrap_or(&0), *c.get(2).unwrap_or(&0)];
        let n = (u32::from(b[0]) << 16) | (u32::from(b[1]) << 8) | u32::from(b[2]);
        out.push(A[(n >> 18) as usize & 63] as char);
        out.push(A[(n >> 12) as usize & 63] as char);
        out.push(if c.len() > 1 {
            A[(n >> 6) as usize & 63] as char
        } else {
            '='
        });
        out.push(if c.len() > 2 {
            A[n as usize & 63] as char
        } else {
            '='
        });
    }
    out
}

const TEMPLATE: &str = include_str!("viewer.html");

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foobar", "Zm9vYmFy"),
        ] {
            assert_eq!(base64(i.as_bytes()), o);
        }
    }

    #[test]
    fn tar_reader_reads_ustar_entries() {
        let mut tar = vec![0u8; 512];
        tar[..11].copy_from_slice(b"package/a.j");
        tar[124..135].copy_from_slice(b"00000000005");
        tar[156] = b'0';
        tar[257..262].copy_from_slice(b"ustar");
        tar.extend_from_slice(b"hello");
        tar.resize(1024 + 1024, 0);
        let e = tar_entries(&tar).unwrap();
        assert_eq!(e, vec![("package/a.j".to_string(), &b"hello"[..])]);
    }
}
