//! Array conversion: any array-like in (one C-ordered float64 copy at most), numpy out.

use super::*;

/// Any array-like (numpy of any order, CPU torch tensors, nested lists) of real numbers as a
/// C-ordered float64 array: one conversion, no copy when it already is one.
pub(crate) fn as_f64<'py>(
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
pub(crate) fn points3(
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
pub(crate) fn vec1(
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
pub(crate) fn mat2(
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

pub(crate) fn v3_of(py: Python<'_>, obj: &Bound<'_, PyAny>, what: &str) -> PyResult<V3> {
    let v = vec1(py, obj, what, Some(3))?;
    Ok([v[0], v[1], v[2]])
}

pub(crate) fn out_points<'py>(py: Python<'py>, v: &[V3]) -> Bound<'py, PyArray2<f64>> {
    let flat: Vec<f64> = v.iter().flatten().copied().collect();
    Array2::from_shape_vec((v.len(), 3), flat)
        .expect("(n, 3) from 3n values")
        .into_pyarray(py)
}

pub(crate) fn out_faces<'py>(py: Python<'py>, f: &[[u32; 3]]) -> Bound<'py, PyArray2<i64>> {
    let flat: Vec<i64> = f.iter().flatten().map(|&i| i64::from(i)).collect();
    Array2::from_shape_vec((f.len(), 3), flat)
        .expect("(n, 3) from 3n values")
        .into_pyarray(py)
}

pub(crate) fn out_vec<'py>(py: Python<'py>, v: &[f64]) -> Bound<'py, PyArray1<f64>> {
    Array1::from_vec(v.to_vec()).into_pyarray(py)
}

/// `json.loads` of a serialisable value (reports, rig parameters).
pub(crate) fn to_python<'py>(
    py: Python<'py>,
    v: &impl serde::Serialize,
) -> PyResult<Bound<'py, PyAny>> {
    let text = serde_json::to_string(v).map_err(|e| invalid(py, e.to_string()))?;
    py.import("json")?.call_method1("loads", (text,))
}

pub(crate) fn path_of(obj: &Bound<'_, PyAny>) -> PyResult<PathBuf> {
    let fspath = obj.py().import("os")?.call_method1("fspath", (obj,))?;
    Ok(PathBuf::from(fspath.extract::<String>()?))
}

/// `B` meshes of `n` vertices as a `(B, n, 3)` float64 array.
pub(crate) fn out_meshes<'py>(
    py: Python<'py>,
    meshes: &[Vec<V3>],
    n: usize,
) -> Bound<'py, PyArray3<f64>> {
    let flat: Vec<f64> = meshes.iter().flatten().flatten().copied().collect();
    Array3::from_shape_vec((meshes.len(), n, 3), flat)
        .expect("(B, V, 3) from B·V·3 values")
        .into_pyarray(py)
}
