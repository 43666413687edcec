//! C3D (the biomechanics standard for 3D point data): a reader for the header, the
//! parameter section and the 3D point data, and a writer for the same subset.
//!
//! Format facts used (C3D.org, "The C3D File Format User Guide"): the file is 512-byte
//! blocks. Block 1 is the header (16-bit words in the processor's byte order): word 1 byte 1
//! the first parameter block, byte 2 the key 0x50; word 2 the number of 3D points; word 3
//! analog samples per 3D frame (all channels); words 4–5 first and last frame (1-based);
//! words 7–8 the scale factor (a float: negative means float storage, its magnitude scales
//! integer coordinates and residuals); word 9 the first data block; words 11–12 the frame
//! rate. The parameter section starts with 4 bytes (byte 3: number of parameter blocks, byte
//! 4: processor type, 84 Intel, 85 DEC, 86 MIPS), followed by group and parameter records
//! `[name length (i8), id (i8; < 0 group, > 0 parameter of group |id|), name, offset to the
//! next record (i16, from the offset field), …]`; parameter records carry a type (−1 char,
//! 1 byte, 2 int16, 4 float), dimensions and data. Each 3D frame is `n_points × (X, Y, Z,
//! residual word)` (int16 or float) followed by that frame's analog samples, which this
//! reader skips. A residual word < 0 marks the sample as missing.
//!
//! Byte orders: Intel and DEC store integers little-endian, MIPS big-endian; Intel floats are
//! IEEE little-endian, MIPS IEEE big-endian, DEC floats VAX F-floating (converted here: the
//! two 16-bit halves swapped, then divided by 4 for the exponent bias and hidden-bit
//! difference).
//!
//! Parameters used: `POINT:USED` (must equal the header's point count), `POINT:SCALE` and
//! `POINT:RATE` (override the header's copies when present), `POINT:LABELS`, `LABELS2`, …
//! (concatenated), `POINT:UNITS` (default `mm` when absent), `POINT:Y_SCREEN` (the up
//! axis, when present), `POINT:LONG_FRAMES` (when the header's last frame is 65535).

use std::path::Path;

use crate::error::{MocapError, Result, format_err, read_bytes};
use crate::markers::{MarkerSequence, UpAxis, UpSource, metres_per_unit};

mod write;
pub use write::{C3dWriteOptions, write_c3d};

/// Bytes per C3D block.
pub const BLOCK: usize = 512;

/// The processor type of a C3D file, which fixes its byte order and float format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Processor {
    /// Code 84: little-endian integers, IEEE floats.
    Intel,
    /// Code 85: little-endian integers, VAX F-floating floats.
    Dec,
    /// Code 86: big-endian integers and IEEE floats (SGI/MIPS).
    Mips,
}

impl Processor {
    /// The code stored in byte 4 of the parameter section.
    pub fn code(self) -> u8 {
        match self {
            Processor::Intel => 84,
            Processor::Dec => 85,
            Processor::Mips => 86,
        }
    }

    fn from_code(c: u8) -> Option<Processor> {
        Some(match c {
            84 => Processor::Intel,
            85 => Processor::Dec,
            86 => Processor::Mips,
            _ => return None,
        })
    }

    fn u16(self, b: [u8; 2]) -> u16 {
        match self {
            Processor::Mips => u16::from_be_bytes(b),
            _ => u16::from_le_bytes(b),
        }
    }

    fn f32(self, b: [u8; 4]) -> f32 {
        match self {
            Processor::Intel => f32::from_le_bytes(b),
            Processor::Mips => f32::from_be_bytes(b),
            Processor::Dec => dec_to_ieee(b),
        }
    }

    fn u16_bytes(self, v: u16) -> [u8; 2] {
        match self {
            Processor::Mips => v.to_be_bytes(),
            _ => v.to_le_bytes(),
        }
    }

    fn f32_bytes(self, v: f32) -> Result<[u8; 4]> {
        Ok(match self {
            Processor::Intel => v.to_le_bytes(),
            Processor::Mips => v.to_be_bytes(),
            Processor::Dec => ieee_to_dec(v)?,
        })
    }
}

/// VAX F-floating (as stored: two little-endian 16-bit words, the high word first) to IEEE.
///
/// VAX F is `(−1)^s · 0.1m · 2^(e−128)`; the same bits read as IEEE single are
/// `(−1)^s · 1.m · 2^(e−127)`, four times larger. Exponent 0 is zero.
pub fn dec_to_ieee(b: [u8; 4]) -> f32 {
    let ieee = f32::from_le_bytes([b[2], b[3], b[0], b[1]]);
    if (ieee.to_bits() >> 23) & 0xff == 0 {
        0.0
    } else {
        ieee / 4.0
    }
}

/// IEEE single to VAX F-floating bytes (the inverse of [`dec_to_ieee`]); values below
/// 2⁻¹²⁷ in magnitude become 0.
///
/// # Errors
/// [`MocapError::Invalid`] for non-finite values or values too large for VAX F.
pub fn ieee_to_dec(v: f32) -> Result<[u8; 4]> {
    if !v.is_finite() {
        return Err(MocapError::Invalid {
            what: format!("{v} has no DEC float form"),
        });
    }
    if v.abs() < f32::MIN_POSITIVE / 2.0 {
        return Ok([0; 4]);
    }
    let x = v * 4.0;
    if !x.is_finite() {
        return Err(MocapError::Invalid {
            what: format!("{v} is too large for a DEC float"),
        });
    }
    let c = x.to_le_bytes();
    Ok([c[2], c[3], c[0], c[1]])
}

/// How 3D coordinates are stored.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Storage {
    /// 32-bit floats in the file's unit (scale factor < 0 in the file).
    Float,
    /// 16-bit integers; coordinate = count · `scale` (file units per count, > 0).
    Integer {
        /// File units per integer count.
        scale: f64,
    },
}

/// The data of one parameter, in the file's type.
#[derive(Clone, Debug, PartialEq)]
pub enum ParamData {
    /// Type −1: characters.
    Char(Vec<u8>),
    /// Type 1: bytes.
    Byte(Vec<u8>),
    /// Type 2: 16-bit integers.
    Int16(Vec<i16>),
    /// Type 4: floats (converted to IEEE).
    Float(Vec<f32>),
}

/// One parameter of the parameter section.
#[derive(Clone, Debug, PartialEq)]
pub struct Parameter {
    /// Group name (upper case as stored), e.g. `POINT`.
    pub group: String,
    /// Parameter name, e.g. `LABELS`.
    pub name: String,
    /// Dimensions, first varying fastest (for characters the first is the string length).
    pub dims: Vec<usize>,
    /// The values.
    pub data: ParamData,
    /// Byte offset of the data in the file (to patch a parameter in place).
    pub data_offset: usize,
}

impl Parameter {
    /// Character data as strings: one per column of a `[len, n]` array (one string for a
    /// 0- or 1-dimensional array), trailing spaces and NULs removed. Empty for non-char data.
    pub fn strings(&self) -> Vec<String> {
        let ParamData::Char(b) = &self.data else {
            return Vec::new();
        };
        let w = if self.dims.len() >= 2 {
            self.dims[0]
        } else {
            b.len()
        };
        if w == 0 {
            return Vec::new();
        }
        b.chunks(w)
            .map(|c| {
                String::from_utf8_lossy(c)
                    .trim_end_matches([' ', '\0'])
                    .trim_start()
                    .to_string()
            })
            .collect()
    }

    /// The first value as `f64` for numeric data (`Int16` read as signed).
    pub fn first_f64(&self) -> Option<f64> {
        match &self.data {
            ParamData::Byte(v) => v.first().map(|&x| x as f64),
            ParamData::Int16(v) => v.first().map(|&x| x as f64),
            ParamData::Float(v) => v.first().map(|&x| x as f64),
            ParamData::Char(_) => None,
        }
    }
}

/// A parsed C3D file: layout facts, all parameters and the 3D points.
#[derive(Clone, Debug)]
pub struct C3d {
    /// Processor type (byte order, float format).
    pub processor: Processor,
    /// Coordinate storage.
    pub storage: Storage,
    /// Analog samples per 3D frame (all channels; skipped by this reader).
    pub analog_words_per_frame: usize,
    /// Byte offset of the first 3D frame.
    pub data_start: usize,
    /// Bytes per 3D frame (points and analog).
    pub frame_bytes: usize,
    /// Every parameter, in file order.
    pub parameters: Vec<Parameter>,
    /// The 3D points in metres, in the file's axes ([`MarkerSequence::up_axis`] from
    /// `POINT:Y_SCREEN` when present).
    pub markers: MarkerSequence,
}

impl C3d {
    /// The parameter `group:name` (case-insensitive).
    pub fn param(&self, group: &str, name: &str) -> Option<&Parameter> {
        self.parameters
            .iter()
            .find(|p| p.group.eq_ignore_ascii_case(group) && p.name.eq_ignore_ascii_case(name))
    }
}

/// Reads a C3D file.
///
/// # Errors
/// [`MocapError::Io`] if it cannot be read; [`MocapError::Format`] naming the file and the
/// byte offset for anything malformed (see [`parse_c3d`]).
pub fn read_c3d(path: &Path) -> Result<C3d> {
    parse_c3d(&read_bytes(path)?, path)
}

/// Bounds-checked little reader over the file bytes.
struct Bytes<'a> {
    b: &'a [u8],
    path: &'a Path,
    proc: Processor,
}

impl Bytes<'_> {
    fn slice(&self, off: usize, n: usize, what: &str) -> Result<&[u8]> {
        off.checked_add(n)
            .and_then(|end| self.b.get(off..end))
            .ok_or_else(|| {
                format_err(
                    self.path,
                    format!(
                        "truncated: {what} needs bytes {off}..{} but the file has {} bytes",
                        off.saturating_add(n),
                        self.b.len()
                    ),
                )
            })
    }
    fn u8(&self, off: usize, what: &str) -> Result<u8> {
        Ok(self.slice(off, 1, what)?[0])
    }
    fn u16(&self, off: usize, what: &str) -> Result<u16> {
        let s = self.slice(off, 2, what)?;
        Ok(self.proc.u16([s[0], s[1]]))
    }
    fn f32(&self, off: usize, what: &str) -> Result<f32> {
        let s = self.slice(off, 4, what)?;
        Ok(self.proc.f32([s[0], s[1], s[2], s[3]]))
    }
    fn err(&self, what: impl Into<String>) -> MocapError {
        format_err(self.path, what)
    }
}

/// Parses C3D bytes; `path` names the source in errors.
///
/// # Errors
/// [`MocapError::Format`] naming `path` and what is wrong: not a C3D file (key byte),
/// unknown processor type, a truncated header / parameter section / point data (the
/// point data must be as long as the header's frame count says — nothing is allocated
/// beyond what the file holds), zero points or zero frames, a point count that disagrees
/// with `POINT:USED`, fewer labels than points, an unknown unit, a non-positive rate, or a
/// non-finite coordinate on a sample that is not flagged missing.
pub fn parse_c3d(bytes: &[u8], path: &Path) -> Result<C3d> {
    let mut r = Bytes {
        b: bytes,
        path,
        proc: Processor::Intel,
    };
    if bytes.len() < BLOCK {
        return Err(r.err(format!(
            "{} bytes, shorter than the {BLOCK}-byte C3D header",
            bytes.len()
        )));
    }
    if bytes[1] != 0x50 {
        return Err(r.err(format!(
            "not a C3D file: byte 2 is 0x{:02x}, expected 0x50",
            bytes[1]
        )));
    }
    let pblock = bytes[0] as usize;
    if pblock < 2 {
        return Err(r.err(format!("parameter section at block {pblock} (must be ≥ 2)")));
    }
    let pstart = (pblock - 1) * BLOCK;
    let code = r.u8(pstart + 3, "the parameter section header")?;
    r.proc = Processor::from_code(code).ok_or_else(|| {
        r.err(format!(
            "unknown processor type {code} at byte {} (expected 84 Intel, 85 DEC or 86 MIPS)",
            pstart + 3
        ))
    })?;
    let n_blocks = r.u8(pstart + 2, "the parameter section header")? as usize;
    let pend = (pstart + n_blocks.max(1) * BLOCK).min(bytes.len());
    let parameters = parse_parameters(&r, pstart + 4, pend)?;
    let header = Header::read(&r)?;
    build(r, header, parameters)
}

/// The header words this reader uses.
struct Header {
    n_points: usize,
    analog_words: usize,
    first_frame: u16,
    last_frame: u16,
    scale: f32,
    data_block: usize,
    rate: f32,
}

impl Header {
    fn read(r: &Bytes) -> Result<Header> {
        let h = "the header";
        Ok(Header {
            n_points: r.u16(2, h)? as usize,
            analog_words: r.u16(4, h)? as usize,
            first_frame: r.u16(6, h)?,
            last_frame: r.u16(8, h)?,
            scale: r.f32(12, h)?,
            data_block: r.u16(16, h)? as usize,
            rate: r.f32(20, h)?,
        })
    }
}

/// Parses the group and parameter records between `start` and `end`.
fn parse_parameters(r: &Bytes, start: usize, end: usize) -> Result<Vec<Parameter>> {
    let mut groups: Vec<(i8, String)> = Vec::new();
    let mut raw: Vec<(i8, Parameter)> = Vec::new();
    let mut pos = start;
    while pos + 2 <= end {
        let nchar = r.u8(pos, "a parameter record")? as i8;
        let id = r.u8(pos + 1, "a parameter record")? as i8;
        if nchar == 0 || id == 0 {
            break;
        }
        let len = nchar.unsigned_abs() as usize;
        let name_b = r.slice(pos + 2, len, "a parameter name")?;
        let name = String::from_utf8_lossy(name_b).trim().to_ascii_uppercase();
        let off_pos = pos + 2 + len;
        let offset = r.u16(off_pos, "a parameter record")? as i16;
        if id < 0 {
            // Group ids are -1..=-127; -128 has no parameter counterpart (and no i8 negation).
            let gid = id.checked_neg().ok_or_else(|| {
                r.err(format!(
                    "group record at byte {pos} has id {id} (groups are -1 to -127)"
                ))
            })?;
            groups.push((gid, name));
        } else {
            let p = parse_param_body(r, off_pos + 2, name, pos)?;
            raw.push((id, p));
        }
        if offset == 0 {
            break;
        }
        let next = off_pos as i64 + offset as i64;
        if next <= pos as i64 {
            return Err(r.err(format!(
                "parameter record at byte {pos} points backwards (offset {offset})"
            )));
        }
        pos = next as usize;
    }
    Ok(raw
        .into_iter()
        .map(|(id, mut p)| {
            p.group = groups
                .iter()
                .find(|(g, _)| *g == id)
                .map(|(_, n)| n.clone())
                .unwrap_or_else(|| format!("#{id}"));
            p
        })
        .collect())
}

/// Parses a parameter's type, dimensions and data starting at `at`.
fn parse_param_body(r: &Bytes, at: usize, name: String, rec: usize) -> Result<Parameter> {
    let what = format!("parameter {name} (record at byte {rec})");
    let ty = r.u8(at, &what)? as i8;
    let ndims = r.u8(at + 1, &what)? as usize;
    let dims: Vec<usize> = r
        .slice(at + 2, ndims, &what)?
        .iter()
        .map(|&d| d as usize)
        .collect();
    let elem = match ty {
        -1 | 1 => 1,
        2 => 2,
        4 => 4,
        _ => return Err(r.err(format!("{what}: unknown data type {ty}"))),
    };
    let n_bytes = dims
        .iter()
        .try_fold(elem as usize, |a: usize, &d| a.checked_mul(d))
        .ok_or_else(|| r.err(format!("{what}: dimensions overflow")))?;
    let data_offset = at + 2 + ndims;
    let raw = r.slice(data_offset, n_bytes, &what)?;
    let data = match ty {
        -1 => ParamData::Char(raw.to_vec()),
        1 => ParamData::Byte(raw.to_vec()),
        2 => ParamData::Int16(
            raw.chunks_exact(2)
                .map(|c| r.proc.u16([c[0], c[1]]) as i16)
                .collect(),
        ),
        _ => ParamData::Float(
            raw.chunks_exact(4)
                .map(|c| r.proc.f32([c[0], c[1], c[2], c[3]]))
                .collect(),
        ),
    };
    Ok(Parameter {
        group: String::new(),
        name,
        dims,
        data,
        data_offset,
    })
}

fn find<'a>(ps: &'a [Parameter], group: &str, name: &str) -> Option<&'a Parameter> {
    ps.iter().find(|p| p.group == group && p.name == name)
}

/// Checks the header against the parameters and reads the point data.
fn build(r: Bytes, h: Header, parameters: Vec<Parameter>) -> Result<C3d> {
    if let Some(used) = find(&parameters, "POINT", "USED").and_then(Parameter::first_f64) {
        let used = (used as i64).rem_euclid(65536) as usize;
        if used != h.n_points {
            return Err(r.err(format!(
                "the header says {} points but POINT:USED says {used}",
                h.n_points
            )));
        }
    }
    if h.n_points == 0 {
        return Err(r.err("zero 3D points (nothing to read)"));
    }
    let scale = find(&parameters, "POINT", "SCALE")
        .and_then(Parameter::first_f64)
        .unwrap_or(h.scale as f64);
    let rate = find(&parameters, "POINT", "RATE")
        .and_then(Parameter::first_f64)
        .unwrap_or(h.rate as f64);
    if !(rate.is_finite() && rate > 0.0) {
        return Err(r.err(format!("frame rate {rate} Hz is not positive")));
    }
    if !scale.is_finite() || scale == 0.0 {
        return Err(r.err(format!("scale factor {scale} is zero or not finite")));
    }
    let storage = if scale < 0.0 {
        Storage::Float
    } else {
        Storage::Integer { scale }
    };
    let n_frames = frame_count(&r, &h, &parameters)?;
    let names = labels(&r, &parameters, h.n_points)?;
    let unit = find(&parameters, "POINT", "UNITS")
        .and_then(|p| p.strings().into_iter().next())
        .filter(|u| !u.is_empty())
        .unwrap_or_else(|| "mm".to_string());
    let mpu =
        metres_per_unit(&unit).ok_or_else(|| r.err(format!("unknown POINT:UNITS `{unit}`")))?;
    let up_axis = find(&parameters, "POINT", "Y_SCREEN")
        .and_then(|p| p.strings().into_iter().next())
        .and_then(|s| UpAxis::parse(&s));
    let w = if storage == Storage::Float { 4 } else { 2 };
    let frame_bytes = (h.n_points * 4 + h.analog_words) * w;
    if h.data_block == 0 {
        return Err(r.err("the header's data block is 0"));
    }
    let data_start = (h.data_block - 1) * BLOCK;
    let total = n_frames
        .checked_mul(frame_bytes)
        .and_then(|t| t.checked_add(data_start))
        .unwrap_or(usize::MAX);
    if total > r.b.len() {
        return Err(r.err(format!(
            "truncated point data: {n_frames} frames × {frame_bytes} bytes from byte \
             {data_start} need {total} bytes, the file has {}",
            r.b.len()
        )));
    }
    let positions = read_points(
        &r,
        data_start,
        frame_bytes,
        n_frames,
        h.n_points,
        storage,
        mpu,
    )?;
    let markers = MarkerSequence {
        names,
        rate_hz: rate,
        first_frame: h.first_frame as i64,
        positions,
        source_unit: unit,
        metres_per_unit: mpu,
        up_axis,
        up_source: if up_axis.is_some() {
            UpSource::File
        } else {
            UpSource::Unknown
        },
    };
    Ok(C3d {
        processor: r.proc,
        storage,
        analog_words_per_frame: h.analog_words,
        data_start,
        frame_bytes,
        parameters,
        markers,
    })
}

/// Number of 3D frames from the header (or `POINT:LONG_FRAMES` when the header's last
/// frame is saturated at 65535).
fn frame_count(r: &Bytes, h: &Header, ps: &[Parameter]) -> Result<usize> {
    let long = find(ps, "POINT", "LONG_FRAMES").and_then(Parameter::first_f64);
    let n = match long {
        Some(n) if h.last_frame == u16::MAX && n.is_finite() && n >= 0.0 => n as usize,
        _ => {
            if h.last_frame < h.first_frame {
                return Err(r.err(format!(
                    "zero frames: the header's frame range is {}..{}",
                    h.first_frame, h.last_frame
                )));
            }
            (h.last_frame - h.first_frame) as usize + 1
        }
    };
    if n == 0 {
        return Err(r.err("zero frames"));
    }
    Ok(n)
}

/// `POINT:LABELS`, `LABELS2`, … concatenated; the first `n` are the point names.
fn labels(r: &Bytes, ps: &[Parameter], n: usize) -> Result<Vec<String>> {
    let mut names = Vec::new();
    if let Some(p) = find(ps, "POINT", "LABELS") {
        names.extend(p.strings());
    }
    for k in 2.. {
        match find(ps, "POINT", &format!("LABELS{k}")) {
            Some(p) => names.extend(p.strings()),
            None => break,
        }
    }
    if names.len() < n {
        return Err(r.err(format!(
            "{n} points but only {} labels in POINT:LABELS",
            names.len()
        )));
    }
    names.truncate(n);
    Ok(names)
}

/// Reads `n_frames × n_points` samples (metres; NaN for a residual < 0).
fn read_points(
    r: &Bytes,
    start: usize,
    frame_bytes: usize,
    n_frames: usize,
    n_points: usize,
    storage: Storage,
    mpu: f64,
) -> Result<Vec<[f64; 3]>> {
    let mut out = Vec::with_capacity(n_frames * n_points);
    for f in 0..n_frames {
        let base = start + f * frame_bytes;
        for m in 0..n_points {
            let (v, residual) = match storage {
                Storage::Float => {
                    let at = base + m * 16;
                    let g = |k: usize| r.f32(at + 4 * k, "point data").map(|x| x as f64);
                    ([g(0)?, g(1)?, g(2)?], g(3)?)
                }
                Storage::Integer { scale } => {
                    let at = base + m * 8;
                    let g = |k: usize| r.u16(at + 2 * k, "point data").map(|x| x as i16);
                    let s = scale.abs();
                    (
                        [g(0)? as f64 * s, g(1)? as f64 * s, g(2)? as f64 * s],
                        g(3)? as f64,
                    )
                }
            };
            if residual < 0.0 {
                out.push([f64::NAN; 3]);
                continue;
            }
            if !v.iter().all(|c| c.is_finite()) || residual.is_nan() {
                return Err(r.err(format!(
                    "non-finite coordinate at frame {f}, point {m} (not flagged missing)"
                )));
            }
            out.push(v.map(|c| c * mpu));
        }
    }
    Ok(out)
}
