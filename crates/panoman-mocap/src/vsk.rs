//! Vicon VSK subject calibrations (XML `KinematicModel`): named parameters, a segment tree
//! with joint types and offsets, and markers attached to segments.
//!
//! `POSITION` attributes are three tokens, each a number or a parameter name with an
//! optional leading `-` (`"0 -UpperLegLength 0"`, `"LFHD_Head_X LFHD_Head_Y LFHD_Head_Z"`),
//! resolved against `<Parameters>`. VSK states no unit: Vicon writes millimetres, which this
//! reader assumes and converts to metres. Segment positions are in the parent segment's
//! frame, marker positions in their segment's frame.

use std::path::Path;

use crate::error::{Result, format_err, read_text};

/// One segment of the skeleton.
#[derive(Clone, Debug, PartialEq)]
pub struct VskSegment {
    /// Segment name.
    pub name: String,
    /// Index of the parent segment in [`Vsk::segments`] (`None` for a root).
    pub parent: Option<usize>,
    /// Offset from the parent's origin in the parent's frame, metres.
    pub position: [f64; 3],
    /// `ORIENTATION` as written: a helical (axis × angle) vector, radians.
    pub orientation: [f64; 3],
    /// The joint element's name (`JointFree`, `JointBall`, `JointHinge`, `JointDummy`, …);
    /// empty when there is none.
    pub joint: String,
}

/// One marker of the marker set.
#[derive(Clone, Debug, PartialEq)]
pub struct VskMarker {
    /// Marker name (as in the captures, e.g. `LFHD`).
    pub name: String,
    /// The `SEGMENT` attribute as written.
    pub segment: String,
    /// Index of that segment in [`Vsk::segments`], when a segment of that name exists.
    pub segment_index: Option<usize>,
    /// Position in the segment's frame, metres.
    pub position: [f64; 3],
    /// Marker radius, metres (0 when absent).
    pub radius: f64,
}

/// A parsed VSK file.
#[derive(Clone, Debug, PartialEq)]
pub struct Vsk {
    /// `<Parameter NAME VALUE>` in file order, values as written (lengths in mm).
    pub parameters: Vec<(String, f64)>,
    /// Segments in document (depth-first) order; parents come before children.
    pub segments: Vec<VskSegment>,
    /// Markers in file order.
    pub markers: Vec<VskMarker>,
    /// `<Stick MARKER1 MARKER2>` pairs (display links between markers).
    pub sticks: Vec<(String, String)>,
}

impl Vsk {
    /// A parameter's value by name (as written, mm for lengths).
    pub fn parameter(&self, name: &str) -> Option<f64> {
        self.parameters
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| *v)
    }
}

/// Reads a VSK file.
///
/// # Errors
/// [`crate::MocapError::Io`] if it cannot be read; [`crate::MocapError::Format`] naming the
/// file, see [`parse_vsk`].
pub fn read_vsk(path: &Path) -> Result<Vsk> {
    parse_vsk(&read_text(path)?, path)
}

/// Parses VSK XML; `path` names the source in errors.
///
/// # Errors
/// [`crate::MocapError::Format`] naming `path` (and the XML line where it applies): invalid
/// XML, a root element other than `KinematicModel`, a parameter without a numeric value, a
/// segment or marker without `NAME`, a `POSITION` that is not three tokens or names an
/// unknown parameter, no segments.
pub fn parse_vsk(text: &str, path: &Path) -> Result<Vsk> {
    let doc = roxmltree::Document::parse(text)
        .map_err(|e| format_err(path, format!("invalid XML: {e}")))?;
    let root = doc.root_element();
    if root.tag_name().name() != "KinematicModel" {
        return Err(format_err(
            path,
            format!(
                "root element is <{}>, expected <KinematicModel>",
                root.tag_name().name()
            ),
        ));
    }
    let line = |n: roxmltree::Node| doc.text_pos_at(n.range().start).row;
    let mut vsk = Vsk {
        parameters: Vec::new(),
        segments: Vec::new(),
        markers: Vec::new(),
        sticks: Vec::new(),
    };
    for n in root.descendants().filter(|n| n.has_tag_name("Parameter")) {
        let name = attr(n, "NAME", path, line(n))?;
        let v = attr(n, "VALUE", path, line(n))?;
        let v = v.trim().parse::<f64>().ok().filter(|x| x.is_finite());
        let v = v.ok_or_else(|| {
            format_err(
                path,
                format!("line {}: parameter `{name}` has no numeric VALUE", line(n)),
            )
        })?;
        vsk.parameters.push((name.to_string(), v));
    }
    for n in root.descendants().filter(|n| n.has_tag_name("Segment")) {
        let name = attr(n, "NAME", path, line(n))?.to_string();
        let parent = n
            .ancestors()
            .skip(1)
            .find(|a| a.has_tag_name("Segment"))
            .and_then(|a| a.attribute("NAME"))
            .and_then(|pn| vsk.segments.iter().rposition(|s| s.name == pn));
        let position = position(&vsk, n, "POSITION", path, line(n))?;
        let orientation = match n.attribute("ORIENTATION") {
            Some(_) => numbers3(n, "ORIENTATION", path, line(n))?,
            None => [0.0; 3],
        };
        let joint = n
            .children()
            .find(|c| c.is_element() && c.tag_name().name().starts_with("Joint"))
            .map(|c| c.tag_name().name().to_string())
            .unwrap_or_default();
        vsk.segments.push(VskSegment {
            name,
            parent,
            position,
            orientation,
            joint,
        });
    }
    if vsk.segments.is_empty() {
        return Err(format_err(path, "no <Segment> elements"));
    }
    for n in root.descendants().filter(|n| n.has_tag_name("Marker")) {
        let name = attr(n, "NAME", path, line(n))?.to_string();
        let segment = n.attribute("SEGMENT").unwrap_or("").to_string();
        let segment_index = vsk.segments.iter().position(|s| s.name == segment);
        let position = position(&vsk, n, "POSITION", path, line(n))?;
        let radius = match n.attribute("RADIUS") {
            Some(r) => r
                .trim()
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    format_err(
                        path,
                        format!("line {}: marker `{name}`: bad RADIUS `{r}`", line(n)),
                    )
                })?,
            None => 0.0,
        } / 1000.0;
        vsk.markers.push(VskMarker {
            name,
            segment,
            segment_index,
            position,
            radius,
        });
    }
    for n in root.descendants().filter(|n| n.has_tag_name("Stick")) {
        if let (Some(a), Some(b)) = (n.attribute("MARKER1"), n.attribute("MARKER2")) {
            vsk.sticks.push((a.to_string(), b.to_string()));
        }
    }
    Ok(vsk)
}

fn attr<'a>(n: roxmltree::Node<'a, '_>, key: &str, path: &Path, line: u32) -> Result<&'a str> {
    n.attribute(key).ok_or_else(|| {
        let tag = n.tag_name().name();
        format_err(path, format!("line {line}: <{tag}> without {key}"))
    })
}

/// Three plain numbers.
fn numbers3(n: roxmltree::Node, key: &str, path: &Path, line: u32) -> Result<[f64; 3]> {
    let s = attr(n, key, path, line)?;
    let v: Vec<f64> = s
        .split_whitespace()
        .filter_map(|t| t.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect();
    if v.len() != 3 || s.split_whitespace().count() != 3 {
        return Err(format_err(
            path,
            format!("line {line}: {key} `{s}` is not three numbers"),
        ));
    }
    Ok([v[0], v[1], v[2]])
}

/// Three tokens, numbers or (negated) parameter names, mm → metres.
fn position(vsk: &Vsk, n: roxmltree::Node, key: &str, path: &Path, line: u32) -> Result<[f64; 3]> {
    let s = attr(n, key, path, line)?;
    let toks: Vec<&str> = s.split_whitespace().collect();
    if toks.len() != 3 {
        return Err(format_err(
            path,
            format!("line {line}: {key} `{s}` is not three values"),
        ));
    }
    let mut out = [0.0; 3];
    for (o, t) in out.iter_mut().zip(&toks) {
        let v = match t.parse::<f64>() {
            Ok(v) if v.is_finite() => v,
            Ok(_) => {
                return Err(format_err(
                    path,
                    format!("line {line}: {key}: `{t}` is not finite"),
                ));
            }
            Err(_) => {
                let (sign, name) = match t.strip_prefix('-') {
                    Some(rest) => (-1.0, rest),
                    None => (1.0, t.strip_prefix('+').unwrap_or(t)),
                };
                sign * vsk.parameter(name).ok_or_else(|| {
                    format_err(
                        path,
                        format!("line {line}: {key} names unknown parameter `{name}`"),
                    )
                })?
            }
        };
        *o = v / 1000.0;
    }
    Ok(out)
}
