//! A C3D writer for the subset [`super::parse_c3d`] reads: header, a `POINT` and an
//! `ANALOG` group, 3D points in either storage and any processor type, and zero-filled
//! analog samples (so readers' analog skipping can be tested).

use super::{BLOCK, Processor, Storage};
use crate::error::{MocapError, Result};
use crate::markers::{MarkerSequence, UpAxis};

/// Options of [`write_c3d`].
#[derive(Clone, Debug, PartialEq)]
pub struct C3dWriteOptions {
    /// Processor type (byte order and float format).
    pub processor: Processor,
    /// Coordinate storage; for [`Storage::Integer`] every coordinate divided by `scale`
    /// must round into `i16`.
    pub storage: Storage,
    /// Length unit written to `POINT:UNITS` and used for the coordinates (`mm`, `cm`, `m`,
    /// `in`, `ft`).
    pub unit: String,
    /// Analog channels to write (one sample per 3D frame each, all zero).
    pub analog_channels: u16,
}

impl Default for C3dWriteOptions {
    /// Intel, float storage, millimetres, no analog channels.
    fn default() -> Self {
        C3dWriteOptions {
            processor: Processor::Intel,
            storage: Storage::Float,
            unit: "mm".into(),
            analog_channels: 0,
        }
    }
}

/// One record of the parameter section.
enum Rec<'a> {
    Group(i8, &'a str),
    Int(i8, &'a str, Vec<i16>),
    Float(i8, &'a str, f32),
    /// Strings padded to a common width: dims `[width, n]` (or `[len]` for one string).
    Chars(i8, &'a str, Vec<String>, bool),
}

/// Serializes `seq` (metres, missing = NaN) as a C3D file.
///
/// Missing samples get residual word −1 and zero coordinates; present samples residual 0.
/// `POINT:Y_SCREEN` is written when [`MarkerSequence::up_axis`] is known. Labels go to
/// `POINT:LABELS`, `LABELS2`, … (255 per parameter).
///
/// # Errors
/// [`MocapError::Invalid`] for an empty sequence, more than 65535 points or frames, a
/// first frame outside 1..=65535, a label longer than 255 bytes, an unknown unit, or a
/// value the chosen storage cannot represent.
pub fn write_c3d(seq: &MarkerSequence, opts: &C3dWriteOptions) -> Result<Vec<u8>> {
    let inv = |what: String| MocapError::Invalid { what };
    let (np, nf) = (seq.n_markers(), seq.n_frames());
    if np == 0 || nf == 0 || np > 65535 {
        return Err(inv(format!(
            "cannot write {np} points × {nf} frames as C3D"
        )));
    }
    let first = u16::try_from(seq.first_frame)
        .ok()
        .filter(|&f| f >= 1)
        .ok_or_else(|| inv(format!("first frame {} outside 1..=65535", seq.first_frame)))?;
    let last = u16::try_from(seq.first_frame + nf as i64 - 1)
        .map_err(|_| inv(format!("{nf} frames from {first} overflow 65535")))?;
    let mpu = crate::markers::metres_per_unit(&opts.unit)
        .ok_or_else(|| inv(format!("unknown unit `{}`", opts.unit)))?;
    let p = opts.processor;
    let scale = match opts.storage {
        Storage::Float => -1.0f32,
        Storage::Integer { scale } if scale > 0.0 && scale.is_finite() => scale as f32,
        Storage::Integer { scale } => return Err(inv(format!("integer scale {scale} ≤ 0"))),
    };
    let width = seq.names.iter().map(|n| n.len()).max().unwrap_or(1).max(1);
    if width > 255 {
        return Err(inv("a label is longer than 255 bytes".into()));
    }
    let na = opts.analog_channels;
    // At most 255 labels per parameter: LABELS, LABELS2, LABELS3, …
    let label_keys: Vec<String> = (0..np.div_ceil(255))
        .map(|k| match k {
            0 => "LABELS".to_string(),
            _ => format!("LABELS{}", k + 1),
        })
        .collect();
    let mut recs = vec![
        Rec::Group(1, "POINT"),
        Rec::Int(1, "USED", vec![np as u16 as i16]),
        Rec::Float(1, "SCALE", scale),
        Rec::Float(1, "RATE", seq.rate_hz as f32),
        Rec::Int(1, "DATA_START", vec![0]), // patched below
        Rec::Int(1, "FRAMES", vec![nf as u16 as i16]),
        Rec::Chars(1, "UNITS", vec![opts.unit.clone()], false),
    ];
    for (key, chunk) in label_keys.iter().zip(seq.names.chunks(255)) {
        recs.push(Rec::Chars(1, key, chunk.to_vec(), true));
    }
    if let Some(up) = seq.up_axis {
        let (x, y) = screen_axes(up);
        recs.push(Rec::Chars(1, "X_SCREEN", vec![x.into()], false));
        recs.push(Rec::Chars(1, "Y_SCREEN", vec![y.into()], false));
    }
    recs.push(Rec::Group(2, "ANALOG"));
    recs.push(Rec::Int(2, "USED", vec![na as i16]));
    recs.push(Rec::Float(2, "RATE", seq.rate_hz as f32));
    let n_param_blocks = encode_params(&recs, p, 0)?.len().div_ceil(BLOCK);
    let data_block = 2 + n_param_blocks;
    if let Some(Rec::Int(_, _, v)) = recs.get_mut(4) {
        v[0] = data_block as i16;
    }
    let mut params = encode_params(&recs, p, n_param_blocks)?;
    params.resize(n_param_blocks * BLOCK, 0);

    let mut out = vec![0u8; BLOCK];
    out[0] = 2;
    out[1] = 0x50;
    let put16 = |out: &mut Vec<u8>, at: usize, v: u16| {
        out[at..at + 2].copy_from_slice(&p.u16_bytes(v));
    };
    put16(&mut out, 2, np as u16);
    put16(&mut out, 4, na);
    put16(&mut out, 6, first);
    put16(&mut out, 8, last);
    out[12..16].copy_from_slice(&p.f32_bytes(scale)?);
    put16(&mut out, 16, data_block as u16);
    put16(&mut out, 18, u16::from(na > 0));
    out[20..24].copy_from_slice(&p.f32_bytes(seq.rate_hz as f32)?);
    out.extend_from_slice(&params);
    for f in 0..nf {
        for &x in seq.frame(f) {
            write_sample(&mut out, x, mpu, opts.storage, p, f)?;
        }
        let w = if opts.storage == Storage::Float { 4 } else { 2 };
        out.extend(std::iter::repeat_n(0u8, na as usize * w));
    }
    Ok(out)
}

/// `(X_SCREEN, Y_SCREEN)` for an up axis (Y_SCREEN is the axis pointing up on screen).
fn screen_axes(up: UpAxis) -> (&'static str, &'static str) {
    match up {
        UpAxis::X => ("+Y", "+X"),
        UpAxis::Y => ("+X", "+Y"),
        UpAxis::Z => ("+X", "+Z"),
        UpAxis::NegX => ("+Y", "-X"),
        UpAxis::NegY => ("+X", "-Y"),
        UpAxis::NegZ => ("+X", "-Z"),
    }
}

/// Appends one point sample (X, Y, Z, residual word).
fn write_sample(
    out: &mut Vec<u8>,
    x: [f64; 3],
    mpu: f64,
    storage: Storage,
    p: Processor,
    f: usize,
) -> Result<()> {
    let missing = !x.iter().all(|c| c.is_finite());
    let v = if missing {
        [0.0; 3]
    } else {
        x.map(|c| c / mpu)
    };
    match storage {
        Storage::Float => {
            for c in v {
                out.extend_from_slice(&p.f32_bytes(c as f32)?);
            }
            out.extend_from_slice(&p.f32_bytes(if missing { -1.0 } else { 0.0 })?);
        }
        Storage::Integer { scale } => {
            for c in v {
                let q = (c / scale).round();
                if !(i16::MIN as f64..=i16::MAX as f64).contains(&q) {
                    return Err(MocapError::Invalid {
                        what: format!(
                            "coordinate {c} at frame {f} does not fit int16 storage at scale {scale}"
                        ),
                    });
                }
                out.extend_from_slice(&p.u16_bytes(q as i16 as u16));
            }
            out.extend_from_slice(&p.u16_bytes(if missing { u16::MAX } else { 0 }));
        }
    }
    Ok(())
}

/// Encodes the parameter section (4-byte section header + records).
fn encode_params(recs: &[Rec], p: Processor, n_blocks: usize) -> Result<Vec<u8>> {
    let mut out = vec![1, 0x50, n_blocks as u8, p.code()];
    for (k, rec) in recs.iter().enumerate() {
        let (id, name, body) = match rec {
            Rec::Group(id, name) => (-*id, *name, vec![0u8]),
            Rec::Int(id, name, v) => {
                let mut b = vec![2u8, 1, v.len() as u8];
                for &x in v {
                    b.extend_from_slice(&p.u16_bytes(x as u16));
                }
                b.push(0);
                (*id, *name, b)
            }
            Rec::Float(id, name, v) => {
                let mut b = vec![4u8, 0];
                b.extend_from_slice(&p.f32_bytes(*v)?);
                b.push(0);
                (*id, *name, b)
            }
            Rec::Chars(id, name, v, array) => {
                let w = v.iter().map(|s| s.len()).max().unwrap_or(0).max(1);
                let mut b = if *array {
                    vec![(-1i8) as u8, 2, w as u8, v.len() as u8]
                } else {
                    vec![(-1i8) as u8, 1, w as u8]
                };
                if v.len() > 255 {
                    return Err(MocapError::Invalid {
                        what: format!("{} labels exceed one C3D parameter (255)", v.len()),
                    });
                }
                for s in v {
                    b.extend_from_slice(s.as_bytes());
                    b.extend(std::iter::repeat_n(b' ', w - s.len()));
                }
                b.push(0);
                (*id, *name, b)
            }
        };
        out.push(name.len() as u8);
        out.push(id as u8);
        out.extend_from_slice(name.as_bytes());
        let last = k + 1 == recs.len();
        let offset = if last { 0 } else { (2 + body.len()) as u16 };
        out.extend_from_slice(&p.u16_bytes(offset));
        out.extend_from_slice(&body);
    }
    Ok(out)
}
