//! `.ply` and `.ply4d` I/O for Python (`pano4d.ply4d` wraps these).
//!
//! Gaussian sets cross as `GaussianArrays`, spacetime sets as `SpacetimeArrays`
//! (python/gaussians.rs). Format errors raise ValueError, OS errors OSError.

use std::path::PathBuf;

use pyo3::exceptions::{PyOSError, PyValueError};
use pyo3::prelude::*;

use super::gaussians::{PyGaussianArrays, PySpacetimeArrays};
use crate::ply::{self, FileError};
use crate::ply4d::{Ply4dReader, Ply4dWriter, SceneMeta};

fn to_py_err(e: FileError) -> PyErr {
    match e {
        FileError::Io { .. } => PyOSError::new_err(e.to_string()),
        FileError::Invalid(msg) => PyValueError::new_err(msg),
    }
}

/// Reads a standard or SuperSplat-compressed 3DGS `.ply`.
#[pyfunction]
fn read_ply(py: Python<'_>, path: PathBuf) -> PyResult<PyGaussianArrays> {
    let set = py.detach(|| ply::read_ply(&path)).map_err(to_py_err)?;
    Ok(set.into())
}

/// Writes `gaussians` as a standard 3DGS `.ply`, atomically.
#[pyfunction]
fn write_ply(
    py: Python<'_>,
    path: PathBuf,
    gaussians: PyRef<'_, PyGaussianArrays>,
) -> PyResult<()> {
    let set = gaussians.set();
    py.detach(|| ply::write_ply(&path, set)).map_err(to_py_err)
}

/// Streams a `.ply4d`: the static set first, then one dynamic set per `push` (version 1) or
/// the one spacetime set (`push_spacetime`, version 2), then `finish(meta_json)` with
/// timestamps, fps, camera, provenance and extra as JSON. A writer closed or dropped before
/// `finish` leaves no file behind.
#[pyclass(name = "Ply4dWriter", module = "pano4d._core")]
struct PyPly4dWriter {
    inner: Option<Ply4dWriter>,
}

fn closed_writer() -> PyErr {
    PyValueError::new_err("the .ply4d writer is already finished or closed")
}

impl PyPly4dWriter {
    fn writer(&mut self) -> PyResult<&mut Ply4dWriter> {
        self.inner.as_mut().ok_or_else(closed_writer)
    }
}

#[pymethods]
impl PyPly4dWriter {
    #[new]
    fn create(
        py: Python<'_>,
        path: PathBuf,
        static_set: PyRef<'_, PyGaussianArrays>,
    ) -> PyResult<Self> {
        let set = static_set.set();
        let inner = py
            .detach(|| Ply4dWriter::create(&path, set))
            .map_err(to_py_err)?;
        Ok(Self { inner: Some(inner) })
    }

    /// Appends the dynamic set of the next timestamp.
    fn push(&mut self, py: Python<'_>, dynamic_set: PyRef<'_, PyGaussianArrays>) -> PyResult<()> {
        let set = dynamic_set.set();
        let writer = self.writer()?;
        py.detach(|| writer.push(set)).map_err(to_py_err)
    }

    /// Appends the one spacetime set of a version-2 file.
    fn push_spacetime(
        &mut self,
        py: Python<'_>,
        spacetime_set: PyRef<'_, PySpacetimeArrays>,
    ) -> PyResult<()> {
        let set = spacetime_set.set();
        let writer = self.writer()?;
        py.detach(|| writer.push_spacetime(set)).map_err(to_py_err)
    }

    fn finish(&mut self, py: Python<'_>, meta_json: &str) -> PyResult<()> {
        let meta: SceneMeta = serde_json::from_str(meta_json)
            .map_err(|e| PyValueError::new_err(format!("invalid .ply4d scene metadata: {e}")))?;
        let writer = self.inner.take().ok_or_else(closed_writer)?;
        py.detach(|| writer.finish(meta)).map_err(to_py_err)
    }

    /// Abandons an unfinished writer (its scratch data is deleted); no-op once finished.
    fn close(&mut self) {
        self.inner = None;
    }
}

/// An open, memory-mapped `.ply4d` file; sections are decoded on request.
#[pyclass(frozen, name = "Ply4dReader", module = "pano4d._core")]
struct PyPly4dReader {
    inner: Ply4dReader,
}

#[pymethods]
impl PyPly4dReader {
    #[new]
    fn open(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let inner = py.detach(|| Ply4dReader::open(&path)).map_err(to_py_err)?;
        Ok(Self { inner })
    }

    /// The JSON header, as text.
    fn header_json(&self) -> PyResult<String> {
        serde_json::to_string(self.inner.header()).map_err(|e| PyValueError::new_err(e.to_string()))
    }

    #[getter]
    fn num_times(&self) -> usize {
        self.inner.num_times()
    }

    /// The static set.
    fn read_static(&self, py: Python<'_>) -> PyResult<PyGaussianArrays> {
        let set = py.detach(|| self.inner.read_static()).map_err(to_py_err)?;
        Ok(set.into())
    }

    /// Timestamp `t`'s dynamic set (version 2: the spacetime set evaluated at `t`).
    fn read_dynamic(&self, py: Python<'_>, t: usize) -> PyResult<PyGaussianArrays> {
        let set = py
            .detach(|| self.inner.read_dynamic(t))
            .map_err(to_py_err)?;
        Ok(set.into())
    }

    /// The static set followed by timestamp `t`'s dynamic set.
    fn read_at(&self, py: Python<'_>, t: usize) -> PyResult<PyGaussianArrays> {
        let set = py.detach(|| self.inner.read_at(t)).map_err(to_py_err)?;
        Ok(set.into())
    }

    /// The spacetime set of a version-2 file, as stored.
    fn read_spacetime(&self, py: Python<'_>) -> PyResult<PySpacetimeArrays> {
        let set = py
            .detach(|| self.inner.read_spacetime())
            .map_err(to_py_err)?;
        Ok(set.into())
    }

    /// Checks every section's CRC32.
    fn verify(&self, py: Python<'_>) -> PyResult<()> {
        py.detach(|| self.inner.verify()).map_err(to_py_err)
    }

    /// Writes timestamp `t` (static + dynamic) as a plain `.ply`, atomically.
    fn export_ply(&self, py: Python<'_>, t: usize, path: PathBuf) -> PyResult<()> {
        py.detach(|| self.inner.export_ply(t, &path))
            .map_err(to_py_err)
    }
}

pub fn register(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(read_ply, m)?)?;
    m.add_function(wrap_pyfunction!(write_ply, m)?)?;
    m.add_class::<PyPly4dReader>()?;
    m.add_class::<PyPly4dWriter>()?;
    Ok(())
}
