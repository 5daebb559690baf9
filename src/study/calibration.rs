//! The calibration benchmark: whether the posterior means what it says, on the suites users
//! meet. Each suite is a [`Study`](crate::study::experiment::Study) (the paper arena, unseen
//! rooms of every size class with the wind from each wall, the mismatch suite, and lawnmower
//! surveys); each run records its credible regions and the smallest level whose region holds
//! the source ([`crate::ste::SourceScore::level`]). Per suite and plume model the benchmark reports the
//! coverage of the 50% and 90% regions beside what a calibrated posterior's would hold (their
//! mean mass) and their areas (sharpness: a flat posterior covers but says nothing), the
//! errors, runs declared converged far off, and a reliability diagram.

use std::path::Path;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::dataset::{RoomParams, random_room};
use crate::error::{Error, Result};
use crate::io;
use crate::layout::{Layout, WindFrom};
use crate::physics::wind::WindField;
use crate::report::curves::CurvePanel;
use crate::report::{Panel, markdown_table, save_figure};
use crate::sim::episode::StartRule;
use crate::sim::reality::Mismatch;
use crate::sim::seed::derive_seed;
use crate::stats::{mean_std, median, quantile};
use crate::ste::credible::pit;
use crate::study::experiment::{PathsRule, RunRow, coverage};
use crate::surrogate::data::{SIZE_CLASSES, size_class};

/// How many runs the benchmark makes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BenchmarkSize {
    /// A few minutes: a handful of runs per suite, to see that it works and roughly where it
    /// stands.
    Quick,
    /// About an hour on two cores: enough runs that each suite's coverage is known to a few
    /// per cent.
    Full,
}

/// One suite of the benchmark: a study's sites, realities, paths, runs and seed.
#[derive(Debug, Clone)]
pub struct Suite {
    /// The suite's name in the reports.
    pub name: String,
    /// The layouts and their names.
    pub sites: Vec<(String, Layout)>,
    /// The realities every run meets.
    pub realities: Vec<Mismatch>,
    /// Whose paths.
    pub paths: PathsRule,
    /// Runs per site and reality.
    pub runs: usize,
    /// The study's seed (no training or tuning used it).
    pub seed: u64,
}

/// The seed of the unseen rooms and the suites' own seeds: none of them drew a training map
/// or tuned a setting.
const ROOMS_SEED: u64 = 41;

/// Unseen rooms: `per_class` rooms of each size class in `classes` ([`SIZE_CLASSES`] indices)
/// for each wind direction, drawn from the default room distribution with the seed (rooms
/// whose wind does not settle are passed over, as the dataset generator does), named
/// `CLASS-DIRECTION-k`.
///
/// # Errors
/// [`Error::Parameter`] when no room of a class is drawn in many tries.
pub fn unseen_rooms(
    classes: &[usize],
    per_class: usize,
    seed: u64,
) -> Result<Vec<(String, Layout)>> {
    let names = ["small", "medium", "large"];
    let mut out = Vec::new();
    for &class in classes {
        for (d, from) in WindFrom::ALL.iter().enumerate() {
            let params = RoomParams {
                directions: vec![*from],
                ..RoomParams::default()
            };
            let stream = derive_seed(seed, (class * WindFrom::ALL.len() + d) as u64);
            let mut rng = ChaCha8Rng::seed_from_u64(stream);
            let mut found = 0;
            for _ in 0..10_000 {
                if found == per_class {
                    break;
                }
                let room = random_room(&params, &mut rng)?;
                // A room whose wind does not settle has no plume model to compare with.
                if size_class(&room) == class && WindField::solve(&room).is_ok() {
                    out.push((format!("{}-{}-{found}", names[class], from.name()), room));
                    found += 1;
                }
            }
            if found < per_class {
                return Err(Error::Parameter(format!(
                    "no {} room with the wind from the {} in 10000 draws",
                    SIZE_CLASSES[class].0,
                    from.name()
                )));
            }
        }
    }
    Ok(out)
}

/// The benchmark's suites in `arena` (the paper's layout): the paper arena (the 200 held-out
/// runs of seed 2000), unseen rooms (three size classes x four wind directions), the mismatch
/// suite in the arena (each strong knob alone and all together), and lawnmower surveys in the
/// arena and four unseen rooms, with reality as the model and under the mixed mismatch.
///
/// # Errors
/// As [`unseen_rooms`].
pub fn suites(arena: &Layout, size: BenchmarkSize) -> Result<Vec<Suite>> {
    let full = size == BenchmarkSize::Full;
    let pick = |quick: usize, whole: usize| if full { whole } else { quick };
    let arena_site = vec![("wind-tunnel".to_string(), arena.clone())];
    let planner = PathsRule::Planner(StartRule::Anywhere);
    let rooms = unseen_rooms(&[0, 1, 2], 1, ROOMS_SEED)?;
    let small_rooms: Vec<(String, Layout)> = rooms.iter().take(4).cloned().collect();
    let suite = Mismatch::suite();
    let mixed = *suite.last().expect("the mixed mismatch");
    let mut survey_sites = arena_site.clone();
    survey_sites.extend(small_rooms.iter().cloned());
    Ok(vec![
        Suite {
            name: "arena".into(),
            sites: arena_site.clone(),
            realities: vec![Mismatch::NONE],
            paths: planner,
            runs: pick(12, 200),
            seed: 2000,
        },
        Suite {
            name: "unseen rooms".into(),
            sites: if full { rooms } else { small_rooms.clone() },
            realities: vec![Mismatch::NONE],
            paths: planner,
            runs: pick(2, 9),
            seed: 4100,
        },
        Suite {
            name: "mismatch".into(),
            sites: arena_site,
            realities: suite[1..].to_vec(),
            paths: planner,
            runs: pick(2, 20),
            seed: 4200,
        },
        Suite {
            name: "surveys".into(),
            sites: survey_sites,
            realities: vec![Mismatch::NONE, mixed],
            paths: PathsRule::Lawnmower(0.5),
            runs: pick(1, 10),
            seed: 4300,
        },
    ])
}

/// One suite and plume model of the benchmark.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationRow {
    /// The suite.
    pub suite: String,
    /// The plume model.
    pub model: String,
    /// Runs.
    pub runs: usize,
    /// Share of runs whose 50% credible region holds the source.
    pub cover_50: f64,
    /// Share of runs whose 90% credible region holds the source.
    pub cover_90: f64,
    /// Mean posterior mass of the 50% regions ([`crate::ste::CredibleRegion::mass`]): the
    /// share of runs whose 50% region a calibrated posterior's would hold the source in, at
    /// least 50%, more where one cell holds much of the mass.
    pub mass_50_mean: f64,
    /// Mean posterior mass of the 90% regions: what [`CalibrationRow::cover_90`] is for a
    /// calibrated posterior.
    pub mass_90_mean: f64,
    /// Mean nonrandomised PIT of the source's cell at 0.5 ([`crate::ste::credible::pit`]):
    /// 0.5 for a calibrated posterior, however sharp, free of the regions' whole cells.
    pub pit_50_mean: f64,
    /// Mean nonrandomised PIT of the source's cell at 0.9: 0.9 for a calibrated posterior.
    pub pit_90_mean: f64,
    /// Median area of the 50% region (m^2).
    pub area_50_median_m2: f64,
    /// Median area of the 90% region (m^2).
    pub area_90_median_m2: f64,
    /// Median log posterior of the source's cell (sharpness: higher is sharper, at a given
    /// coverage).
    pub log_p_source_median: f64,
    /// Mean error (m).
    pub error_mean_m: f64,
    /// Median error (m).
    pub error_median_m: f64,
    /// 90th percentile of the error (m).
    pub error_p90_m: f64,
    /// Largest error (m).
    pub error_max_m: f64,
    /// Runs declared converged [`crate::study::experiment::WRONG_CONVERGENCE_M`] or more off.
    pub wrong_converged: usize,
    /// Planner runs that reached their iteration budget without converging.
    pub unresolved: usize,
    /// Median iterations (0 for surveys).
    pub iterations_median: f64,
    /// Median distance the robot drove (m): iterations count legs, and a robot pays for
    /// metres and time.
    pub distance_median_m: f64,
    /// Mean error of the highest-reading baseline (m).
    pub highest_error_mean_m: f64,
}

impl CalibrationRow {
    /// The row of one suite's runs of one plume model.
    pub fn of(suite: &str, model: &str, runs: &[&RunRow]) -> Self {
        let error: Vec<f64> = runs.iter().map(|r| r.error_m).collect();
        let column = |f: fn(&RunRow) -> f64| runs.iter().map(|r| f(r)).collect::<Vec<f64>>();
        Self {
            suite: suite.into(),
            model: model.into(),
            runs: runs.len(),
            cover_50: coverage(runs, |r| r.covers_50),
            cover_90: coverage(runs, |r| r.covers_90),
            mass_50_mean: mean_std(&column(|r| r.mass_50)).0,
            mass_90_mean: mean_std(&column(|r| r.mass_90)).0,
            pit_50_mean: mean_pit(runs.iter().copied(), 0.5),
            pit_90_mean: mean_pit(runs.iter().copied(), 0.9),
            area_50_median_m2: median(&column(|r| r.area_50_m2)),
            area_90_median_m2: median(&column(|r| r.area_90_m2)),
            log_p_source_median: median(&column(|r| r.log_p_source)),
            error_mean_m: mean_std(&error).0,
            error_median_m: median(&error),
            error_p90_m: quantile(&error, 0.9),
            error_max_m: error.iter().copied().fold(f64::NAN, f64::max),
            wrong_converged: runs.iter().filter(|r| r.wrongly_converged()).count(),
            unresolved: runs
                .iter()
                .filter(|r| r.paths == "planner" && !r.converged)
                .count(),
            iterations_median: median(&column(|r| r.iterations as f64)),
            distance_median_m: median(&column(|r| r.distance_m)),
            highest_error_mean_m: mean_std(&column(|r| r.highest_error_m)).0,
        }
    }
}

/// The rows of every suite's runs (`(suite, runs)`), one per suite and plume model, plume
/// models in the order they first appear.
pub fn calibration_rows(suites: &[(String, Vec<RunRow>)]) -> Vec<CalibrationRow> {
    let mut out = Vec::new();
    for (name, rows) in suites {
        for model in models_in_order(rows) {
            let runs: Vec<&RunRow> = rows.iter().filter(|r| r.model == model).collect();
            out.push(CalibrationRow::of(name, &model, &runs));
        }
    }
    out
}

/// The plume models of `rows`, in the order they first appear.
fn models_in_order<'a>(rows: impl IntoIterator<Item = &'a RunRow>) -> Vec<String> {
    let mut models: Vec<String> = Vec::new();
    for r in rows {
        if !models.contains(&r.model) {
            models.push(r.model.clone());
        }
    }
    models
}

/// The benchmark's table in Markdown.
pub fn calibration_table(rows: &[CalibrationRow]) -> String {
    let header = [
        "suite",
        "model",
        "runs",
        "50% covers (calibrated)",
        "90% covers (calibrated)",
        "PIT at 50% / 90%",
        "90% area median (m²)",
        "error mean / median / p90 / max (m)",
        "converged > 1.5 m off",
        "unresolved",
        "median iterations",
        "median distance (m)",
        "highest reading mean (m)",
    ];
    markdown_table(
        &header,
        rows.iter().map(|r| {
            vec![
                r.suite.clone(),
                r.model.clone(),
                r.runs.to_string(),
                format!(
                    "{:.0}% ({:.0}%)",
                    100.0 * r.cover_50,
                    100.0 * r.mass_50_mean
                ),
                format!(
                    "{:.0}% ({:.0}%)",
                    100.0 * r.cover_90,
                    100.0 * r.mass_90_mean
                ),
                format!("{:.2} / {:.2}", r.pit_50_mean, r.pit_90_mean),
                format!("{:.2}", r.area_90_median_m2),
                format!(
                    "{:.2} / {:.2} / {:.2} / {:.2}",
                    r.error_mean_m, r.error_median_m, r.error_p90_m, r.error_max_m
                ),
                r.wrong_converged.to_string(),
                r.unresolved.to_string(),
                format!("{:.0}", r.iterations_median),
                format!("{:.0}", r.distance_median_m),
                format!("{:.2}", r.highest_error_mean_m),
            ]
        }),
    )
}

/// Whether a run scored the source: a finite level and a log posterior (negative infinity
/// for a cell the prior excluded).
fn scored(r: &RunRow) -> bool {
    r.source_level.is_finite() && !r.log_p_source.is_nan()
}

/// The mean nonrandomised PIT at `u` ([`pit`]) of the runs that scored the source (NaN for
/// none).
fn mean_pit<'a>(runs: impl IntoIterator<Item = &'a RunRow>, u: f64) -> f64 {
    let values: Vec<f64> = runs
        .into_iter()
        .filter(|r| scored(r))
        .map(|r| pit(r.source_level, r.log_p_source, u))
        .collect();
    mean_std(&values).0
}

/// The nominal levels of the reliability diagram.
const NOMINAL: [f64; 10] = [0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];

/// Bins of the levels' histogram.
const BINS: usize = 10;

/// The reliability diagram of each plume model over every suite's runs, by the nonrandomised
/// probability integral transform of the source's cell ([`crate::ste::credible::pit`]): its
/// mean against the credible level (a calibrated posterior lies on the diagonal, however sharp
/// it is), and its histogram, where the source's cell lies among the posterior's levels (flat
/// at 1 when calibrated).
pub fn reliability_panels(suites: &[(String, Vec<RunRow>)]) -> [CurvePanel; 2] {
    let models = models_in_order(suites.iter().flat_map(|(_, rows)| rows));
    let mut coverage = Vec::new();
    let mut histogram: Vec<(String, Vec<(f64, f64)>)> = Vec::new();
    for m in &models {
        let rows = suites.iter().flat_map(|(_, rows)| rows);
        let runs: Vec<&RunRow> = rows.filter(|r| &r.model == m && scored(r)).collect();
        let points = NOMINAL
            .iter()
            .map(|&u| (u, mean_pit(runs.iter().copied(), u)))
            .collect();
        coverage.push((format!("{m} ({} runs)", runs.len()), points));
        // The mean PIT at the bins' edges, once each: a bin's density is its rise.
        let edges: Vec<f64> = (0..=BINS)
            .map(|e| mean_pit(runs.iter().copied(), e as f64 / BINS as f64))
            .collect();
        let points = edges
            .windows(2)
            .enumerate()
            .map(|(k, w)| ((k as f64 + 0.5) / BINS as f64, (w[1] - w[0]) * BINS as f64))
            .collect();
        histogram.push((m.clone(), points));
    }
    let top = histogram
        .iter()
        .flat_map(|(_, p)| p.iter().map(|q| q.1))
        .fold(2.0, f64::max);
    [
        CurvePanel {
            title: "the source within the credible level (PIT)".into(),
            x_desc: "credible level".into(),
            y_desc: "mean share of the source's cell within it".into(),
            y_max: 1.0,
            ideal: ("calibrated".into(), vec![(0.0, 0.0), (1.0, 1.0)]),
            series: coverage,
        },
        CurvePanel {
            title: "where the source's cell lies among the levels (PIT histogram)".into(),
            x_desc: "level".into(),
            y_desc: "density of runs".into(),
            y_max: top * 1.1,
            ideal: ("calibrated".into(), vec![(0.0, 1.0), (1.0, 1.0)]),
            series: histogram,
        },
    ]
}

/// Writes the benchmark's reports into `dir`: `calibration.md`, `.csv` and `.json` (one row
/// per suite and plume model) and `reliability.png`; returns the Markdown table.
///
/// # Errors
/// [`Error::Io`] when a file cannot be written, [`Error::Figure`] when the picture cannot be
/// drawn.
pub fn write_calibration(dir: &Path, suites: &[(String, Vec<RunRow>)]) -> Result<String> {
    let rows = calibration_rows(suites);
    let table = calibration_table(&rows);
    io::write_csv(&dir.join("calibration.csv"), &rows)?;
    io::write_json(&dir.join("calibration.json"), &rows)?;
    io::write_atomic(&dir.join("calibration.md"), |buf| {
        buf.extend_from_slice(table.as_bytes());
        Ok(())
    })?;
    let panels = reliability_panels(suites).map(Panel::Curves);
    save_figure(&panels, &dir.join("reliability.png"))?;
    Ok(table)
}
