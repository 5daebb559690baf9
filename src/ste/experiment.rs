//! The paper's simulation study: every feature x every sensor x `R` runs with random sources
//! and robot starts, run in parallel, summarised per feature and sensor.
//!
//! Run `r` of a study with seed `S` uses the run seed `derive_seed(S, r)` for every feature and
//! sensor: the same source, start, plume and sensor noise, so the comparison is paired. Sources
//! are uniform over the prior's support (free space at least 0.25 m from walls and obstacles),
//! starts uniform over the positions the robot may occupy.

use image::RgbImage;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::Result;
use crate::report::boxplot::{BoxGroup, render_boxplots};
use crate::report::stack_vertical;
use crate::ste::features::Feature;
use crate::ste::run::{
    EpisodeConfig, World, derive_seed, random_source, random_start, run_episode,
};
use crate::ste::sensor::SensorPreset;

/// One run of a study, as a CSV row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRow {
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

/// Mean and standard deviation of error and iterations of one feature and sensor.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
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

/// Runs every planned run in parallel; `configure` gives the settings of a feature and sensor,
/// and `done` is called after each run (for a progress bar). Rows come back in plan order.
///
/// # Errors
/// The first run's error, if any fails.
pub fn run_study(
    world: &World,
    plan: &[(Feature, SensorPreset, usize)],
    seed: u64,
    configure: impl Fn(Feature, SensorPreset) -> EpisodeConfig + Sync,
    done: impl Fn() + Sync,
) -> Result<Vec<RunRow>> {
    plan.par_iter()
        .map(|&(feature, sensor, run)| {
            let config = configure(feature, sensor);
            let run_seed = derive_seed(seed, run as u64);
            let source = random_source(&world.layout, derive_seed(run_seed, 10))?;
            let start = random_start(&world.layout, &config.robot, derive_seed(run_seed, 11))?;
            let ep = run_episode(world, &config, source, start, run_seed, false)?;
            done();
            let distance_m = ep
                .trajectory
                .windows(2)
                .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
                .sum();
            Ok(RunRow {
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

fn mean_std(v: &[f64]) -> (f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<f64>() / n;
    let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0).max(1.0);
    (mean, var.sqrt())
}

/// Median of a slice (NaN-free).
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Summary per feature and sensor, in the order they first appear in `rows`.
pub fn summarize(rows: &[RunRow]) -> Vec<SummaryRow> {
    let mut groups: Vec<(String, String)> = Vec::new();
    for r in rows {
        let key = (r.feature.clone(), r.sensor.clone());
        if !groups.contains(&key) {
            groups.push(key);
        }
    }
    groups
        .into_iter()
        .map(|(feature, sensor)| {
            let g: Vec<&RunRow> = rows
                .iter()
                .filter(|r| r.feature == feature && r.sensor == sensor)
                .collect();
            let err: Vec<f64> = g.iter().map(|r| r.error_m).collect();
            let it: Vec<f64> = g.iter().map(|r| r.iterations as f64).collect();
            let (error_mean_m, error_std_m) = mean_std(&err);
            let (iterations_mean, iterations_std) = mean_std(&it);
            SummaryRow {
                runs: g.len(),
                error_median_m: median(&err),
                converged_share: g.iter().filter(|r| r.converged).count() as f64 / g.len() as f64,
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

/// The study's picture: box plots of error (top) and iterations (bottom), one group per
/// feature and one box per sensor.
pub fn study_plot(rows: &[RunRow]) -> RgbImage {
    let panel = |title: &str, metric: fn(&RunRow) -> f64| {
        let mut groups: Vec<BoxGroup> = Vec::new();
        for r in rows {
            let g = match groups.iter().position(|g| g.label == r.feature) {
                Some(g) => g,
                None => {
                    groups.push(BoxGroup {
                        label: r.feature.clone(),
                        boxes: Vec::new(),
                    });
                    groups.len() - 1
                }
            };
            let boxes = &mut groups[g].boxes;
            match boxes.iter_mut().find(|b| b.0 == r.sensor) {
                Some(b) => b.1.push(metric(r)),
                None => boxes.push((r.sensor.clone(), vec![metric(r)])),
            }
        }
        render_boxplots(title, &groups)
    };
    stack_vertical(&[
        panel("localisation error (m)", |r| r.error_m),
        panel("iterations", |r| r.iterations as f64),
    ])
}
