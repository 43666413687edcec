//! Wavefront OBJ reading and writing (geometry only).
//!
//! Reading understands `v x y z [w ...]` (any extra columns, such as a `w` or per-vertex colours,
//! are ignored) and `f` records whose corners are `v`, `v/vt`, `v//vn` or `v/vt/vn`, with
//! 1-based or negative (relative to the vertices read so far) indices. Polygons are triangulated
//! by [`super::triangulate_polygon`]. Everything else (`vt`, `vn`, `g`, `o`, `s`, `usemtl`,
//! `mtllib`, `l`, comments, blank lines, unknown statements) is ignored; CRLF line ends are fine.
//!
//! Writing produces `v x y z` lines (shortest round-trip formatting) followed by `f a b c` lines
//! with 1-based indices.

use std::io::Write;
use std::path::Path;

use super::{
    check_for_writing, format_error, read_file, repeated_vertex, triangulate_polygon,
    write_atomically, write_f64,
};
use crate::error::Result;
use crate::mesh::TriMesh;

/// Reads an OBJ file into a triangle mesh. See [`parse_obj`] for what is accepted; I/O failures
/// are [`crate::MeshError::Io`], content problems [`crate::MeshError::Format`] naming the file and
/// the line.
pub fn read_obj(path: &Path) -> Result<TriMesh> {
    let bytes = read_file(path)?;
    // Comments may carry non-UTF-8 bytes; numbers containing them fail to parse with a clear error.
    let text = String::from_utf8_lossy(&bytes);
    parse_obj(&text, path)
}

/// Parses OBJ text; `path_for_errors` is only used in error messages.
///
/// Errors (one line each, naming the file and line): malformed number or index, a vertex with
/// fewer than three coordinates, a non-finite coordinate, a face with fewer than three corners,
/// index 0, an index out of range, a face that repeats a vertex, and a file without vertices or
/// without faces.
pub fn parse_obj(text: &str, path_for_errors: &Path) -> Result<TriMesh> {
    let path = path_for_errors;
    let err = |line: usize, what: String| format_error(path, format!("line {line}: {what}"));

    let mut positions: Vec<[f64; 3]> = Vec::new();
    // Polygons, stored flat: `corners[starts[k]..starts[k + 1]]` with 0-based vertex indices
    // (positive indices are checked against the final vertex count once the file is read).
    let mut corners: Vec<u32> = Vec::new();
    let mut starts: Vec<usize> = Vec::new();
    let mut poly_lines: Vec<usize> = Vec::new();
    let mut scratch: Vec<u32> = Vec::new();

    for (i, line) in text.lines().enumerate() {
        let line_no = i + 1;
        let mut tokens = line
            .split_ascii_whitespace()
            .take_while(|t| !t.starts_with('#'));
        let Some(keyword) = tokens.next() else {
            continue;
        };
        match keyword {
            "v" => {
                let mut p = [0.0f64; 3];
                for (k, c) in p.iter_mut().enumerate() {
                    let Some(tok) = tokens.next() else {
                        return Err(err(
                            line_no,
                            format!("vertex has {k} coordinates, expected 3"),
                        ));
                    };
                    let x: f64 = tok
                        .parse()
                        .map_err(|_| err(line_no, format!("malformed number '{tok}' in vertex")))?;
                    if !x.is_finite() {
                        return Err(err(
                            line_no,
                            format!("non-finite coordinate '{tok}' in vertex"),
                        ));
                    }
                    *c = x;
                }
                positions.push(p);
            }
            "f" => {
                let start = corners.len();
                for tok in tokens {
                    let v_part = tok.split('/').next().unwrap_or("");
                    let idx: i64 = v_part.parse().map_err(|_| {
                        err(line_no, format!("malformed vertex index '{tok}' in face"))
                    })?;
                    let resolved = if idx > 0 {
                        idx - 1
                    } else if idx < 0 {
                        let r = positions.len() as i64 + idx;
                        if r < 0 {
                            return Err(err(
                                line_no,
                                format!(
                                    "relative vertex index {idx} is out of range ({} vertices read so far)",
                                    positions.len()
                                ),
                            ));
                        }
                        r
                    } else {
                        return Err(err(
                            line_no,
                            "vertex index 0 is invalid (OBJ indices start at 1)".to_string(),
                        ));
                    };
                    let Ok(resolved) = u32::try_from(resolved) else {
                        return Err(err(line_no, format!("vertex index {idx} is out of range")));
                    };
                    corners.push(resolved);
                }
                let n = corners.len() - start;
                if n < 3 {
                    return Err(err(
                        line_no,
                        format!("face has {n} vertices, need at least 3"),
                    ));
                }
                if let Some(v) = repeated_vertex(&corners[start..], &mut scratch) {
                    return Err(err(
                        line_no,
                        format!("face repeats vertex {}", v as u64 + 1),
                    ));
                }
                starts.push(start);
                poly_lines.push(line_no);
            }
            _ => {}
        }
    }

    if positions.is_empty() {
        return Err(format_error(path, "no vertices ('v' lines) in file"));
    }
    if starts.is_empty() {
        return Err(format_error(path, "no faces ('f' lines) in file"));
    }
    let nv = positions.len();
    let mut faces = Vec::with_capacity(starts.len());
    for (k, &start) in starts.iter().enumerate() {
        let end = starts.get(k + 1).copied().unwrap_or(corners.len());
        let poly = &corners[start..end];
        if let Some(&bad) = poly.iter().find(|&&v| v as usize >= nv) {
            return Err(err(
                poly_lines[k],
                format!(
                    "vertex index {} is out of range (file has {nv} vertices)",
                    bad as u64 + 1
                ),
            ));
        }
        triangulate_polygon(poly, &positions, &mut faces);
    }
    Ok(TriMesh { positions, faces })
}

/// Writes `mesh` as OBJ (`v x y z` lines, then `f a b c` with 1-based indices, after a
/// `# generated by panoman` comment), atomically (see [`super`]). Coordinates read back
/// bit-exactly. The mesh must pass [`TriMesh::check_basic`].
pub fn write_obj(path: &Path, mesh: &TriMesh) -> Result<()> {
    check_for_writing(path, mesh)?;
    write_atomically(path, |w| {
        writeln!(
            w,
            "# generated by panoman\n# {} vertices, {} faces",
            mesh.positions.len(),
            mesh.faces.len()
        )?;
        for p in &mesh.positions {
            w.write_all(b"v ")?;
            write_f64(w, p[0])?;
            w.write_all(b" ")?;
            write_f64(w, p[1])?;
            w.write_all(b" ")?;
            write_f64(w, p[2])?;
            w.write_all(b"\n")?;
        }
        for f in &mesh.faces {
            writeln!(
                w,
                "f {} {} {}",
                f[0] as u64 + 1,
                f[1] as u64 + 1,
                f[2] as u64 + 1
            )?;
        }
        Ok(())
    })
}
