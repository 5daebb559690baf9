//! Timings of the physics pipeline on one layout, measured side by side with a reference solver.
//!
//! [`time_bank`] measures, as medians over repeats: the wind solve, the factorisation of the
//! transport operator, one source, and the whole candidate bank. [`export_system`] writes the
//! same transport system for `scripts/superlu_bench.py` (scipy's SuperLU) so both are timed in
//! one `plumenet bench` run.

use std::path::Path;
use std::time::Instant;

use faer::Mat;
use ndarray::Array1;

use crate::error::Result;
use crate::io;
use crate::layout::Layout;
use crate::physics::transport::Transport;
use crate::physics::wind::WindField;

/// Median timings (seconds) of the physics bank on one layout.
#[derive(Debug, Clone, PartialEq)]
pub struct BankTimings {
    /// Steady wind solve.
    pub wind_s: f64,
    /// Assembly and sparse LU factorisation of the transport operator.
    pub factor_s: f64,
    /// One source (one back-substitution).
    pub one_source_s: f64,
    /// Every candidate source, in parallel blocks.
    pub bank_s: f64,
    /// Number of candidate sources.
    pub candidates: usize,
    /// Number of transport unknowns (free cells).
    pub unknowns: usize,
    /// Wind iterations.
    pub wind_steps: usize,
}

impl BankTimings {
    /// Wind + factorisation + bank: the whole cost of a new layout's bank.
    pub fn total_s(&self) -> f64 {
        self.wind_s + self.factor_s + self.bank_s
    }
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn timed<T>(f: impl FnOnce() -> Result<T>) -> Result<(T, f64)> {
    let start = Instant::now();
    let out = f()?;
    Ok((out, start.elapsed().as_secs_f64()))
}

/// Times the bank pipeline `repeats` times and returns the medians, with the last run's
/// transport operator and candidates for export.
///
/// # Errors
/// Solver errors of the wind or transport solve; [`crate::Error::Parameter`] for a bad spacing.
pub fn time_bank(
    layout: &Layout,
    spacing_m: f64,
    repeats: usize,
) -> Result<(BankTimings, Transport, Vec<[f64; 2]>)> {
    let candidates = layout.candidates(spacing_m)?;
    let probe = candidates
        .first()
        .copied()
        .unwrap_or([layout.width() / 2.0, layout.height() / 2.0]);
    let (mut wind_t, mut factor_t, mut one_t, mut bank_t) = (vec![], vec![], vec![], vec![]);
    let mut last = None;
    let mut steps = 0;
    for _ in 0..repeats.max(1) {
        let (wind, t) = timed(|| WindField::solve(layout))?;
        wind_t.push(t);
        steps = wind.steps;
        let (transport, t) = timed(|| Transport::new(layout, &wind))?;
        factor_t.push(t);
        one_t.push(timed(|| transport.solve(probe[0], probe[1]))?.1);
        bank_t.push(timed(|| transport.bank(&candidates))?.1);
        last = Some(transport);
    }
    let transport = last.ok_or_else(|| crate::Error::Solver("no benchmark run".into()))?;
    let timings = BankTimings {
        wind_s: median(wind_t),
        factor_s: median(factor_t),
        one_source_s: median(one_t),
        bank_s: median(bank_t),
        candidates: candidates.len(),
        unknowns: transport.unknowns(),
        wind_steps: steps,
    };
    Ok((timings, transport, candidates))
}

/// Writes the transport matrix and the candidates' right-hand sides (COO `.npy` triplets) and
/// plumenet's own solution (`plumenet_bank.npy`, unknowns x candidates) into `dir`.
///
/// # Errors
/// [`crate::Error::Source`] for a bad candidate, [`crate::Error::Io`] on write failure.
pub fn export_system(transport: &Transport, candidates: &[[f64; 2]], dir: &Path) -> Result<()> {
    io::create_dir_all(dir)?;
    let (mut rows, mut cols, mut vals) = (vec![], vec![], vec![]);
    let a = transport.matrix();
    for j in 0..a.ncols() {
        for (i, v) in a.row_idx_of_col(j).zip(a.val_of_col(j)) {
            rows.push(i as i64);
            cols.push(j as i64);
            vals.push(*v);
        }
    }
    io::write_npy(&dir.join("matrix_rows.npy"), &Array1::from(rows))?;
    io::write_npy(&dir.join("matrix_cols.npy"), &Array1::from(cols))?;
    io::write_npy(&dir.join("matrix_vals.npy"), &Array1::from(vals))?;
    let n = transport.unknowns();
    let mut rhs = Mat::<f64>::zeros(n, candidates.len());
    let (mut rows, mut cols, mut vals) = (vec![], vec![], vec![]);
    for (c, &[x, y]) in candidates.iter().enumerate() {
        for (k, w) in transport.source_weights(x, y)? {
            rows.push(k as i64);
            cols.push(c as i64);
            vals.push(w);
            rhs[(k, c)] = w;
        }
    }
    io::write_npy(&dir.join("rhs_rows.npy"), &Array1::from(rows))?;
    io::write_npy(&dir.join("rhs_cols.npy"), &Array1::from(cols))?;
    io::write_npy(&dir.join("rhs_vals.npy"), &Array1::from(vals))?;
    transport.solve_unknowns(&mut rhs);
    let solution = ndarray::Array2::from_shape_fn((n, candidates.len()), |(i, c)| rhs[(i, c)]);
    io::write_npy(&dir.join("plumenet_bank.npy"), &solution)
}
