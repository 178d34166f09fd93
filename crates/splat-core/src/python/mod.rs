//! `pano4d._core`: the Python extension module.

use pyo3::prelude::*;

mod gaussians;
mod io;
mod raster;
mod train;

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    gaussians::register(m)?;
    io::register(m)?;
    raster::register(m)?;
    train::register(m)?;
    Ok(())
}
