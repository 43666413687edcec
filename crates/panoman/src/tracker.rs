//! [`Tracker`]: a sequence of frames fitted in order, for PanoMan and the LBS baseline.
use panoman_fit::fit::{FitOptions, warm_fit_options};
use panoman_fit::ik::{IkConfig, IkState};
use panoman_fit::{Sequence, ik_config_for_noise};

use crate::error::Result;
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
    sequence: Sequence,
    lbs_state: Option<IkState>,
    frames: usize,
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
        let sequence = Sequence::new(cold, warm, ik, ik_start == IkStart::Cold);
        Tracker {
            fitter,
            request,
            ik_start,
            sequence,
            lbs_state: None,
            frames: 0,
        }
    }

    /// Frames fitted so far.
    pub fn frames(&self) -> usize {
        self.frames
    }

    /// The fitter (e.g. for its setup time).
    pub fn fitter(&self) -> &Fitter {
        &self.fitter
    }

    /// Fits the next frame.
    ///
    /// # Errors
    /// Invalid targets (see [`Fitter::fit`]); the sequence state is unchanged then.
    pub fn track(&mut self, targets: &Targets) -> Result<FitOutput> {
        let c = self.fitter.constraints(targets, &self.request)?;
        let out = match self.request.method {
            Method::Lbs => {
                let ikc = ik_config_for_noise(self.request.keypoint_sigma);
                let warm = match self.ik_start {
                    IkStart::Warm => self.lbs_state.as_ref(),
                    IkStart::Cold => None,
                };
                let q = self.request.quality();
                let (r, attempts) = self.fitter.lbs(&c, &ikc, &q, warm)?;
                self.lbs_state = Some(r.state.clone());
                self.fitter.lbs_output(&c, r, attempts, &q)
            }
            Method::PanoMan => {
                let (rig, ik, shell) = self.fitter.parts();
                let (r, fit) = self.sequence.fit_next(rig, ik, shell, &c)?;
                self.fitter.panoman_output(&r, fit)
            }
        };
        self.frames += 1;
        Ok(out)
    }
}
