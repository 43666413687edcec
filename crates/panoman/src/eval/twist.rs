//! The twist study (Fig. 1, 13): a limb twisted about its bone by the LBS rig, fitted from
//! its keypoints by the LBS rig and by PanoMan; cross-section radii and volume against rest.
use panoman_fit::Constraints;
use panoman_fit::fit::keypoint_residuals;
use panoman_fit::ik::IkConfig;
use panoman_fit::twist::LimbSegment;
use panoman_human::generator::Identity;
use panoman_human::keypoints::KeypointsFile;
use panoman_human::params::{PoseParams, ShapeParams};
use panoman_mesh::TriMesh;
use panoman_mesh::geom::V3;
use panoman_mesh::measure::enclosed_volume;

use super::summary::{TwistLimb, TwistRow, TwistSummary};
use super::{Bench, EvalPreset, EvalProgress, MeshTriple, TwistRender};
use crate::error::{Error, Result};

/// One limb of the twist study: the bone twisted (about its own y axis, the bone direction)
/// and the keypoints spanning the measured segment with the `t` range near the joint.
struct Limb {
    name: &'static str,
    bone: &'static str,
    a: &'static str,
    b: &'static str,
    t: (f64, f64),
    r_max: f64,
}

const LIMBS: [Limb; 4] = [
    Limb {
        name: "forearm",
        bone: "lowerarm02.L",
        a: "l_elbow",
        b: "l_wrist",
        t: (0.15, 0.85),
        r_max: 0.06,
    },
    Limb {
        name: "upper arm",
        bone: "upperarm02.L",
        a: "l_shoulder",
        b: "l_elbow",
        t: (0.15, 0.85),
        r_max: 0.08,
    },
    Limb {
        name: "wrist",
        bone: "wrist.L",
        a: "l_elbow",
        b: "l_wrist",
        t: (0.6, 1.0),
        r_max: 0.06,
    },
    Limb {
        name: "neck",
        bone: "neck02",
        a: "neck",
        b: "nose",
        t: (0.0, 0.45),
        r_max: 0.09,
    },
];

/// The forearm angles rendered.
const RENDERED: [f64; 3] = [90.0, 150.0, 180.0];

/// What the twist study gives the summary and the renders.
pub(crate) struct TwistRun {
    pub(crate) summary: TwistSummary,
    pub(crate) forearm: Vec<TwistRender>,
}

/// The rest person (default shape) of the study.
struct RestPerson<'g> {
    id: Identity<'g>,
    names: Vec<String>,
    rest: Vec<V3>,
    keypoints: Vec<V3>,
    volume: f64,
}

/// One limb's measured segment.
struct Segment {
    seg: LimbSegment,
    bone: usize,
    ra: usize,
    rb: usize,
}

impl Segment {
    /// The smallest finite radius ratio of `x` over `rest`.
    fn min_ratio(&self, b: &Bench, rest: &[V3], x: &[V3]) -> f64 {
        let kr = b.model.inner().keypoints.evaluate(rest);
        let k = b.model.inner().keypoints.evaluate(x);
        self.seg
            .radius_ratios(
                rest,
                (kr[self.ra], kr[self.rb]),
                x,
                (k[self.ra], k[self.rb]),
            )
            .into_iter()
            .filter(|r| r.is_finite())
            .fold(f64::INFINITY, f64::min)
    }
}

/// Runs the study on every limb the model's keypoints span.
pub(crate) fn run(
    b: &mut Bench,
    preset: &EvalPreset,
    progress: &mut dyn FnMut(EvalProgress),
) -> Result<TwistRun> {
    let g = b.rig().generator.clone();
    let id = g.identity(&ShapeParams::default())?;
    let rest = b.rig().map.map(b.rig().topology, id.rest_vertices());
    let p = RestPerson {
        names: g.bone_names().to_vec(),
        keypoints: b.model.inner().keypoints.evaluate(&rest),
        volume: enclosed_volume(&TriMesh::new(rest.clone(), b.model.faces().to_vec())),
        rest,
        id,
    };
    let mut out = TwistRun {
        summary: TwistSummary {
            angles_deg: preset.twist_angles.clone(),
            limbs: Vec::new(),
        },
        forearm: Vec::new(),
    };
    let total = LIMBS.len() * preset.twist_angles.len();
    for (i, limb) in LIMBS.iter().enumerate() {
        let bone = p
            .names
            .iter()
            .position(|n| n == limb.bone)
            .ok_or_else(|| Error::Invalid(format!("the rig has no bone `{}`", limb.bone)))?;
        let names = &b.model.inner().keypoints.names;
        let rows_a = names.iter().position(|n| n == limb.a);
        let rows_b = names.iter().position(|n| n == limb.b);
        let (Some(ra), Some(rb)) = (rows_a, rows_b) else {
            continue;
        };
        let kr = &p.keypoints;
        let s = Segment {
            seg: LimbSegment::new(&p.rest, kr[ra], kr[rb], limb.t.0, limb.t.1, limb.r_max, 7),
            bone,
            ra,
            rb,
        };
        let mut rows = Vec::new();
        for (j, &ang) in preset.twist_angles.iter().enumerate() {
            let (row, meshes) = twist_row(b, &p, &s, ang)?;
            rows.push(row);
            if limb.name == "forearm" && RENDERED.contains(&ang) {
                out.forearm.push(TwistRender {
                    angle_deg: ang,
                    meshes,
                });
            }
            progress(EvalProgress::Step {
                done: i * preset.twist_angles.len() + j + 1,
                total,
            });
        }
        out.summary.limbs.push(TwistLimb {
            bone: limb.bone.into(),
            limb: limb.name.into(),
            rows,
        });
    }
    Ok(out)
}

/// One angle of one limb: the twisted target, its LBS fit and PanoMan fit, measured.
fn twist_row(
    b: &mut Bench,
    p: &RestPerson,
    s: &Segment,
    ang: f64,
) -> Result<(TwistRow, MeshTriple)> {
    let mut pose = PoseParams {
        euler_deg: vec![[0.0; 3]; p.names.len()],
        ..Default::default()
    };
    pose.euler_deg[s.bone][1] = ang;
    let posed = p.id.pose(&pose);
    let truth = b.rig().map.map(b.rig().topology, &posed.vertices);
    let c = Constraints::from_keypoints(KeypointsFile::from_all(
        &b.model.inner().keypoints.evaluate(&truth),
    ));
    // The identity is known here (the study is about the twist): the IK keeps the true
    // phenotype and fits the pose only, for both the baseline and the initializer.
    let ik_known = IkConfig {
        fit_phenotype: false,
        initial_shape: Some(ShapeParams::default()),
        ..b.ikc.clone()
    };
    let ikr = b.solver.ik_fit(&c, &ik_known)?;
    let fit = b.solver.fit_from_ik(&c, &ikr, &b.opts)?;
    let pm = b.model.inner();
    let kres = |x: &[V3]| {
        let r = keypoint_residuals(pm, &c.targets.keypoints, x);
        r.values().map(|g| g.mean_mm * g.n as f64).sum::<f64>()
            / r.values().map(|g| g.n).sum::<usize>().max(1) as f64
    };
    let vol = |x: &[V3]| {
        100.0 * (enclosed_volume(&TriMesh::new(x.to_vec(), pm.faces.clone())) / p.volume - 1.0)
    };
    // Over PanoMan's own rest shape B_S(α) (the 10-component shape PCA makes the limb a few %
    // thinner than the person's true rest even untwisted).
    let own = pm.rest_shape(&fit.params.alpha);
    let row = TwistRow {
        angle_deg: ang,
        lbs_fit_keypoint_mean_mm: kres(&ikr.posed),
        lbs_fit_min_radius_ratio: s.min_ratio(b, &p.rest, &ikr.posed),
        lbs_fit_volume_change_pct: vol(&ikr.posed),
        panoman_keypoint_mean_mm: kres(&fit.vertices),
        panoman_min_radius_ratio: s.min_ratio(b, &p.rest, &fit.vertices),
        panoman_own_rest_min_radius_ratio: s.min_ratio(b, &own, &fit.vertices),
        panoman_volume_change_pct: vol(&fit.vertices),
        rig_min_radius_ratio: s.min_ratio(b, &p.rest, &truth),
        rig_volume_change_pct: vol(&truth),
    };
    let meshes = MeshTriple {
        truth,
        panoman: fit.vertices,
        lbs: ikr.posed,
    };
    Ok((row, meshes))
}
