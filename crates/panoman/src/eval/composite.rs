//! Composite motion (Fig. 16): the body of one fit, the expression of a second and the
//! gesture of a third, posed from the mixed β blocks.
use panoman_fit::Constraints;
use panoman_fit::fit::FitResult;
use panoman_human::keypoints::KeypointsFile;
use panoman_model::model::Params;

use super::fitting::HeldOut;
use super::metrics::to_v3;
use super::summary::CompositeRows;
use super::{Bench, CompositeMeshes, EvalProgress};
use crate::error::Result;
use crate::model::{BlockName, Correction};

/// A cold fit of dataset row `r` from its exact keypoints.
fn fit_row(b: &mut Bench, r: usize) -> Result<FitResult> {
    let truth = to_v3(b.ds.vertices(r)?);
    let c = Constraints::from_keypoints(KeypointsFile::from_all(
        &b.model.inner().keypoints.evaluate(&truth),
    ));
    Ok(b.solver.fit(&c, &b.ikc, &b.opts, None)?.1)
}

/// `body` with the face blocks of `face` and the hand blocks of `hands` (the blocks they
/// have).
pub(crate) fn compose(body: &Params, face: &Params, hands: &Params) -> Params {
    let mut p = body.clone();
    for (src, blocks) in [
        (face, [BlockName::FaceLength, BlockName::FaceAngle]),
        (hands, [BlockName::HandsLength, BlockName::HandsAngle]),
    ] {
        for blk in blocks {
            if let Some(v) = src.beta.get(&blk) {
                p.beta.insert(blk, v.clone());
            }
        }
    }
    p
}

/// The composite of the first held-out body fit with the first held-out face and hand rows;
/// `None` when the dataset has no held-out face or hand rows.
pub(crate) fn run(
    b: &mut Bench,
    held: &HeldOut,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<Option<(CompositeRows, CompositeMeshes)>> {
    let (face_rows, hand_rows) = (b.held_out_rows(2), b.held_out_rows(3));
    let (Some(fa), Some(&rf), Some(&rh)) =
        (held.fits.first(), face_rows.first(), hand_rows.first())
    else {
        return Ok(None);
    };
    let fb = fit_row(b, rf)?;
    progress(EvalProgress::Step { done: 1, total: 2 });
    let fc = fit_row(b, rh)?;
    progress(EvalProgress::Step { done: 2, total: 2 });
    let p = compose(&fa.params, &fb.params, &fc.params);
    let pose = |p: &Params| b.model.pose(p, Correction::Apply);
    let posed = [
        pose(&fa.params)?,
        pose(&fb.params)?,
        pose(&fc.params)?,
        pose(&p)?,
    ];
    let rows = CompositeRows {
        body_from_row: held.pick[0],
        expression_from_row: rf,
        gesture_from_row: rh,
    };
    Ok(Some((rows, CompositeMeshes { posed, params: p })))
}
