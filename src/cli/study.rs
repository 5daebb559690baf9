//! Studies: `survey`, `experiment` and `compare`.

use std::path::{Path, PathBuf};

use anyhow::Result;
use clap::Args;

use plumenet::io;
use plumenet::layout::Layout;
use plumenet::physics::wind::WindField;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::sim::episode::StartRule;
use plumenet::sim::survey::{fly, lawnmower};
use plumenet::sim::{EpisodeConfig, Mismatch, Reality};
use plumenet::ste::{Baselines, Feature, SensorPreset, SteParams, ValidSteParams};
use plumenet::study::calibration::{self, BenchmarkSize, write_calibration};
use plumenet::study::compare;
use plumenet::study::experiment::{PathsRule, RunRow, Study, load_sites, plan_runs, write_study};

use super::args::*;
use super::parse_point;

/// The survey pattern on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PatternArg {
    /// Crosswind lanes, swept back and forth from the outlet upwind.
    Lawnmower,
}

#[derive(Debug, Args)]
pub struct SurveyArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// True source position "X,Y" (m).
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: (f64, f64),
    /// Survey pattern.
    #[arg(long, value_enum, default_value_t = PatternArg::Lawnmower)]
    pattern: PatternArg,
    /// Lane spacing (m).
    #[arg(long, default_value_t = 0.5)]
    spacing: f64,
    /// Sensor.
    #[arg(long, value_enum, default_value_t = SensorArg::SensorII)]
    sensor: SensorArg,
    /// A noise-free sensor.
    #[arg(long)]
    noise_free: bool,
    #[command(flatten)]
    reality: RealityArgs,
    /// Seed of the plume and the sensor noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The readings log to write (CSV t,x,y,value, as `replay` reads it).
    #[arg(long)]
    out: PathBuf,
}

pub fn survey(a: SurveyArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let source = [a.source.0, a.source.1];
    layout.check_source(source[0], source[1])?;
    let mismatch = a.reality.mismatch()?;
    let mut config = EpisodeConfig::new(Feature::Rank, a.sensor.into());
    config.sensor_noise = !a.noise_free;
    let plan = match a.pattern {
        PatternArg::Lawnmower => lawnmower(&layout, &config.robot, a.spacing)?,
    };
    let wind = WindField::solve(&layout)?;
    let reality = Reality::new(&layout, &wind, mismatch)?;
    let samples = fly(&reality, &plan.path, source, &config.flight(), a.seed)?;
    io::write_csv(&a.out, &samples)?;
    let last = samples.last().map_or(0.0, |s| s.t);
    println!(
        "{} lanes{}, {:.1} m in {last:.0} s, {} readings; reality: {mismatch}",
        plan.lanes,
        if plan.skipped > 0 {
            format!(" ({} unreachable stretches skipped)", plan.skipped)
        } else {
            String::new()
        },
        plumenet::ste::robot::path_length(&plan.path),
        samples.len()
    );
    print_guesses(None, &Baselines::new(&layout, &samples, Some(source))?);
    println!("wrote {}", a.out.display());
    Ok(())
}

#[derive(Debug, Args)]
pub struct CompareArgs {
    /// The base study's runs.csv.
    base: PathBuf,
    /// The other study's runs.csv (the same --seed, other settings).
    other: PathBuf,
    /// Only the base study's runs with this plume model (`solver` or `plumenet`, for a study
    /// run with --with-solver).
    #[arg(long)]
    base_model: Option<String>,
    /// Only the other study's runs with this plume model.
    #[arg(long)]
    other_model: Option<String>,
    /// Also write the comparison as CSV.
    #[arg(long)]
    csv: Option<PathBuf>,
}

/// `plumenet compare`: two studies run by run.
pub fn compare(a: CompareArgs) -> Result<()> {
    let load = |path: &PathBuf, model: &Option<String>| -> Result<Vec<RunRow>> {
        let mut rows = compare::load_runs(path)?;
        if let Some(m) = model {
            rows.retain(|r| &r.model == m);
            anyhow::ensure!(
                !rows.is_empty(),
                "{} holds no run of plume model {m}",
                path.display()
            );
        }
        Ok(rows)
    };
    let base = load(&a.base, &a.base_model)?;
    let other = load(&a.other, &a.other_model)?;
    let (rows, [base_alone, other_alone]) = compare::compare(&base, &other)?;
    if base_alone + other_alone > 0 {
        eprintln!("left out: {base_alone} base and {other_alone} other runs without a twin");
    }
    if let Some(path) = &a.csv {
        io::write_csv(path, &rows)?;
    }
    print!("{}", compare::compare_table(&rows));
    Ok(())
}

#[derive(Debug, Args)]
pub struct ExperimentArgs {
    /// Layout JSON files, comma-separated: the study runs in each [default:
    /// data/layouts/wind-tunnel.json, unless --rooms-of is given].
    #[arg(long, value_delimiter = ',')]
    layout: Option<Vec<PathBuf>>,
    /// Also run in the first --rooms layouts of this generated dataset (for example unseen
    /// rooms: `generate --seed 2`), named DATASET-k.
    #[arg(long)]
    rooms_of: Option<PathBuf>,
    /// How many of --rooms-of's layouts.
    #[arg(long, default_value_t = 5, requires = "rooms_of")]
    rooms: usize,
    /// Where robots start: anywhere free, or within 1.5 m of the outlet (the far downwind end).
    #[arg(long, value_enum, default_value_t = StartArg::Anywhere)]
    start: StartArg,
    /// Whose paths: the planner's (the paper's study), or one lawnmower survey per layout whose
    /// readings the STE takes at once (as `survey` then `replay`).
    #[arg(long, value_enum, default_value_t = PathsArg::Planner)]
    paths: PathsArg,
    /// Lane spacing of the lawnmower survey (m).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Robot and stopping rule",
        default_value_t = 0.5
    )]
    survey_spacing: f64,
    /// Run the mismatch suite: reality as the model, each knob alone at a strong setting (wind
    /// x0.5, diffusivity x3, 30° meander, background 1), and all together
    /// (`--reality-meander-walled` makes its wander the walled one).
    #[arg(long, conflicts_with_all = ["reality_wind_scale", "reality_diffusivity_scale", "reality_meander_deg", "reality_background"])]
    mismatch: bool,
    #[command(flatten)]
    reality: RealityArgs,
    /// Also run every run with the physics solver's bank (paired: the same sources, starts and
    /// noise), beside PlumeNet's.
    #[arg(long, conflicts_with = "solver")]
    with_solver: bool,
    /// Runs per feature and sensor (random source and start each).
    #[arg(long, default_value_t = 10)]
    runs: usize,
    /// Study seed: run r uses the same source, start and noise for every feature and sensor.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output directory (runs.csv, summary.csv, summary.md, boxplots.png).
    #[arg(long, default_value = "out/experiment")]
    out: PathBuf,
    /// Features to compare.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [FeatureArg::Value, FeatureArg::FixedHit, FeatureArg::AdaptiveHit, FeatureArg::Rank])]
    features: Vec<FeatureArg>,
    /// Sensors to compare.
    #[arg(long, value_enum, value_delimiter = ',', default_values_t = [SensorArg::Calibrated, SensorArg::SensorI, SensorArg::SensorII])]
    sensors: Vec<SensorArg>,
    #[command(flatten)]
    estimator: StudySettings,
}

/// Whose paths a study's runs follow.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PathsArg {
    /// The planner's, from a random start.
    Planner,
    /// A lawnmower survey.
    Lawnmower,
}

/// Where robots start in a study.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum StartArg {
    /// Anywhere the robot may be.
    Anywhere,
    /// Within 1.5 m of the outlet.
    Downwind,
}

pub fn experiment(a: ExperimentArgs) -> Result<()> {
    let features: Vec<Feature> = a.features.iter().map(|&f| f.into()).collect();
    let sensors: Vec<SensorPreset> = a.sensors.iter().map(|&s| s.into()).collect();
    let plan = plan_runs(&features, &sensors, a.runs);
    let paths = match (a.paths, a.start) {
        (PathsArg::Lawnmower, _) => PathsRule::Lawnmower(a.survey_spacing),
        (PathsArg::Planner, StartArg::Anywhere) => PathsRule::Planner(StartRule::Anywhere),
        (PathsArg::Planner, StartArg::Downwind) => PathsRule::Planner(StartRule::Downwind),
    };
    let mut models = vec![if a.estimator.plume.solver {
        "solver"
    } else {
        "plumenet"
    }];
    if a.with_solver {
        models.push("solver");
    }
    let realities = if a.mismatch {
        // `--reality-meander-walled` turns the suite's wander into the walled one.
        let walled = a.reality.reality_meander_walled;
        Mismatch::suite()
            .into_iter()
            .map(|m| Mismatch {
                meander_walled: walled && m.meander_deg > 0.0,
                ..m
            })
            .collect()
    } else {
        vec![a.reality.mismatch()?]
    };
    let robot = a
        .estimator
        .run
        .config(
            SteParams::for_feature(Feature::Rank).validate()?,
            SensorPreset::SensorII,
            PhysicsSolver.rank_factor(),
        )
        .robot;
    let default_layout = [PathBuf::from("data/layouts/wind-tunnel.json")];
    let files: Vec<&Path> = match (&a.layout, &a.rooms_of) {
        (Some(files), _) => files.iter().map(PathBuf::as_path).collect(),
        (None, Some(_)) => Vec::new(),
        (None, None) => default_layout.iter().map(PathBuf::as_path).collect(),
    };
    let sites = load_sites(&files, a.rooms_of.as_deref(), a.rooms)?;
    for (_, layout) in &sites {
        a.estimator.run.check(layout)?;
    }
    let runner = Runner::new(&models, &features, &a.estimator)?;
    let study = Study {
        sites: &sites,
        models: &models,
        realities: &realities,
        paths,
        robot,
        plan: &plan,
        seed: a.seed,
    };
    let bar = super::progress_bar(study.total_runs(), "runs");
    let rows = runner.run(&study, &bar)?;
    bar.finish_and_clear();
    let table = write_study(&a.out, &rows)?;
    print!("{table}");
    println!("wrote {}", a.out.display());
    Ok(())
}

/// What runs a study's runs: the plume models, loaded, and every feature's settings checked
/// with each of them, before any bank.
struct Runner<'a> {
    loaded: Vec<Box<dyn PlumeModel>>,
    settings: Vec<Vec<ValidSteParams>>,
    features: &'a [Feature],
    plume: &'a PlumeArgs,
    run: &'a RunArgs,
}

/// The plume model, likelihood and run flags a study shares with the single-run commands.
#[derive(Debug, Args)]
pub struct StudySettings {
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    overrides: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
}

impl<'a> Runner<'a> {
    fn new(models: &[&str], features: &'a [Feature], settings: &'a StudySettings) -> Result<Self> {
        let (plume, overrides, run) = (&settings.plume, &settings.overrides, &settings.run);
        let loaded = models
            .iter()
            .map(|&name| plume.model_of(name == "solver"))
            .collect::<Result<Vec<_>>>()?;
        let settings = loaded
            .iter()
            .map(|model| {
                let of = |&f| overrides.params(f, model.rank_factor());
                features.iter().map(of).collect::<Result<Vec<_>>>()
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            loaded,
            settings,
            features,
            plume,
            run,
        })
    }

    /// Runs a study with the bar counting its runs.
    fn run(&self, study: &Study<'_>, bar: &indicatif::ProgressBar) -> Result<Vec<RunRow>> {
        let (features, settings, run) = (self.features, &self.settings, self.run);
        let factors: Vec<f64> = self.loaded.iter().map(|m| m.rank_factor()).collect();
        let rows = study.run(
            |layout, k| {
                let (room, note) = self
                    .plume
                    .room_of(layout.clone(), self.loaded[k].as_ref())?;
                super::say(bar, note);
                Ok::<_, anyhow::Error>(room)
            },
            |f, s, k| {
                let at = features.iter().position(|&g| g == f);
                let params = at.map(|i| settings[k][i]).expect("a planned feature");
                run.config(params, s, factors[k])
            },
            || bar.inc(1),
        )?;
        Ok(rows)
    }
}

#[derive(Debug, Args)]
pub struct CalibrationArgs {
    /// A few runs per suite (minutes) instead of the full benchmark (about an hour).
    #[arg(long)]
    quick: bool,
    /// The paper's arena, whose layout the arena, mismatch and survey suites use.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Output directory (calibration.md, .csv, .json, reliability.png, and each suite's study).
    #[arg(long, default_value = "out/calibration")]
    out: PathBuf,
    #[command(flatten)]
    estimator: StudySettings,
}

pub fn calibration(a: CalibrationArgs) -> Result<()> {
    let size = if a.quick {
        BenchmarkSize::Quick
    } else {
        BenchmarkSize::Full
    };
    let arena = Layout::load(&a.layout)?;
    let suites = calibration::suites(&arena, size)?;
    for (_, layout) in suites.iter().flat_map(|s| &s.sites) {
        a.estimator.run.check(layout)?;
    }
    let models = ["plumenet", "solver"];
    let features = [Feature::Rank];
    let runner = Runner::new(&models, &features, &a.estimator)?;
    let robot = a
        .estimator
        .run
        .config(
            runner.settings[0][0],
            SensorPreset::SensorII,
            runner.loaded[0].rank_factor(),
        )
        .robot;
    let plans: Vec<_> = suites
        .iter()
        .map(|s| plan_runs(&features, &[SensorPreset::SensorII], s.runs))
        .collect();
    let studies: Vec<Study> = suites
        .iter()
        .zip(&plans)
        .map(|(s, plan)| Study {
            sites: &s.sites,
            models: &models,
            realities: &s.realities,
            paths: s.paths,
            robot,
            plan,
            seed: s.seed,
        })
        .collect();
    let total = studies.iter().map(Study::total_runs).sum();
    let bar = super::progress_bar(total, "runs");
    let mut results = Vec::new();
    for (suite, study) in suites.iter().zip(&studies) {
        let rows = runner.run(study, &bar)?;
        write_study(&a.out.join(suite.name.replace(' ', "-")), &rows)?;
        results.push((suite.name.clone(), rows));
    }
    bar.finish_and_clear();
    let table = write_calibration(&a.out, &results)?;
    print!("{table}");
    println!("wrote {}", a.out.display());
    Ok(())
}
