//! `panoman.Model`: pose (single, batched, flat and differentiable), encode, keypoints, topology.

use super::*;

/// A loaded PanoMan model (see `panoman.Model.load`). Thread-safe; calls release the GIL.
#[pyclass(module = "panoman", name = "Model", frozen)]
pub(crate) struct PyModel {
    pub(crate) inner: panoman::Model,
}

pub(crate) fn correction(c: bool) -> Correction {
    if c {
        Correction::Apply
    } else {
        Correction::Skip
    }
}

/// `(keypoint, vertex, weight)` arrays of [`PyModel::keypoint_rows`].
pub(crate) type KeypointRows<'py> = (
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<i64>>,
    Bound<'py, PyArray1<f64>>,
);

impl PyModel {
    /// `B` parameter sets from flat arrays (see `pose_flat`), sizes checked against the model.
    fn flat_params(
        &self,
        py: Python<'_>,
        alphas: &Bound<'_, PyAny>,
        betas: &Bound<'_, PyAny>,
        rotations: &Bound<'_, PyAny>,
        translations: &Bound<'_, PyAny>,
    ) -> PyResult<Vec<panoman::Params>> {
        let m = &self.inner;
        let (a, b, s) = mat2(py, alphas, "alphas", None)?;
        if s != m.n_shape() {
            return Err(invalid(
                py,
                format!(
                    "alphas: {s} columns, the model has {} shape coefficients",
                    m.n_shape()
                ),
            ));
        }
        let blocks = m.blocks();
        let k_total: usize = blocks.iter().map(|bi| bi.size).sum();
        let (bt, _, k) = mat2(py, betas, "betas", Some(b))?;
        if k != k_total {
            return Err(invalid(
                py,
                format!("betas: {k} columns, the model's blocks have {k_total} coefficients"),
            ));
        }
        let rot = points3(py, rotations, "rotations", Some(b))?;
        let tr = points3(py, translations, "translations", Some(b))?;
        Ok((0..b)
            .map(|i| {
                let mut off = i * k;
                panoman::Params {
                    alpha: a[i * s..(i + 1) * s].to_vec(),
                    beta: blocks
                        .iter()
                        .map(|bi| {
                            let v = bt[off..off + bi.size].to_vec();
                            off += bi.size;
                            (bi.name, v)
                        })
                        .collect(),
                    rotation: rot[i],
                    translation: tr[i],
                }
            })
            .collect())
    }
}

#[pymethods]
impl PyModel {
    /// Loads a model file (safetensors written by `panoman train`).
    #[staticmethod]
    fn load(py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<Self> {
        let path = path_of(path)?;
        run(py, move || panoman::Model::load(&path)).map(|inner| PyModel { inner })
    }

    /// Posed vertices `B_P(α, β)`, `(V, 3)` float64 metres.
    #[pyo3(signature = (alpha=None, beta=None, correction=true, rotation=None, translation=None))]
    fn pose<'py>(
        &self,
        py: Python<'py>,
        alpha: Option<&Bound<'py, PyAny>>,
        beta: Option<&Bound<'py, PyAny>>,
        correction: bool,
        rotation: Option<&Bound<'py, PyAny>>,
        translation: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let params = match alpha.map(|a| a.extract::<PyParams>()) {
            Some(Ok(p)) if beta.is_none() && rotation.is_none() && translation.is_none() => p.inner,
            _ => PyParams::new(py, alpha, beta, rotation, translation)?.inner,
        };
        let m = &self.inner;
        let c = self::correction(correction);
        let v = run(py, || m.pose(&params, c))?;
        Ok(out_points(py, &v))
    }

    /// Many poses at once, in parallel with the GIL released: `alphas (B, S)`, `betas
    /// {block: (B, K)}`, optional `rotations`/`translations (B, 3)` → `(B, V, 3)` float64.
    #[pyo3(signature = (alphas=None, betas=None, correction=true, rotations=None, translations=None))]
    fn pose_batch<'py>(
        &self,
        py: Python<'py>,
        alphas: Option<&Bound<'py, PyAny>>,
        betas: Option<&Bound<'py, PyAny>>,
        correction: bool,
        rotations: Option<&Bound<'py, PyAny>>,
        translations: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let alphas = alphas.map(|a| mat2(py, a, "alphas", None)).transpose()?;
        let mut blocks = Vec::new();
        if let Some(b) = betas {
            let dict = b
                .cast::<PyDict>()
                .map_err(|_| invalid(py, "betas: expected a dict {block name: (B, K)}"))?;
            for (k, v) in dict.iter() {
                let name: String = k
                    .extract()
                    .map_err(|_| invalid(py, "betas: block names must be strings"))?;
                let block = BlockName::parse(&name).map_err(|e| lib_err(py, e.into()))?;
                let m = mat2(py, &v, &format!("betas['{name}']"), None)?;
                blocks.push((block, m));
            }
        }
        let batch = alphas
            .as_ref()
            .map(|a| a.1)
            .or_else(|| blocks.first().map(|b| b.1.1))
            .ok_or_else(|| invalid(py, "pose_batch: give alphas and/or betas"))?;
        if let Some((name, (_, rows, _))) = blocks.iter().find(|(_, m)| m.1 != batch) {
            return Err(invalid(
                py,
                format!("betas['{name}'] has {rows} rows, the batch has {batch}"),
            ));
        }
        let rigid = |o: Option<&Bound<'py, PyAny>>, what: &str| -> PyResult<Option<Vec<V3>>> {
            o.map(|o| points3(py, o, what, Some(batch))).transpose()
        };
        let rotations = rigid(rotations, "rotations")?;
        let translations = rigid(translations, "translations")?;
        let params: Vec<panoman::Params> = (0..batch)
            .map(|i| panoman::Params {
                alpha: alphas
                    .as_ref()
                    .map(|(a, _, s)| a[i * s..(i + 1) * s].to_vec())
                    .unwrap_or_default(),
                beta: blocks
                    .iter()
                    .map(|(n, (b, _, k))| (*n, b[i * k..(i + 1) * k].to_vec()))
                    .collect(),
                rotation: rotations.as_ref().map_or([0.0; 3], |r| r[i]),
                translation: translations.as_ref().map_or([0.0; 3], |t| t[i]),
            })
            .collect();
        let m = &self.inner;
        let c = self::correction(correction);
        let n = m.n_vertices();
        let meshes = run(py, || {
            params
                .par_iter()
                .map(|p| m.pose(p, c))
                .collect::<panoman::Result<Vec<_>>>()
        })?;
        Ok(out_meshes(py, &meshes, n))
    }

    /// Many poses from flat arrays, in parallel with the GIL released: `alphas (B, S)`,
    /// `betas (B, K)` (every block's coefficients concatenated in `blocks` order, K their
    /// total), `rotations`/`translations (B, 3)` → `(B, V, 3)` float64. With `precise` (the
    /// default) g's frame solve is polished to its minimiser: the function `pose_vjp`
    /// differentiates (what `panoman.torch` calls).
    #[pyo3(signature = (alphas, betas, rotations, translations, correction=true, precise=true))]
    #[allow(clippy::too_many_arguments)]
    fn pose_flat<'py>(
        &self,
        py: Python<'py>,
        alphas: &Bound<'py, PyAny>,
        betas: &Bound<'py, PyAny>,
        rotations: &Bound<'py, PyAny>,
        translations: &Bound<'py, PyAny>,
        correction: bool,
        precise: bool,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let params = self.flat_params(py, alphas, betas, rotations, translations)?;
        let m = &self.inner;
        let c = self::correction(correction);
        let n = m.n_vertices();
        let meshes = run(py, || {
            params
                .par_iter()
                .map(|p| {
                    if precise {
                        m.pose_precise(p, c)
                    } else {
                        m.pose(p, c)
                    }
                })
                .collect::<panoman::Result<Vec<_>>>()
        })?;
        Ok(out_meshes(py, &meshes, n))
    }

    /// The vector–Jacobian product of `pose_flat` (precise): for `grad (B, V, 3)` (∂loss/∂
    /// vertices), the gradients `{alpha: (B, S), beta: (B, K), rotation: (B, 3), translation:
    /// (B, 3)}` of `Σ ⟨grad, vertices⟩`, exact (g differentiated through its frame solve),
    /// in parallel with the GIL released.
    #[pyo3(signature = (alphas, betas, rotations, translations, grad, correction=true))]
    #[allow(clippy::too_many_arguments)]
    fn pose_vjp<'py>(
        &self,
        py: Python<'py>,
        alphas: &Bound<'py, PyAny>,
        betas: &Bound<'py, PyAny>,
        rotations: &Bound<'py, PyAny>,
        translations: &Bound<'py, PyAny>,
        grad: &Bound<'py, PyAny>,
        correction: bool,
    ) -> PyResult<Bound<'py, PyDict>> {
        let params = self.flat_params(py, alphas, betas, rotations, translations)?;
        let (b, n) = (params.len(), self.inner.n_vertices());
        let g = as_f64(py, grad, "grad")?;
        if g.shape() != [b, n, 3] {
            return Err(invalid(
                py,
                format!("grad: expected shape ({b}, {n}, 3), got {:?}", g.shape()),
            ));
        }
        let g: Vec<V3> = g
            .as_slice()?
            .chunks_exact(3)
            .map(|c| [c[0], c[1], c[2]])
            .collect();
        let m = &self.inner;
        let c = self::correction(correction);
        let grads = run(py, || {
            params
                .par_iter()
                .enumerate()
                .map(|(i, p)| m.pose_vjp(p, c, &g[i * n..(i + 1) * n]))
                .collect::<panoman::Result<Vec<_>>>()
        })?;
        let names: Vec<BlockName> = m.blocks().iter().map(|bi| bi.name).collect();
        let rows = |f: &dyn Fn(&panoman::Params) -> Vec<f64>| -> Bound<'py, PyArray2<f64>> {
            let data: Vec<Vec<f64>> = grads.iter().map(f).collect();
            let k = data.first().map_or(0, Vec::len);
            Array2::from_shape_vec((b, k), data.concat())
                .expect("(B, k) rows")
                .into_pyarray(py)
        };
        let d = PyDict::new(py);
        d.set_item("alpha", rows(&|p| p.alpha.clone()))?;
        d.set_item(
            "beta",
            rows(&|p| names.iter().flat_map(|nm| p.beta[nm].clone()).collect()),
        )?;
        d.set_item("rotation", rows(&|p| p.rotation.to_vec()))?;
        d.set_item("translation", rows(&|p| p.translation.to_vec()))?;
        Ok(d)
    }

    /// The keypoints as sparse rows of vertices: `(keypoint, vertex, weight)` arrays
    /// `(N,)` int64, int64, float64, keypoint `k = Σ weight·vertex` over its entries (what
    /// `keypoints` evaluates; `panoman.torch` builds its differentiable keypoints from it).
    #[getter]
    fn keypoint_rows<'py>(&self, py: Python<'py>) -> KeypointRows<'py> {
        let (mut k, mut v, mut w) = (Vec::new(), Vec::new(), Vec::new());
        for (i, row) in self.inner.keypoint_rows().iter().enumerate() {
            for &(vert, weight) in row {
                k.push(i as i64);
                v.push(i64::from(vert));
                w.push(weight);
            }
        }
        (
            Array1::from_vec(k).into_pyarray(py),
            Array1::from_vec(v).into_pyarray(py),
            Array1::from_vec(w).into_pyarray(py),
        )
    }

    /// Parameters of a registered mesh `(V, 3)` metres (the inverse of `pose`); `rest` is
    /// the person's rest shape `(V, 3)` when known.
    #[pyo3(signature = (vertices, rest=None, correction=true))]
    fn encode(
        &self,
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        rest: Option<&Bound<'_, PyAny>>,
        correction: bool,
    ) -> PyResult<PyParams> {
        let n = self.inner.n_vertices();
        let v = points3(py, vertices, "vertices", Some(n))?;
        let r = rest.map(|r| points3(py, r, "rest", Some(n))).transpose()?;
        let m = &self.inner;
        let c = self::correction(correction);
        run(py, || m.encode(&v, r.as_deref(), c)).map(|inner| PyParams { inner })
    }

    /// The model's keypoints `(133, 3)` float64 metres (TC-133; a model of the older layout
    /// gives its 127) of a mesh `(V, 3)`.
    fn keypoints<'py>(
        &self,
        py: Python<'py>,
        vertices: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let v = points3(py, vertices, "vertices", Some(self.inner.n_vertices()))?;
        let m = &self.inner;
        let k = run(py, || m.keypoints(&v))?;
        Ok(out_points(py, &k))
    }

    /// The rest shape `B_S(α)`, `(V, 3)` float64 metres.
    fn rest_shape<'py>(
        &self,
        py: Python<'py>,
        alpha: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let a = vec1(py, alpha, "alpha", None)?;
        if a.len() > self.inner.n_shape() {
            return Err(invalid(
                py,
                format!(
                    "alpha has {} entries, the model has {}",
                    a.len(),
                    self.inner.n_shape()
                ),
            ));
        }
        let m = &self.inner;
        let v = run(py, || Ok(m.rest_shape(&a)))?;
        Ok(out_points(py, &v))
    }

    /// The sole's big-toe, little-toe and heel vertices of each foot (the contact prior's
    /// points; the foot keypoints are `l_big_toe` … `r_heel` of `keypoint_names`), a dict
    /// `{"l_big_toe": v, …}` picked on the default identity's rest soles. Raises `ValueError`
    /// for a model without an embedded rig.
    fn sole_points(&self, py: Python<'_>) -> PyResult<std::collections::BTreeMap<String, u32>> {
        let m = &self.inner;
        let v = run(py, || m.sole_points())?;
        Ok(panoman::FEET_NAMES
            .iter()
            .zip(v)
            .map(|(n, v)| ((*n).to_string(), v))
            .collect())
    }

    /// The model's keypoint names in order (TC-133: 133 strings).
    #[getter]
    fn keypoint_names(&self) -> Vec<String> {
        self.inner.keypoint_names().to_vec()
    }

    /// Template triangles `(F, 3)` int64 (vertex indices).
    #[getter]
    fn faces<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<i64>> {
        out_faces(py, self.inner.faces())
    }

    /// Number of template vertices V.
    #[getter]
    fn n_vertices(&self) -> usize {
        self.inner.n_vertices()
    }

    /// Number of shape coefficients S.
    #[getter]
    fn n_shape(&self) -> usize {
        self.inner.n_shape()
    }

    /// The template topology's name (`full` or `small`).
    #[getter]
    fn topology(&self) -> String {
        self.inner.topology_name().to_string()
    }

    /// Whether the model file carries the LBS rig (fits need no asset tree).
    #[getter]
    fn has_rig(&self) -> bool {
        self.inner.has_rig()
    }

    /// β block sizes `{name: K}` in file order (K = trained components + 1 for the mean).
    #[getter]
    fn blocks<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for b in self.inner.blocks() {
            d.set_item(b.name.as_str(), b.size)?;
        }
        Ok(d)
    }

    /// Part of each edge `(E,)` uint8: 0 body, 1 face, 2 left hand, 3 right hand.
    #[getter]
    fn edge_parts<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u8>> {
        Array1::from_vec(self.inner.edge_parts().to_vec()).into_pyarray(py)
    }

    /// Part of each vertex `(V,)` uint8 (0 body, 1 face, 2 left hand, 3 right hand): the
    /// highest-priority part (hands, face, body) among the vertex's edges.
    #[getter]
    fn vertex_parts<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<u8>> {
        Array1::from_vec(self.inner.vertex_parts()).into_pyarray(py)
    }

    /// Vertex ids of each region `{name: (n,) int64}` for `body`, `face`, `left_hand`,
    /// `right_hand` (ascending; a partition of the vertices, by `vertex_parts`).
    #[getter]
    fn regions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, ids) in self.inner.regions() {
            let ids: Vec<i64> = ids.into_iter().map(i64::from).collect();
            d.set_item(name, Array1::from_vec(ids).into_pyarray(py))?;
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        format!(
            "Model(topology={:?}, vertices={}, shape={}, rig={})",
            self.inner.topology_name(),
            self.inner.n_vertices(),
            self.inner.n_shape(),
            self.inner.has_rig()
        )
    }
}
