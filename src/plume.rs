//! The plume-model abstraction the STE consumes: a bank of predicted mean fields, one per
//! candidate source, from either the physics solver or the trained PlumeNet surrogate.

use std::path::{Path, PathBuf};

use ndarray::Array3;

use crate::error::{Error, Result};
use crate::io;
use crate::layout::Layout;
use crate::physics::transport::Transport;
use crate::physics::wind::WindField;

/// Mean fields of every candidate source of a layout.
#[derive(Debug, Clone, PartialEq)]
pub struct PlumeBank {
    /// Candidate source positions (m), one per field.
    pub candidates: Vec<[f64; 2]>,
    /// Fields `[N, ny, nx]` (units/m^2 for a 1 unit/s source), zero in obstacle cells.
    pub fields: Array3<f32>,
}

/// A model that predicts the mean concentration field of a source in a layout.
pub trait PlumeModel {
    /// Short name for reports (`solver`, `plumenet:DIR`).
    fn name(&self) -> String;

    /// Identifies the model's predictions (weights and settings) for the bank cache.
    fn digest(&self) -> String;

    /// The fields of all `candidates` in `layout`.
    ///
    /// # Errors
    /// [`Error::Source`] for a candidate outside free space, or the model's own failures.
    fn bank(&self, layout: &Layout, candidates: &[[f64; 2]]) -> Result<PlumeBank>;
}

/// The physics model: steady wind plus advection-diffusion, exact but slower for new layouts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PhysicsSolver;

impl PlumeModel for PhysicsSolver {
    fn name(&self) -> String {
        "solver".into()
    }

    fn digest(&self) -> String {
        format!("solver-{}", env!("CARGO_PKG_VERSION"))
    }

    fn bank(&self, layout: &Layout, candidates: &[[f64; 2]]) -> Result<PlumeBank> {
        if candidates.is_empty() {
            return Err(Error::Parameter(
                "a bank needs at least one candidate".into(),
            ));
        }
        let wind = WindField::solve(layout)?;
        let fields = Transport::new(layout, &wind)?.bank(candidates)?;
        Ok(PlumeBank {
            candidates: candidates.to_vec(),
            fields,
        })
    }
}

/// Where a bank of `model` for `layout` and `candidates` is cached in `dir`: the file name is
/// the SHA-256 of the model digest, the layout (with its defaults made explicit) and the
/// candidate coordinates.
pub fn bank_cache_path(
    dir: &Path,
    model: &dyn PlumeModel,
    layout: &Layout,
    candidates: &[[f64; 2]],
) -> PathBuf {
    let mut key = format!("{}\n{}\n", model.digest(), layout.to_json());
    for [x, y] in candidates {
        key.push_str(&format!("{x:.6},{y:.6};"));
    }
    dir.join(format!(
        "bank-{}.npy",
        &io::sha256_hex(key.as_bytes())[..24]
    ))
}

/// The bank of `model`, read from the cache directory when a valid copy is there, otherwise
/// computed and written there atomically. Returns the bank and whether it came from the cache.
/// A cached file that cannot be read or has the wrong shape is recomputed and replaced.
///
/// # Errors
/// The model's own errors, or [`Error::Io`] when the cache cannot be written.
pub fn cached_bank(
    model: &dyn PlumeModel,
    layout: &Layout,
    candidates: &[[f64; 2]],
    dir: &Path,
) -> Result<(PlumeBank, bool)> {
    let path = bank_cache_path(dir, model, layout, candidates);
    let expected = (candidates.len(), layout.ny(), layout.nx());
    if path.exists()
        && let Ok(fields) = io::read_npy::<f32, ndarray::Ix3>(&path)
        && fields.dim() == expected
        && fields.iter().all(|v| v.is_finite())
    {
        let bank = PlumeBank {
            candidates: candidates.to_vec(),
            fields,
        };
        return Ok((bank, true));
    }
    let bank = model.bank(layout, candidates)?;
    io::write_npy(&path, &bank.fields)?;
    Ok((bank, false))
}
