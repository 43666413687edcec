//! `panoman.Params`: α, β per block, rotation and translation.

use super::*;

/// PanoMan parameters: shape coefficients α `(S,)`, β per block `{name: (K,)}` (names
/// `body_l`, `face_l`, `hands_l`, `body_a`, `face_a`, `hands_a`; a missing block is zeros),
/// rotation (axis-angle, radians, `(3,)`) and translation (metres, `(3,)`) applied after
/// posing. All float64.
#[pyclass(module = "panoman", name = "Params", from_py_object)]
#[derive(Clone, Default)]
pub(crate) struct PyParams {
    pub(crate) inner: panoman::Params,
}

pub(crate) fn beta_of(
    py: Python<'_>,
    obj: &Bound<'_, PyAny>,
) -> PyResult<BTreeMap<BlockName, Vec<f64>>> {
    let dict = obj
        .cast::<PyDict>()
        .map_err(|_| invalid(py, "beta: expected a dict {block name: coefficients}"))?;
    let mut beta = BTreeMap::new();
    for (k, v) in dict.iter() {
        let name: String = k
            .extract()
            .map_err(|_| invalid(py, "beta: block names must be strings"))?;
        let block = BlockName::parse(&name).map_err(|e| lib_err(py, e.into()))?;
        let vals = vec1(py, &v, &format!("beta['{name}']"), None)?;
        beta.insert(block, vals);
    }
    Ok(beta)
}

#[pymethods]
impl PyParams {
    /// `Params(alpha=None, beta=None, rotation=None, translation=None)`; missing parts are 0.
    #[new]
    #[pyo3(signature = (alpha=None, beta=None, rotation=None, translation=None))]
    pub(crate) fn new(
        py: Python<'_>,
        alpha: Option<&Bound<'_, PyAny>>,
        beta: Option<&Bound<'_, PyAny>>,
        rotation: Option<&Bound<'_, PyAny>>,
        translation: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let mut p = panoman::Params::default();
        if let Some(a) = alpha {
            p.alpha = vec1(py, a, "alpha", None)?;
        }
        if let Some(b) = beta {
            p.beta = beta_of(py, b)?;
        }
        if let Some(r) = rotation {
            p.rotation = v3_of(py, r, "rotation")?;
        }
        if let Some(t) = translation {
            p.translation = v3_of(py, t, "translation")?;
        }
        Ok(PyParams { inner: p })
    }

    /// Shape coefficients α, `(S,)` float64 (unit variance on the training identities).
    #[getter]
    fn alpha<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        out_vec(py, &self.inner.alpha)
    }

    #[setter]
    fn set_alpha(&mut self, py: Python<'_>, v: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner.alpha = vec1(py, v, "alpha", None)?;
        Ok(())
    }

    /// β per block: `{name: (K,) float64}` (dimensionless component coefficients).
    #[getter]
    fn beta<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (k, v) in &self.inner.beta {
            d.set_item(k.as_str(), out_vec(py, v))?;
        }
        Ok(d)
    }

    #[setter]
    fn set_beta(&mut self, py: Python<'_>, v: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner.beta = beta_of(py, v)?;
        Ok(())
    }

    /// Rotation after posing, axis-angle `(3,)` (radians), about the posed mesh's origin.
    #[getter]
    fn rotation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        out_vec(py, &self.inner.rotation)
    }

    #[setter]
    fn set_rotation(&mut self, py: Python<'_>, v: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner.rotation = v3_of(py, v, "rotation")?;
        Ok(())
    }

    /// Translation after posing, `(3,)` (metres).
    #[getter]
    fn translation<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        out_vec(py, &self.inner.translation)
    }

    #[setter]
    fn set_translation(&mut self, py: Python<'_>, v: &Bound<'_, PyAny>) -> PyResult<()> {
        self.inner.translation = v3_of(py, v, "translation")?;
        Ok(())
    }

    /// The `params.json` text of these parameters (`docs/formats.md`).
    fn to_json(&self, py: Python<'_>) -> PyResult<String> {
        serde_json::to_string(&self.inner).map_err(|e| invalid(py, e.to_string()))
    }

    /// Parameters from `params.json` text.
    #[staticmethod]
    fn from_json(py: Python<'_>, text: &str) -> PyResult<Self> {
        serde_json::from_str(text)
            .map(|inner| PyParams { inner })
            .map_err(|e| invalid(py, format!("not a valid parameter file: {e}")))
    }

    /// Reads a `params.json` file and checks it against `model` (sizes, block names, finite).
    #[staticmethod]
    fn read(py: Python<'_>, path: &Bound<'_, PyAny>, model: &PyModel) -> PyResult<Self> {
        let path = path_of(path)?;
        let m = model.inner.clone();
        run(py, move || m.read_params(&path)).map(|inner| PyParams { inner })
    }

    /// Writes these parameters as `params.json` (`docs/formats.md`).
    fn write(&self, py: Python<'_>, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = path_of(path)?;
        let p = self.inner.clone();
        run(py, move || p.write(&path).map_err(panoman::Error::from))
    }

    fn __reduce__<'py>(slf: &Bound<'py, Self>) -> PyResult<(Bound<'py, PyAny>, (String,))> {
        let py = slf.py();
        let ctor = py.get_type::<PyParams>().getattr("from_json")?;
        Ok((ctor, (slf.borrow().to_json(py)?,)))
    }

    fn __eq__(&self, other: &Bound<'_, PyAny>) -> bool {
        other
            .extract::<PyParams>()
            .is_ok_and(|o| o.inner == self.inner)
    }

    fn __repr__(&self) -> String {
        let blocks: Vec<String> = self
            .inner
            .beta
            .iter()
            .map(|(k, v)| format!("{k}: {}", v.len()))
            .collect();
        format!(
            "Params(alpha: {}, beta: {{{}}}, rotation: {:?}, translation: {:?})",
            self.inner.alpha.len(),
            blocks.join(", "),
            self.inner.rotation,
            self.inner.translation
        )
    }
}
