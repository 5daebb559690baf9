//! The STE over a logged run, for users with a real robot: readings from a CSV file with the
//! columns `t,x,y,value` (time in s, position in m, the raw reading; any column order, extra
//! columns ignored, rows in time order).

use std::path::Path;
use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::ste::banks::{PRIOR_BAND_M, RoomBanks};
use crate::ste::baseline::Baselines;
use crate::ste::credible::Uncertainty;
use crate::ste::posterior::{
    CellProbability, Estimator, Sample, Sigmas, SteParams, ValidSteParams, prior_support,
};
use crate::ste::sampler::FieldSampler;

const COLUMNS: [&str; 4] = ["t", "x", "y", "value"];

/// Reads a readings log.
///
/// # Errors
/// [`Error::Log`] when the file cannot be parsed, a column is missing, a field is not a finite
/// number, there is no row, or time goes backwards; [`Error::Io`] when it cannot be read.
pub fn read_log(path: &Path) -> Result<Vec<Sample>> {
    let bad = |reason: String| Error::Log {
        path: path.to_path_buf(),
        reason,
    };
    let text = crate::io::read_to_string(path)?;
    let mut reader = csv::ReaderBuilder::new()
        .trim(csv::Trim::All)
        .from_reader(text.as_bytes());
    let headers = reader
        .headers()
        .map_err(|e| bad(format!("cannot read the header: {e}")))?
        .clone();
    let mut index = [0usize; 4];
    for (slot, name) in index.iter_mut().zip(COLUMNS) {
        *slot = headers.iter().position(|h| h == name).ok_or_else(|| {
            bad(format!(
                "missing column '{name}' (need t,x,y,value; found {})",
                headers.iter().collect::<Vec<_>>().join(",")
            ))
        })?;
    }
    let mut samples: Vec<Sample> = Vec::new();
    for (row, record) in reader.records().enumerate() {
        let line = row + 2;
        let record = record.map_err(|e| bad(format!("line {line}: {e}")))?;
        let mut v = [0.0f64; 4];
        for ((slot, &col), name) in v.iter_mut().zip(&index).zip(COLUMNS) {
            let field = record.get(col).unwrap_or("");
            *slot = field
                .parse::<f64>()
                .ok()
                .filter(|x| x.is_finite())
                .ok_or_else(|| {
                    bad(format!(
                        "line {line}: {name} = '{field}' is not a finite number"
                    ))
                })?;
        }
        if samples.last().is_some_and(|s| v[0] < s.t) {
            return Err(bad(format!("line {line}: time goes backwards")));
        }
        samples.push(Sample {
            t: v[0],
            x: v[1],
            y: v[2],
            value: v[3],
        });
    }
    if samples.is_empty() {
        return Err(bad("no readings".into()));
    }
    Ok(samples)
}

/// Every `k`-th reading of `samples`, from the first, with the smallest `k` that leaves at
/// most `max` of them (all of them when they are no more than `max`): a long log thinned
/// evenly in time, so that a replay fits in memory ([`Estimator::memory_bytes`]).
///
/// # Errors
/// [`Error::Parameter`] for `max` 0.
pub fn thin(samples: &[Sample], max: usize) -> Result<Vec<Sample>> {
    if max == 0 {
        return Err(Error::Parameter("cannot thin a log to no readings".into()));
    }
    let k = samples.len().div_ceil(max).max(1);
    Ok(samples.iter().step_by(k).copied().collect())
}

/// The estimator's state after a step of a replay.
#[derive(Debug, Clone, PartialEq)]
pub struct ReplayStep {
    /// Readings taken in so far.
    pub samples: usize,
    /// Posterior entropy (nats).
    pub entropy: f64,
    /// MAP estimate (m).
    pub estimate: [f64; 2],
    /// Posterior of every candidate.
    pub posterior: Vec<f64>,
}

/// Checks that a replay of `readings` readings over `room`'s banks fits in memory: what the
/// estimator needs ([`Estimator::memory_bytes`]) against the free memory (`free`, in bytes;
/// nothing is checked without it).
///
/// # Errors
/// [`Error::Parameter`] when it does not fit, naming the `--thin-to N` (the most readings
/// that fit in half the free memory) that does.
pub fn check_memory(
    room: &RoomBanks,
    params: &SteParams,
    readings: usize,
    free: Option<u64>,
) -> Result<()> {
    let banks = room.banks.len();
    let candidates = room.sampler.candidates().len();
    let need = Estimator::memory_bytes(banks, candidates, params, readings);
    let Some(free) = free.filter(|&free| need > free) else {
        return Ok(());
    };
    let per_reading = Estimator::memory_bytes(banks, candidates, params, 1).max(1);
    let fits = ((free / 2) / per_reading).max(1);
    Err(Error::Parameter(format!(
        "replaying {readings} readings over {candidates} candidates and {banks} bank(s) needs \
         about {:.1} GB, more than the {:.1} GB free; thin the log with --thin-to {fits} or \
         fewer",
        need as f64 / 1e9,
        free as f64 / 1e9,
    )))
}

/// Runs the estimator over all readings at once, over one bank or several (see
/// [`Estimator::with_banks`]), with the uniform prior of a simulated run (obstacles inflated by
/// `robot_radius_m`, the 0.25 m boundary band excluded).
///
/// # Errors
/// [`Error::Parameter`] for bad settings, no bank, or a sample outside the arena.
pub fn replay<P>(
    samplers: Vec<Arc<FieldSampler>>,
    params: P,
    robot_radius_m: f64,
    samples: &[Sample],
) -> Result<Estimator>
where
    P: TryInto<ValidSteParams>,
    Error: From<P::Error>,
{
    replay_in_steps(samplers, params, robot_radius_m, samples, 1).map(|(est, _)| est)
}

/// [`replay`], taking the readings in `steps` chunks of (nearly) equal count, as a robot would
/// have sent them, and keeping the state after each chunk (for the run viewer).
///
/// # Errors
/// As [`replay`]; [`Error::Parameter`] for zero steps.
pub fn replay_in_steps<P>(
    samplers: Vec<Arc<FieldSampler>>,
    params: P,
    robot_radius_m: f64,
    samples: &[Sample],
    steps: usize,
) -> Result<(Estimator, Vec<ReplayStep>)>
where
    P: TryInto<ValidSteParams>,
    Error: From<P::Error>,
{
    if steps == 0 {
        return Err(Error::Parameter("a replay needs at least one step".into()));
    }
    let Some(first) = samplers.first() else {
        return Err(Error::Parameter("no plume bank".into()));
    };
    let support = prior_support(
        first.layout(),
        first.candidates(),
        robot_radius_m,
        PRIOR_BAND_M,
    )?;
    let mut est = Estimator::with_banks(samplers, &support, params)?;
    let chunk = samples.len().div_ceil(steps).max(1);
    let mut out = Vec::new();
    for (k, part) in samples.chunks(chunk).enumerate() {
        est.update(part)?;
        out.push(ReplayStep {
            samples: (k * chunk + part.len()).min(samples.len()),
            entropy: est.entropy(),
            estimate: est.estimate(),
            posterior: est.posterior().to_vec(),
        });
    }
    Ok((est, out))
}

/// What `replay --json` writes: the estimate beside its uncertainty and the baselines, the
/// posterior and the nuisances' posteriors, and the error when the source is known.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ReplayReport {
    /// The posterior's most probable cell (m).
    pub estimate: [f64; 2],
    /// The credible regions and expected distance, scored against the source when it is known.
    #[serde(default)]
    pub uncertainty: Option<Uncertainty>,
    /// Posterior entropy (nats).
    pub entropy: f64,
    /// Goodness of fit ([`Estimator::fit`]).
    pub fit: Option<f64>,
    /// Readings the estimator took in.
    pub samples: usize,
    /// Readings in the log (more when it was thinned).
    pub log_readings: usize,
    /// The gas feature's name.
    pub feature: String,
    /// The likelihood's standard deviations.
    pub sigmas: Sigmas,
    /// The plume model's name.
    pub model: String,
    /// The simple guesses beside the estimate, over every reading of the log.
    pub baselines: Baselines,
    /// The background rises marginalised and their posterior ([`Estimator::backgrounds`]).
    pub backgrounds: Vec<[f64; 2]>,
    /// Each candidate with its posterior probability.
    pub posterior: Vec<CellProbability>,
    /// The model wind speeds marginalised (factors of the layout's) and their posterior.
    pub wind_scales: Vec<[f64; 2]>,
    /// The wind-direction spreads marginalised (degrees) and their posterior.
    pub wind_spreads: Vec<[f64; 2]>,
    /// The posterior probability of a steady wind, when a wander is weighed.
    pub steady_wind: Option<f64>,
    /// The true source (m), when known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<[f64; 2]>,
    /// The estimate's distance from the source (m), when it is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub error_m: Option<f64>,
}

impl ReplayReport {
    /// The report of a replay: `est` after the readings over `room`'s banks of the plume model
    /// `model`, `log_readings` in the log, with its `baselines` and the `source` when known.
    pub fn new(
        est: &Estimator,
        room: &RoomBanks,
        model: &str,
        log_readings: usize,
        baselines: Baselines,
        source: Option<[f64; 2]>,
    ) -> Self {
        let estimate = est.estimate();
        Self {
            estimate,
            uncertainty: Some(est.uncertainty(source)),
            entropy: est.entropy(),
            fit: est.fit(),
            samples: est.positions().len(),
            log_readings,
            feature: est.params().feature.name().into(),
            sigmas: est.params().sigmas,
            model: model.into(),
            baselines,
            backgrounds: est.backgrounds(),
            posterior: est.posterior_cells(),
            wind_scales: room.marginal(est.bank_posterior(), |b| b.wind_scale),
            wind_spreads: room.marginal(est.bank_posterior(), |b| b.spread_deg),
            steady_wind: est.steady_posterior(),
            source,
            error_m: source.map(|s| (estimate[0] - s[0]).hypot(estimate[1] - s[1])),
        }
    }
}
