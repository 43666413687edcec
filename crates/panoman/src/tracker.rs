//! [`Tracker`]: a sequence of frames fitted in order, for PanoMan and the LBS baseline.
use panoman_fit::fit::{FitOptions, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Previous, Tracking, TrackingState, ik_config_for_noise};
use panoman_model::model::{BlockName, Params};

use crate::error::{Error, Result};
use crate::feet::ContactPrior;
use crate::fitter::{FitOutput, FitRequest, Fitter, Method};
use crate::model::Model;
use crate::targets::Targets;

/// How the initializer of each frame starts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum IkStart {
    /// Warm-started from the previous frame's IK state (final IK stage only). Default.
    #[default]
    Warm,
    /// Cold on every frame (robust to large motion between frames; slower).
    Cold,
}

/// Frame-to-frame state of a tracked sequence (paper §5.3; Total Capture's temporal
/// propagation). PanoMan: the first frame is a cold fit, the next ones warm-start the IK,
/// keep the shape α, add temporal terms on β and on the vertices (the previous fit carried
/// along the skeletal motion) and propagate the rigid placement (re-anchored every 30
/// frames). LBS: the IK warm-started from the previous frame.
pub struct Tracker {
    fitter: Fitter,
    request: FitRequest,
    ik_start: IkStart,
    sequence: Tracking,
    lbs_state: Option<IkState>,
    frames: usize,
    contacts: Option<ContactPrior>,
}

impl Tracker {
    /// A tracker for `model` (builds its own [`Fitter`]); `request` applies to every frame
    /// (its `fixed` parameters and motion data too).
    ///
    /// # Errors
    /// See [`Fitter::new`].
    pub fn new(model: &Model, request: FitRequest, ik_start: IkStart) -> Result<Tracker> {
        Ok(Tracker::with_fitter(Fitter::new(model)?, request, ik_start))
    }

    /// A tracker around an existing fitter.
    pub fn with_fitter(fitter: Fitter, request: FitRequest, ik_start: IkStart) -> Tracker {
        let ik = IkConfig {
            ..ik_config_for_noise(request.keypoint_sigma)
        };
        let cold = request.options();
        let warm = FitOptions {
            keypoint_weight: cold.keypoint_weight,
            motion_weight: cold.motion_weight,
            quality: cold.quality.clone(),
            ..warm_fit_options()
        };
        let sequence = Tracking::new(cold, warm, ik, ik_start == IkStart::Cold);
        Tracker {
            fitter,
            request,
            ik_start,
            sequence,
            lbs_state: None,
            frames: 0,
            contacts: None,
        }
    }

    /// Frames fitted so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// Holds the identity for the frames that follow, as MoSh holds a calibrated shape: local
    /// changes (e.g. the limb lengths of [`Fitter::calibrate_shape`]) and all phenotype values,
    /// the six IK ones included, are `shape`'s and no longer fitted per frame
    /// ([`IkConfig::initial_shape`], `fit_phenotype` off; CMU `01_01`: 11.20 → 10.64 mm,
    /// docs/design/rig-and-ik.md §4.10). `None`: the default shape with the six IK phenotype
    /// values fitted per frame (as a new tracker). Both methods use it. Not part of a
    /// [`Tracker::checkpoint`]: set it again after a restore.
    pub fn set_shape(&mut self, shape: Option<panoman_human::params::ShapeParams>) {
        self.sequence.ik.fit_phenotype = shape.is_none();
        self.sequence.ik.initial_shape = shape;
    }

    /// Sets the foot–floor contact prior of the frames that follow ([`ContactPrior`]): each
    /// [`Tracker::track`] adds the prior's next frame's level pairs and anchor handles to its
    /// targets and advances it. `None` removes it. Not part of a [`Tracker::checkpoint`]: set
    /// it again after a restore (with its anchors and next frame, e.g. from
    /// [`Tracker::contacts`] saved beside the checkpoint).
    pub fn set_contacts(&mut self, prior: Option<ContactPrior>) {
        self.contacts = prior;
    }

    /// The contact prior, if any ([`Tracker::set_contacts`]).
    pub fn contacts(&self) -> Option<&ContactPrior> {
        self.contacts.as_ref()
    }

    /// Calibrates the identity's limb and trunk lengths from `frames` with this tracker's
    /// request ([`Fitter::calibrate_shape`]) and holds the result for the frames that follow
    /// ([`Tracker::set_shape`]).
    ///
    /// # Errors
    /// See [`Fitter::calibrate_shape`]; the tracker is unchanged then.
    pub fn calibrate_shape(
        &mut self,
        frames: &[Targets],
        opts: &panoman_fit::ShapeCalibrationOptions,
    ) -> Result<panoman_fit::ShapeCalibration> {
        let cal = self.fitter.calibrate_shape(frames, &self.request, opts)?;
        self.set_shape(Some(cal.shape.clone()));
        Ok(cal)
    }

    /// The fitter (e.g. for its setup time).
    pub fn fitter(&self) -> &Fitter {
        &self.fitter
    }

    /// The tracker's frame-to-frame state as bytes (a checkpoint): the frame count, the last
    /// IK state and the previous fit, every number stored bit-exactly, with a checksum. A tracker
    /// of the same model, request and [`IkStart`] given these bytes by [`Tracker::restore`]
    /// fits the following frames exactly as this one would (`panoman track --resume`).
    pub fn checkpoint(&self) -> Vec<u8> {
        let mut w = Enc(CHECKPOINT_MAGIC.to_vec());
        w.u64(u64::from(self.request.method == Method::Lbs));
        w.u64(u64::from(self.ik_start == IkStart::Cold));
        w.u64(self.fitter.model().n_vertices() as u64);
        w.u64(self.fitter.bone_names().len() as u64);
        w.u64(self.frames as u64);
        w.ik(self.lbs_state.as_ref());
        let s = self.sequence.state();
        w.u64(s.frames as u64);
        w.ik(s.ik.as_ref());
        match &s.previous {
            None => w.u64(0),
            Some(p) => {
                w.u64(1);
                w.v3s(&p.vertices);
                w.f64s(&p.params.alpha);
                w.u64(p.params.beta.len() as u64);
                for (name, b) in &p.params.beta {
                    w.u64(name.as_str().len() as u64);
                    w.0.extend_from_slice(name.as_str().as_bytes());
                    w.f64s(b);
                }
                p.params.translation.iter().for_each(|&x| w.f64(x));
                p.params.rotation.iter().for_each(|&x| w.f64(x));
                match &p.init {
                    None => w.u64(0),
                    Some(v) => {
                        w.u64(1);
                        w.v3s(v);
                    }
                }
            }
        }
        let sum = panoman_mesh::io::fnv1a(&w.0);
        w.u64(sum);
        w.0
    }

    /// Restores the state of [`Tracker::checkpoint`]: the next [`Tracker::track`] continues
    /// the checkpointed sequence.
    ///
    /// # Errors
    /// [`Error::Invalid`] when the bytes are not a complete checkpoint (bad magic, length or
    /// checksum) or were written by a tracker of another method, IK start, vertex or bone
    /// count; the tracker is unchanged then.
    pub fn restore(&mut self, bytes: &[u8]) -> Result<()> {
        let bad = |what: &str| Error::Invalid(format!("not a usable track checkpoint: {what}"));
        if bytes.len() < CHECKPOINT_MAGIC.len() + 8 || !bytes.starts_with(CHECKPOINT_MAGIC) {
            return Err(bad("no checkpoint header"));
        }
        let (body, sum) = bytes.split_at(bytes.len() - 8);
        if panoman_mesh::io::fnv1a(body) != u64::from_le_bytes(sum.try_into().expect("8 bytes")) {
            return Err(bad("checksum mismatch (truncated or damaged)"));
        }
        let mut r = Dec {
            b: &body[CHECKPOINT_MAGIC.len()..],
        };
        let expect = [
            (u64::from(self.request.method == Method::Lbs), "method"),
            (
                u64::from(self.ik_start == IkStart::Cold),
                "IK start (--cold)",
            ),
            (
                self.fitter.model().n_vertices() as u64,
                "model vertex count",
            ),
            (self.fitter.bone_names().len() as u64, "rig bone count"),
        ];
        for (v, what) in expect {
            if r.u64()? != v {
                return Err(bad(&format!("written with another {what}")));
            }
        }
        let n_bones = self.fitter.bone_names().len();
        let n_v = self.fitter.model().n_vertices();
        let frames = r.usize()?;
        let lbs_state = r.ik(n_bones)?;
        let seq_frames = r.usize()?;
        let ik = r.ik(n_bones)?;
        let previous = match r.u64()? {
            0 => None,
            1 => {
                let vertices = r.v3s(n_v)?;
                let alpha = r.f64s()?;
                let mut beta = std::collections::BTreeMap::new();
                for _ in 0..r.usize()? {
                    let n = r.usize()?;
                    let name = std::str::from_utf8(r.take(n)?)
                        .ok()
                        .and_then(|n| BlockName::parse(n).ok())
                        .ok_or_else(|| bad("unknown block name"))?;
                    beta.insert(name, r.f64s()?);
                }
                let translation = r.f64x3()?;
                let rotation = r.f64x3()?;
                let init = match r.u64()? {
                    0 => None,
                    1 => Some(r.v3s(n_v)?),
                    _ => return Err(bad("bad tag")),
                };
                Some(Previous {
                    vertices,
                    params: Params {
                        alpha,
                        beta,
                        translation,
                        rotation,
                    },
                    init,
                })
            }
            _ => return Err(bad("bad tag")),
        };
        if !r.b.is_empty() {
            return Err(bad("trailing bytes"));
        }
        self.frames = frames;
        self.lbs_state = lbs_state;
        self.sequence.set_state(TrackingState {
            frames: seq_frames,
            ik,
            previous,
        });
        Ok(())
    }

    /// Fits the next frame. With a contact prior ([`Tracker::set_contacts`]) the prior's
    /// next frame's level pairs and anchor handles join `targets`.
    ///
    /// # Errors
    /// Invalid targets (see [`Fitter::fit`]), a contact prior whose frames are all fitted;
    /// the sequence state (and the prior) is unchanged then.
    pub fn track(&mut self, targets: &Targets) -> Result<FitOutput> {
        let with_contacts = match &self.contacts {
            Some(p) => Some(p.apply(targets)?),
            None => None,
        };
        let targets = with_contacts.as_ref().unwrap_or(targets);
        let c = self.fitter.constraints(targets, &self.request)?;
        let out = match self.request.method {
            Method::Lbs => {
                let warm = match self.ik_start {
                    IkStart::Warm => self.lbs_state.as_ref(),
                    IkStart::Cold => None,
                };
                // The PanoMan sequence's IK settings, so both methods share the IK.
                let ikc = self.sequence.ik_config(&self.sequence.ik, warm.is_some());
                let q = self.request.quality();
                let (r, attempts) = self.fitter.solver().fit_lbs(&c, &ikc, &q, warm)?;
                self.lbs_state = Some(r.state.clone());
                self.fitter.lbs_output(&c, r, attempts, &q)
            }
            Method::PanoMan => {
                let (r, fit) = self.sequence.fit_next(self.fitter.solver_mut(), &c)?;
                self.fitter.panoman_output(&r, fit)
            }
        };
        self.frames += 1;
        if let Some(p) = &mut self.contacts {
            p.advance(&out.vertices);
        }
        Ok(out)
    }
}

/// First bytes of a [`Tracker::checkpoint`] (format version 1).
const CHECKPOINT_MAGIC: &[u8; 8] = b"PMTRKCK1";

/// Little-endian writer of the checkpoint (f64 as their bits: exact).
struct Enc(Vec<u8>);

impl Enc {
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.u64(v.to_bits());
    }
    fn f64s(&mut self, v: &[f64]) {
        self.u64(v.len() as u64);
        v.iter().for_each(|&x| self.f64(x));
    }
    fn v3s(&mut self, v: &[[f64; 3]]) {
        self.u64(v.len() as u64);
        v.iter().flatten().for_each(|&x| self.f64(x));
    }
    fn ik(&mut self, s: Option<&IkState>) {
        let Some(s) = s else {
            return self.u64(0);
        };
        self.u64(1);
        s.rotation.iter().flatten().for_each(|&x| self.f64(x));
        s.translation.iter().for_each(|&x| self.f64(x));
        self.v3s(&s.angles);
        self.f64s(&s.phenotype);
        self.f64s(&s.face_units);
    }
}

/// Reader of [`Enc`]'s layout; every length is checked against the bytes left.
struct Dec<'a> {
    b: &'a [u8],
}

impl Dec<'_> {
    fn err() -> Error {
        Error::Invalid("not a usable track checkpoint: truncated or malformed".into())
    }
    fn take(&mut self, n: usize) -> Result<&[u8]> {
        if n > self.b.len() {
            return Err(Self::err());
        }
        let (a, rest) = self.b.split_at(n);
        self.b = rest;
        Ok(a)
    }
    fn u64(&mut self) -> Result<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn usize(&mut self) -> Result<usize> {
        usize::try_from(self.u64()?).map_err(|_| Self::err())
    }
    fn f64(&mut self) -> Result<f64> {
        Ok(f64::from_bits(self.u64()?))
    }
    fn f64x3(&mut self) -> Result<[f64; 3]> {
        Ok([self.f64()?, self.f64()?, self.f64()?])
    }
    fn f64s(&mut self) -> Result<Vec<f64>> {
        let n = self.usize()?;
        if n > self.b.len() / 8 {
            return Err(Self::err());
        }
        (0..n).map(|_| self.f64()).collect()
    }
    fn v3s(&mut self, expect: usize) -> Result<Vec<[f64; 3]>> {
        if self.usize()? != expect {
            return Err(Self::err());
        }
        (0..expect).map(|_| self.f64x3()).collect()
    }
    fn fixed<const N: usize>(&mut self) -> Result<[f64; N]> {
        let v = self.f64s()?;
        v.try_into().map_err(|_| Self::err())
    }
    fn ik(&mut self, n_bones: usize) -> Result<Option<IkState>> {
        match self.u64()? {
            0 => Ok(None),
            1 => {
                let mut rotation = [[0.0; 3]; 3];
                for row in &mut rotation {
                    *row = self.f64x3()?;
                }
                Ok(Some(IkState {
                    rotation,
                    translation: self.f64x3()?,
                    angles: self.v3s(n_bones)?,
                    phenotype: self.fixed()?,
                    face_units: self.fixed()?,
                }))
            }
            _ => Err(Self::err()),
        }
    }
}
