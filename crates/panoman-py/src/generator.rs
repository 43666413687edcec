//! `panoman.Generator`: the MakeHuman (Anny-equivalent) generator.

use super::*;

/// The open human generator (Anny-equivalent meshes from phenotype, face units, local
/// changes and a 163-bone pose).
#[pyclass(module = "panoman", name = "Generator", frozen)]
pub(crate) struct PyGenerator {
    inner: panoman::Generator,
}

pub(crate) fn topology_of(py: Python<'_>, name: &str) -> PyResult<panoman::OutputTopology> {
    use panoman::OutputTopology as T;
    match name {
        "anny" => Ok(T::Anny),
        "full" => Ok(T::Full),
        "small" => Ok(T::Small),
        other => Err(invalid(
            py,
            format!("unknown topology '{other}' (expected 'anny', 'full' or 'small')"),
        )),
    }
}

#[pymethods]
impl PyGenerator {
    /// The generator from the asset tree (`$PANOMAN_ASSETS` or the user cache; fetched with
    /// pip on first use).
    #[staticmethod]
    fn load(py: Python<'_>) -> PyResult<Self> {
        run(py, panoman::Generator::load).map(|inner| PyGenerator { inner })
    }

    /// The generator embedded in a model file (no asset access).
    #[staticmethod]
    fn from_model(py: Python<'_>, model: &PyModel) -> PyResult<Self> {
        let m = &model.inner;
        run(py, || panoman::Generator::from_model(m)).map(|inner| PyGenerator { inner })
    }

    /// The rig's bone names (DFS order).
    #[getter]
    fn bone_names(&self) -> Vec<String> {
        self.inner.bone_names().to_vec()
    }

    /// The posed mesh `(V, 3)` float64 metres of generator parameters (a dict or JSON text in
    /// the layout of `docs/formats.md`), on `topology` (`anny`, `full` or `small`).
    #[pyo3(signature = (params, topology="full"))]
    fn generate<'py>(
        &self,
        py: Python<'py>,
        params: &Bound<'py, PyAny>,
        topology: &str,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let topo = topology_of(py, topology)?;
        let text: String = if params.is_instance_of::<PyString>() {
            params.extract()?
        } else {
            py.import("json")?
                .call_method1("dumps", (params,))
                .map_err(|e| invalid(py, format!("generator parameters: {e}")))?
                .extract()?
        };
        let g = &self.inner;
        let v = run(py, || {
            let p = g.parse_params(&text)?;
            g.generate(&p, topo)
        })?;
        Ok(out_points(py, &v))
    }

    /// Triangles `(F, 3)` int64 of `topology`.
    #[pyo3(signature = (topology="full"))]
    fn faces<'py>(&self, py: Python<'py>, topology: &str) -> PyResult<Bound<'py, PyArray2<i64>>> {
        Ok(out_faces(py, self.inner.faces(topology_of(py, topology)?)))
    }
}
