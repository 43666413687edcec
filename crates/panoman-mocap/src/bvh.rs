//! BVH (Biovision hierarchy) skeletal motion: reader, writer and forward kinematics.
//!
//! `HIERARCHY` gives a joint tree (`ROOT`/`JOINT name { OFFSET x y z CHANNELS n … }`, leaves
//! `End Site { OFFSET … }`); `MOTION` gives `Frames: N`, `Frame Time: t` (seconds) and `N`
//! rows of all joints' channel values in hierarchy order. Any order and number (≤ 6, each at
//! most once) of the channels `Xposition Yposition Zposition Xrotation Yrotation Zrotation`
//! is accepted per joint; rotations are degrees.
//!
//! Forward kinematics (the common reading, as in CMU's and MotionBuilder's files): a joint's
//! local transform is `T(offset + p) · R₁ · R₂ · …`, where `p` collects its position
//! channels and `R₁, R₂, …` are its rotation channels in the order listed (a listed
//! `Zrotation Yrotation Xrotation` is `Rz·Ry·Rx` acting on column vectors); the world
//! transform is the parent's world transform times the local one.
//!
//! Units: BVH states none. This module keeps the file's units ([`Bvh::scaled`] converts);
//! CMU's files use `1 unit = 0.0254 / 0.45 m` ([`CMU_UNIT_M`]).

use std::fmt::Write as _;
use std::path::Path;

use crate::csm::clip;
use crate::error::{MocapError, Result, format_err, read_text, write_atomic};

/// Metres per unit of the CMU mocap BVH files (CMU's `0.45` scale of inches).
pub const CMU_UNIT_M: f64 = 0.0254 / 0.45;

/// Deepest joint nesting accepted (guards the recursive parser).
pub const MAX_DEPTH: usize = 256;

pub use panoman_mesh::align::Rigid;

/// One BVH channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Channel {
    /// Translation along X (file units).
    Xposition,
    /// Translation along Y.
    Yposition,
    /// Translation along Z.
    Zposition,
    /// Rotation about X, degrees.
    Xrotation,
    /// Rotation about Y, degrees.
    Yrotation,
    /// Rotation about Z, degrees.
    Zrotation,
}

impl Channel {
    /// The keyword as written in BVH.
    pub fn name(self) -> &'static str {
        match self {
            Channel::Xposition => "Xposition",
            Channel::Yposition => "Yposition",
            Channel::Zposition => "Zposition",
            Channel::Xrotation => "Xrotation",
            Channel::Yrotation => "Yrotation",
            Channel::Zrotation => "Zrotation",
        }
    }

    /// Parses a keyword (case-insensitive).
    pub fn parse(s: &str) -> Option<Channel> {
        [
            Channel::Xposition,
            Channel::Yposition,
            Channel::Zposition,
            Channel::Xrotation,
            Channel::Yrotation,
            Channel::Zrotation,
        ]
        .into_iter()
        .find(|c| c.name().eq_ignore_ascii_case(s))
    }

    /// The axis index (0 = X, 1 = Y, 2 = Z).
    pub fn axis(self) -> usize {
        match self {
            Channel::Xposition | Channel::Xrotation => 0,
            Channel::Yposition | Channel::Yrotation => 1,
            Channel::Zposition | Channel::Zrotation => 2,
        }
    }

    /// Whether this is a rotation channel.
    pub fn is_rotation(self) -> bool {
        matches!(
            self,
            Channel::Xrotation | Channel::Yrotation | Channel::Zrotation
        )
    }
}

/// One joint of the hierarchy.
#[derive(Clone, Debug, PartialEq)]
pub struct BvhJoint {
    /// Joint name.
    pub name: String,
    /// Parent index in [`Bvh::joints`] (`None` for a root); must be smaller than the
    /// joint's own index (as [`parse_bvh`] produces; forward kinematics relies on it).
    pub parent: Option<usize>,
    /// Offset from the parent joint in the parent's frame, file units.
    pub offset: [f64; 3],
    /// Channels in file order.
    pub channels: Vec<Channel>,
    /// `End Site` offset in this joint's frame, when the joint has one.
    pub end_site: Option<[f64; 3]>,
}

/// A BVH file: hierarchy and motion, in file units.
#[derive(Clone, Debug, PartialEq)]
pub struct Bvh {
    /// Joints in file (depth-first) order.
    pub joints: Vec<BvhJoint>,
    /// Seconds per frame (> 0).
    pub frame_time_s: f64,
    /// Channel values, `[n_frames · n_channels]`, frame-major, joints and channels in file
    /// order.
    pub motion: Vec<f64>,
}

/// Rotation about axis `a` (0 X, 1 Y, 2 Z) by `deg` degrees.
pub fn axis_rotation(a: usize, deg: f64) -> [[f64; 3]; 3] {
    let (s, c) = deg.to_radians().sin_cos();
    match a {
        0 => [[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]],
        1 => [[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]],
        _ => [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]],
    }
}

/// `a · b`.
pub fn mul3(a: &[[f64; 3]; 3], b: &[[f64; 3]; 3]) -> [[f64; 3]; 3] {
    let mut o = [[0.0; 3]; 3];
    for (i, row) in o.iter_mut().enumerate() {
        for (j, x) in row.iter_mut().enumerate() {
            *x = (0..3).map(|k| a[i][k] * b[k][j]).sum();
        }
    }
    o
}

impl Bvh {
    /// Number of channels over all joints.
    pub fn n_channels(&self) -> usize {
        self.joints.iter().map(|j| j.channels.len()).sum()
    }

    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.motion
            .len()
            .checked_div(self.n_channels())
            .unwrap_or(0)
    }

    /// Frame rate, Hz.
    pub fn rate_hz(&self) -> f64 {
        1.0 / self.frame_time_s
    }

    /// Index of a joint by name.
    pub fn joint_index(&self, name: &str) -> Option<usize> {
        self.joints.iter().position(|j| j.name == name)
    }

    /// The channel values of frame `f`.
    ///
    /// # Panics
    /// If `f ≥ n_frames`.
    #[track_caller]
    pub fn frame(&self, f: usize) -> &[f64] {
        let c = self.n_channels();
        &self.motion[f * c..(f + 1) * c]
    }

    /// World transforms of every joint at frame `f` (see the module docs), file units.
    ///
    /// # Panics
    /// If `f ≥ n_frames`.
    #[track_caller]
    pub fn world_transforms(&self, f: usize) -> Vec<Rigid> {
        let values = self.frame(f);
        let mut k = 0;
        let mut out: Vec<Rigid> = Vec::with_capacity(self.joints.len());
        for j in &self.joints {
            let mut t = j.offset;
            let mut r = axis_rotation(0, 0.0);
            for &c in &j.channels {
                let v = values[k];
                k += 1;
                if c.is_rotation() {
                    r = mul3(&r, &axis_rotation(c.axis(), v));
                } else {
                    t[c.axis()] += v;
                }
            }
            let w = match j.parent {
                None => Rigid { r, t },
                Some(p) => {
                    let pw = &out[p];
                    Rigid {
                        r: mul3(&pw.r, &r),
                        t: pw.apply(t),
                    }
                }
            };
            out.push(w);
        }
        out
    }

    /// World positions of every joint at frame `f`, file units.
    ///
    /// # Panics
    /// If `f ≥ n_frames`.
    #[track_caller]
    pub fn joint_positions(&self, f: usize) -> Vec<[f64; 3]> {
        self.world_transforms(f).into_iter().map(|w| w.t).collect()
    }

    /// World positions of the end sites at frame `f`, as `(joint index, position)`.
    ///
    /// # Panics
    /// If `f ≥ n_frames`.
    #[track_caller]
    pub fn end_site_positions(&self, f: usize) -> Vec<(usize, [f64; 3])> {
        let w = self.world_transforms(f);
        self.joints
            .iter()
            .enumerate()
            .filter_map(|(i, j)| j.end_site.map(|e| (i, w[i].apply(e))))
            .collect()
    }

    /// A copy with every length (offsets, end sites, position channels) multiplied by `s`
    /// (e.g. [`CMU_UNIT_M`] to get metres).
    pub fn scaled(&self, s: f64) -> Bvh {
        let mut out = self.clone();
        let mut pos_mask = Vec::new();
        for j in &mut out.joints {
            j.offset = j.offset.map(|x| x * s);
            j.end_site = j.end_site.map(|e| e.map(|x| x * s));
            pos_mask.extend(j.channels.iter().map(|c| !c.is_rotation()));
        }
        if !pos_mask.is_empty() {
            for (i, v) in out.motion.iter_mut().enumerate() {
                if pos_mask[i % pos_mask.len()] {
                    *v *= s;
                }
            }
        }
        out
    }

    /// The BVH text (tabs for indentation; numbers in Rust's shortest round-trip form, so
    /// [`parse_bvh`] reads back the same values exactly). Joints are written depth-first
    /// from each root (children in index order), and each row's values in that order.
    pub fn to_text(&self) -> String {
        let mut s = String::from("HIERARCHY\n");
        let kids =
            |p: usize| (0..self.joints.len()).filter(move |&c| self.joints[c].parent == Some(p));
        // Depth-first with an explicit stack: (joint, depth, opened?).
        let roots: Vec<usize> = (0..self.joints.len())
            .filter(|&j| self.joints[j].parent.is_none())
            .collect();
        let mut stack: Vec<(usize, usize, bool)> =
            roots.iter().rev().map(|&r| (r, 0, false)).collect();
        let v3 = |v: [f64; 3]| format!("{} {} {}", v[0], v[1], v[2]);
        let mut visit = Vec::with_capacity(self.joints.len());
        while let Some((j, d, opened)) = stack.pop() {
            let ind = "\t".repeat(d);
            let jt = &self.joints[j];
            if opened {
                if let Some(e) = jt.end_site {
                    let _ = writeln!(
                        s,
                        "{ind}\tEnd Site\n{ind}\t{{\n{ind}\t\tOFFSET {}\n{ind}\t}}",
                        v3(e)
                    );
                }
                let _ = writeln!(s, "{ind}}}");
                continue;
            }
            let kw = if jt.parent.is_none() { "ROOT" } else { "JOINT" };
            let _ = writeln!(
                s,
                "{ind}{kw} {}\n{ind}{{\n{ind}\tOFFSET {}",
                jt.name,
                v3(jt.offset)
            );
            let ch: Vec<&str> = jt.channels.iter().map(|c| c.name()).collect();
            let _ = writeln!(s, "{ind}\tCHANNELS {} {}", ch.len(), ch.join(" "));
            stack.push((j, d, true));
            visit.push(j);
            let k: Vec<usize> = kids(j).collect();
            stack.extend(k.iter().rev().map(|&c| (c, d + 1, false)));
        }
        let _ = writeln!(
            s,
            "MOTION\nFrames: {}\nFrame Time: {}",
            self.n_frames(),
            self.frame_time_s
        );
        // Rows follow the written (depth-first) joint order, which is `joints` order for
        // anything read by `parse_bvh`.
        let mut start = Vec::with_capacity(self.joints.len());
        let mut k = 0;
        for j in &self.joints {
            start.push(k);
            k += j.channels.len();
        }
        for f in 0..self.n_frames() {
            let values = self.frame(f);
            let row: Vec<String> = visit
                .iter()
                .flat_map(|&j| &values[start[j]..start[j] + self.joints[j].channels.len()])
                .map(|v| v.to_string())
                .collect();
            s.push_str(&row.join(" "));
            s.push('\n');
        }
        s
    }

    /// Writes [`Bvh::to_text`] to `path` atomically (temporary file + rename).
    ///
    /// # Errors
    /// [`MocapError::Io`] naming the file.
    pub fn write(&self, path: &Path) -> Result<()> {
        write_atomic(path, self.to_text().as_bytes())
    }
}

/// Reads a BVH file.
///
/// # Errors
/// [`MocapError::Io`] if it cannot be read; [`MocapError::Format`] naming the file and the
/// line, see [`parse_bvh`].
pub fn read_bvh(path: &Path) -> Result<Bvh> {
    parse_bvh(&read_text(path)?, path)
}

/// Token cursor over the hierarchy lines.
struct Toks<'a> {
    t: Vec<(usize, &'a str)>,
    i: usize,
    path: &'a Path,
    last_line: usize,
}

impl<'a> Toks<'a> {
    fn err(&self, what: impl Into<String>) -> MocapError {
        let ln = self.t.get(self.i).map(|x| x.0).unwrap_or(self.last_line);
        format_err(self.path, format!("line {ln}: {}", what.into()))
    }
    fn next(&mut self, what: &str) -> Result<&'a str> {
        let tok = self.t.get(self.i).map(|x| x.1);
        let tok =
            tok.ok_or_else(|| self.err(format!("unexpected end of HIERARCHY, expected {what}")))?;
        self.i += 1;
        Ok(tok)
    }
    fn expect(&mut self, kw: &str) -> Result<()> {
        let t = self.next(kw)?;
        if t.eq_ignore_ascii_case(kw) {
            Ok(())
        } else {
            self.i -= 1;
            Err(self.err(format!("expected `{kw}`, found `{}`", clip(t))))
        }
    }
    fn number(&mut self, what: &str) -> Result<f64> {
        let t = self.next(what)?;
        t.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| {
                self.i -= 1;
                self.err(format!("{what}: `{}` is not a finite number", clip(t)))
            })
    }
    fn vec3(&mut self, what: &str) -> Result<[f64; 3]> {
        Ok([self.number(what)?, self.number(what)?, self.number(what)?])
    }
}

/// Parses BVH text; `path` names the source in errors. Several `ROOT` hierarchies may
/// follow each other; their joints are numbered in file order.
///
/// # Errors
/// [`MocapError::Format`] naming `path` and the line: a missing `HIERARCHY`/`ROOT`/`MOTION`,
/// unbalanced braces, an unknown or repeated channel, more than 6 channels on a joint,
/// nesting deeper than [`MAX_DEPTH`], a duplicate joint name, no channels at all, a missing
/// or non-positive frame time, a row with the wrong number of values, a non-finite value,
/// or a row count different from `Frames:`.
pub fn parse_bvh(text: &str, path: &Path) -> Result<Bvh> {
    let lines: Vec<&str> = text.lines().collect();
    let motion_at = lines
        .iter()
        .position(|l| l.trim().eq_ignore_ascii_case("MOTION"))
        .ok_or_else(|| format_err(path, "no MOTION line"))?;
    let t: Vec<(usize, &str)> = lines[..motion_at]
        .iter()
        .enumerate()
        .flat_map(|(i, l)| l.split_whitespace().map(move |w| (i + 1, w)))
        .collect();
    let mut toks = Toks {
        t,
        i: 0,
        path,
        last_line: motion_at + 1,
    };
    toks.expect("HIERARCHY")?;
    toks.expect("ROOT")?;
    let mut joints = Vec::new();
    parse_joint(&mut toks, &mut joints, None, 0)?;
    while toks
        .t
        .get(toks.i)
        .is_some_and(|t| t.1.eq_ignore_ascii_case("ROOT"))
    {
        toks.i += 1;
        parse_joint(&mut toks, &mut joints, None, 0)?;
    }
    if toks.i < toks.t.len() {
        return Err(toks.err(format!(
            "unexpected `{}` after the hierarchy",
            clip(toks.t[toks.i].1)
        )));
    }
    let n_ch: usize = joints.iter().map(|j: &BvhJoint| j.channels.len()).sum();
    if n_ch == 0 {
        return Err(format_err(path, "the hierarchy has no channels"));
    }
    let (frame_time_s, motion) = parse_motion(&lines, motion_at, n_ch, path)?;
    Ok(Bvh {
        joints,
        frame_time_s,
        motion,
    })
}

/// Parses one joint (after its `ROOT`/`JOINT` keyword) and its subtree.
fn parse_joint(
    t: &mut Toks,
    joints: &mut Vec<BvhJoint>,
    parent: Option<usize>,
    depth: usize,
) -> Result<()> {
    if depth > MAX_DEPTH {
        return Err(t.err(format!("joints nested deeper than {MAX_DEPTH}")));
    }
    let name = t.next("a joint name")?.to_string();
    if joints.iter().any(|j| j.name == name) {
        t.i -= 1;
        return Err(t.err(format!("duplicate joint name `{}`", clip(&name))));
    }
    t.expect("{")?;
    t.expect("OFFSET")?;
    let offset = t.vec3(&format!("OFFSET of `{}`", clip(&name)))?;
    let me = joints.len();
    joints.push(BvhJoint {
        name,
        parent,
        offset,
        channels: Vec::new(),
        end_site: None,
    });
    loop {
        let kw = t.next("`}`")?;
        match kw.to_ascii_uppercase().as_str() {
            "CHANNELS" => {
                let n = t.number("the channel count")?;
                if !(0.0..=6.0).contains(&n) || n.fract() != 0.0 {
                    t.i -= 1;
                    return Err(t.err(format!("channel count {n} (expected 0 to 6)")));
                }
                for _ in 0..n as usize {
                    let c = t.next("a channel name")?;
                    let ch = Channel::parse(c).ok_or_else(|| {
                        t.i -= 1;
                        t.err(format!(
                            "unknown channel `{}` on joint `{}`",
                            clip(c),
                            joints[me].name
                        ))
                    })?;
                    if joints[me].channels.contains(&ch) {
                        t.i -= 1;
                        return Err(
                            t.err(format!("channel `{c}` repeated on `{}`", joints[me].name))
                        );
                    }
                    joints[me].channels.push(ch);
                }
            }
            "JOINT" => parse_joint(t, joints, Some(me), depth + 1)?,
            "END" => {
                t.expect("Site")?;
                t.expect("{")?;
                t.expect("OFFSET")?;
                let e = t.vec3("End Site OFFSET")?;
                t.expect("}")?;
                if joints[me].end_site.replace(e).is_some() {
                    return Err(t.err(format!("second End Site on `{}`", joints[me].name)));
                }
            }
            "}" => return Ok(()),
            _ => {
                t.i -= 1;
                return Err(t.err(format!(
                    "unexpected `{}` in joint `{}`",
                    clip(kw),
                    joints[me].name
                )));
            }
        }
    }
}

/// Parses `Frames:`, `Frame Time:` and the rows after the `MOTION` line.
fn parse_motion(
    lines: &[&str],
    motion_at: usize,
    n_ch: usize,
    path: &Path,
) -> Result<(f64, Vec<f64>)> {
    let err = |ln: usize, what: String| format_err(path, format!("line {ln}: {what}"));
    let mut it = lines
        .iter()
        .enumerate()
        .skip(motion_at + 1)
        .filter(|(_, l)| !l.trim().is_empty());
    let mut header = |key: &str| -> Result<(usize, f64)> {
        let (i, l) = it
            .next()
            .ok_or_else(|| err(lines.len(), format!("expected `{key}` after MOTION")))?;
        let l = l.trim();
        let v = l
            .get(..key.len())
            .filter(|p| p.eq_ignore_ascii_case(key))
            .map(|_| l[key.len()..].trim())
            .ok_or_else(|| err(i + 1, format!("expected `{key}`, found `{}`", clip(l))))?;
        let x = v.parse::<f64>().ok().filter(|x| x.is_finite());
        let x = x.ok_or_else(|| err(i + 1, format!("{key} `{}` is not a number", clip(v))))?;
        Ok((i + 1, x))
    };
    let (fl, n_frames) = header("Frames:")?;
    if n_frames < 0.0 || n_frames.fract() != 0.0 {
        return Err(err(fl, format!("Frames: {n_frames} is not a count")));
    }
    let (tl, dt) = header("Frame Time:")?;
    if dt <= 0.0 {
        return Err(err(tl, format!("Frame Time: {dt} is not positive")));
    }
    let rest = &lines[tl..];
    let bytes_left: usize = rest.iter().map(|l| l.len() + 1).sum();
    // Each value takes at least 2 bytes ("0 "), so this caps a lying `Frames:`.
    let cap = (n_frames as usize)
        .saturating_mul(n_ch)
        .min(bytes_left / 2 + n_ch);
    let mut motion = Vec::with_capacity(cap);
    let mut rows = 0usize;
    for (k, l) in rest.iter().enumerate() {
        if l.trim().is_empty() {
            continue;
        }
        let ln = tl + k + 1;
        let before = motion.len();
        for tok in l.split_whitespace() {
            let v = tok.parse::<f64>().ok().filter(|x| x.is_finite());
            motion
                .push(v.ok_or_else(|| err(ln, format!("`{}` is not a finite number", clip(tok))))?);
        }
        let got = motion.len() - before;
        if got != n_ch {
            return Err(err(
                ln,
                format!("{got} values, expected {n_ch} (one per channel)"),
            ));
        }
        rows += 1;
    }
    if rows as f64 != n_frames {
        return Err(err(
            fl,
            format!("Frames: {n_frames} but the file has {rows} rows"),
        ));
    }
    Ok((dt, motion))
}
