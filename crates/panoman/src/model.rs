//! [`Model`]: a loaded PanoMan model, shared and thread-safe ("load once, forward many").
use std::path::Path;
use std::sync::{Arc, Mutex};

use panoman_mesh::geom::V3;
pub use panoman_model::model::BlockName;
use panoman_model::model::{Evaluator, GnOptions, PanoManModel, Params};

use crate::error::{Error, Result};

/// Whether the correction MLP `R(β_body)` (PanoMan Eq. 4) is added to the RL/RA of a pose.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Correction {
    /// Add `R(β_body)` when the model has a correction network (the model's own output).
    #[default]
    Apply,
    /// The linear model `X̄ + Mβ` alone (ablation).
    Skip,
}

/// How [`Model::encode_with`] finds β.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Encoder {
    /// The least-squares fit of the mesh's RL/RA (one small dense solve per quantity; the
    /// best RL/RA, not the best mesh: RA errors integrate along the body's chains).
    LeastSquares,
    /// The least-squares β refined by damped Gauss–Newton (Levenberg–Marquardt, per-block
    /// damping) on the vertex error through `g` (docs/design/splocs-model.md §8): the model's
    /// closest mesh up to a rigid motion. Costs up to 20 iterations per start (three runs
    /// with the correction: `GnOptions::correction_two_start`), each one linearization and
    /// one or more g solves: 10–40 s on the full template (measured 34.8 s with the
    /// correction); `VertexErrorWith(GnOptions { max_iterations: 4, .. })` takes a fraction of it.
    #[default]
    VertexError,
    /// [`Encoder::VertexError`] with explicit iteration counts.
    VertexErrorWith(GnOptions),
}

/// Size and support of one β block.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BlockInfo {
    /// Which block.
    pub name: BlockName,
    /// Number of coefficients (trained components + 1 for the mean).
    pub size: usize,
    /// Number of edges of the block's part (the components' support).
    pub n_edges: usize,
}

struct Shared {
    model: Arc<PanoManModel>,
    /// Evaluators ready for use (topology tables and `g`'s factorizations are built once, in
    /// [`Model::from_model`], and shared by every evaluator cloned from the first).
    pool: Mutex<Vec<Evaluator>>,
    prototype: Evaluator,
}

/// A loaded model: shape PCA, the six sparse localized component blocks, the correction and
/// motion networks, the keypoint regressors and (for model files written by
/// `panoman train`) the LBS rig the fit's initializer needs. Cheap to clone (`Arc`),
/// `Send + Sync`; calls from several threads run in parallel.
#[derive(Clone)]
pub struct Model {
    shared: Arc<Shared>,
}

impl std::fmt::Debug for Model {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let m = self.inner();
        f.debug_struct("Model")
            .field("topology", &m.topology_name)
            .field("vertices", &m.n_vertices)
            .field("rig", &m.rig.is_some())
            .finish()
    }
}

impl Model {
    /// Loads and validates a model file (safetensors written by `panoman train`), and builds
    /// the per-topology state (topology tables, `g`'s factorizations, the β encoder's normal
    /// equations) once.
    ///
    /// # Errors
    /// [`Error::Io`] / [`Error::Model`] naming the file: unreadable, not a model, inconsistent.
    pub fn load(path: impl AsRef<Path>) -> Result<Model> {
        let path = path.as_ref();
        let m = PanoManModel::load(path)?;
        Model::from_model(m).map_err(|e| match e {
            Error::Model(m) => Error::Format {
                path: path.to_path_buf(),
                what: m.to_string(),
            },
            other => other,
        })
    }

    /// Wraps an in-memory model (see [`Model::load`]).
    ///
    /// # Errors
    /// The model's topology is invalid.
    pub fn from_model(model: PanoManModel) -> Result<Model> {
        let model = Arc::new(model);
        let prototype = Evaluator::new(model.clone())?;
        Ok(Model {
            shared: Arc::new(Shared {
                model,
                pool: Mutex::new(Vec::new()),
                prototype,
            }),
        })
    }

    /// The underlying model data (the library's own experiments and fitter).
    pub(crate) fn inner(&self) -> &Arc<PanoManModel> {
        &self.shared.model
    }

    /// An evaluator sharing this model's per-topology state (no factorization is redone).
    pub fn evaluator(&self) -> Evaluator {
        self.shared.prototype.clone()
    }

    fn with_evaluator<T>(&self, f: impl FnOnce(&mut Evaluator) -> T) -> T {
        let popped = self.shared.pool.lock().map(|mut p| p.pop()).ok().flatten();
        let mut ev = popped.unwrap_or_else(|| self.evaluator());
        let out = f(&mut ev);
        if let Ok(mut p) = self.shared.pool.lock() {
            p.push(ev);
        }
        out
    }

    /// Number of template vertices.
    pub fn n_vertices(&self) -> usize {
        self.inner().n_vertices
    }

    /// Template triangles (indices into the vertices).
    pub fn faces(&self) -> &[[u32; 3]] {
        &self.inner().faces
    }

    /// The template topology's name (`full`: 13,348 vertices; `small`: 1,229).
    pub fn topology_name(&self) -> &str {
        &self.inner().topology_name
    }

    /// The generator topology of the model's template (for [`crate::Generator::generate`]).
    ///
    /// # Errors
    /// [`Error::Invalid`] for a model on another topology than `full` or `small`.
    pub fn output_topology(&self) -> Result<panoman_human::outputs::OutputTopology> {
        use panoman_human::outputs::OutputTopology;
        match self.topology_name() {
            "full" => Ok(OutputTopology::Full),
            "small" => Ok(OutputTopology::Small),
            other => Err(Error::Invalid(format!(
                "the model's topology `{other}` is not a generator topology"
            ))),
        }
    }

    /// The rest shape `B_S(α)` (PanoMan Eq. 2: mean + Σ αᵢ σᵢ uᵢ, `(V, 3)` metres; missing
    /// entries of α count as 0).
    pub fn rest_shape(&self, alpha: &[f64]) -> Vec<V3> {
        self.inner().rest_shape(alpha)
    }

    /// Number of shape coefficients α.
    pub fn n_shape(&self) -> usize {
        self.inner().shape.n_components()
    }

    /// The six β blocks with their sizes.
    pub fn blocks(&self) -> Vec<BlockInfo> {
        let m = self.inner();
        BlockName::ALL
            .into_iter()
            .zip(&m.blocks)
            .map(|(name, b)| BlockInfo {
                name,
                size: b.n_components(),
                n_edges: b.columns.len(),
            })
            .collect()
    }

    /// Part of each edge (0 body, 1 face, 2 left hand, 3 right hand), in the topology's edge
    /// order.
    pub fn edge_parts(&self) -> &[u8] {
        &self.inner().edge_part
    }

    /// Part of each vertex `(V,)` (0 body, 1 face, 2 left hand, 3 right hand): the
    /// highest-priority part (left hand, right hand, face, body) among the vertex's edges, so a
    /// region owns its boundary (the wrist seam belongs to the hand, the neck seam to the
    /// face). On the full template this is the template's own vertex labelling (every face at
    /// a vertex lends its part to two of the vertex's edges); a vertex on no edge is body.
    pub fn vertex_parts(&self) -> Vec<u8> {
        use panoman_human::regions::Part;
        let edges = &self.shared.prototype.topology().edges;
        let mut mask = vec![0u8; self.n_vertices()];
        for (&[a, b], &p) in edges.iter().zip(self.edge_parts()) {
            let bit = Part::ALL[usize::from(p.min(3))].bit();
            mask[a as usize] |= bit;
            mask[b as usize] |= bit;
        }
        mask.into_iter()
            .map(|m| Part::highest_in(m) as u8)
            .collect()
    }

    /// The vertex ids of each part, ascending, by [`Model::vertex_parts`]: `[(name, ids)]` for
    /// `body`, `face`, `left_hand`, `right_hand`.
    pub fn regions(&self) -> Vec<(&'static str, Vec<u32>)> {
        use panoman_human::regions::Part;
        let parts = self.vertex_parts();
        Part::ALL
            .into_iter()
            .map(|part| {
                let ids = (0..parts.len() as u32)
                    .filter(|&v| parts[v as usize] == part as u8)
                    .collect();
                (part.name(), ids)
            })
            .collect()
    }

    /// Whether the file carries the LBS rig (fits need no asset tree).
    pub fn has_rig(&self) -> bool {
        self.inner().rig.is_some()
    }

    /// The LBS rig embedded in the model file (the generator and its map onto the template
    /// topologies), if any; [`crate::Generator::from_model`] wraps it.
    pub fn rig(&self) -> Option<&Arc<panoman_human::rigfile::RigData>> {
        self.inner().rig.as_ref()
    }

    /// Whether the model has the correction MLP `R(β_B)`.
    pub fn has_correction(&self) -> bool {
        self.inner().correction.is_some()
    }

    /// Whether the model has the motion MLP θ → β_B (motion data in fits).
    pub fn has_motion(&self) -> bool {
        self.inner().motion.is_some()
    }

    /// The template topology's hash (`Topology::hash_hex`), which datasets and keypoint rows
    /// record.
    pub fn topology_hash(&self) -> &str {
        &self.inner().topology_hash
    }

    /// The observed range `[lo, hi]` of each coefficient of `block` over the training rows.
    pub fn beta_range(&self, block: BlockName) -> &[[f32; 2]] {
        &self.inner().blocks[block.index()].beta_range
    }

    /// The shape coefficients α of a rest mesh: its projection onto the shape PCA (PanoMan
    /// Eq. 2; `(V, 3)` metres in, one value per shape component out).
    ///
    /// # Errors
    /// [`Error::Invalid`] if `rest` has the wrong count or non-finite values.
    pub fn project_shape(&self, rest: &[V3]) -> Result<Vec<f64>> {
        self.check_vertices("rest mesh", rest)?;
        let flat: Vec<f64> = rest.iter().flatten().copied().collect();
        Ok(self.inner().shape.project(&flat))
    }

    /// Reads a `params.json` file and checks it against this model (sizes, block names,
    /// finite values; `docs/formats.md`).
    ///
    /// # Errors
    /// The file is unreadable or malformed, or does not fit the model (naming the file).
    pub fn read_params(&self, path: impl AsRef<Path>) -> Result<Params> {
        Ok(Params::read(path.as_ref(), self.inner())?)
    }

    /// The keypoints as sparse rows of vertices: keypoint `k = Σ weight · x[vertex]` over
    /// `rows[k]`'s `(vertex, weight)` entries, in [`Model::keypoint_names`] order.
    pub fn keypoint_rows(&self) -> &[Vec<(u32, f64)>] {
        &self.inner().keypoints.rows
    }

    /// The names of the model's keypoints (TC-133 order: 15 body, 6 feet, 70 face (iBUG-68 +
    /// two pupils), 21 left hand, 21 right hand; see `docs/formats.md`; a model file of the
    /// older TC-127 layout has no feet).
    pub fn keypoint_names(&self) -> &[String] {
        &self.inner().keypoints.names
    }

    /// The keypoints of a mesh in the model's topology (`(133, 3)`, metres, in
    /// [`Model::keypoint_names`] order): each is a fixed sparse linear combination of vertices.
    ///
    /// # Errors
    /// [`Error::Invalid`] if `vertices` has the wrong count or non-finite values.
    pub fn keypoints(&self, vertices: &[V3]) -> Result<Vec<V3>> {
        self.check_vertices("mesh", vertices)?;
        Ok(self.inner().keypoints.evaluate(vertices))
    }

    /// `B_P(α, β)` (PanoMan Eq. 5): the posed vertices (`(V, 3)`, metres) of the parameters,
    /// rebuilt from their RL/RA by `g` and placed by `params.rotation` (axis-angle, radians)
    /// and `params.translation` (metres). Missing α entries or β blocks count as 0.
    ///
    /// # Errors
    /// [`Error::Model`] for parameters that do not fit the model (sizes, non-finite values).
    pub fn pose(&self, params: &Params, correction: Correction) -> Result<Vec<V3>> {
        params
            .validate(self.inner())
            .map_err(|w| Error::Invalid(format!("parameters: {w}")))?;
        self.with_evaluator(|ev| ev.pose(params, correction == Correction::Apply))
            .map_err(Error::from)
    }

    /// [`Model::pose`] with `g`'s frame solve polished to its minimiser by Newton steps: the
    /// function [`Model::pose_vjp`] differentiates (it differs from `pose` by the frame solve's
    /// stopping tolerance). What a differentiable layer (the Python `panoman.torch`) calls.
    ///
    /// # Errors
    /// As [`Model::pose`].
    pub fn pose_precise(&self, params: &Params, correction: Correction) -> Result<Vec<V3>> {
        params
            .validate(self.inner())
            .map_err(|w| Error::Invalid(format!("parameters: {w}")))?;
        self.with_evaluator(|ev| ev.pose_precise(params, correction == Correction::Apply))
            .map_err(Error::from)
    }

    /// The vector–Jacobian product of [`Model::pose_precise`]: the gradient of `⟨grad, pose⟩`
    /// with respect to every parameter (α, each β block, `rotation`, `translation`) for a
    /// vertex covector `grad` (`(V, 3)`, e.g. ∂loss/∂vertices). Exact: g by the implicit
    /// derivative of its frame solve (docs/design/rla-and-g.md §3.8), α through the rest
    /// shape and g's gauge, the correction MLP within its ReLU pattern. Costs about one
    /// `pose_precise` plus a few back-substitutions.
    ///
    /// # Errors
    /// [`Error::Invalid`] for a `grad` of the wrong length or with non-finite values, or
    /// parameters that do not fit the model; numerical failures of g.
    pub fn pose_vjp(&self, params: &Params, correction: Correction, grad: &[V3]) -> Result<Params> {
        params
            .validate(self.inner())
            .map_err(|w| Error::Invalid(format!("parameters: {w}")))?;
        self.check_vertices("vertex gradient", grad)?;
        self.with_evaluator(|ev| ev.pose_vjp(params, correction == Correction::Apply, grad))
            .map_err(Error::from)
    }

    /// Encodes a registered mesh (the model's topology, metres) into parameters, the inverse of
    /// [`Model::pose`], with the default encoder ([`Encoder::VertexError`]): see
    /// [`Model::encode_with`].
    ///
    /// # Errors
    /// [`Error::Invalid`] for wrong vertex counts or non-finite values; numerical failures.
    pub fn encode(
        &self,
        vertices: &[V3],
        rest: Option<&[V3]>,
        correction: Correction,
    ) -> Result<Params> {
        self.encode_with(vertices, rest, correction, Encoder::default())
    }

    /// Encodes a registered mesh (the model's topology, metres) into parameters: α is the
    /// shape-PCA projection of `rest` when given (the person's rest shape), else of the mesh
    /// itself — which is right only near the rest pose: the pose then leaks into α (measured
    /// on the default model, a generated person with one arm raised 50° and the elbow bent
    /// 40°: `pose(encode(x))` is 141 mm off without `rest`, 0.97 mm with it); β is the least-squares fit of the mesh's RL/RA with the correction applied
    /// (unless `correction` is [`Correction::Skip`]), then, with [`Encoder::VertexError`],
    /// refined to minimise `Σ_v |B_P(α, β)_v − T x_v|²` over β (T rigid). The rigid placement
    /// is kept: `pose(encode(x))` lands where `x` is (`rotation`/`translation` are the
    /// least-squares rigid motion from `B_P(α, β)` built in the rest shape's gauge onto `x`).
    ///
    /// # Errors
    /// [`Error::Invalid`] for wrong vertex counts or non-finite values; numerical failures.
    pub fn encode_with(
        &self,
        vertices: &[V3],
        rest: Option<&[V3]>,
        correction: Correction,
        encoder: Encoder,
    ) -> Result<Params> {
        self.check_vertices("mesh", vertices)?;
        if let Some(r) = rest {
            self.check_vertices("rest mesh", r)?;
        }
        self.with_evaluator(|ev| -> Result<Params> {
            let corr = correction == Correction::Apply;
            let mut p = ev.encode(vertices, rest, corr)?;
            let gn = match encoder {
                Encoder::LeastSquares => None,
                Encoder::VertexError => Some(GnOptions::default()),
                Encoder::VertexErrorWith(o) => Some(o),
            };
            if let Some(o) = gn {
                ev.refine_beta(vertices, &mut p, corr, &o)?;
            }
            let built = ev.pose(&p, corr)?;
            let rigid = panoman_mesh::align::rigid_align(&built, vertices, None);
            p.rotation = panoman_mesh::rotation::rotation_vector(&rigid.r);
            p.translation = rigid.t;
            Ok(p)
        })
    }

    fn check_vertices(&self, what: &str, v: &[V3]) -> Result<()> {
        if v.len() != self.n_vertices() {
            return Err(Error::Invalid(format!(
                "{what} has {} vertices, the model's {} topology has {}",
                v.len(),
                self.topology_name(),
                self.n_vertices()
            )));
        }
        if let Some(i) = v.iter().position(|p| !p.iter().all(|c| c.is_finite())) {
            return Err(Error::Invalid(format!("{what}: vertex {i} is not finite")));
        }
        Ok(())
    }
}
