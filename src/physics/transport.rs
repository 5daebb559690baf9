//! Steady advection-diffusion of a point source on the layout's wind: the mean concentration
//! field, and the bank of fields for many sources.
//!
//! The operator is assembled in the layout's canonical frame ([`crate::frame`]: inlet at the
//! first column), and sources and fields are turned in and out of it, so every wind direction
//! shares one discretisation.
//!
//! **Equation.** `div(u c) - D lap(c) = q delta(x - x_s)` in free cells, with `q = 1` unit/s (per
//! unit depth), so `c` is in units per m^2. Zero flux through the side walls and obstacle faces;
//! `c = 0` on the inlet face (diffusive loss through the inlet is kept, it is tiny); pure
//! advective outflow at the outlet (zero diffusive flux). Obstacle cells are not unknowns and hold
//! exactly zero.
//!
//! **Discretisation.** Cell-centred finite volumes on the wind's staggered grid. The face fluxes
//! are the wind solver's exactly divergence-free face velocities, so the scheme conserves mass to
//! round-off. Face coefficients follow Patankar's generalised form
//! `a_nb = D A(|Pe|) + max(-F, 0)` with the cell Peclet number `Pe = F / D`; [`Scheme`] selects
//! `A`. The default [`Scheme::Central`] is second-order (the tests verify its observed order on a
//! manufactured solution, `docs/method.md`, and its error against the analytic point source); where a face's Peclet number exceeds 2 it
//! falls back to the power-law profile, which keeps the matrix an M-matrix.
//!
//! **Point source.** The unit rate is spread over the four cell centres around the source with
//! bilinear (cloud-in-cell) weights; weights falling on obstacle cells are dropped and the rest
//! renormalised.
//!
//! **Solve.** The operator depends only on the layout, so it is factorised once (sparse LU) and
//! each source is one back-substitution; a bank of sources is solved in blocks of right-hand
//! sides, in parallel.

use faer::Mat;
use faer::sparse::SparseColMat;
use ndarray::{Array2, Array3, Axis};
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::physics::scheme::Scheme;
use crate::physics::sparse::{SparseLu, Workload, assemble};
use crate::physics::wind::WindField;

/// Number of right-hand sides solved together in a bank (fixed, so results do not depend on
/// the number of threads).
pub const BANK_BLOCK: usize = 64;

/// The factorised transport operator of one layout.
#[derive(Debug)]
pub struct Transport {
    shape: (usize, usize),
    cell: f64,
    /// Unknown index of each cell (`usize::MAX` in obstacle cells).
    index: Array2<usize>,
    /// `(row, outflow F in m^2/s)` for each outlet face.
    outlet: Vec<(usize, f64)>,
    /// `(row, conductance in m^2/s)` for each inlet face: the gas lost upwind per unit of the
    /// first cell's concentration.
    inlet: Vec<(usize, f64)>,
    lu: SparseLu,
    matrix: SparseColMat<usize, f64>,
    /// The layout as given (sources are checked against it).
    layout: Layout,
    /// The canonical frame the operator is assembled in; `shape`, `index` and `outlet` are
    /// canonical.
    frame: Frame,
    /// The layout turned into that frame.
    canonical: Layout,
}

impl Transport {
    /// Assembles and factorises the operator with the default scheme.
    ///
    /// # Errors
    /// [`Error::Solver`] when the matrix is singular (it is not for a valid layout and wind).
    pub fn new(layout: &Layout, wind: &WindField) -> Result<Self> {
        Self::with_scheme(layout, wind, Scheme::default())
    }

    /// Assembles and factorises the operator with a chosen scheme.
    ///
    /// # Errors
    /// [`Error::Solver`] when the matrix is singular; [`Error::Parameter`] when the wind was
    /// solved on another grid.
    pub fn with_scheme(real: &Layout, real_wind: &WindField, scheme: Scheme) -> Result<Self> {
        if real_wind.shape() != real.shape() {
            return Err(Error::Parameter(format!(
                "wind grid {:?} does not match layout grid {:?}",
                real_wind.shape(),
                real.shape()
            )));
        }
        let frame = Frame::of(real);
        let layout = frame.layout_to_canonical(real)?;
        let wind = &real_wind.to_canonical(&frame);
        let (ny, nx) = layout.shape();
        let (index, n) = layout.free_cell_index();
        let h = layout.cell();
        let d = layout.diffusivity();
        let mut trip = Vec::with_capacity(5 * n);
        let mut outlet = Vec::new();
        let mut inlet = Vec::new();
        for j in 0..ny {
            for i in 0..nx {
                let c = index[[j, i]];
                if c == usize::MAX {
                    continue;
                }
                let mut diag = 0.0;
                // Each face with outward flux F (m^2/s) towards a neighbour unknown; faces against
                // obstacles carry nothing.
                let mut face = |flux: f64, nb: usize| {
                    if nb != usize::MAX {
                        let a = d * scheme.profile(flux / d);
                        diag += a + flux.max(0.0);
                        trip.push((c, nb, -(a + (-flux).max(0.0))));
                    }
                };
                if i > 0 {
                    face(-wind.u[[j, i]] * h, index[[j, i - 1]]);
                }
                if i + 1 < nx {
                    face(wind.u[[j, i + 1]] * h, index[[j, i + 1]]);
                }
                if j > 0 {
                    face(-wind.v[[j, i]] * h, index[[j - 1, i]]);
                }
                if j + 1 < ny {
                    face(wind.v[[j + 1, i]] * h, index[[j + 1, i]]);
                }
                if i == 0 {
                    // Inlet: c = 0 half a cell away (conductance 2D), inflow carries no gas.
                    let inflow = wind.u[[j, 0]] * h;
                    let loss = 2.0 * d * scheme.profile(inflow / (2.0 * d)) + (-inflow).max(0.0);
                    diag += loss;
                    inlet.push((j, loss));
                }
                if i + 1 == nx {
                    // Outlet: advective outflow only; any backflow brings clean air.
                    let outflow = wind.u[[j, nx]] * h;
                    diag += outflow.max(0.0);
                    outlet.push((j, outflow.max(0.0)));
                }
                trip.push((c, c, diag));
            }
        }
        let matrix = assemble(n, &trip)?;
        let lu = SparseLu::factorize(&matrix, Workload::Blocks)?;
        Ok(Self {
            shape: (ny, nx),
            cell: h,
            index,
            outlet,
            inlet,
            lu,
            matrix,
            layout: real.clone(),
            frame,
            canonical: layout,
        })
    }

    /// The assembled operator (free cells in row-major order), for export to other solvers.
    pub fn matrix(&self) -> &SparseColMat<usize, f64> {
        &self.matrix
    }

    /// Number of unknowns (free cells).
    pub fn unknowns(&self) -> usize {
        self.lu.dim()
    }

    /// Cloud-in-cell weights `(unknown, weight)` of a unit source at `(x, y)`.
    ///
    /// # Errors
    /// [`Error::Source`] when the position is not in free space.
    pub fn source_weights(&self, x: f64, y: f64) -> Result<Vec<(usize, f64)>> {
        self.layout.check_source(x, y)?;
        let (x, y) = self.frame.to_canonical(x, y);
        let (ny, nx) = self.shape;
        let fx = (x / self.cell - 0.5).clamp(0.0, (nx - 1) as f64);
        let fy = (y / self.cell - 0.5).clamp(0.0, (ny - 1) as f64);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (tx, ty) = (fx - i0 as f64, fy - j0 as f64);
        let mut weights: Vec<(usize, f64)> = Vec::with_capacity(4);
        for (dj, wy) in [(0, 1.0 - ty), (1, ty)] {
            for (di, wx) in [(0, 1.0 - tx), (1, tx)] {
                let (j, i) = ((j0 + dj).min(ny - 1), (i0 + di).min(nx - 1));
                let k = self.index[[j, i]];
                if k != usize::MAX && wx * wy > 0.0 {
                    match weights.iter_mut().find(|(idx, _)| *idx == k) {
                        Some(entry) => entry.1 += wx * wy,
                        None => weights.push((k, wx * wy)),
                    }
                }
            }
        }
        let total: f64 = weights.iter().map(|w| w.1).sum();
        if total <= 0.0 {
            // The containing cell is free (checked above), so put the source there.
            let (j, i) = self.canonical.cell_of(x, y);
            return Ok(vec![(self.index[[j, i]], 1.0)]);
        }
        Ok(weights.into_iter().map(|(k, w)| (k, w / total)).collect())
    }

    /// Mean concentration (units/m^2) of a unit source at `(x, y)`, shape `[ny, nx]`, rounded to
    /// single precision as in a bank.
    ///
    /// # Errors
    /// [`Error::Source`] when the position is not in free space.
    pub fn solve(&self, x: f64, y: f64) -> Result<Array2<f64>> {
        let bank = self.bank(&[[x, y]])?;
        Ok(bank.index_axis_move(Axis(0), 0).mapv(f64::from))
    }

    /// Fields of many unit sources, shape `[N, ny, nx]`, solved in parallel blocks of
    /// [`BANK_BLOCK`] right-hand sides.
    ///
    /// # Errors
    /// [`Error::Source`] for the first position not in free space.
    pub fn bank(&self, sources: &[[f64; 2]]) -> Result<Array3<f32>> {
        let weights: Vec<Vec<(usize, f64)>> = sources
            .iter()
            .map(|&[x, y]| self.source_weights(x, y))
            .collect::<Result<_>>()?;
        let (ny, nx) = self.layout.shape();
        let mut out = Array3::<f32>::zeros((sources.len(), ny, nx));
        let n = self.unknowns();
        out.axis_chunks_iter_mut(Axis(0), BANK_BLOCK)
            .into_par_iter()
            .zip(weights.par_chunks(BANK_BLOCK))
            .for_each(|(mut block, w)| {
                let mut rhs = Mat::<f64>::zeros(n, w.len());
                for (col, ws) in w.iter().enumerate() {
                    for &(k, wt) in ws {
                        rhs[(k, col)] = wt;
                    }
                }
                self.solve_unknowns(&mut rhs);
                for (col, mut field) in block.outer_iter_mut().enumerate() {
                    for ((j, i), value) in field.indexed_iter_mut() {
                        let k = self.index[self.frame.cell_to_canonical(j, i)];
                        if k != usize::MAX {
                            *value = rhs[(k, col)] as f32;
                        }
                    }
                }
            });
        Ok(out)
    }

    /// Solves the operator in place for a block of right-hand sides over the unknowns
    /// (`unknowns x k`), as used by [`Transport::bank`].
    pub fn solve_unknowns(&self, rhs: &mut Mat<f64>) {
        self.lu.solve_in_place(rhs);
    }

    /// Gas flux (units/s) leaving through the outlet for a field of this layout.
    pub fn outlet_flux(&self, field: &Array2<f64>) -> f64 {
        let field = self.frame.cells_to_canonical(field.view());
        let last = self.shape.1 - 1;
        self.outlet.iter().map(|&(j, f)| f * field[[j, last]]).sum()
    }

    /// Gas flux (units/s) lost upwind through the inlet face (`c = 0` beyond it) for a field of
    /// this layout. With [`Transport::outlet_flux`] it balances the release: the two add up to
    /// the source's rate to round-off, the discrete conservation law.
    pub fn inlet_flux(&self, field: &Array2<f64>) -> f64 {
        let field = self.frame.cells_to_canonical(field.view());
        self.inlet.iter().map(|&(j, a)| a * field[[j, 0]]).sum()
    }
}
