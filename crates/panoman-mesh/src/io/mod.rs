//! Mesh file I/O: OBJ and PLY (ascii and binary), atomic writes.
//!
//! * [`read_mesh`] / [`write_mesh`] pick the format from the file extension (`.obj`, `.ply`,
//!   case-insensitive). PLY is written as binary little-endian; [`ply::write_ply`] can also write
//!   ascii.
//! * Readers never panic on malformed input: every problem is a [`MeshError::Format`] that names
//!   the file and, for text formats, the line. Polygons with more than three corners are
//!   triangulated (see [`triangulate_polygon`]).
//! * Writers are atomic: the data go to a temporary file next to the target (`.<name>.tmp-<pid>-<n>`),
//!   which is flushed, synced and then renamed onto the target; on any error the temporary file is
//!   removed and the target is left as it was. A missing output directory is reported as
//!   `<path>: output directory <dir> does not exist` (not as a missing input). Temporary files of
//!   the same target left by a process that was killed (`.<name>.tmp-<pid>[-<n>]` whose process
//!   no longer runs; checked through `/proc/<pid>` on Linux) are removed before writing (see
//!   [`remove_stale_temp_files`]). [`check_output_path`] checks a location up front, before a
//!   long computation.
//! * Coordinates are printed with Rust's shortest round-trip formatting, so every finite `f64`
//!   (including `-0.0` and subnormals) reads back bit-exactly.

pub mod obj;
pub mod ply;

pub use ply::PlyFormat;

use std::ffi::OsString;
use std::fs::{self, File, OpenOptions};
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

use crate::error::{MeshError, Result};
use crate::mesh::TriMesh;

/// The mesh file formats understood by [`read_mesh`] and [`write_mesh`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MeshFormat {
    /// Wavefront OBJ (`.obj`).
    Obj,
    /// Stanford PLY (`.ply`).
    Ply,
}

impl MeshFormat {
    /// The format implied by the extension of `path` (case-insensitive), or a
    /// [`MeshError::Format`] naming the file and the supported extensions.
    pub fn from_path(path: &Path) -> Result<MeshFormat> {
        let ext = path
            .extension()
            .map(|e| e.to_string_lossy().to_ascii_lowercase());
        match ext.as_deref() {
            Some("obj") => Ok(MeshFormat::Obj),
            Some("ply") => Ok(MeshFormat::Ply),
            Some(other) => Err(format_error(
                path,
                format!("unsupported mesh file extension '.{other}' (supported: .obj, .ply)"),
            )),
            None => Err(format_error(
                path,
                "mesh file has no extension (supported: .obj, .ply)",
            )),
        }
    }
}

/// Reads a triangle mesh, choosing the parser from the extension: `.obj` → [`obj::read_obj`],
/// `.ply` → [`ply::read_ply`] (case-insensitive). Any other extension is a
/// [`MeshError::Format`] that names the file and the supported extensions.
pub fn read_mesh(path: &Path) -> Result<TriMesh> {
    match MeshFormat::from_path(path)? {
        MeshFormat::Obj => obj::read_obj(path),
        MeshFormat::Ply => ply::read_ply(path),
    }
}

/// Writes a triangle mesh atomically, choosing the format from the extension: `.obj` → OBJ
/// ([`obj::write_obj`]), `.ply` → binary little-endian PLY ([`ply::write_ply`]).
/// The mesh must pass [`TriMesh::check_basic`] (finite coordinates, indices in range).
pub fn write_mesh(path: &Path, mesh: &TriMesh) -> Result<()> {
    match MeshFormat::from_path(path)? {
        MeshFormat::Obj => obj::write_obj(path, mesh),
        MeshFormat::Ply => ply::write_ply(path, mesh, PlyFormat::BinaryLittleEndian),
    }
}

/// Appends the triangles of the polygon `poly` (vertex indices, already validated to be in range
/// of `positions`) to `out`, keeping its winding:
///
/// * a triangle is copied;
/// * a quad `(a, b, c, d)` is split along its shorter diagonal: if `|a − c| < |b − d|` (strictly)
///   into `(a, b, c), (c, d, a)`, otherwise into `(a, b, d), (d, b, c)`;
/// * an n-gon with n > 4 is fan-triangulated from its first corner:
///   `(p0, p_i, p_{i+1})` for `i = 1 .. n−2`.
///
/// Polygons with fewer than three corners add nothing (the readers reject them earlier).
pub fn triangulate_polygon(poly: &[u32], positions: &[[f64; 3]], out: &mut Vec<[u32; 3]>) {
    match *poly {
        [a, b, c] => out.push([a, b, c]),
        [a, b, c, d] => {
            let dist2 = |i: u32, j: u32| {
                let p = positions[i as usize];
                let q = positions[j as usize];
                (p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)
            };
            if dist2(a, c) < dist2(b, d) {
                out.push([a, b, c]);
                out.push([c, d, a]);
            } else {
                out.push([a, b, d]);
                out.push([d, b, c]);
            }
        }
        _ if poly.len() > 4 => {
            let p0 = poly[0];
            out.extend(poly[1..].windows(2).map(|w| [p0, w[0], w[1]]));
        }
        _ => {}
    }
}

/// The first vertex index that occurs twice in `poly`, if any. `scratch` is reused between calls
/// to avoid allocating for large polygons.
pub(crate) fn repeated_vertex(poly: &[u32], scratch: &mut Vec<u32>) -> Option<u32> {
    if poly.len() <= 16 {
        for (i, &v) in poly.iter().enumerate() {
            if poly[i + 1..].contains(&v) {
                return Some(v);
            }
        }
        None
    } else {
        scratch.clear();
        scratch.extend_from_slice(poly);
        scratch.sort_unstable();
        scratch.windows(2).find(|w| w[0] == w[1]).map(|w| w[0])
    }
}

/// A [`MeshError::Format`] for `path`.
pub(crate) fn format_error(path: &Path, what: impl Into<String>) -> MeshError {
    MeshError::Format {
        path: path.to_path_buf(),
        what: what.into(),
    }
}

/// Reads a whole file, mapping failures to [`MeshError::Io`] naming the file.
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>> {
    fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// Validates a mesh before writing it, so that no file is produced from invalid data.
pub(crate) fn check_for_writing(path: &Path, mesh: &TriMesh) -> Result<()> {
    mesh.check_basic().map_err(|e| e.in_file(path))?;
    if mesh.positions.len() > u32::MAX as usize {
        return Err(format_error(
            path,
            format!("too many vertices to write: {}", mesh.positions.len()),
        ));
    }
    Ok(())
}

/// Writes an `f64` so that it parses back to the identical bits: Rust's shortest round-trip
/// formatting, in plain notation for moderate magnitudes and in exponent notation otherwise
/// (keeps huge and tiny values short; `-0.0` prints as `-0`).
#[inline]
pub(crate) fn write_f64<W: Write>(w: &mut W, x: f64) -> std::io::Result<()> {
    let a = x.abs();
    if a == 0.0 || (1e-5..1e16).contains(&a) {
        write!(w, "{x}")
    } else {
        write!(w, "{x:e}")
    }
}

static TMP_COUNTER: AtomicU64 = AtomicU64::new(0);

/// The directory an output file goes to (`.` for a bare file name).
fn output_dir(path: &Path) -> PathBuf {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    }
}

/// A [`MeshError::Io`] for `path` whose message is `what`.
fn io_error(path: &Path, kind: std::io::ErrorKind, what: String) -> MeshError {
    MeshError::Io {
        path: path.to_path_buf(),
        source: std::io::Error::new(kind, what),
    }
}

/// Checks that the directory of the output file `path` exists and is a directory.
fn check_output_dir(path: &Path) -> Result<PathBuf> {
    if path.file_name().is_none() {
        return Err(format_error(path, "output path does not name a file"));
    }
    let dir = output_dir(path);
    match fs::metadata(&dir) {
        Ok(m) if m.is_dir() => Ok(dir),
        Ok(_) => Err(io_error(
            path,
            std::io::ErrorKind::NotADirectory,
            format!("output directory {} is not a directory", dir.display()),
        )),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(io_error(
            path,
            std::io::ErrorKind::NotFound,
            format!("output directory {} does not exist", dir.display()),
        )),
        Err(source) => Err(MeshError::Io {
            path: path.to_path_buf(),
            source,
        }),
    }
}

/// Checks, before any long computation, that `path` can be written: its directory exists and
/// a probe file can be created in it (and is removed again). The target itself is not touched.
///
/// # Errors
/// [`MeshError::Io`] naming `path`: `output directory <dir> does not exist`, `… is not a
/// directory`, or the error of creating the probe (e.g. `Permission denied`, a read-only file
/// system).
pub fn check_output_path(path: &Path) -> Result<()> {
    let dir = check_output_dir(path)?;
    let mut probe_name = OsString::from(".");
    probe_name.push(path.file_name().unwrap_or_default());
    probe_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let probe = dir.join(probe_name);
    match OpenOptions::new().write(true).create_new(true).open(&probe) {
        Ok(f) => {
            drop(f);
            let _ = fs::remove_file(&probe);
            Ok(())
        }
        Err(e) => Err(io_error(
            path,
            e.kind(),
            format!("cannot write to output directory {}: {e}", dir.display()),
        )),
    }
}

/// Whether process `pid` is running. On Linux this looks at `/proc/<pid>`; elsewhere every
/// process is assumed to run (nothing is removed).
fn process_is_alive(pid: u32) -> bool {
    if pid == std::process::id() {
        return true;
    }
    if cfg!(target_os = "linux") && Path::new("/proc/self").exists() {
        Path::new("/proc").join(pid.to_string()).exists()
    } else {
        true
    }
}

/// Removes the temporary files of the atomic writers for target `path` that a killed process
/// left behind: files `.<name>.tmp-<pid>` or `.<name>.tmp-<pid>-<n>` in the target's directory
/// whose process `<pid>` no longer runs (Linux: no `/proc/<pid>`; on other systems nothing is
/// removed). Failures are ignored (this is housekeeping); returns the number removed.
pub fn remove_stale_temp_files(path: &Path) -> usize {
    let Some(name) = path.file_name() else {
        return 0;
    };
    let mut prefix = OsString::from(".");
    prefix.push(name);
    prefix.push(".tmp-");
    let prefix = prefix.to_string_lossy().into_owned();
    let Ok(entries) = fs::read_dir(output_dir(path)) else {
        return 0;
    };
    let mut removed = 0;
    for entry in entries.flatten() {
        let file_name = entry.file_name();
        let file_name = file_name.to_string_lossy();
        let Some(rest) = file_name.strip_prefix(&prefix) else {
            continue;
        };
        let (pid, counter) = rest.split_once('-').unwrap_or((rest, "0"));
        let (Ok(pid), true) = (
            pid.parse::<u32>(),
            !counter.is_empty() && counter.bytes().all(|b| b.is_ascii_digit()),
        ) else {
            continue;
        };
        if !process_is_alive(pid)
            && entry.file_type().is_ok_and(|t| t.is_file())
            && fs::remove_file(entry.path()).is_ok()
        {
            removed += 1;
        }
    }
    removed
}

/// Writes `bytes` to `path` atomically (see [`write_atomically`]).
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    write_atomically(path, |w| std::io::Write::write_all(w, bytes))
}

/// FNV-1a (64 bit) of `bytes`: the checksum of checkpoints and the identity of the files they
/// were made from (not cryptographic).
pub fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &x| {
        (h ^ u64::from(x)).wrapping_mul(0x0100_0000_01b3)
    })
}

/// Writes `path` atomically: `body` writes into a buffered temporary file in the same directory,
/// which is then flushed, synced to disk and renamed onto `path`. On any failure the temporary
/// file is removed and a [`MeshError::Io`] naming `path` is returned. This is the one atomic
/// writer of the project (meshes, models, reports, images).
///
/// A missing directory is `<path>: output directory <dir> does not exist`; stale temporary
/// files of `path` left by killed processes are removed first ([`remove_stale_temp_files`]).
pub fn write_atomically<F>(path: &Path, body: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<File>) -> std::io::Result<()>,
{
    let io_err = |source: std::io::Error| MeshError::Io {
        path: path.to_path_buf(),
        source,
    };
    let dir = check_output_dir(path)?;
    let Some(name) = path.file_name() else {
        return Err(format_error(path, "output path does not name a file"));
    };
    remove_stale_temp_files(path);
    let mut tmp_name = OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(
        ".tmp-{}-{}",
        std::process::id(),
        TMP_COUNTER.fetch_add(1, Ordering::Relaxed)
    ));
    let tmp = dir.join(tmp_name);
    let file = OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&tmp)
        .map_err(io_err)?;
    let result = (|| {
        let mut w = BufWriter::with_capacity(1 << 16, file);
        body(&mut w)?;
        let file = w.into_inner().map_err(|e| e.into_error())?;
        file.sync_all()?;
        drop(file);
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp);
        return Err(io_err(e));
    }
    Ok(())
}
