//! Vicon CSM (Character Studio Marker) text files: `$Key value` header lines, `$Order`
//! followed by the marker names, `$Points` followed by one row per frame
//! `frame x₁ y₁ z₁ x₂ y₂ z₂ …`, where a marker missing in that frame is the single token
//! `DROPOUT` instead of its three coordinates.
//!
//! The format states no unit and no axes; Vicon writes millimetres in its Z-up lab frame,
//! which this reader assumes ([`UpSource::Convention`]). Rows must be numbered
//! `$FirstFrame, $FirstFrame + 1, …, $LastFrame` when those keys are present.

use std::path::Path;

use crate::error::{Result, format_err, read_text};
use crate::markers::{MarkerSequence, UpAxis, UpSource};

/// A CSM file's header values besides the points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CsmInfo {
    /// Other `$Key value` header lines (e.g. `Filename`, `Date`, `Actor`), in file order,
    /// key without `$`; `$Comments` text lines are joined with newlines.
    pub header: Vec<(String, String)>,
}

/// Reads a CSM file into a [`MarkerSequence`] (metres, Z up by convention) and its header.
///
/// # Errors
/// [`crate::MocapError::Io`] if it cannot be read; [`crate::MocapError::Format`] naming the
/// file and line, see [`parse_csm`].
pub fn read_csm(path: &Path) -> Result<(MarkerSequence, CsmInfo)> {
    parse_csm(&read_text(path)?, path)
}

/// Parses CSM text; `path` names the source in errors.
///
/// # Errors
/// [`crate::MocapError::Format`] naming `path` and the line: no `$Order` or no names, no
/// `$Points` or zero frames, a missing or non-positive `$Rate`, a row whose value count does
/// not match the marker count, a non-number or non-finite value, a frame number out of
/// sequence, or a row count that disagrees with `$FirstFrame`/`$LastFrame`.
pub fn parse_csm(text: &str, path: &Path) -> Result<(MarkerSequence, CsmInfo)> {
    let err = |line: usize, what: String| format_err(path, format!("line {line}: {what}"));
    let mut info = CsmInfo::default();
    let (mut names, mut rate, mut first, mut last) = (Vec::<String>::new(), None, None, None);
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l)).peekable();
    let mut points_line = None;
    while let Some((ln, line)) = lines.next() {
        let t = line.trim();
        let Some(rest) = t.strip_prefix('$') else {
            if t.is_empty() {
                continue;
            }
            return Err(err(
                ln,
                format!("expected a `$Key` line, found `{}`", clip(t)),
            ));
        };
        let (key, value) = rest.split_once(char::is_whitespace).unwrap_or((rest, ""));
        let value = value.trim();
        let num = |v: &str| -> Result<f64> {
            v.parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| err(ln, format!("${key}: `{v}` is not a number")))
        };
        match key.to_ascii_lowercase().as_str() {
            "rate" => rate = Some(num(value)?),
            "firstframe" => first = Some(num(value)? as i64),
            "lastframe" => last = Some(num(value)? as i64),
            "order" => {
                names.extend(value.split_whitespace().map(str::to_string));
                while let Some((_, l)) = lines.next_if(|(_, l)| !l.trim_start().starts_with('$')) {
                    names.extend(l.split_whitespace().map(str::to_string));
                }
            }
            "comments" => {
                let mut c = vec![value.to_string()];
                while let Some((_, l)) = lines.next_if(|(_, l)| !l.trim_start().starts_with('$')) {
                    c.push(l.trim().to_string());
                }
                let c = c.join("\n").trim().to_string();
                info.header.push(("Comments".into(), c));
            }
            "points" => {
                points_line = Some(ln);
                break;
            }
            _ => info.header.push((key.to_string(), value.to_string())),
        }
    }
    let points_line = points_line.ok_or_else(|| format_err(path, "no `$Points` section"))?;
    if names.is_empty() {
        return Err(format_err(
            path,
            "no marker names (`$Order` missing or empty)",
        ));
    }
    let rate = rate.ok_or_else(|| format_err(path, "no `$Rate`"))?;
    if rate <= 0.0 {
        return Err(format_err(path, format!("$Rate {rate} is not positive")));
    }
    let (positions, frame0, n_rows) = parse_rows(lines, &names, first, path)?;
    if n_rows == 0 {
        return Err(err(points_line, "zero frames after `$Points`".into()));
    }
    if let (Some(f), Some(l)) = (first, last)
        && l - f + 1 != n_rows as i64
    {
        return Err(format_err(
            path,
            format!(
                "$FirstFrame {f} .. $LastFrame {l} is {} frames but the file has {n_rows}",
                l - f + 1
            ),
        ));
    }
    let seq = MarkerSequence {
        names,
        rate_hz: rate,
        first_frame: frame0,
        positions,
        source_unit: "mm".into(),
        metres_per_unit: 0.001,
        up_axis: Some(UpAxis::Z),
        up_source: UpSource::Convention,
    };
    Ok((seq, info))
}

/// Rows after `$Points`: `(positions in metres, first row's frame number, row count)`.
fn parse_rows<'a>(
    lines: impl Iterator<Item = (usize, &'a str)>,
    names: &[String],
    first: Option<i64>,
    path: &Path,
) -> Result<(Vec<[f64; 3]>, i64, usize)> {
    let err = |line: usize, what: String| format_err(path, format!("line {line}: {what}"));
    let n = names.len();
    let mut positions: Vec<[f64; 3]> = Vec::new();
    let mut frame0 = None;
    let mut n_rows = 0usize;
    for (ln, line) in lines {
        let mut tok = line.split_whitespace();
        let Some(fr) = tok.next() else { continue };
        let fr: i64 = fr
            .parse()
            .map_err(|_| err(ln, format!("frame number `{}` is not an integer", clip(fr))))?;
        let expect = frame0
            .map(|f0: i64| f0 + n_rows as i64)
            .or(first)
            .unwrap_or(fr);
        if fr != expect {
            return Err(err(
                ln,
                format!("frame {fr} out of sequence (expected {expect})"),
            ));
        }
        frame0.get_or_insert(fr);
        let mut k = 0;
        while let Some(t) = tok.next() {
            if k == n {
                return Err(err(
                    ln,
                    format!("more values than the {n} markers of `$Order`"),
                ));
            }
            if t.eq_ignore_ascii_case("DROPOUT") {
                positions.push([f64::NAN; 3]);
            } else {
                let mut c = [0.0; 3];
                let mut got = 0;
                for (j, s) in std::iter::once(t).chain(tok.by_ref().take(2)).enumerate() {
                    c[j] = s
                        .parse::<f64>()
                        .ok()
                        .filter(|x| x.is_finite())
                        .ok_or_else(|| {
                            let m = &names[k];
                            err(
                                ln,
                                format!("marker `{m}`: `{}` is not a finite number", clip(s)),
                            )
                        })?;
                    got = j + 1;
                }
                if got != 3 {
                    let m = &names[k];
                    return Err(err(ln, format!("marker `{m}` has {got} of 3 coordinates")));
                }
                positions.push(c.map(|x| x / 1000.0));
            }
            k += 1;
        }
        if k != n || positions.len() != (n_rows + 1) * n {
            return Err(err(
                ln,
                format!("{k} markers' values, expected {n} (`$Order`)"),
            ));
        }
        n_rows += 1;
    }
    Ok((positions, frame0.unwrap_or(1), n_rows))
}

/// The first 40 characters of a token, for messages.
pub(crate) fn clip(s: &str) -> String {
    let mut c: String = s.chars().take(40).collect();
    if c.len() < s.len() {
        c.push('…');
    }
    c
}
