//! The paper's simulation study: every feature x every sensor x `R` runs with random sources
//! and robot starts, run in parallel, summarised per layout, plume model, feature and sensor.
//!
//! Run `r` of a study with seed `S` uses the run seed `derive_seed(S, r)` for every feature,
//! sensor, plume model and reality: the same source, start, plume and sensor noise, so the
//! comparison is paired. Runs either follow the planner ([`Paths::Planner`], the paper's study)
//! or fly one fixed survey path whose readings the STE takes in one update
//! ([`Paths::Survey`]); every row also carries the baselines' errors (highest reading, arena
//! centre) on the same readings. Sources are uniform over the prior's support (free space at least 0.25 m from walls
//! and obstacles), starts uniform over the positions the robot may occupy ([`StartRule`]), or
//! over those near the outlet.

use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::io;
use crate::layout::Layout;
use crate::report::boxplot::{BoxPanel, group_values};
use crate::report::{Panel, markdown_table, save_figure};
use crate::sim::episode::{
    EpisodeConfig, StartRule, World, random_source, random_start, run_episode,
};
use crate::sim::reality::Mismatch;
use crate::sim::seed::derive_seed;
use crate::sim::survey::{fly, lawnmower};
use crate::stats::{mean_std, median, quantile};
use crate::ste::banks::RoomBanks;
use crate::ste::baseline::Baselines;
use crate::ste::credible::Uncertainty;
use crate::ste::features::Feature;
use crate::ste::replay::replay;
use crate::ste::robot::RobotParams;
use crate::ste::robot::path_length;
use crate::ste::sensor::SensorPreset;

/// One run of a study, as a CSV row.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunRow {
    /// Layout name (its file stem).
    pub layout: String,
    /// Plume model of the bank (`plumenet` or `solver`).
    pub model: String,
    /// How reality departed from the model (`none`, or the knobs that were on).
    pub reality: String,
    /// Whose paths: `planner` or `survey`.
    pub paths: String,
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
    /// Position of the highest reading, x (m).
    pub highest_x: f64,
    /// Position of the highest reading, y (m).
    pub highest_y: f64,
    /// Error of the highest-reading baseline (m).
    pub highest_error_m: f64,
    /// Error of the arena-centre baseline (m).
    pub centre_error_m: f64,
    /// Iterations (0 for a survey, whose readings arrive in one update).
    pub iterations: usize,
    /// Whether the termination rule fired.
    pub converged: bool,
    /// Readings recorded.
    pub samples: usize,
    /// Distance driven (m).
    pub distance_m: f64,
    /// Wall-clock time (s).
    pub wall_time_s: f64,
    /// Goodness of fit at the end ([`crate::ste::posterior::Estimator::fit`]).
    pub fit: f64,
    /// Area of the final 50% credible region (m^2; NaN in a record without it).
    #[serde(default = "not_recorded")]
    pub area_50_m2: f64,
    /// Area of the final 90% credible region (m^2; NaN in a record without it).
    #[serde(default = "not_recorded")]
    pub area_90_m2: f64,
    /// Posterior mass of the final 50% credible region ([`crate::ste::CredibleRegion::mass`];
    /// NaN in a record without it).
    #[serde(default = "not_recorded")]
    pub mass_50: f64,
    /// Posterior mass of the final 90% credible region (NaN in a record without it).
    #[serde(default = "not_recorded")]
    pub mass_90: f64,
    /// Whether the final 50% credible region holds the source.
    #[serde(default)]
    pub covers_50: Option<bool>,
    /// Whether the final 90% credible region holds the source.
    #[serde(default)]
    pub covers_90: Option<bool>,
    /// The smallest credible level whose region holds the source
    /// ([`crate::ste::SourceScore::level`]).
    #[serde(default = "not_recorded")]
    pub source_level: f64,
    /// Log posterior of the source's cell ([`crate::ste::SourceScore::log_posterior`]).
    #[serde(default = "not_recorded")]
    pub log_p_source: f64,
    /// The posterior's expected distance from its estimate (m).
    #[serde(default = "not_recorded")]
    pub expected_distance_m: f64,
}

/// What a run record without an uncertainty column reads as.
fn not_recorded() -> f64 {
    f64::NAN
}

/// A run declared converged this far or farther from the source (m) is confidently wrong.
pub const WRONG_CONVERGENCE_M: f64 = 1.5;

impl RunRow {
    /// Whether the run declared convergence [`WRONG_CONVERGENCE_M`] or more from the source.
    pub fn wrongly_converged(&self) -> bool {
        self.converged && self.error_m >= WRONG_CONVERGENCE_M
    }
}

/// The share of `runs` whose credible region (`covers` picks which) holds the source, among
/// the runs that record it; NaN when none does.
pub fn coverage(runs: &[&RunRow], covers: fn(&RunRow) -> Option<bool>) -> f64 {
    let known: Vec<bool> = runs.iter().filter_map(|r| covers(r)).collect();
    let hits = known.iter().filter(|&&c| c).count();
    if known.is_empty() {
        f64::NAN
    } else {
        hits as f64 / known.len() as f64
    }
}

/// Mean and standard deviation of error and iterations of one layout, plume model, reality,
/// path kind, feature and sensor, with the baselines' mean errors on the same runs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SummaryRow {
    /// Layout name.
    pub layout: String,
    /// Plume model.
    pub model: String,
    /// How reality departed from the model.
    pub reality: String,
    /// Whose paths.
    pub paths: String,
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
    /// Mean error of the highest-reading baseline (m).
    pub highest_error_mean_m: f64,
    /// Mean error of the arena-centre baseline (m).
    pub centre_error_mean_m: f64,
    /// Mean iterations.
    pub iterations_mean: f64,
    /// Standard deviation of the iterations.
    pub iterations_std: f64,
    /// Share of runs that converged before the limit.
    pub converged_share: f64,
    /// 90th percentile of the error (m).
    #[serde(default = "not_recorded")]
    pub error_p90_m: f64,
    /// Largest error (m).
    #[serde(default = "not_recorded")]
    pub error_max_m: f64,
    /// Share of runs whose 50% credible region holds the source.
    #[serde(default = "not_recorded")]
    pub cover_50_share: f64,
    /// Share of runs whose 90% credible region holds the source.
    #[serde(default = "not_recorded")]
    pub cover_90_share: f64,
    /// Median area of the 90% credible region (m^2).
    #[serde(default = "not_recorded")]
    pub area_90_median_m2: f64,
    /// Runs declared converged [`WRONG_CONVERGENCE_M`] or more off.
    #[serde(default)]
    pub wrong_converged: usize,
    /// Median iterations.
    #[serde(default = "not_recorded")]
    pub iterations_median: f64,
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

/// Whose paths a study's runs follow.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Paths<'a> {
    /// The planner's, iteration by iteration, from a random start (the paper's study).
    Planner(StartRule),
    /// This fixed survey path (e.g. [`crate::sim::survey::lawnmower`]), flown at the robot's
    /// speed; the STE takes all its readings in one update.
    Survey(&'a [[f64; 2]]),
}

impl Paths<'_> {
    /// The name in the rows: `planner` or `survey`.
    pub fn name(&self) -> &'static str {
        match self {
            Paths::Planner(_) => "planner",
            Paths::Survey(_) => "survey",
        }
    }
}

/// Where a study runs: the world (layout, bank and reality), its names in the rows, and whose
/// paths the robots follow.
#[derive(Debug, Clone, Copy)]
pub struct StudySite<'a> {
    /// The layout, its bank and its reality.
    pub world: &'a World,
    /// Layout name for the rows.
    pub layout: &'a str,
    /// Plume model name for the rows.
    pub model: &'a str,
    /// Whose paths.
    pub paths: Paths<'a>,
}

/// What a study keeps of one run.
struct Outcome {
    start: [f64; 2],
    estimate: [f64; 2],
    error_m: f64,
    baselines: Baselines,
    iterations: usize,
    converged: bool,
    samples: usize,
    distance_m: f64,
    wall_time_s: f64,
    fit: f64,
    uncertainty: Uncertainty,
}

/// Runs one run of a study at `source` with the run seed `seed`.
fn run_one(
    site: StudySite<'_>,
    config: &EpisodeConfig,
    source: [f64; 2],
    seed: u64,
) -> Result<Outcome> {
    let world = site.world;
    match site.paths {
        Paths::Planner(rule) => {
            let start = random_start(
                &world.room.layout,
                &config.robot,
                rule,
                derive_seed(seed, 11),
            )?;
            let ep = run_episode(world, config, source, start, seed, false)?;
            let distance_m = ep
                .trajectory
                .windows(2)
                .map(|w| (w[1][1] - w[0][1]).hypot(w[1][2] - w[0][2]))
                .sum();
            Ok(Outcome {
                start,
                estimate: ep.estimate,
                error_m: ep.error_m,
                baselines: ep.baselines,
                iterations: ep.iterations,
                converged: ep.converged,
                samples: ep.samples.len(),
                distance_m,
                wall_time_s: ep.wall_time_s,
                fit: ep.history.last().and_then(|h| h.fit).unwrap_or(f64::NAN),
                uncertainty: ep.uncertainty.expect("a run's uncertainty"),
            })
        }
        Paths::Survey(path) => {
            let clock = std::time::Instant::now();
            let samples = fly(&world.reality, path, source, &config.flight(), seed)?;
            let est = replay(
                world.room.samplers(),
                config.ste,
                config.robot.radius_m,
                &samples,
            )?;
            let estimate = est.estimate();
            Ok(Outcome {
                start: path[0],
                estimate,
                error_m: (estimate[0] - source[0]).hypot(estimate[1] - source[1]),
                baselines: Baselines::new(&world.room.layout, &samples, Some(source))?,
                iterations: 0,
                converged: false,
                samples: samples.len(),
                distance_m: path_length(path),
                wall_time_s: clock.elapsed().as_secs_f64(),
                fit: est.fit().unwrap_or(f64::NAN),
                uncertainty: est.uncertainty(Some(source)),
            })
        }
    }
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
    let reality = world.reality.mismatch().to_string();
    plan.par_iter()
        .map(|&(feature, sensor, run)| {
            let config = configure(feature, sensor);
            let run_seed = derive_seed(seed, run as u64);
            let source = random_source(&world.room.layout, derive_seed(run_seed, 10))?;
            let out = run_one(site, &config, source, run_seed)?;
            done();
            let error = |g: crate::ste::baseline::Guess| g.error_m.unwrap_or(f64::NAN);
            let region = |level| out.uncertainty.region(level);
            let score = out.uncertainty.source;
            Ok(RunRow {
                layout: site.layout.into(),
                model: site.model.into(),
                reality: reality.clone(),
                paths: site.paths.name().into(),
                feature: feature.name().into(),
                sensor: sensor.name().into(),
                run,
                seed: run_seed,
                source_x: source[0],
                source_y: source[1],
                start_x: out.start[0],
                start_y: out.start[1],
                estimate_x: out.estimate[0],
                estimate_y: out.estimate[1],
                error_m: out.error_m,
                highest_x: out.baselines.highest_reading.x,
                highest_y: out.baselines.highest_reading.y,
                highest_error_m: error(out.baselines.highest_reading),
                centre_error_m: error(out.baselines.centre),
                iterations: out.iterations,
                converged: out.converged,
                samples: out.samples,
                distance_m: out.distance_m,
                wall_time_s: out.wall_time_s,
                fit: out.fit,
                area_50_m2: region(0.5).map_or(f64::NAN, |r| r.area_m2),
                area_90_m2: region(0.9).map_or(f64::NAN, |r| r.area_m2),
                mass_50: region(0.5).and_then(|r| r.mass).unwrap_or(f64::NAN),
                mass_90: region(0.9).and_then(|r| r.mass).unwrap_or(f64::NAN),
                covers_50: region(0.5).and_then(|r| r.covers_source),
                covers_90: region(0.9).and_then(|r| r.covers_source),
                source_level: score.map_or(f64::NAN, |s| s.level),
                log_p_source: score.map_or(f64::NAN, |s| s.log_posterior),
                expected_distance_m: out.uncertainty.expected_distance_m,
            })
        })
        .collect()
}

/// Summary per layout, plume model, reality, path kind, feature and sensor, in the order they
/// first appear in `rows`.
pub fn summarize(rows: &[RunRow]) -> Vec<SummaryRow> {
    let key = |r: &RunRow| {
        [
            r.layout.clone(),
            r.model.clone(),
            r.reality.clone(),
            r.paths.clone(),
            r.feature.clone(),
            r.sensor.clone(),
        ]
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
            let mean_of =
                |f: fn(&RunRow) -> f64| mean_std(&g.iter().map(|r| f(r)).collect::<Vec<_>>()).0;
            let [layout, model, reality, paths, feature, sensor] = k;
            let areas: Vec<f64> = g
                .iter()
                .map(|r| r.area_90_m2)
                .filter(|a| !a.is_nan())
                .collect();
            SummaryRow {
                error_p90_m: quantile(&err, 0.9),
                error_max_m: err.iter().copied().fold(f64::NAN, f64::max),
                cover_50_share: coverage(&g, |r| r.covers_50),
                cover_90_share: coverage(&g, |r| r.covers_90),
                area_90_median_m2: if areas.is_empty() {
                    f64::NAN
                } else {
                    median(&areas)
                },
                wrong_converged: g.iter().filter(|r| r.wrongly_converged()).count(),
                iterations_median: median(&it),
                runs: g.len(),
                error_median_m: median(&err),
                highest_error_mean_m: mean_of(|r| r.highest_error_m),
                centre_error_mean_m: mean_of(|r| r.centre_error_m),
                converged_share: g.iter().filter(|r| r.converged).count() as f64 / g.len() as f64,
                layout,
                model,
                reality,
                paths,
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

/// A text column of a row.
type Column = fn(&RunRow) -> &str;
/// A number of a row.
type Metric = fn(&RunRow) -> f64;

/// The values the study's box plots show, as `(group, series, value)`: one group per feature
/// (with the layout, plume model, reality and path kind when a study has several), one series
/// per sensor; `metric` picks the value. With `baselines`, the highest-reading and arena-centre
/// errors follow as groups of their own (over the runs of every feature).
pub fn plot_values(rows: &[RunRow], metric: Metric, baselines: bool) -> Vec<(String, String, f64)> {
    let several = |f: Column| rows.iter().any(|r| f(r) != f(&rows[0]));
    let parts: [(bool, Column); 4] = [
        (several(|r| &r.layout), |r| &r.layout),
        (several(|r| &r.model), |r| &r.model),
        (several(|r| &r.reality), |r| &r.reality),
        (several(|r| &r.paths), |r| &r.paths),
    ];
    let group = |name: &str, r: &RunRow| {
        let mut group = name.to_string();
        for (on, part) in parts {
            if on {
                group = format!("{group} {}", part(r));
            }
        }
        group
    };
    let mut values: Vec<(String, String, f64)> = rows
        .iter()
        .map(|r| (group(&r.feature, r), r.sensor.clone(), metric(r)))
        .collect();
    if baselines {
        let guesses: [(&str, Metric); 2] = [
            ("highest reading", |r| r.highest_error_m),
            ("centre", |r| r.centre_error_m),
        ];
        for (name, error) in guesses {
            values.extend(
                rows.iter()
                    .map(|r| (group(name, r), r.sensor.clone(), error(r))),
            );
        }
    }
    values
}

/// Whose paths the runs of every site follow ([`Paths`] before a site's survey is planned).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PathsRule {
    /// The planner's, from a start drawn by the rule.
    Planner(StartRule),
    /// One lawnmower survey per site with lanes this far apart (m).
    Lawnmower(f64),
}

/// A whole study: every site x plume model x reality x planned run.
#[derive(Debug, Clone, Copy)]
pub struct Study<'a> {
    /// The layouts and their names in the rows.
    pub sites: &'a [(String, Layout)],
    /// The plume models, by their names in the rows.
    pub models: &'a [&'a str],
    /// The realities each model's runs meet.
    pub realities: &'a [Mismatch],
    /// Whose paths.
    pub paths: PathsRule,
    /// The robot a survey is planned for.
    pub robot: RobotParams,
    /// The runs of each site, model and reality ([`plan_runs`]).
    pub plan: &'a [(Feature, SensorPreset, usize)],
    /// The study's seed.
    pub seed: u64,
}

impl Study<'_> {
    /// How many runs the study holds.
    pub fn total_runs(&self) -> usize {
        self.sites.len() * self.models.len() * self.realities.len() * self.plan.len()
    }

    /// Runs the study: `room` gives a site's banks for a plume model (its index in
    /// [`Study::models`]), `configure` a run's settings for a feature, sensor and plume model
    /// (that index), and `done` is called after each run. Rows come back site by site, model by model, reality by reality, in plan order.
    ///
    /// # Errors
    /// The banks' errors (of the caller's type `E`), the surveys' and the runs' errors.
    pub fn run<E: From<Error>>(
        &self,
        mut room: impl FnMut(&Layout, usize) -> std::result::Result<RoomBanks, E>,
        configure: impl Fn(Feature, SensorPreset, usize) -> EpisodeConfig + Sync,
        done: impl Fn() + Sync,
    ) -> std::result::Result<Vec<RunRow>, E> {
        let mut rows = Vec::with_capacity(self.total_runs());
        for (name, layout) in self.sites {
            let survey;
            let paths = match self.paths {
                PathsRule::Planner(rule) => Paths::Planner(rule),
                PathsRule::Lawnmower(spacing_m) => {
                    survey = lawnmower(layout, &self.robot, spacing_m)?;
                    Paths::Survey(&survey.path)
                }
            };
            for (k, &model) in self.models.iter().enumerate() {
                let model_world = World::new(room(layout, k)?)?;
                for &mismatch in self.realities {
                    let world = model_world.with_mismatch(mismatch)?;
                    let site = StudySite {
                        world: &world,
                        layout: name,
                        model,
                        paths,
                    };
                    rows.extend(run_study(
                        site,
                        self.plan,
                        self.seed,
                        |f, s| configure(f, s, k),
                        &done,
                    )?);
                }
            }
        }
        Ok(rows)
    }
}

/// The layouts of a study: each file of `files`, named by its stem, then the first `rooms`
/// layouts of the dataset `rooms_of`, named `DATASET-k`.
///
/// # Errors
/// The layouts' and the manifest's errors; [`Error::Parameter`] for a `rooms` that is not
/// between 1 and the dataset's layouts.
pub fn load_sites(
    files: &[&Path],
    rooms_of: Option<&Path>,
    rooms: usize,
) -> Result<Vec<(String, Layout)>> {
    let name = |path: &Path| {
        path.file_stem().map_or_else(
            || path.display().to_string(),
            |s| s.to_string_lossy().into(),
        )
    };
    let mut sites = Vec::new();
    for &path in files {
        sites.push((name(path), Layout::load(path)?));
    }
    if let Some(dir) = rooms_of {
        let manifest = crate::dataset::Manifest::load(dir)?;
        if rooms == 0 || rooms > manifest.layouts.len() {
            return Err(Error::Parameter(format!(
                "--rooms {rooms} is not between 1 and the {} layouts of {}",
                manifest.layouts.len(),
                dir.display()
            )));
        }
        for (k, spec) in manifest.layouts.into_iter().take(rooms).enumerate() {
            sites.push((format!("{}-{k}", name(dir)), spec.check()?));
        }
    }
    Ok(sites)
}

/// Writes a study's `runs.csv`, `summary.csv`, `summary.md` and `boxplots.png` into `dir`,
/// and returns the summary's Markdown table.
///
/// # Errors
/// [`Error::Io`] when a file cannot be written; the figure's errors.
pub fn write_study(dir: &Path, rows: &[RunRow]) -> Result<String> {
    let summary = summarize(rows);
    io::write_csv(&dir.join("runs.csv"), rows)?;
    io::write_csv(&dir.join("summary.csv"), &summary)?;
    let table = summary_table(&summary);
    io::write_atomic(&dir.join("summary.md"), |buf| {
        buf.extend_from_slice(table.as_bytes());
        Ok(())
    })?;
    let panel = |title: &str, y_desc: &str, metric: Metric, baselines: bool| {
        Panel::Boxes(BoxPanel {
            title: title.into(),
            y_desc: y_desc.into(),
            groups: group_values(&plot_values(rows, metric, baselines)),
        })
    };
    save_figure(
        &[
            panel(
                "localisation error, with the highest-reading and centre baselines",
                "error (m)",
                |r| r.error_m,
                true,
            ),
            panel("iterations", "iterations", |r| r.iterations as f64, false),
        ],
        &dir.join("boxplots.png"),
    )?;
    Ok(table)
}

/// A study's summary as a Markdown table.
pub fn summary_table(summary: &[SummaryRow]) -> String {
    let header = [
        "layout",
        "model",
        "reality",
        "paths",
        "feature",
        "sensor",
        "runs",
        "error mean ± std (m)",
        "median (m)",
        "highest reading (m)",
        "centre (m)",
        "iterations mean ± std",
        "converged",
        "wrongly converged",
        "50% region covers",
        "90% region covers",
        "90% region median (m²)",
    ];
    markdown_table(
        &header,
        summary.iter().map(|s| {
            vec![
                s.layout.clone(),
                s.model.clone(),
                s.reality.clone(),
                s.paths.clone(),
                s.feature.clone(),
                s.sensor.clone(),
                s.runs.to_string(),
                format!("{:.2} ± {:.2}", s.error_mean_m, s.error_std_m),
                format!("{:.2}", s.error_median_m),
                format!("{:.2}", s.highest_error_mean_m),
                format!("{:.2}", s.centre_error_mean_m),
                format!("{:.1} ± {:.1}", s.iterations_mean, s.iterations_std),
                format!("{:.0}%", 100.0 * s.converged_share),
                s.wrong_converged.to_string(),
                format!("{:.0}%", 100.0 * s.cover_50_share),
                format!("{:.0}%", 100.0 * s.cover_90_share),
                format!("{:.2}", s.area_90_median_m2),
            ]
        }),
    )
}
