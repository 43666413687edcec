//! A minimal reader for NumPy `.npy` files (format versions 1, 2 and 3).
//!
//! Supported: little-endian `<f8`, `<f4`, `<i8`, `<i4` arrays in C order. Used to compare
//! against the reference fixtures.

use std::path::Path;

use crate::error::{HumanError, Result};

/// Element type of an `.npy` array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NpyDtype {
    /// `<f8`
    F64,
    /// `<f4`
    F32,
    /// `<i8`
    I64,
    /// `<i4`
    I32,
}

impl NpyDtype {
    fn size(self) -> usize {
        match self {
            NpyDtype::F64 | NpyDtype::I64 => 8,
            NpyDtype::F32 | NpyDtype::I32 => 4,
        }
    }
}

/// A parsed `.npy` header plus the raw little-endian data bytes.
struct Raw {
    dtype: NpyDtype,
    shape: Vec<usize>,
    data: Vec<u8>,
}

fn read_raw(path: &Path) -> Result<Raw> {
    let bytes = std::fs::read(path).map_err(|e| HumanError::io(path, e))?;
    parse_raw(bytes).map_err(|what| HumanError::format(path, what))
}

fn parse_raw(bytes: Vec<u8>) -> std::result::Result<Raw, String> {
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err("not a .npy file (bad magic)".into());
    }
    let major = bytes[6];
    let (header_len, start) = match major {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        2 | 3 => {
            if bytes.len() < 12 {
                return Err("truncated header".into());
            }
            (
                u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
                12,
            )
        }
        v => return Err(format!("unsupported .npy version {v}")),
    };
    let end = start + header_len;
    if bytes.len() < end {
        return Err("truncated header".into());
    }
    let header = std::str::from_utf8(&bytes[start..end]).map_err(|_| "header is not text")?;
    let descr = dict_value(header, "descr").ok_or("header has no `descr`")?;
    let descr = descr.trim().trim_matches(|c| c == '\'' || c == '"');
    let dtype = match descr {
        "<f8" => NpyDtype::F64,
        "<f4" => NpyDtype::F32,
        "<i8" => NpyDtype::I64,
        "<i4" => NpyDtype::I32,
        d => {
            return Err(format!(
                "unsupported dtype `{d}` (need <f8, <f4, <i8 or <i4)"
            ));
        }
    };
    let fortran = dict_value(header, "fortran_order").ok_or("header has no `fortran_order`")?;
    if fortran.trim() != "False" {
        return Err("Fortran-order arrays are not supported".into());
    }
    let shape_s = dict_value(header, "shape").ok_or("header has no `shape`")?;
    let shape_s = shape_s.trim();
    let inner = shape_s
        .strip_prefix('(')
        .and_then(|s| s.strip_suffix(')'))
        .ok_or_else(|| format!("bad shape `{shape_s}`"))?;
    let shape = inner
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| {
            s.parse::<usize>()
                .map_err(|_| format!("bad shape `{shape_s}`"))
        })
        .collect::<std::result::Result<Vec<_>, _>>()?;
    // Checked: a header may claim a shape whose byte count overflows `usize`.
    let needed = shape
        .iter()
        .try_fold(dtype.size(), |a, &d| a.checked_mul(d))
        .ok_or_else(|| format!("shape {shape:?} of {descr} is too large"))?;
    let data_len = bytes.len() - end;
    if data_len != needed {
        return Err(format!(
            "data has {data_len} bytes, shape {shape:?} of {descr} needs {needed}"
        ));
    }
    let data = bytes[end..].to_vec();
    Ok(Raw { dtype, shape, data })
}

/// The text of the value of `key` in a Python dict literal (up to the next top-level comma).
fn dict_value<'a>(header: &'a str, key: &str) -> Option<&'a str> {
    let k1 = format!("'{key}'");
    let k2 = format!("\"{key}\"");
    let pos = header.find(&k1).or_else(|| header.find(&k2))? + k1.len();
    let rest = header[pos..].trim_start().strip_prefix(':')?;
    let mut depth = 0i32;
    for (i, c) in rest.char_indices() {
        match c {
            '(' | '[' => depth += 1,
            ')' | ']' => depth -= 1,
            ',' | '}' if depth == 0 => return Some(&rest[..i]),
            _ => {}
        }
    }
    Some(rest)
}

fn chunks<const N: usize>(data: &[u8]) -> impl Iterator<Item = [u8; N]> + '_ {
    data.chunks_exact(N)
        .map(|c| c.try_into().expect("chunk size"))
}

/// Reads an `.npy` array as `f64` (from `<f8`, `<f4`, `<i8` or `<i4`): returns the shape and
/// the elements in C order.
pub fn read_npy_f64(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<f64>)> {
    let raw = read_raw(path.as_ref())?;
    let v = match raw.dtype {
        NpyDtype::F64 => chunks::<8>(&raw.data).map(f64::from_le_bytes).collect(),
        NpyDtype::F32 => chunks::<4>(&raw.data)
            .map(|b| f32::from_le_bytes(b) as f64)
            .collect(),
        NpyDtype::I64 => chunks::<8>(&raw.data)
            .map(|b| i64::from_le_bytes(b) as f64)
            .collect(),
        NpyDtype::I32 => chunks::<4>(&raw.data)
            .map(|b| i32::from_le_bytes(b) as f64)
            .collect(),
    };
    Ok((raw.shape, v))
}

/// Reads an integer `.npy` array (`<i8` or `<i4`) as `i64`: returns the shape and the elements
/// in C order. Floating-point files are an error.
pub fn read_npy_i64(path: impl AsRef<Path>) -> Result<(Vec<usize>, Vec<i64>)> {
    let path = path.as_ref();
    let raw = read_raw(path)?;
    let v = match raw.dtype {
        NpyDtype::I64 => chunks::<8>(&raw.data).map(i64::from_le_bytes).collect(),
        NpyDtype::I32 => chunks::<4>(&raw.data)
            .map(|b| i32::from_le_bytes(b) as i64)
            .collect(),
        d => {
            return Err(HumanError::format(
                path,
                format!("expected an integer array, found {d:?}"),
            ));
        }
    };
    Ok((raw.shape, v))
}

/// Reads an `.npy` array of shape `[n, 3]` as `f64` points.
pub fn read_npy_points(path: impl AsRef<Path>) -> Result<Vec<[f64; 3]>> {
    let path = path.as_ref();
    let (shape, v) = read_npy_f64(path)?;
    if shape.len() != 2 || shape[1] != 3 {
        return Err(HumanError::format(
            path,
            format!("expected shape [n, 3], found {shape:?}"),
        ));
    }
    Ok(v.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn npy(descr: &str, shape: &str, data: &[u8]) -> Vec<u8> {
        let mut h = format!("{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape}, }}");
        while (10 + h.len() + 1) % 64 != 0 {
            h.push(' ');
        }
        h.push('\n');
        let mut b = b"\x93NUMPY\x01\x00".to_vec();
        b.extend((h.len() as u16).to_le_bytes());
        b.extend(h.as_bytes());
        b.extend(data);
        b
    }

    #[test]
    fn parses_shapes_and_types() {
        let data: Vec<u8> = [1.5f64, -2.0]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let r = parse_raw(npy("<f8", "(2,)", &data)).unwrap();
        assert_eq!(r.shape, [2]);
        assert_eq!(r.dtype, NpyDtype::F64);
        let data: Vec<u8> = [7i32, 8, 9, 10]
            .iter()
            .flat_map(|x| x.to_le_bytes())
            .collect();
        let r = parse_raw(npy("<i4", "(2, 2)", &data)).unwrap();
        assert_eq!(r.shape, [2, 2]);
        assert!(parse_raw(npy("<i4", "(3, 2)", &data)).is_err());
        assert!(parse_raw(npy(">f8", "(2,)", &data)).is_err());
        let r = parse_raw(npy("<f8", "()", &1.0f64.to_le_bytes())).unwrap();
        assert!(r.shape.is_empty());
    }
}
