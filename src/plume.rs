//! The plume-model abstraction the STE consumes: a bank of predicted mean fields, one per
//! candidate source, from either the physics solver or the trained PlumeNet surrogate.

use ndarray::Array3;

use crate::error::{Error, Result};
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
    /// Short name for reports ("solver", "plumenet:<model dir>").
    fn name(&self) -> String;

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
