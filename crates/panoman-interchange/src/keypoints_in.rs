//! Keypoints from other tools → TC-133 targets ([`KeypointsFile`]).
//!
//! Layouts (mapping tables and examples: `docs/formats-interchange.md`):
//!
//! * **panoman JSON** (`{"units": "m", "keypoints": {…}, "weights": {…}}`, TC-133 names; a
//!   TC-127 file is one without the feet), read by [`KeypointsFile::parse`]; always metres.
//! * **OpenPose JSON** (one file per frame): `people[person]` with `pose_keypoints_3d` (BODY_25,
//!   25 × `x y z c`: the 15 body joints and the six foot points), `face_keypoints_3d` (70 × 4), `hand_left_keypoints_3d` and
//!   `hand_right_keypoints_3d` (21 × 4 each). An empty or absent array is an absent group. The
//!   `_2d` arrays are recognised, but a file that has only 2D keypoints is rejected (the fit
//!   needs 3D targets).
//! * **CMU Panoptic** (Total Capture's studio format), three files per frame:
//!   `hdPose3d_stage1_coco19` (`bodies[person].joints19`, 19 × `x y z c`), `hdFace3d`
//!   (`people[person].face70.landmarks`, 70 × `x y z`) and `hdHand3d`
//!   (`people[person].left_hand` / `right_hand` with `landmarks`, 21 × `x y z`, and
//!   `averageScore`). The face and hands have no per-point confidence: each point gets the
//!   part's `averageScore` (1 when absent).
//!
//! Confidences become weights; a point whose confidence is 0 is skipped (missing), as is every
//! TC-133 keypoint the source has no counterpart for. A negative or non-finite confidence or
//! coordinate is an error. OpenPose and Panoptic coordinates are scaled by [`Unit`]
//! (centimetres by default, both tools' unit) and otherwise taken as they are (no change of
//! axes: the fit's placement absorbs the frame).
//!
//! [`detect`] names the layout of a parsed JSON document from its keys; every error names the
//! file.

use std::path::Path;

use panoman_human::keypoints::{
    FACE_OFFSET, FEET_OFFSET, KeypointsFile, LHAND_OFFSET, N_BODY, N_FACE, N_FEET, N_HAND,
    RHAND_OFFSET,
};
use panoman_mesh::geom::V3;
use serde_json::Value;

use crate::error::{InterchangeError, Result};

/// Which of the supported formats a keypoints file is in (the CLI's `--keypoints-format`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum KeypointFormat {
    /// panoman's keypoints JSON (TC-133 names; TC-127 files are the same without the feet).
    Panoman,
    /// OpenPose JSON (BODY_25 + face 70 + hands 2 × 21).
    OpenPose,
    /// CMU Panoptic `hdPose3d_stage1_coco19` / `hdFace3d` / `hdHand3d` JSON.
    Panoptic,
}

impl std::str::FromStr for KeypointFormat {
    type Err = InterchangeError;

    /// `panoman` (also `tc133` and the older layout's `tc127`), `openpose` or `panoptic`
    /// (case-insensitive).
    fn from_str(s: &str) -> Result<Self> {
        match s.to_ascii_lowercase().as_str() {
            "panoman" | "tc133" | "tc-133" | "tc127" | "tc-127" => Ok(KeypointFormat::Panoman),
            "openpose" => Ok(KeypointFormat::OpenPose),
            "panoptic" => Ok(KeypointFormat::Panoptic),
            _ => Err(InterchangeError::Invalid(format!(
                "unknown keypoints format `{s}` (expected panoman, openpose or panoptic)"
            ))),
        }
    }
}

/// The concrete layout of one file, as [`detect`] finds it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Layout {
    /// panoman's keypoints JSON (`keypoints`).
    Panoman,
    /// OpenPose JSON (`people[].pose_keypoints_*` / `face_keypoints_*` / `hand_*_keypoints_*`).
    OpenPose,
    /// Panoptic body (`bodies[].joints19`).
    PanopticBody,
    /// Panoptic face (`people[].face70`).
    PanopticFace,
    /// Panoptic hands (`people[].left_hand` / `right_hand`).
    PanopticHand,
}

impl Layout {
    /// The format this layout belongs to.
    pub fn format(self) -> KeypointFormat {
        match self {
            Layout::Panoman => KeypointFormat::Panoman,
            Layout::OpenPose => KeypointFormat::OpenPose,
            _ => KeypointFormat::Panoptic,
        }
    }
}

/// Length unit of OpenPose / Panoptic coordinates (TC-133 files are always metres).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Unit {
    /// Metres.
    Metre,
    /// Centimetres (the default: OpenPose's 3D reconstruction and CMU Panoptic use cm).
    #[default]
    Centimetre,
    /// Millimetres.
    Millimetre,
}

impl Unit {
    /// Metres per unit.
    pub fn metres(self) -> f64 {
        1.0 / self.per_metre()
    }

    /// Units per metre (1, 100, 1000). Coordinates are converted by dividing by it, which is
    /// correctly rounded: a value written as `x · 100` converts back to `x` far more often
    /// than with a multiplication by 0.01.
    pub fn per_metre(self) -> f64 {
        match self {
            Unit::Metre => 1.0,
            Unit::Centimetre => 100.0,
            Unit::Millimetre => 1000.0,
        }
    }
}

impl std::str::FromStr for Unit {
    type Err = InterchangeError;

    /// `m`, `cm` or `mm`.
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "m" => Ok(Unit::Metre),
            "cm" => Ok(Unit::Centimetre),
            "mm" => Ok(Unit::Millimetre),
            _ => Err(InterchangeError::Invalid(format!(
                "unknown unit `{s}` (expected m, cm or mm)"
            ))),
        }
    }
}

/// Options of the readers.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImportOptions {
    /// Unit of OpenPose / Panoptic coordinates (default centimetres).
    pub unit: Unit,
    /// Which person of `people[]` / `bodies[]` to read (default 0, the first).
    pub person: usize,
    /// The expected format; `None` detects it from the keys.
    pub format: Option<KeypointFormat>,
}

/// OpenPose BODY_25 index of each TC-133 body keypoint (all 15 have one).
pub const OPENPOSE_BODY25_TO_TC133: [usize; N_BODY] =
    [1, 0, 8, 5, 6, 7, 12, 13, 14, 2, 3, 4, 9, 10, 11];

/// Panoptic `coco19` index of each TC-133 body keypoint: the first 15 joints, same order.
pub const PANOPTIC_COCO19_TO_TC133: [usize; N_BODY] =
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14];

/// The layout of a parsed keypoints document, from its keys.
///
/// # Errors
/// A [`InterchangeError::Format`] naming `path` when no layout or more than one fits.
pub fn detect(doc: &Value, path: &Path) -> Result<Layout> {
    let obj = doc
        .as_object()
        .ok_or_else(|| InterchangeError::format(path, "expected a JSON object"))?;
    let mut found = Vec::new();
    if obj.contains_key("keypoints") {
        found.push(Layout::Panoman);
    }
    if obj.contains_key("bodies") {
        found.push(Layout::PanopticBody);
    }
    if let Some(people) = obj.get("people").and_then(Value::as_array) {
        let has = |k: &str| people.iter().any(|p| p.get(k).is_some());
        let openpose = people.iter().any(|p| {
            p.as_object().is_some_and(|m| {
                m.keys().any(|k| {
                    k.starts_with("pose_keypoints")
                        || k.starts_with("face_keypoints")
                        || k.starts_with("hand_left_keypoints")
                        || k.starts_with("hand_right_keypoints")
                })
            })
        });
        if openpose {
            found.push(Layout::OpenPose);
        }
        if has("face70") {
            found.push(Layout::PanopticFace);
        }
        if has("left_hand") || has("right_hand") {
            found.push(Layout::PanopticHand);
        }
        if people.is_empty() && obj.contains_key("version") {
            // OpenPose writes `{"version": 1.3, "people": []}` for a frame with nobody.
            found.push(Layout::OpenPose);
        }
    }
    match found.as_slice() {
        [one] => Ok(*one),
        [] => Err(InterchangeError::format(
            path,
            "unknown keypoints layout: expected panoman (`keypoints`), OpenPose \
             (`people[].pose_keypoints_3d` …) or CMU Panoptic (`bodies[].joints19`, \
             `people[].face70`, `people[].left_hand`/`right_hand`)",
        )),
        many => Err(InterchangeError::format(
            path,
            format!("ambiguous keypoints layout: the keys fit {many:?}"),
        )),
    }
}

/// Reads one keypoints file of any supported layout as TC-133 targets.
///
/// # Errors
/// I/O, JSON, unknown or unexpected layout, wrong array lengths, 2D-only OpenPose data, bad
/// values: one error naming the file.
pub fn read_keypoints(path: &Path, options: &ImportOptions) -> Result<KeypointsFile> {
    let text = std::fs::read_to_string(path).map_err(|e| InterchangeError::io(path, e))?;
    parse_keypoints(&text, path, options)
}

/// Reads several files (e.g. a Panoptic frame's body, face and hand files) and merges them.
///
/// # Errors
/// Those of [`read_keypoints`], and a keypoint given by two of the files (naming both).
pub fn read_keypoints_files(paths: &[&Path], options: &ImportOptions) -> Result<KeypointsFile> {
    let mut out = KeypointsFile::default();
    let mut from: std::collections::BTreeMap<usize, &Path> = Default::default();
    for &p in paths {
        let k = read_keypoints(p, options)?;
        for (i, q) in k.points {
            if let Some(prev) = from.insert(i, p) {
                let name = &panoman_human::keypoints::keypoint_names()[i];
                return Err(InterchangeError::format(
                    p,
                    format!("keypoint `{name}` is also given by {}", prev.display()),
                ));
            }
            out.points.insert(i, q);
            if let Some(&w) = k.weights.get(&i) {
                out.weights.insert(i, w);
            }
        }
    }
    Ok(out)
}

/// OpenPose BODY_25 index of each TC-133 foot keypoint (`LBigToe`, `LSmallToe`, `LHeel`,
/// `RBigToe`, `RSmallToe`, `RHeel`: [`panoman_human::keypoints::FEET_NAMES`] order).
pub const OPENPOSE_BODY25_FEET: [usize; N_FEET] = [19, 20, 21, 22, 23, 24];

/// Parses keypoints JSON text of any supported layout (`path` names the file in errors).
///
/// # Errors
/// See [`read_keypoints`].
pub fn parse_keypoints(text: &str, path: &Path, options: &ImportOptions) -> Result<KeypointsFile> {
    let doc: Value = serde_json::from_str(text)
        .map_err(|e| InterchangeError::format(path, format!("invalid JSON: {e}")))?;
    let layout = detect(&doc, path)?;
    if let Some(want) = options.format
        && layout.format() != want
    {
        return Err(InterchangeError::format(
            path,
            format!("expected {want:?} keypoints, the file's keys say {layout:?}"),
        ));
    }
    let fmt = |w: String| InterchangeError::format(path, w);
    let mut acc = Acc {
        out: KeypointsFile::default(),
        per_metre: options.unit.per_metre(),
    };
    match layout {
        Layout::Panoman => {
            return KeypointsFile::parse(text).map_err(|e| fmt(e.to_string()));
        }
        Layout::OpenPose => openpose(&doc, options.person, &mut acc).map_err(fmt)?,
        Layout::PanopticBody => {
            let body = pick(&doc, "bodies", options.person).map_err(fmt)?;
            if let Some(b) = body {
                let j = numbers(b.get("joints19"), "joints19").map_err(fmt)?;
                check_len(&j, 19, 4, "joints19 (COCO-19 × x y z c)").map_err(fmt)?;
                for (t, &s) in PANOPTIC_COCO19_TO_TC133.iter().enumerate() {
                    acc.point(t, &j[4 * s..4 * s + 3], j[4 * s + 3], "joints19", s)
                        .map_err(fmt)?;
                }
            }
        }
        Layout::PanopticFace => {
            if let Some(p) = pick(&doc, "people", options.person).map_err(fmt)?
                && let Some(face) = p.get("face70")
            {
                panoptic_part(face, "face70", FACE_OFFSET, N_FACE, &mut acc).map_err(fmt)?;
            }
        }
        Layout::PanopticHand => {
            if let Some(p) = pick(&doc, "people", options.person).map_err(fmt)? {
                for (key, offset) in [("left_hand", LHAND_OFFSET), ("right_hand", RHAND_OFFSET)] {
                    if let Some(h) = p.get(key) {
                        panoptic_part(h, key, offset, N_HAND, &mut acc).map_err(fmt)?;
                    }
                }
            }
        }
    }
    acc.out.validate().map_err(|e| fmt(e.to_string()))?;
    Ok(acc.out)
}

/// The collected targets and the unit (units per metre).
struct Acc {
    out: KeypointsFile,
    per_metre: f64,
}

impl Acc {
    /// Source values `xyz` with confidence `c` in metres; `None` for confidence 0.
    fn value(
        &self,
        xyz: &[f64],
        c: f64,
        array: &str,
        s: usize,
    ) -> std::result::Result<Option<V3>, String> {
        if !c.is_finite() || c < 0.0 {
            return Err(format!(
                "{array}[{s}]: confidence must be finite and ≥ 0, got {c}"
            ));
        }
        if let Some(x) = xyz.iter().find(|x| !x.is_finite()) {
            return Err(format!("{array}[{s}]: coordinate {x} is not finite"));
        }
        let m = self.per_metre;
        Ok((c > 0.0).then(|| [xyz[0] / m, xyz[1] / m, xyz[2] / m]))
    }

    /// Adds TC-133 keypoint `t` from source values `xyz` with confidence `c` (skipped if 0).
    fn point(
        &mut self,
        t: usize,
        xyz: &[f64],
        c: f64,
        array: &str,
        s: usize,
    ) -> std::result::Result<(), String> {
        if let Some(p) = self.value(xyz, c, array, s)? {
            self.out.points.insert(t, p);
            self.out.weights.insert(t, c);
        }
        Ok(())
    }
}

/// `doc[key][person]`, `None` when the array is shorter (nobody there).
fn pick<'a>(
    doc: &'a Value,
    key: &str,
    person: usize,
) -> std::result::Result<Option<&'a Value>, String> {
    let arr = doc
        .get(key)
        .and_then(Value::as_array)
        .ok_or_else(|| format!("`{key}` must be an array"))?;
    Ok(arr.get(person))
}

/// A JSON array of numbers (absent → empty).
fn numbers(v: Option<&Value>, name: &str) -> std::result::Result<Vec<f64>, String> {
    let Some(v) = v else { return Ok(Vec::new()) };
    let arr = v
        .as_array()
        .ok_or_else(|| format!("`{name}` must be an array of numbers"))?;
    arr.iter()
        .enumerate()
        .map(|(i, x)| {
            x.as_f64()
                .ok_or_else(|| format!("`{name}`[{i}]: `{x}` is not a number"))
        })
        .collect()
}

/// `values` must hold `n` records of `stride` numbers.
fn check_len(
    values: &[f64],
    n: usize,
    stride: usize,
    what: &str,
) -> std::result::Result<(), String> {
    if values.len() != n * stride {
        return Err(format!(
            "{what}: expected {} numbers ({n} × {stride}), got {}",
            n * stride,
            values.len()
        ));
    }
    Ok(())
}

/// OpenPose's four arrays: `(array stem, record count, TC-133 index of each source index)`,
/// `usize::MAX` where TC-133 has no counterpart (BODY_25's eyes and ears).
fn openpose_groups() -> [(&'static str, usize, Vec<usize>); 4] {
    let body: Vec<usize> = {
        let mut m = vec![usize::MAX; 25];
        for (t, &s) in OPENPOSE_BODY25_TO_TC133.iter().enumerate() {
            m[s] = t;
        }
        for (k, &s) in OPENPOSE_BODY25_FEET.iter().enumerate() {
            m[s] = FEET_OFFSET + k;
        }
        m
    };
    let seq = |o: usize, n: usize| (o..o + n).collect::<Vec<usize>>();
    [
        ("pose_keypoints", 25, body),
        ("face_keypoints", N_FACE, seq(FACE_OFFSET, N_FACE)),
        ("hand_left_keypoints", N_HAND, seq(LHAND_OFFSET, N_HAND)),
        ("hand_right_keypoints", N_HAND, seq(RHAND_OFFSET, N_HAND)),
    ]
}

/// 2D keypoints of one image: per TC-133 index, the pixel `[x, y]` and the detector's
/// confidence (> 0; points with confidence 0 are absent).
pub type Keypoints2d = std::collections::BTreeMap<usize, ([f64; 2], f64)>;

/// Reads the 2D keypoints of `people[person]` of one OpenPose JSON file (`*_keypoints_2d`
/// arrays, `x y c` per point, pixels; BODY_25 with the foot points, face 70, hands 21 each)
/// as TC-133 [`Keypoints2d`] (the mapping of the 3D reader). A frame without that person
/// gives an empty map.
///
/// # Errors
/// I/O, JSON, not an OpenPose file, an array whose length is not its count × 3, a
/// non-finite coordinate or a negative or non-finite confidence: one error naming the file.
pub fn read_openpose_2d(path: &Path, person: usize) -> Result<Keypoints2d> {
    let text = std::fs::read_to_string(path).map_err(|e| InterchangeError::io(path, e))?;
    parse_openpose_2d(&text, path, person)
}

/// [`read_openpose_2d`] on the file's text (`path` names it in errors).
///
/// # Errors
/// See [`read_openpose_2d`].
pub fn parse_openpose_2d(text: &str, path: &Path, person: usize) -> Result<Keypoints2d> {
    let fmt = |w: String| InterchangeError::format(path, w);
    let doc: Value = serde_json::from_str(text).map_err(|e| fmt(format!("invalid JSON: {e}")))?;
    if detect(&doc, path)? != Layout::OpenPose {
        return Err(fmt(
            "not an OpenPose file (no `people[]` keypoint arrays)".into()
        ));
    }
    let mut out = Keypoints2d::new();
    let Some(p) = pick(&doc, "people", person).map_err(fmt)? else {
        return Ok(out);
    };
    for (stem, n, map) in openpose_groups() {
        let key = format!("{stem}_2d");
        let v = numbers(p.get(key.as_str()), &key).map_err(fmt)?;
        if v.is_empty() {
            continue;
        }
        check_len(&v, n, 3, &format!("{key} (x y c per point)")).map_err(fmt)?;
        for (s, &t) in map.iter().enumerate() {
            let (xy, c) = ([v[3 * s], v[3 * s + 1]], v[3 * s + 2]);
            if !c.is_finite() || c < 0.0 {
                return Err(fmt(format!(
                    "{key}[{s}]: confidence must be finite and ≥ 0, got {c}"
                )));
            }
            if let Some(x) = xy.iter().find(|x| !x.is_finite()) {
                return Err(fmt(format!("{key}[{s}]: coordinate {x} is not finite")));
            }
            if t != usize::MAX && c > 0.0 {
                out.insert(t, (xy, c));
            }
        }
    }
    Ok(out)
}

/// OpenPose `people[person]`: 3D arrays if any is non-empty, else an error if 2D data exist.
fn openpose(doc: &Value, person: usize, acc: &mut Acc) -> std::result::Result<(), String> {
    let Some(p) = pick(doc, "people", person)? else {
        return Ok(());
    };
    let groups = openpose_groups();
    let mut any3d = false;
    let mut any2d = None;
    for (stem, _, _) in &groups {
        if !numbers(p.get(format!("{stem}_3d").as_str()), stem)?.is_empty() {
            any3d = true;
        }
        if any2d.is_none() && !numbers(p.get(format!("{stem}_2d").as_str()), stem)?.is_empty() {
            any2d = Some(format!("{stem}_2d"));
        }
    }
    if !any3d && let Some(k) = any2d {
        return Err(format!(
            "only 2D OpenPose keypoints (`{k}`); a 3D fit needs the `_3d` arrays \
                 (OpenPose's 3D reconstruction, x y z c per point)"
        ));
    }
    for (stem, n, map) in &groups {
        let key = format!("{stem}_3d");
        let v = numbers(p.get(key.as_str()), &key)?;
        if v.is_empty() {
            continue;
        }
        let what = if *stem == "pose_keypoints" {
            format!("{key} (BODY_25 × x y z c)")
        } else {
            format!("{key} (x y z c per point)")
        };
        check_len(&v, *n, 4, &what)?;
        for (s, &t) in map.iter().enumerate() {
            if t != usize::MAX {
                acc.point(t, &v[4 * s..4 * s + 3], v[4 * s + 3], &key, s)?;
            }
        }
    }
    Ok(())
}

/// A Panoptic face or hand part: `landmarks` (`n` × x y z), weight `averageScore` (default 1).
fn panoptic_part(
    part: &Value,
    key: &str,
    offset: usize,
    n: usize,
    acc: &mut Acc,
) -> std::result::Result<(), String> {
    let lm_key = format!("{key}.landmarks");
    let lm = numbers(part.get("landmarks"), &lm_key)?;
    check_len(&lm, n, 3, &format!("{lm_key} (x y z per point)"))?;
    let score = match part.get("averageScore") {
        None => 1.0,
        Some(s) => s
            .as_f64()
            .ok_or_else(|| format!("`{key}.averageScore`: `{s}` is not a number"))?,
    };
    for s in 0..n {
        acc.point(offset + s, &lm[3 * s..3 * s + 3], score, &lm_key, s)?;
    }
    Ok(())
}
