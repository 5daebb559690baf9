//! Timings of the physics pipeline on one layout, measured side by side with a reference solver.
//!
//! [`time_bank`] measures, as medians over repeats: the wind solve, the factorisation of the
//! transport operator, one source, and the whole candidate bank. [`export_system`] writes the
//! same transport system for `scripts/superlu_bench.py` (scipy's SuperLU) so both are timed in
//! one `plumenet bench` run. [`time_ste_update`] times one STE update per feature against the
//! floor of reading the estimate matrix once (`plumenet bench-ste`). [`time_model_bank`] times
//! a trained PlumeNet's bank of the same candidates (`plumenet bench --model`).

use std::path::Path;
use std::time::Instant;

use faer::Mat;
use ndarray::Array1;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use plumenet::Result;
use plumenet::io;
use plumenet::layout::Layout;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;
use plumenet::plume::PlumeModel;
use plumenet::service::{RemoteSession, serve_tcp};
use plumenet::sim::episode::Steering;
use plumenet::stats::median;
use plumenet::ste::banks::{PRIOR_BAND_M, RoomBanks};
use plumenet::ste::posterior::prior_support;
use plumenet::ste::protocol::{NoJournal, Protocol};
use plumenet::ste::session::{Session, SessionConfig};
use plumenet::ste::{Estimator, Sample, SteParams};

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

fn timed<T>(f: impl FnOnce() -> Result<T>) -> Result<(T, f64)> {
    let start = Instant::now();
    let out = f()?;
    Ok((out, start.elapsed().as_secs_f64()))
}

/// Times the bank pipeline `repeats` times and returns the medians, with the last run's
/// transport operator and candidates for export.
///
/// # Errors
/// Solver errors of the wind or transport solve; [`plumenet::Error::Parameter`] for a bad spacing.
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
    let transport = last.ok_or_else(|| plumenet::Error::Solver("no benchmark run".into()))?;
    let timings = BankTimings {
        wind_s: median(&wind_t),
        factor_s: median(&factor_t),
        one_source_s: median(&one_t),
        bank_s: median(&bank_t),
        candidates: candidates.len(),
        unknowns: transport.unknowns(),
        wind_steps: steps,
    };
    Ok((timings, transport, candidates))
}

/// Median seconds of `model`'s bank of `candidates` in `layout` over `repeats` runs: all it
/// costs a new room (for PlumeNet: the wind solve, the input encoding, the network, the
/// inverse transform).
///
/// # Errors
/// As [`PlumeModel::bank`].
pub fn time_model_bank(
    model: &dyn PlumeModel,
    layout: &Layout,
    candidates: &[[f64; 2]],
    repeats: usize,
) -> Result<f64> {
    let times = (0..repeats.max(1))
        .map(|_| timed(|| model.bank(layout, candidates)).map(|(_, t)| t))
        .collect::<Result<Vec<f64>>>()?;
    Ok(median(&times))
}

/// Writes the transport matrix and the candidates' right-hand sides (COO `.npy` triplets) and
/// plumenet's own solution (`plumenet_bank.npy`, unknowns x candidates) into `dir`.
///
/// # Errors
/// [`plumenet::Error::Source`] for a bad candidate, [`plumenet::Error::Io`] on write failure.
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

/// Median timings (seconds) of one STE update on one core.
#[derive(Debug, Clone, PartialEq)]
pub struct SteTimings {
    /// The estimator settings timed (feature, rank additions).
    pub params: SteParams,
    /// One update: `batch` new readings on top of the others, posterior recomputed.
    pub update_s: f64,
    /// Reading an `N x n` estimate matrix once (a squared difference per entry): the floor.
    pub floor_s: f64,
    /// Candidates `N`.
    pub candidates: usize,
    /// Readings after the update, `n`.
    pub samples: usize,
}

/// Times estimator updates of `batch` readings each (random free positions, random values), on
/// a single thread: `repeats` successive updates that end at `total` readings, as in a run, so
/// the vectors grow the way they do in practice. Also times the floor: touching every entry
/// of the `N x total` estimate matrix once.
///
/// # Errors
/// [`plumenet::Error::Parameter`] for `batch` not below `total`, and the estimator's errors.
pub fn time_ste_update(
    room: &RoomBanks,
    params: SteParams,
    total: usize,
    batch: usize,
    repeats: usize,
) -> Result<SteTimings> {
    let repeats = repeats.max(1);
    if batch == 0 || batch * repeats >= total {
        return Err(plumenet::Error::Parameter(format!(
            "{repeats} updates of {batch} readings must stay below the total {total}"
        )));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .map_err(|e| plumenet::Error::Parameter(format!("cannot build a thread pool: {e}")))?;
    let samples = synthetic_readings(&room.layout, total, 0.1, 0);
    let support = prior_support(&room.layout, room.sampler.candidates(), 0.07, PRIOR_BAND_M)?;
    let mut est = Estimator::with_banks(room.samplers(), &support, params)?;
    let first = total - batch * repeats;
    est.update(&samples[..first])?;
    let n_cand = room.sampler.len();
    let matrix: Vec<f32> = (0..n_cand * total)
        .map(|k| (k % 97) as f32 * 0.01)
        .collect();
    let m: Vec<f32> = (0..total).map(|k| (k % 13) as f32 * 0.07).collect();
    pool.install(|| {
        let mut update = Vec::with_capacity(repeats);
        let mut floor = Vec::with_capacity(repeats);
        for r in 0..repeats {
            let from = first + r * batch;
            let ((), s) = timed(|| est.update(&samples[from..from + batch]))?;
            update.push(s);
            let (sum, s) = timed(|| {
                Ok(matrix
                    .chunks(total)
                    .map(|row| {
                        row.iter()
                            .zip(&m)
                            .map(|(e, m)| f64::from((e - m) * (e - m)))
                            .sum::<f64>()
                    })
                    .sum::<f64>())
            })?;
            std::hint::black_box(sum);
            floor.push(s);
        }
        Ok(SteTimings {
            params,
            update_s: median(&update),
            floor_s: median(&floor),
            candidates: n_cand,
            samples: total,
        })
    })
}

/// `count` synthetic readings `dt_s` apart at uniformly random free positions (0.2 m from the
/// walls) with uniformly random values in `[0, 1)`, from `seed`.
pub fn synthetic_readings(layout: &Layout, count: usize, dt_s: f64, seed: u64) -> Vec<Sample> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut samples = Vec::with_capacity(count);
    while samples.len() < count {
        let x = rng.random_range(0.2..layout.width() - 0.2);
        let y = rng.random_range(0.2..layout.height() - 0.2);
        if layout.is_free(x, y) {
            samples.push(Sample {
                t: samples.len() as f64 * dt_s,
                x,
                y,
                value: rng.random_range(0.0..1.0),
            });
        }
    }
    samples
}

/// The time (s) of one session iteration (update of `batch` new readings on top of
/// `total - batch`, then planning), on all cores.
///
/// # Errors
/// [`plumenet::Error::Parameter`] for `batch` not below `total`, and the session's errors.
pub fn time_session_iteration(
    room: &RoomBanks,
    config: SessionConfig,
    total: usize,
    batch: usize,
) -> Result<f64> {
    if batch == 0 || batch >= total {
        return Err(plumenet::Error::Parameter(format!(
            "an iteration of {batch} readings must stay below the total {total}"
        )));
    }
    let readings = synthetic_readings(&room.layout, total, 0.1, 1);
    let mut session = Session::new(room, config)?;
    session.add_readings(&readings[..total - batch])?;
    session.iterate(None)?;
    session.add_readings(&readings[total - batch..])?;
    let clock = Instant::now();
    session.iterate(None)?;
    Ok(clock.elapsed().as_secs_f64())
}

/// What a streaming load test saw.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct LoadReport {
    /// Readings the client sent.
    pub sent: usize,
    /// Readings the server counted.
    pub accepted: usize,
    /// Requests refused.
    pub errors: usize,
    /// Round trips of `readings` + `iterate` (s), in order.
    pub round_trips_s: Vec<f64>,
    /// Wall-clock time of the whole stream (s).
    pub wall_s: f64,
    /// Resident memory (bytes) after each iteration, where the system reports it.
    pub resident_bytes: Vec<u64>,
}

/// The process's resident memory (Linux `/proc/self/status`), when readable.
pub fn resident_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Streams `rate_hz` synthetic readings per simulated second for `seconds` to a session served
/// over TCP on loopback (in this process), one `readings` request a second and an `iterate`
/// every `iterate_every` of them, and reports what came back. As fast as the server answers,
/// not in real time.
///
/// # Errors
/// When the server cannot be started or reached.
pub fn serve_load(
    room: &RoomBanks,
    config: SessionConfig,
    rate_hz: usize,
    seconds: usize,
    iterate_every: usize,
) -> Result<LoadReport> {
    let session = Session::new(room, config)?;
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut protocol = Protocol::new(session, "bench", "bench");
        let _ = serve_tcp(&mut protocol, &mut NoJournal, "127.0.0.1:0", |at| {
            let _ = tx.send(at);
        });
    });
    let at = rx
        .recv()
        .map_err(|_| plumenet::Error::Parameter("the server did not start".into()))?;
    let mut client = RemoteSession::connect(at)?;
    let readings = synthetic_readings(&room.layout, rate_hz * seconds, 1.0 / rate_hz as f64, 2);
    let clock = Instant::now();
    let (mut accepted, mut errors) = (0, 0);
    let mut round_trips_s = Vec::new();
    let mut resident = Vec::new();
    for (k, batch) in readings.chunks(rate_hz.max(1)).enumerate() {
        let start = Instant::now();
        match client.send_readings(batch) {
            Ok(n) => accepted = n,
            Err(_) => errors += 1,
        }
        if (k + 1) % iterate_every.max(1) == 0 {
            let last = batch[batch.len() - 1];
            if client.iterate([last.x, last.y]).is_err() {
                errors += 1;
            }
            round_trips_s.push(start.elapsed().as_secs_f64());
            resident.extend(resident_bytes());
        }
    }
    Ok(LoadReport {
        sent: readings.len(),
        accepted,
        errors,
        round_trips_s,
        wall_s: clock.elapsed().as_secs_f64(),
        resident_bytes: resident,
    })
}
