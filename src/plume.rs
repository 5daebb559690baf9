//! The plume-model abstraction the STE consumes: a bank of predicted mean fields, one per
//! candidate source, from either the physics solver or the trained PlumeNet surrogate.

use std::path::{Path, PathBuf};

use ndarray::{Array3, ArrayView2, ArrayViewMut2, Axis};
use rayon::prelude::*;

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

/// The angles of [`PlumeBank::spread_over_directions`], in standard deviations: a Gaussian
/// truncated at 1.5 of them, at seven equally spaced angles.
const SPREAD_NODES: [f64; 7] = [-1.5, -1.0, -0.5, 0.0, 0.5, 1.0, 1.5];

/// The largest angular spread (degrees): beyond it the wind would blow back to the inlet.
pub const MAX_SPREAD_DEG: f64 = 90.0;

impl PlumeBank {
    /// Checks a spread for [`PlumeBank::spread_over_directions`].
    ///
    /// # Errors
    /// [`Error::Parameter`] for a spread that is not in `0..=90` degrees.
    pub fn check_spread(sigma_deg: f64) -> Result<()> {
        if (0.0..=MAX_SPREAD_DEG).contains(&sigma_deg) {
            Ok(())
        } else {
            Err(Error::Parameter(format!(
                "a wind-direction spread must be between 0 and {MAX_SPREAD_DEG} degrees, got {sigma_deg}"
            )))
        }
    }

    /// The bank as it looks on average under a wind whose direction wanders: each candidate's
    /// field averaged over copies of itself turned about the candidate by angles Gaussian with
    /// standard deviation `sigma_deg` (truncated at 1.5 of them, seven angles, see
    /// `SPREAD_NODES`). A turned copy is read at the nearest cell, folded back into the arena
    /// at its walls (a wall reflects the plume); copies that land in an obstacle cell are left
    /// out of that cell's average. Obstacle cells stay zero, and a spread of 0 is the bank
    /// itself.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a spread that is not in `0..=90` degrees, or a bank that does not
    /// fit the layout's grid.
    pub fn spread_over_directions(&self, layout: &Layout, sigma_deg: f64) -> Result<Self> {
        Self::check_spread(sigma_deg)?;
        if sigma_deg == 0.0 {
            self.check_grid(layout)?;
            return Ok(self.clone());
        }
        let turns: Vec<[f64; 3]> = SPREAD_NODES
            .iter()
            .map(|u| {
                let (sin, cos) = (u * sigma_deg).to_radians().sin_cos();
                [cos, sin, (-0.5 * u * u).exp()]
            })
            .collect();
        self.averaged_over_turns(layout, &turns)
    }

    /// The bank under a wind turned by `angle_deg` (counter-clockwise): each candidate's field
    /// turned about the candidate by that angle, read at the nearest cell and folded back into
    /// the arena at its walls, as in [`PlumeBank::spread_over_directions`]. A free cell whose
    /// turned copy lands in an obstacle is zero (that gas is blocked there); obstacle cells
    /// stay zero, and an angle of 0 is the bank itself.
    ///
    /// # Errors
    /// [`Error::Parameter`] for an angle that is not within 90 degrees either way, or a bank
    /// that does not fit the layout's grid.
    pub fn turned(&self, layout: &Layout, angle_deg: f64) -> Result<Self> {
        if angle_deg.is_nan() || angle_deg.abs() > MAX_SPREAD_DEG {
            return Err(Error::Parameter(format!(
                "a wind turn must be within {MAX_SPREAD_DEG} degrees either way, got {angle_deg}"
            )));
        }
        if angle_deg == 0.0 {
            self.check_grid(layout)?;
            return Ok(self.clone());
        }
        // A cell reads the field where the turn's inverse takes it.
        let (sin, cos) = (-angle_deg).to_radians().sin_cos();
        self.averaged_over_turns(layout, &[[cos, sin, 1.0]])
    }

    /// Checks that the bank fits `layout`'s grid.
    fn check_grid(&self, layout: &Layout) -> Result<()> {
        let (n, ny, nx) = self.fields.dim();
        if (ny, nx) != layout.shape() || n != self.candidates.len() {
            return Err(Error::Parameter(format!(
                "bank of shape {:?} with {} candidates does not fit the layout grid {:?}",
                self.fields.dim(),
                self.candidates.len(),
                layout.shape()
            )));
        }
        Ok(())
    }

    /// Every field averaged over its copies turned about its candidate by `turns`
    /// (`[cos, sin, weight]`, see [`spread_one`]).
    fn averaged_over_turns(&self, layout: &Layout, turns: &[[f64; 3]]) -> Result<Self> {
        self.check_grid(layout)?;
        let mut fields = Array3::zeros(self.fields.dim());
        fields
            .axis_iter_mut(Axis(0))
            .into_par_iter()
            .zip(self.fields.axis_iter(Axis(0)).into_par_iter())
            .zip(self.candidates.par_iter())
            .for_each(|((out, field), &source)| spread_one(layout, turns, source, field, out));
        Ok(Self {
            candidates: self.candidates.clone(),
            fields,
        })
    }
}

/// One field of [`PlumeBank::spread_over_directions`] or [`PlumeBank::turned`]: `turns` are
/// `[cos, sin, weight]`; a free cell none of whose turned copies is free stays zero.
fn spread_one(
    layout: &Layout,
    turns: &[[f64; 3]],
    [sx, sy]: [f64; 2],
    field: ArrayView2<f32>,
    mut out: ArrayViewMut2<f32>,
) {
    // Folds a coordinate back into [0, len], as a mirror at each wall would.
    let fold = |v: f64, len: f64| {
        let p = v.rem_euclid(2.0 * len);
        if p > len { 2.0 * len - p } else { p }
    };
    let (width, height) = (layout.width(), layout.height());
    for ((j, i), value) in out.indexed_iter_mut() {
        if layout.is_solid(j, i) {
            continue;
        }
        let (x, y) = layout.cell_centre(j, i);
        let (dx, dy) = (x - sx, y - sy);
        let (mut sum, mut weights) = (0.0, 0.0);
        for &[cos, sin, weight] in turns {
            let px = fold(sx + cos * dx - sin * dy, width);
            let py = fold(sy + sin * dx + cos * dy, height);
            let (jj, ii) = layout.cell_of(px, py);
            if !layout.is_solid(jj, ii) {
                sum += weight * f64::from(field[[jj, ii]]);
                weights += weight;
            }
        }
        if weights > 0.0 {
            *value = (sum / weights) as f32;
        }
    }
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

    /// The factor within which the model's mean concentrations are known, as the rank
    /// feature's expected ranks take it ([`crate::ste::params::RankParams::model_rank_factor`]): 1, exact,
    /// unless the model says otherwise.
    fn rank_factor(&self) -> f64 {
        1.0
    }
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
