//! Optical marker trajectories common to every marker reader ([`crate::c3d`],
//! [`crate::csm`]): names, rate, per-frame positions in metres with missing samples, and the
//! source's units and up axis; plus the change to the project frame.

use crate::error::{MocapError, Result};

/// Which lab axis points up (the direction opposite to gravity), as recorded or assumed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// +X up.
    X,
    /// +Y up (Vicon C3D exports with `POINT:Y_SCREEN = +Y`, BVH).
    Y,
    /// +Z up (Vicon lab frame, CSM; the project frame).
    Z,
    /// −X up.
    NegX,
    /// −Y up.
    NegY,
    /// −Z up.
    NegZ,
}

impl UpAxis {
    /// Parses `"+X"`, `"X"`, `"-Y"`, … (case-insensitive), as in C3D `POINT:Y_SCREEN`.
    pub fn parse(s: &str) -> Option<UpAxis> {
        let s = s.trim().to_ascii_uppercase();
        Some(match s.as_str() {
            "X" | "+X" => UpAxis::X,
            "Y" | "+Y" => UpAxis::Y,
            "Z" | "+Z" => UpAxis::Z,
            "-X" => UpAxis::NegX,
            "-Y" => UpAxis::NegY,
            "-Z" => UpAxis::NegZ,
            _ => return None,
        })
    }

    /// The proper rotation (row-major, `p' = R·p`) that takes this axis to +Z: a quarter
    /// or half turn about X or Y (identity for +Z).
    pub fn rotation_to_z_up(self) -> [[f64; 3]; 3] {
        match self {
            UpAxis::Z => [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            // Rx(+90°): (x, y, z) ↦ (x, −z, y).
            UpAxis::Y => [[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]],
            // Ry(−90°): (x, y, z) ↦ (−z, y, x).
            UpAxis::X => [[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]],
            // Rx(180°): (x, y, z) ↦ (x, −y, −z).
            UpAxis::NegZ => [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]],
            // Rx(−90°): (x, y, z) ↦ (x, z, −y).
            UpAxis::NegY => [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]],
            // Ry(+90°): (x, y, z) ↦ (z, y, −x).
            UpAxis::NegX => [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]],
        }
    }
}

/// Where an up axis came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpSource {
    /// Stated by the file (e.g. C3D `POINT:Y_SCREEN`).
    File,
    /// The format's convention (e.g. Vicon CSM is Z up); the file says nothing.
    Convention,
    /// Unknown: the file says nothing and the format has no convention.
    Unknown,
}

/// Marker trajectories: `n_frames × n_markers` positions in metres, frame-major.
///
/// Missing samples (a C3D residual < 0, a CSM `DROPOUT`) are stored as NaN in all three
/// coordinates and read back as `None` by [`MarkerSequence::get`].
#[derive(Clone, Debug, PartialEq)]
pub struct MarkerSequence {
    /// Marker labels as written in the file (C3D labels are trimmed; a Vicon subject prefix
    /// such as `Nick01:` is kept, see [`MarkerSequence::strip_subject_prefix`]).
    pub names: Vec<String>,
    /// Frame rate in Hz (> 0).
    pub rate_hz: f64,
    /// The file's number of frame 0 (C3D/CSM frames are 1-based).
    pub first_frame: i64,
    /// Positions, `[n_frames · n_markers]`, frame-major, metres; NaN = missing.
    pub positions: Vec<[f64; 3]>,
    /// The file's length unit as written (`"mm"`, …).
    pub source_unit: String,
    /// Metres per source unit (0.001 for mm); positions are already multiplied by it.
    pub metres_per_unit: f64,
    /// The up axis of the coordinates in [`MarkerSequence::positions`], if known.
    pub up_axis: Option<UpAxis>,
    /// Where [`MarkerSequence::up_axis`] came from.
    pub up_source: UpSource,
}

impl MarkerSequence {
    /// Number of markers.
    pub fn n_markers(&self) -> usize {
        self.names.len()
    }

    /// Number of frames.
    pub fn n_frames(&self) -> usize {
        self.positions
            .len()
            .checked_div(self.names.len())
            .unwrap_or(0)
    }

    /// Duration between frame 0 and the last frame, seconds.
    pub fn duration_s(&self) -> f64 {
        self.n_frames().saturating_sub(1) as f64 / self.rate_hz
    }

    /// Index of a marker by exact name.
    pub fn marker_index(&self, name: &str) -> Option<usize> {
        self.names.iter().position(|n| n == name)
    }

    /// Position of marker `m` at frame `f` in metres; `None` when missing.
    ///
    /// # Panics
    /// If `f ≥ n_frames` or `m ≥ n_markers`.
    #[track_caller]
    pub fn get(&self, f: usize, m: usize) -> Option<[f64; 3]> {
        assert!(
            m < self.n_markers() && f < self.n_frames(),
            "sample out of range"
        );
        let p = self.positions[f * self.n_markers() + m];
        p.iter().all(|c| c.is_finite()).then_some(p)
    }

    /// The `n_markers` positions of frame `f` (NaN = missing).
    ///
    /// # Panics
    /// If `f ≥ n_frames`.
    #[track_caller]
    pub fn frame(&self, f: usize) -> &[[f64; 3]] {
        let n = self.n_markers();
        &self.positions[f * n..(f + 1) * n]
    }

    /// Number of missing samples (marker × frame).
    pub fn n_missing(&self) -> usize {
        self.positions
            .iter()
            .filter(|p| !p.iter().all(|c| c.is_finite()))
            .count()
    }

    /// Fraction of missing samples in [0, 1] (0 for an empty sequence).
    pub fn missing_fraction(&self) -> f64 {
        if self.positions.is_empty() {
            0.0
        } else {
            self.n_missing() as f64 / self.positions.len() as f64
        }
    }

    /// Removes a `Subject:` prefix from every name (`Nick01:LFHD` → `LFHD`).
    ///
    /// # Errors
    /// [`MocapError::Invalid`] if two names become equal.
    pub fn strip_subject_prefix(&mut self) -> Result<()> {
        let stripped: Vec<String> = self
            .names
            .iter()
            .map(|n| n.rsplit(':').next().unwrap_or(n).to_string())
            .collect();
        for (i, a) in stripped.iter().enumerate() {
            if stripped[..i].contains(a) {
                return Err(MocapError::Invalid {
                    what: format!("marker name `{a}` occurs twice once subject prefixes go"),
                });
            }
        }
        self.names = stripped;
        Ok(())
    }

    /// The sequence in the project frame: Z up, metres.
    ///
    /// `up` overrides the recorded [`MarkerSequence::up_axis`]; with neither, this is an
    /// error. The coordinates are rotated by [`UpAxis::rotation_to_z_up`] (a proper
    /// rotation, so a right-handed lab stays right-handed and left stays left).
    ///
    /// What can be inferred: the up axis (C3D `POINT:Y_SCREEN` when present; the CSM
    /// convention) and the unit. What cannot: the heading — which horizontal direction
    /// the subject faces is a property of the motion, not of the file, and changes when
    /// the subject turns. Use [`MarkerSequence::face_minus_y`] with a left/right marker
    /// pair at a chosen frame to turn the subject to face −Y (left along +X) there.
    ///
    /// # Errors
    /// [`MocapError::Invalid`] when the up axis is unknown and `up` is `None`.
    pub fn to_project_frame(&self, up: Option<UpAxis>) -> Result<MarkerSequence> {
        let up = up.or(self.up_axis).ok_or_else(|| MocapError::Invalid {
            what: "the up axis of this marker sequence is unknown; pass it explicitly".into(),
        })?;
        let r = up.rotation_to_z_up();
        let mut out = self.clone();
        for p in &mut out.positions {
            *p = matvec(&r, *p);
        }
        out.up_axis = Some(UpAxis::Z);
        Ok(out)
    }

    /// Rotates a Z-up sequence about the vertical through the origin so that at frame `f`
    /// the horizontal direction from marker `right` to marker `left` is +X; a subject whose
    /// left is +X with Z up faces −Y (the project convention). Returns the angle turned,
    /// radians (counter-clockwise seen from above).
    ///
    /// # Errors
    /// [`MocapError::Invalid`] if the sequence is not Z up, a name is unknown, `f` is out
    /// of range, a marker is missing at `f`, or the two are vertically aligned.
    pub fn face_minus_y(&mut self, left: &str, right: &str, f: usize) -> Result<f64> {
        let inv = |what: String| MocapError::Invalid { what };
        if self.up_axis != Some(UpAxis::Z) {
            return Err(inv("face_minus_y needs a Z-up sequence".into()));
        }
        if f >= self.n_frames() {
            return Err(inv(format!("frame {f} out of range ({})", self.n_frames())));
        }
        let idx = |n: &str| {
            self.marker_index(n)
                .ok_or_else(|| inv(format!("unknown marker `{n}`")))
        };
        let (l, r) = (idx(left)?, idx(right)?);
        let missing = || inv(format!("`{left}` or `{right}` is missing at frame {f}"));
        let (pl, pr) = (
            self.get(f, l).ok_or_else(missing)?,
            self.get(f, r).ok_or_else(missing)?,
        );
        let (dx, dy) = (pl[0] - pr[0], pl[1] - pr[1]);
        if dx.hypot(dy) < 1e-9 {
            return Err(inv(format!(
                "`{left}` and `{right}` are vertically aligned"
            )));
        }
        let a = -dy.atan2(dx);
        let (s, c) = a.sin_cos();
        let rz = [[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]];
        for p in &mut self.positions {
            *p = matvec(&rz, *p);
        }
        Ok(a)
    }
}

/// `m · v` (NaN stays NaN).
pub(crate) fn matvec(m: &[[f64; 3]; 3], v: [f64; 3]) -> [f64; 3] {
    [0, 1, 2].map(|i| m[i][0] * v[0] + m[i][1] * v[1] + m[i][2] * v[2])
}

/// Metres per unit for a length-unit name (`mm`, `cm`, `m`, `in`, `ft`, case-insensitive).
pub fn metres_per_unit(unit: &str) -> Option<f64> {
    Some(match unit.trim().to_ascii_lowercase().as_str() {
        "mm" | "millimeter" | "millimetre" | "millimeters" | "millimetres" => 0.001,
        "cm" | "centimeter" | "centimetre" => 0.01,
        "m" | "meter" | "metre" | "meters" | "metres" => 1.0,
        "in" | "inch" | "inches" => 0.0254,
        "ft" | "feet" => 0.3048,
        _ => return None,
    })
}
