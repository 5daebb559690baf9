//! The paper's simulation study: every feature x every sensor x `R` runs with random sources
//! and robot starts, run in parallel, summarised per layout, plume model, feature and sensor.
//!
//! Run `r` of a study with seed `S` uses the run seed `derive_seed(S, r)` for every feature,
//! sensor and plume model: the same source, start, plume and sensor noise, so the comparison is
//! paired. Sources are uniform over the prior's support (free space at least 0.25 m from walls
//! and obstacles), starts uniform over the positions the robot may occupy ([`StartRule`]), or
//! over those near the outlet.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::stats::{mean_std, median};
use crate::ste::features::Feature;
use crate::ste::run::{
    EpisodeConfig, StartRule, World, derive_seed, random_source, random_start, run_episode,
};
use crate::ste::sensor::SensorPreset;

/// One run of a study, as a CSV row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRow {
    /// Layout name (its file stem).
    pub layout: String,
    /// Plume model of the bank (`plumenet` or `solver`).
    pub model: String,
    /// Gas feature.
    pub feature: String,
    /// Sensor preset.
    pub sensor: String,
    /// Run index.
    pub run: usize,
    /// The run's seed.
    pub seed: u64,
    /// True source x (m).
    pub source_x: f64,
    /// True source y (m).
    pub source_y: f64,
    /// Robot start x (m).
    pub start_x: f64,
    /// Robot start y (m).
    pub start_y: f64,
    /// Estimate x (m).
    pub estimate_x: f64,
    /// Estimate y (m).
    pub estimate_y: f64,
    /// Localisation error (m).
    pub error_m: f64,
    /// Iterations.
    pub iterations: usize,
    /// Whether the termination rule fired.
    pub converged: bool,
    /// Readings recorded.
    pub samples: usize,
    /// Distance driven (m).
    pub distance_m: f64,
    /// Wall-clock time (s).
    pub wall_time_s: f64,
}

/// Mean and standard deviation of error and iterations of one layout, plume model, feature and
/// sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
    /// Layout name.
    pub layout: String,
    /// Plume model.
    pub model: String,
    /// Gas feature.
    pub feature: String,
    /// Sensor preset.
    pub sensor: String,
    /// Runs.
    pub runs: usize,
    /// Mean error (m).
    pub error_mean_m: f64,
    /// Standard deviation of the error (m).
    pub error_std_m: f64,
    /// Median error (m).
    pub error_median_m: f64,
    /// Mean iterations.
    pub iterations_mean: f64,
    /// Standard deviation of the iterations.
    pub iterations_std: f64,
    /// Share of runs that converged before the limit.
    pub converged_share: f64,
}

/// The runs of a study, in a fixed order (feature, sensor, run).
pub fn plan_runs(
    features: &[Feature],
    sensors: &[SensorPreset],
    runs: usize,
) -> Vec<(Feature, SensorPreset, usize)> {
    features
        .iter()
        .flat_map(|&f| {
            sensors
                .iter()
                .flat_map(move |&s| (0..runs).map(move |r| (f, s, r)))
        })
        .collect()
}

/// Where a study runs: the world (layout and bank), its names in the rows, and where robots start.
#[derive(Debug, Clone, Copy)]
pub struct StudySite<'a> {
    /// The layout and its bank.
    pub world: &'a World,
    /// Layout name for the rows.
    pub layout: &'a str,
    /// Plume model name for the rows.
    pub model: &'a str,
    /// Where robots start.
    pub start: StartRule,
}

/// Runs every planned run in parallel; `configure` gives the settings of a feature and sensor,
/// and `done` is called after each run (for a progress bar). Rows come back in plan order.
///
/// # Errors
/// The first run's error, if any fails.
pub fn run_study(
    site: StudySite<'_>,
    plan: &[(Feature, SensorPreset, usize)],
    seed: u64,
    configure: impl Fn(Feature, SensorPreset) -> EpisodeConfig + Sync,
    done: impl Fn() + Sync,
) -> Result<Vec<RunRow>> {
    let world = site.world;
    plan.par_iter()
        .map(|&(feature, sensor, run)| {
            let config = configure(feature, sensor);
            let run_seed = derive_seed(seed, run as u64);
            let source = random_source(&world.layout, derive_seed(run_seed, 10))?;
            let start = random_start(
                &world.layout,
                &config.robot,
                site.start,
                derive_seed(run_seed, 11),
            )?;
            let ep = run_episode(world, &config, source, start, run_seed, false)?;
            done();
            let distance_m = ep
                .trajectory
                .windows(2)
                .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
                .sum();
            Ok(RunRow {
                layout: site.layout.into(),
                model: site.model.into(),
                feature: feature.name().into(),
                sensor: sensor.name().into(),
                run,
                seed: run_seed,
                source_x: source[0],
                source_y: source[1],
                start_x: start[0],
                start_y: start[1],
                estimate_x: ep.estimate[0],
                estimate_y: ep.estimate[1],
                error_m: ep.error_m,
                iterations: ep.iterations,
                converged: ep.converged,
                samples: ep.samples.len(),
                distance_m,
                wall_time_s: ep.wall_time_s,
            })
        })
        .collect()
}

/// Summary per layout, plume model, feature and sensor, in the order they first appear in
/// `rows`.
pub fn summarize(rows: &[RunRow]) -> Vec<SummaryRow> {
    let key = |r: &RunRow| {
        (
            r.layout.clone(),
            r.model.clone(),
            r.feature.clone(),
            r.sensor.clone(),
        )
    };
    let mut groups = Vec::new();
    for r in rows {
        if !groups.contains(&key(r)) {
            groups.push(key(r));
        }
    }
    groups
        .into_iter()
        .map(|k| {
            let g: Vec<&RunRow> = rows.iter().filter(|r| key(r) == k).collect();
            let err: Vec<f64> = g.iter().map(|r| r.error_m).collect();
            let it: Vec<f64> = g.iter().map(|r| r.iterations as f64).collect();
            let (error_mean_m, error_std_m) = mean_std(&err);
            let (iterations_mean, iterations_std) = mean_std(&it);
            let (layout, model, feature, sensor) = k;
            SummaryRow {
                runs: g.len(),
                error_median_m: median(&err),
                converged_share: g.iter().filter(|r| r.converged).count() as f64 / g.len() as f64,
                layout,
                model,
                feature,
                sensor,
                error_mean_m,
                error_std_m,
                iterations_mean,
                iterations_std,
            }
        })
        .collect()
}

/// The values the study's box plots show, as `(group, series, value)`: one group per feature
/// (with the layout and plume model when a study has several), one series per sensor; `metric`
/// picks the value.
pub fn plot_values(rows: &[RunRow], metric: fn(&RunRow) -> f64) -> Vec<(String, String, f64)> {
    let several = |f: fn(&RunRow) -> &str| rows.iter().any(|r| f(r) != f(&rows[0]));
    let (layouts, models) = (several(|r| &r.layout), several(|r| &r.model));
    rows.iter()
        .map(|r| {
            let mut group = r.feature.clone();
            if layouts {
                group = format!("{group} {}", r.layout);
            }
            if models {
                group = format!("{group} {}", r.model);
            }
            (group, r.sensor.clone(), metric(r))
        })
        .collect()
}
