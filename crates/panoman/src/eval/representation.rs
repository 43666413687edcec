//! Representation error versus number of components (Fig. 7) and the correction MLP (Fig. 18).
use panoman_model::train::{
    CurvePoint, RepresentationError, component_curves, evaluate_representation,
};

use super::{Bench, EvalPreset, EvalProgress};
use crate::error::Result;

/// The held-out representation error and the component curves.
pub(crate) fn run(
    b: &Bench,
    preset: &EvalPreset,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<(RepresentationError, Vec<CurvePoint>)> {
    let pm = b.model.inner();
    let gn = panoman_model::model::GnOptions::default();
    let gn = preset.repr_gn.then_some(&gn);
    let repr = evaluate_representation(pm, &b.ds, &b.regions, preset.repr_rows, gn, &mut |d| {
        progress(EvalProgress::Detail(&format!("representation error: {d}")))
    })?;
    let curves = component_curves(pm, &b.ds, &b.regions, preset.curve_rows, &mut |d| {
        progress(EvalProgress::Detail(&format!("component curves: {d}")))
    })?;
    Ok((repr, curves))
}
