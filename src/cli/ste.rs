//! The STE commands: `localize` (one simulated run) and `replay` (a logged run).

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::json;

use plumenet::io;
use plumenet::layout::Layout;
use plumenet::physics::wind::WindField;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::report::belief::{BeliefPlot, belief_panel, write_episode_pictures};
use plumenet::report::boxplot::{BoxPanel, group_values};

use plumenet::report::{Panel, markdown_table, save_figure};
use plumenet::sim::episode::StartRule;
use plumenet::sim::survey::{fly, lawnmower};
use plumenet::sim::{EpisodeConfig, Mismatch, Reality, World, derive_seed, run_episode};
use plumenet::ste::baseline::Guess;
use plumenet::ste::replay::{read_log, replay_in_steps, thin};
use plumenet::ste::{
    Baselines, Estimator, Feature, PlannerKind, RobotParams, RoomBanks, Sampling, SensorPreset,
    Sigmas, SteParams, Termination,
};
use plumenet::study::compare;
use plumenet::study::experiment::{
    Paths, RunRow, StudySite, SummaryRow, plan_runs, plot_values, run_study, summarize,
};
use plumenet::surrogate::Surrogate;
use plumenet::viewer::RunView;

use super::parse_point;

/// Which plume model feeds the estimator, and where its banks are cached.
#[derive(Debug, Args)]
pub struct PlumeArgs {
    /// Use the physics solver as plume model instead of PlumeNet.
    #[arg(long, conflicts_with = "model")]
    solver: bool,
    /// Trained PlumeNet model directory.
    #[arg(long, default_value = "models/default")]
    model: PathBuf,
    /// Candidate grid spacing (m).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Plume model and bank",
        default_value_t = 0.25
    )]
    spacing: f64,
    /// Bank cache directory (banks are keyed by layout and model digest).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Plume model and bank",
        default_value = "data/cache"
    )]
    cache_dir: PathBuf,
    /// Do not read or write the bank cache.
    #[arg(long, hide_short_help = true, help_heading = "Plume model and bank")]
    no_cache: bool,
    /// Model wind speeds to marginalise over, as factors of the layout's (one bank each, equally
    /// likely a priori), e.g. 0.5,1,2; the default 1 trusts the layout's speed.
    #[arg(long, hide_short_help = true, help_heading = "Plume model and bank", value_delimiter = ',', default_values_t = [1.0])]
    wind_scales: Vec<f64>,
    /// Spreads of the wind's direction to marginalise over (degrees; each bank's plumes averaged
    /// over winds turned about the source, Gaussian with this standard deviation), e.g. 0,30;
    /// the default 0 trusts the layout's direction.
    #[arg(long, hide_short_help = true, help_heading = "Plume model and bank", value_delimiter = ',', default_values_t = [0.0])]
    wind_spreads: Vec<f64>,
}

impl PlumeArgs {
    /// The layout's banks for the chosen model; also returns the model's name for reports.
    pub fn room(&self, layout: Layout) -> Result<(RoomBanks, String)> {
        let (room, name, note) = self.room_of(layout, self.solver)?;
        println!("{note}");
        Ok((room, name))
    }

    /// [`PlumeArgs::room`] with its note on standard error (standard output being a
    /// protocol's).
    pub fn room_quietly(&self, layout: Layout) -> Result<(RoomBanks, String)> {
        let (room, name, note) = self.room_of(layout, self.solver)?;
        eprintln!("{note}");
        Ok((room, name))
    }

    /// The banks of the physics solver (`solver`) or the chosen PlumeNet model, its name, and
    /// a note on the bank for the user.
    fn room_of(&self, layout: Layout, solver: bool) -> Result<(RoomBanks, String, String)> {
        let model: Box<dyn PlumeModel> = if solver {
            Box::new(PhysicsSolver)
        } else {
            Box::new(Surrogate::load(&self.model).with_context(|| {
                format!(
                    "cannot load the plume model {} (or pass --solver)",
                    self.model.display()
                )
            })?)
        };
        let cache = (!self.no_cache).then_some(self.cache_dir.as_path());
        let (room, hit) = RoomBanks::build(layout, model.as_ref(), self.spacing, cache)?;
        // The defaults (scale 1, spread 0) keep the layout's own bank.
        let room = room
            .with_wind_scales(model.as_ref(), &self.wind_scales, cache)?
            .with_wind_spreads(&self.wind_spreads)?;
        let note = format!(
            "plume model {}: {} candidates{}",
            model.name(),
            room.sampler.len(),
            if hit { " (bank from cache)" } else { "" }
        );
        Ok((room, model.name(), note))
    }

    /// The candidate spacing (m).
    pub fn spacing(&self) -> f64 {
        self.spacing
    }
}

/// Feature and likelihood settings shared by `localize`, `replay` and `experiment`.
#[derive(Debug, Args)]
pub struct FeatureArgs {
    /// Model-error standard deviation sigma_E (default: the feature's tuned value).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    sigma_model: Option<f64>,
    /// Measurement-error standard deviation sigma_M (default: the feature's tuned value).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    sigma_measurement: Option<f64>,
    /// Threshold of the fixed-hit feature (reading units).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    fixed_threshold: Option<f64>,
    /// Smoothing factor of the adaptive-hit feature.
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    lambda: Option<f64>,
    /// Compare the plume model's values directly, without passing them through the sensor's
    /// response and recovery dynamics first (the paper's form).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    no_lag_model: bool,
    /// The exponent of the sensor's response in which its lag acts: the estimated
    /// concentrations are raised to it, lagged and taken back (default: for rank 1/|k| of the
    /// MiCS-5521's datasheet slope k = -1.58, about 0.633; for the other features 1, which
    /// lags the concentration itself).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    lag_exponent: Option<f64>,
    /// Estimated concentrations below this many ppm are set to zero, as the sensor cannot
    /// tell them from clean air (default: 0.2 for rank, 1 for the other features).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    detection_floor: Option<f64>,
    /// Rank only: the factor within which the plume model's concentrations are trusted; the
    /// share of estimates within it adds to each rank's model error (1 turns it off).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning", default_value_t = SteParams::for_feature(Feature::Rank).rank_tolerance)]
    rank_tolerance: f64,
    /// Rank only: the factor within which the plume model's concentrations are known when
    /// ranked; each candidate's expected ranks under that uncertainty are compared (default:
    /// the model's own, 3 for PlumeNet and 1 for the solver; 1 compares exact ranks).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    model_rank_factor: Option<f64>,
    /// Rank only, with the background nuisance: the nuisance's estimates of the background
    /// alone that rank within the readings' clean-air tie group join that group, instead of
    /// being compared by their order in time (helps a rising background on surveys).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    clean_air_model_ties: bool,
    /// Rank only, with the background nuisance: in its slots every estimate that ranks within
    /// the readings' clean-air tie group joins that group, so the order of a candidate's
    /// faintest values, which the sensor cannot see, is not compared (helps surveys in unseen
    /// rooms, costs on the planner's paths).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    clean_air_rank_floor: bool,
    /// Rank only: follow a drifting clean-air baseline, taken in a centred window of this many
    /// seconds (default: one baseline for the whole run).
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    clean_air_window: Option<f64>,
    /// Marginalise a background of recirculated gas rising during the run by 0, half or the
    /// whole of this many fully mixed concentrations q / (U H) (default: 0.5 for rank, 0 for
    /// the other features; 0 turns it off).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    background_rise: Option<f64>,
    /// The time constant (s) of that background's rise, the room's air-exchange time.
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning", allow_negative_numbers = true, default_value_t = SteParams::for_feature(Feature::Rank).background_time_s)]
    background_time: f64,
    /// Weigh a wind whose direction wanders during the run against a steady one: the prior
    /// standard deviation (degrees, at most 60) of its turn, fixed within each 20 s of
    /// readings (seven turned banks per bank; 0, the default, takes the wind as steady).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true,
        default_value_t = 0.0
    )]
    wind_wander: f64,
    /// Rank only: the paper's rank likelihood, without our clean-air ties (of the readings and
    /// the model), rank tolerance, expected model ranks, background nuisance, and lag in the
    /// sensor's response with its lower floor (the other features' lag and floor instead);
    /// exactly invariant under every increasing transform of the readings.
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning", conflicts_with_all = ["rank_tolerance", "model_rank_factor", "background_rise", "clean_air_model_ties", "clean_air_rank_floor", "wind_wander"])]
    paper_rank: bool,
}

impl FeatureArgs {
    /// The estimator settings for a feature over a room's banks (whose plume model gives the
    /// default model rank factor) with these overrides.
    pub fn params(&self, feature: Feature, room: &RoomBanks) -> SteParams {
        let mut p = room.ste_params(feature);
        let d = Sigmas::default_for(feature);
        p.sigmas = Sigmas {
            model: self.sigma_model.unwrap_or(d.model),
            measurement: self.sigma_measurement.unwrap_or(d.measurement),
        };
        if let Some(t) = self.fixed_threshold {
            p.features.fixed_threshold = t;
        }
        if let Some(l) = self.lambda {
            p.features.lambda = l;
        }
        if self.no_lag_model {
            p.sensor_lag_s = None;
        }
        p.rank_tolerance = self.rank_tolerance;
        if let Some(factor) = self.model_rank_factor {
            p.model_rank_factor = factor;
        }
        p.clean_air_window_s = self.clean_air_window;
        p.clean_air_model_ties = self.clean_air_model_ties;
        p.clean_air_rank_floor = self.clean_air_rank_floor;
        if let Some(a) = self.background_rise {
            p.background_rise = a;
        }
        p.background_time_s = self.background_time;
        p.wander_deg = self.wind_wander;
        if self.paper_rank {
            p = p.papers_rank();
        }
        if let Some(a) = self.lag_exponent {
            p.sensor_lag_exponent = a;
        }
        if let Some(f) = self.detection_floor {
            p.detection_floor_ppm = f;
        }
        p
    }
}

/// The gas feature on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum FeatureArg {
    Value,
    FixedHit,
    AdaptiveHit,
    Rank,
}

impl From<FeatureArg> for Feature {
    fn from(f: FeatureArg) -> Self {
        match f {
            FeatureArg::Value => Feature::Value,
            FeatureArg::FixedHit => Feature::FixedHit,
            FeatureArg::AdaptiveHit => Feature::AdaptiveHit,
            FeatureArg::Rank => Feature::Rank,
        }
    }
}

/// The sensor preset on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum SensorArg {
    Calibrated,
    SensorI,
    SensorII,
}

impl From<SensorArg> for SensorPreset {
    fn from(s: SensorArg) -> Self {
        match s {
            SensorArg::Calibrated => SensorPreset::Calibrated,
            SensorArg::SensorI => SensorPreset::SensorI,
            SensorArg::SensorII => SensorPreset::SensorII,
        }
    }
}

/// The planner on the command line.
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PlannerArg {
    BeliefClustering,
    Baseline,
}

impl From<PlannerArg> for PlannerKind {
    fn from(p: PlannerArg) -> Self {
        match p {
            PlannerArg::BeliefClustering => PlannerKind::BeliefClustering,
            PlannerArg::Baseline => PlannerKind::Baseline,
        }
    }
}

/// Robot and run settings shared by `localize` and `experiment`.
#[derive(Debug, Args)]
pub struct RunArgs {
    /// Planner.
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule", value_enum, default_value_t = PlannerArg::BeliefClustering)]
    planner: PlannerArg,
    /// Stop-sense-go sampling (a stop every metre, 10 s settle, 10 s average) instead of
    /// sense-in-motion.
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule")]
    stop_sense_go: bool,
    /// A noise-free sensor.
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule")]
    noise_free: bool,
    /// Iteration limit.
    #[arg(long, default_value_t = Termination::default().max_iterations)]
    max_iterations: usize,
    /// Entropy (nats) below which the run may stop (default: the tuned value).
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule")]
    entropy_threshold: Option<f64>,
    /// Consecutive concentrated iterations, around the same estimate, needed to stop
    /// (1 = the paper's rule alone).
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule", default_value_t = Termination::default().stable_iterations)]
    stable_iterations: usize,
}

impl RunArgs {
    /// The run settings for a feature and sensor.
    pub fn config(&self, ste: SteParams, sensor: SensorPreset) -> EpisodeConfig {
        let mut c = EpisodeConfig::new(ste.feature, sensor);
        c.ste = ste;
        c.planner = self.planner.into();
        c.sensor_noise = !self.noise_free;
        c.termination.max_iterations = self.max_iterations;
        c.termination.stable_iterations = self.stable_iterations;
        if let Some(h) = self.entropy_threshold {
            c.termination.entropy_nats = h;
        }
        if self.stop_sense_go {
            c.robot = RobotParams {
                sampling: Sampling::stop_sense_go(),
                ..c.robot
            };
        }
        c
    }
}

/// How the simulated reality departs from the plume model (all off by default).
#[derive(Debug, Args)]
pub struct RealityArgs {
    /// Reality's wind speed as a multiple of the layout's (the model keeps the layout's).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Simulated reality (mismatch with the plume model)",
        allow_negative_numbers = true,
        default_value_t = 1.0
    )]
    reality_wind_scale: f64,
    /// Reality's diffusivity as a multiple of the layout's.
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Simulated reality (mismatch with the plume model)",
        allow_negative_numbers = true,
        default_value_t = 1.0
    )]
    reality_diffusivity_scale: f64,
    /// Wander of reality's wind direction: an Ornstein-Uhlenbeck angle with this standard
    /// deviation (degrees, at most 90) and a 20 s correlation time.
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Simulated reality (mismatch with the plume model)",
        allow_negative_numbers = true,
        default_value_t = 0.0
    )]
    reality_meander_deg: f64,
    /// The wander turns only the flow the room's walls let through (the turned wind projected
    /// onto flows that pass no wall or obstacle), not the whole field, walls included.
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Simulated reality (mismatch with the plume model)"
    )]
    reality_meander_walled: bool,
    /// Recirculated gas: a uniform background in free space of this many times the fully mixed
    /// concentration q / (U H), rising with a 60 s time constant.
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Simulated reality (mismatch with the plume model)",
        allow_negative_numbers = true,
        default_value_t = 0.0
    )]
    reality_background: f64,
}

impl RealityArgs {
    /// The mismatch these flags ask for, validated.
    pub fn mismatch(&self) -> Result<Mismatch> {
        let m = Mismatch {
            wind_scale: self.reality_wind_scale,
            diffusivity_scale: self.reality_diffusivity_scale,
            meander_deg: self.reality_meander_deg,
            meander_walled: self.reality_meander_walled,
            background: self.reality_background,
        };
        m.check()?;
        Ok(m)
    }
}

/// A layout's name in reports: its file stem.
fn layout_name(path: &std::path::Path) -> String {
    path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into(),
    )
}

/// Prints the baselines (survey: no estimate of its own).
fn print_baselines(b: &Baselines) {
    print_guesses(None, b);
}

/// Prints an estimate, when there is one, with the two baselines under it, one per line, so
/// that a reader sees what the estimator is compared with.
fn print_guesses(estimate: Option<Guess>, b: &Baselines) {
    let line = |name: &str, g: Guess, note: &str| {
        let error = g
            .error_m
            .map_or(String::new(), |e| format!("error {e:5.2} m"));
        println!("  {name:<16} ({:6.2}, {:5.2})  {error:<16}{note}", g.x, g.y);
    };
    if let Some(g) = estimate {
        line("estimate", g, "the posterior's most probable cell");
    }
    line(
        "highest reading",
        b.highest_reading,
        "baseline: where the sensor read the most",
    );
    line(
        "arena centre",
        b.centre,
        "baseline: a guess without readings",
    );
}

/// Where a simulated run happens: the layout, the source and the robot's start.
#[derive(Debug, Args)]
pub struct TrialArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// True source position "X,Y" (m).
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: (f64, f64),
    /// Robot start "X,Y" (m); default: a random free position drawn from --seed.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    start: Option<(f64, f64)>,
}

impl TrialArgs {
    /// The layout and the source, checked to lie in free space.
    fn layout_and_source(&self) -> Result<(Layout, [f64; 2])> {
        let layout = Layout::load(&self.layout)?;
        let source = [self.source.0, self.source.1];
        layout.check_source(source[0], source[1])?;
        Ok((layout, source))
    }

    /// The robot's start: as given, or drawn from the run seed's stream 4.
    fn start(&self, layout: &Layout, robot: &RobotParams, seed: u64) -> Result<[f64; 2]> {
        Ok(match self.start {
            Some((x, y)) => [x, y],
            None => plumenet::sim::episode::random_start(
                layout,
                robot,
                StartRule::Anywhere,
                derive_seed(seed, 4),
            )?,
        })
    }
}

#[derive(Debug, Args)]
pub struct LocalizeArgs {
    #[command(flatten)]
    trial: TrialArgs,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    /// Sensor.
    #[arg(long, value_enum, default_value_t = SensorArg::SensorII)]
    sensor: SensorArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    reality: RealityArgs,
    /// Seed of the plume, the sensor noise, the planner and the default start.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the run (estimate, error, trajectory, samples, sigmas, history) as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write one picture per iteration into this directory.
    #[arg(long)]
    png_dir: Option<PathBuf>,
    /// Write the run viewer: one self-contained HTML page with a slider over the iterations.
    #[arg(long)]
    html: Option<PathBuf>,
}

pub fn localize(a: LocalizeArgs) -> Result<()> {
    let (layout, source) = a.trial.layout_and_source()?;
    let mismatch = a.reality.mismatch()?;
    let (room, model_name) = a.plume.room(layout)?;
    let world = World::new(room)?.with_mismatch(mismatch)?;
    let feature = Feature::from(a.feature);
    let config = a
        .run
        .config(a.features.params(feature, &world.room), a.sensor.into());
    let start = a.trial.start(&world.room.layout, &config.robot, a.seed)?;
    let keep_posteriors = a.png_dir.is_some() || a.html.is_some();
    let episode = run_episode(&world, &config, source, start, a.seed, keep_posteriors)?;
    println!(
        "{} / {} / {}, source ({:.2}, {:.2}), start ({:.2}, {:.2}): {} after {} iterations, {} readings, {:.1} s",
        feature.name(),
        config.sensor.name(),
        model_name,
        source[0],
        source[1],
        start[0],
        start[1],
        if episode.converged {
            "converged"
        } else {
            "not converged"
        },
        episode.iterations,
        episode.samples.len(),
        episode.wall_time_s
    );
    let estimate = Guess {
        x: episode.estimate[0],
        y: episode.estimate[1],
        error_m: Some(episode.error_m),
    };
    print_guesses(Some(estimate), &episode.baselines);
    println!(
        "  (one run is one draw: `experiment` compares the estimate with both baselines over many runs)"
    );
    if !mismatch.is_none() {
        println!("reality departed from the model: {mismatch}");
    }
    if let Some(dir) = &a.png_dir {
        let paths = write_episode_pictures(
            &world.room.layout,
            world.room.sampler.candidates(),
            a.plume.spacing(),
            &episode,
            dir,
        )?;
        println!("wrote {} pictures into {}", paths.len(), dir.display());
    }
    if let Some(path) = &a.html {
        let title = format!(
            "localize: {} / {} / {}, seed {}: error {:.2} m after {} iterations",
            feature.name(),
            config.sensor.name(),
            model_name,
            a.seed,
            episode.error_m,
            episode.iterations
        );
        RunView::from_episode(
            title,
            &world.room.layout,
            world.room.sampler.candidates(),
            a.plume.spacing(),
            &episode,
        )?
        .write(path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.json {
        let mut value = serde_json::to_value(&episode)?;
        value["model"] = json!(model_name);
        value["sigmas"] = json!(config.ste.sigmas);
        value["candidates"] = json!(world.room.sampler.candidates());
        io::write_json(path, &value)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Readings log, CSV with the columns t,x,y,value.
    #[arg(long)]
    log: PathBuf,
    /// The true source "X,Y" (m), when known: errors are reported for the estimate and the
    /// baselines.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: Option<(f64, f64)>,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    /// Robot radius (m): the prior excludes obstacles inflated by it.
    #[arg(long, default_value_t = 0.07)]
    robot_radius: f64,
    /// Write estimate and posterior as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Draw the posterior with the samples (PNG, or SVG when the name ends in .svg).
    #[arg(long)]
    png: Option<PathBuf>,
    /// Write the run viewer: one self-contained HTML page with a slider over the replay taken
    /// in --html-steps chunks of readings.
    #[arg(long)]
    html: Option<PathBuf>,
    /// Chunks of readings the viewer's replay takes them in (its iterations).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    html_steps: u64,
    /// Use every k-th reading, k the smallest that leaves at most N (a long log, thinned evenly
    /// in time so that the replay fits in memory; the baselines still see every reading).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    thin_to: Option<u64>,
}

pub fn replay_log(a: ReplayArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let samples = read_log(&a.log)?;
    let source = a.source.map(|(x, y)| [x, y]);
    if let Some([x, y]) = source {
        layout.check_source(x, y)?;
    }
    let (room, model_name) = a.plume.room(layout)?;
    let feature = Feature::from(a.feature);
    let params = a.features.params(feature, &room);
    let steps = if a.html.is_some() {
        a.html_steps as usize
    } else {
        1
    };
    let used = match a.thin_to {
        Some(n) => thin(&samples, n as usize)?,
        None => samples.clone(),
    };
    let banks = room.samplers().len();
    let candidates = room.sampler.candidates().len();
    let need = Estimator::memory_bytes(banks, candidates, &params, used.len());
    if let Some(free) = io::available_memory_bytes().filter(|&free| need > free) {
        // The most readings that fit in half the free memory.
        let per_reading = Estimator::memory_bytes(banks, candidates, &params, 1).max(1);
        let fits = ((free / 2) / per_reading).max(1);
        bail!(
            "replaying {} readings over {candidates} candidates and {banks} bank(s) needs about \
             {:.1} GB, more than the {:.1} GB free; thin the log with --thin-to {fits} or fewer",
            used.len(),
            need as f64 / 1e9,
            free as f64 / 1e9,
        );
    }
    if used.len() < samples.len() {
        println!("thinned to {} of {} readings", used.len(), samples.len());
    }
    let (est, trace) = replay_in_steps(room.samplers(), params, a.robot_radius, &used, steps)?;
    let estimate = est.estimate();
    let error_m = source.map(|s| (estimate[0] - s[0]).hypot(estimate[1] - s[1]));
    let baselines = Baselines::new(&room.layout, &samples, source)?;
    println!(
        "{} readings, {}: entropy {:.2} nats, fit {:.3}",
        used.len(),
        feature.name(),
        est.entropy(),
        est.fit().unwrap_or(f64::NAN)
    );
    let guess = Guess {
        x: estimate[0],
        y: estimate[1],
        error_m,
    };
    print_guesses(Some(guess), &baselines);
    if let Some(path) = &a.png {
        let title = format!(
            "replay  {}  estimate ({:.2}, {:.2})",
            feature.name(),
            estimate[0],
            estimate[1]
        );
        let panel = belief_panel(
            &room.layout,
            BeliefPlot {
                title: &title,
                candidates: est.candidates(),
                spacing_m: a.plume.spacing(),
                posterior: est.posterior(),
                trajectory: &[],
                samples: est.positions(),
                edf: est.measured_edf(),
                source,
                estimate,
            },
        )?;
        save_figure(&[Panel::Field(panel)], path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.html {
        let view = RunView::from_replay(
            &room.layout,
            est.candidates(),
            a.plume.spacing(),
            &params,
            &used,
            &trace,
        );
        let title = format!(
            "replay of {}: {} / {}, {} readings in {} steps",
            a.log.display(),
            feature.name(),
            model_name,
            used.len(),
            trace.len()
        );
        RunView {
            title,
            source,
            ..view
        }
        .write(path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.json {
        let posterior = plumenet::ste::protocol::posterior_json(&est);
        let mut report = json!({
            "estimate": estimate, "entropy": est.entropy(), "fit": est.fit(), "samples": used.len(), "log_readings": samples.len(),
            "feature": feature.name(), "sigmas": params.sigmas, "model": model_name,
            "baselines": baselines, "backgrounds": est.backgrounds(), "posterior": posterior,
            "wind_scales": room.marginal(est.bank_posterior(), |b| b.wind_scale),
            "wind_spreads": room.marginal(est.bank_posterior(), |b| b.spread_deg),
            "steady_wind": est.steady_posterior(),
        });
        if let (Some(s), Some(e)) = (source, error_m) {
            report["source"] = json!(s);
            report["error_m"] = json!(e);
        }
        io::write_json(path, &report)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

/// What a live session needs: the layout, the plume model, the STE settings and the seed.
#[derive(Debug, Args)]
pub struct SessionArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
    /// Run seed, as `localize --seed`: the planner draws from its stream 3.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Keep only the most recent N readings in the posterior (a sliding window: memory stays
    /// flat in long sessions); default: all of them.
    #[arg(long)]
    max_readings: Option<usize>,
}

impl SessionArgs {
    /// The session's settings over a room's banks.
    fn config(&self, room: &RoomBanks) -> plumenet::ste::session::SessionConfig {
        let mut config = self
            .run
            .config(
                self.features.params(self.feature.into(), room),
                SensorPreset::SensorII,
            )
            .session(self.seed);
        config.max_readings = self.max_readings;
        config
    }

    /// The layout's world and the model's name; notes go to standard error (standard output
    /// may be a protocol's).
    fn room(&self) -> Result<(RoomBanks, String)> {
        self.plume.room_quietly(Layout::load(&self.layout)?)
    }

    /// A fresh session, with the layout's and the model's names.
    fn session(&self) -> Result<(plumenet::ste::session::Session, String, String)> {
        let (room, model) = self.room()?;
        let session = plumenet::ste::session::Session::new(&room, self.config(&room))?;
        Ok((session, layout_name(&self.layout), model))
    }
}

#[derive(Debug, Args)]
pub struct ServeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Listen on this TCP address (port 0 picks a free one, printed on start); without it the
    /// session is served on standard input and output.
    #[arg(long)]
    listen: Option<String>,
    /// Keep the session's readings in this file (appended and synced before each reply) and
    /// start from what it holds.
    #[arg(long)]
    state: Option<PathBuf>,
}

#[derive(Debug, Args)]
pub struct RobotSimArgs {
    /// The server, HOST:PORT (`plumenet serve --listen`).
    #[arg(long)]
    connect: String,
    /// The layout (the server's), the source and the start.
    #[command(flatten)]
    trial: TrialArgs,
    /// Sensor.
    #[arg(long, value_enum, default_value_t = SensorArg::SensorII)]
    sensor: SensorArg,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    reality: RealityArgs,
    /// Seed of the plume, the sensor noise and the default start (as `localize --seed`).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the outcome as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn robot_sim(a: RobotSimArgs) -> Result<()> {
    use plumenet::service::RemoteSession;
    let (layout, source) = a.trial.layout_and_source()?;
    let mismatch = a.reality.mismatch()?;
    let config = a
        .run
        .config(SteParams::for_feature(Feature::Rank), a.sensor.into());
    let start = a.trial.start(&layout, &config.robot, a.seed)?;
    let wind = WindField::solve(&layout)?;
    let reality = Reality::new(&layout, &wind, mismatch)?;
    let mut server = RemoteSession::connect(a.connect.as_str())?;
    let run = plumenet::sim::episode::simulate_robot(
        &reality,
        &config.flight(),
        [source, start],
        a.seed,
        config.termination.max_iterations,
        &mut server,
    )?;
    println!(
        "estimate ({:.2}, {:.2}), error {:.2} m, {} legs, {}, {} readings",
        run.last.estimate[0],
        run.last.estimate[1],
        run.error_m,
        run.legs,
        if run.last.converged {
            "converged"
        } else {
            "not converged"
        },
        run.readings
    );
    if let Some(path) = &a.json {
        io::write_json(path, &run)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

pub fn serve(a: ServeArgs) -> Result<()> {
    use plumenet::service::{StateFile, serve_lines, serve_tcp};
    use plumenet::ste::protocol::{Journal, NoJournal, Protocol};
    let (mut session, name, model) = a.session.session()?;
    let mut journal: Box<dyn Journal> = match &a.state {
        None => Box::new(NoJournal),
        Some(path) => {
            let (file, restored) = StateFile::open(path)?;
            session.add_readings(&restored.readings)?;
            session.update()?;
            eprintln!(
                "state {}: {} readings in {} batches restored{}",
                path.display(),
                restored.readings.len(),
                restored.batches,
                if restored.dropped_torn_line {
                    " (a torn last line dropped)"
                } else {
                    ""
                }
            );
            Box::new(file)
        }
    };
    let mut protocol = Protocol::new(session, &name, &model);
    match &a.listen {
        None => {
            let stdin = std::io::stdin();
            serve_lines(
                &mut protocol,
                journal.as_mut(),
                stdin.lock(),
                std::io::stdout().lock(),
            )?;
        }
        Some(address) => serve_tcp(&mut protocol, journal.as_mut(), address.as_str(), |at| {
            println!("listening on {at}");
            use std::io::Write as _;
            let _ = std::io::stdout().flush();
        })?,
    }
    Ok(())
}

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
    print_baselines(&Baselines::new(&layout, &samples, Some(source))?);
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
    plume: PlumeArgs,
    #[command(flatten)]
    overrides: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
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
    let start = match a.start {
        StartArg::Anywhere => StartRule::Anywhere,
        StartArg::Downwind => StartRule::Downwind,
    };
    let mut models = vec![a.plume.solver];
    if a.with_solver {
        models.push(true);
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
        .run
        .config(
            SteParams::for_feature(Feature::Rank),
            SensorPreset::SensorII,
        )
        .robot;
    let mut sites = Vec::new();
    let files = match (&a.layout, &a.rooms_of) {
        (Some(files), _) => files.clone(),
        (None, Some(_)) => Vec::new(),
        (None, None) => vec![PathBuf::from("data/layouts/wind-tunnel.json")],
    };
    for path in &files {
        sites.push((layout_name(path), Layout::load(path)?));
    }
    if let Some(dir) = &a.rooms_of {
        let manifest = plumenet::dataset::Manifest::load(dir)?;
        if a.rooms == 0 || a.rooms > manifest.layouts.len() {
            bail!(
                "--rooms {} is not between 1 and the {} layouts of {}",
                a.rooms,
                manifest.layouts.len(),
                dir.display()
            );
        }
        for (k, spec) in manifest.layouts.into_iter().take(a.rooms).enumerate() {
            sites.push((format!("{}-{k}", layout_name(dir)), spec.check()?));
        }
    }
    let mut rows = Vec::new();
    for (name, layout) in sites {
        let survey = match a.paths {
            PathsArg::Planner => None,
            PathsArg::Lawnmower => Some(lawnmower(&layout, &robot, a.survey_spacing)?),
        };
        let paths = match &survey {
            None => Paths::Planner(start),
            Some(s) => Paths::Survey(&s.path),
        };
        for &solver in &models {
            let (room, _, note) = a.plume.room_of(layout.clone(), solver)?;
            println!("{note}");
            let model_world = World::new(room)?;
            for &mismatch in &realities {
                let world = model_world.with_mismatch(mismatch)?;
                let bar = super::progress_bar(plan.len(), "runs");
                let site = StudySite {
                    world: &world,
                    layout: &name,
                    model: if solver { "solver" } else { "plumenet" },
                    paths,
                };
                rows.extend(run_study(
                    site,
                    &plan,
                    a.seed,
                    |f, s| a.run.config(a.overrides.params(f, &world.room), s),
                    || bar.inc(1),
                )?);
                bar.finish_and_clear();
            }
        }
    }
    let summary = summarize(&rows);
    io::write_csv(&a.out.join("runs.csv"), &rows)?;
    io::write_csv(&a.out.join("summary.csv"), &summary)?;
    let table = summary_table(&summary);
    io::write_atomic(&a.out.join("summary.md"), |buf| {
        buf.extend_from_slice(table.as_bytes());
        Ok(())
    })?;
    let panel = |title: &str, y_desc: &str, metric: fn(&RunRow) -> f64, baselines: bool| {
        Panel::Boxes(BoxPanel {
            title: title.into(),
            y_desc: y_desc.into(),
            groups: group_values(&plot_values(&rows, metric, baselines)),
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
        &a.out.join("boxplots.png"),
    )?;
    print!("{table}");
    println!("wrote {}", a.out.display());
    Ok(())
}

/// The study's summary as a Markdown table.
fn summary_table(summary: &[SummaryRow]) -> String {
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
            ]
        }),
    )
}

#[derive(Debug, Args)]
pub struct BenchSteArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Readings after the last timed update.
    #[arg(long, default_value_t = 3000)]
    samples: usize,
    /// Readings arriving in the timed update (one iteration's worth).
    #[arg(long, default_value_t = 100)]
    batch: usize,
    /// Successive timed updates (medians are reported).
    #[arg(long, default_value_t = 7)]
    repeats: usize,
    /// Also time rank over one bank per model wind-speed factor (e.g. 0.5,1,2) against one
    /// bank, side by side: the cost of marginalising the wind speed.
    #[arg(long, value_delimiter = ',')]
    wind_scales: Vec<f64>,
    /// Also time rank over one bank per spread of the wind's direction (degrees, e.g. 0,30)
    /// against one bank, side by side: the cost of marginalising the direction's spread.
    #[arg(long, value_delimiter = ',')]
    wind_spreads: Vec<f64>,
    /// Also time rank with the background nuisance at this rise (three rises) against rank
    /// without it, side by side (0: not timed).
    #[arg(long, default_value_t = 0.0)]
    background_rise: f64,
    /// Also time rank weighing a wandering wind of this standard deviation (degrees; seven
    /// turned banks) against rank over one bank, side by side (0: not timed).
    #[arg(long, default_value_t = 0.0)]
    wind_wander: f64,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn bench_ste(a: BenchSteArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let (world, _) = World::build(layout, &PhysicsSolver, 0.25, None)?;
    println!(
        "one STE update on one core: {} new readings, the last of {} successive updates ending at {} readings ({} candidates), medians",
        a.batch,
        a.repeats,
        a.samples,
        world.room.sampler.len()
    );
    let mut report = Vec::new();
    let rank = SteParams::for_feature(Feature::Rank);
    let variants = Feature::ALL
        .map(|f| (f.name(), SteParams::for_feature(f)))
        .into_iter()
        .chain([
            (
                "rank-expected",
                SteParams {
                    model_rank_factor: plumenet::surrogate::inference::RANK_FACTOR,
                    ..rank
                },
            ),
            (
                "rank-ties",
                SteParams {
                    clean_air_model_ties: true,
                    ..rank
                },
            ),
            ("rank-lag-c", rank.lag_in_concentration()),
            ("rank-paper", rank.papers_rank()),
        ]);
    for (name, params) in variants {
        let t =
            plumenet::bench::time_ste_update(&world.room, params, a.samples, a.batch, a.repeats)?;
        println!(
            "  {:13} update {:7.2} ms   floor (read N x n once) {:6.2} ms   ratio {:5.1}x",
            name,
            t.update_s * 1e3,
            t.floor_s * 1e3,
            t.update_s / t.floor_s
        );
        report.push(json!({
            "feature": name, "update_ms": t.update_s * 1e3, "floor_ms": t.floor_s * 1e3,
            "candidates": t.candidates, "samples": t.samples,
        }));
    }
    // Each nuisance against rank over one bank without any (not even rank's default background
    // nuisance), side by side: (what, world, settings, values).
    let bare = SteParams {
        background_rise: 0.0,
        ..rank
    };
    let mut nuisances = Vec::new();
    if a.wind_scales.len() > 1 {
        let banks = world
            .room
            .with_wind_scales(&PhysicsSolver, &a.wind_scales, None)?;
        nuisances.push(("wind-speed banks", banks, bare, a.wind_scales.len()));
    }
    if a.wind_spreads.len() > 1 {
        let banks = world.room.with_wind_spreads(&a.wind_spreads)?;
        nuisances.push(("wind-spread banks", banks, bare, a.wind_spreads.len()));
    }
    if a.background_rise > 0.0 {
        let with = SteParams {
            background_rise: a.background_rise,
            ..bare
        };
        nuisances.push(("background rises", world.room.clone(), with, 3));
    }
    if a.wind_wander > 0.0 {
        let with = SteParams {
            wander_deg: a.wind_wander,
            ..bare
        };
        nuisances.push((
            "wind turns",
            world.room.clone(),
            with,
            with.wander_turns().len(),
        ));
    }
    let time =
        |w: &RoomBanks, p| plumenet::bench::time_ste_update(w, p, a.samples, a.batch, a.repeats);
    let mut nuisance = Vec::new();
    if !nuisances.is_empty() {
        let one = time(&world.room, bare)?;
        for (what, w, params, k) in &nuisances {
            let all = time(w, *params)?;
            let per_added = (all.update_s - one.update_s) / (k - 1) as f64 / one.update_s;
            println!(
                "  rank over {k} {what}: update {:7.2} ms against {:.2} ms over one; each added value costs {per_added:.2}x one bank's update",
                all.update_s * 1e3,
                one.update_s * 1e3
            );
            nuisance.push(json!({"nuisance": what, "values": k, "update_ms": all.update_s * 1e3, "one_bank_ms": one.update_s * 1e3, "per_added_value": per_added}));
        }
    }
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let ep = run_episode(&world, &config, [5.1, 2.1], [15.0, 1.0], 0, false)?;
    println!(
        "  whole run (rank, sensor-ii, solver bank ready, all cores): {:.2} s, {} iterations, {} readings",
        ep.wall_time_s,
        ep.iterations,
        ep.samples.len()
    );
    if let Some(path) = &a.json {
        let value = json!({"updates": report, "run_s": ep.wall_time_s, "run_iterations": ep.iterations, "nuisances": nuisance});
        io::write_json(path, &value)?;
    }
    Ok(())
}

/// The ROS 2 node's topics, types and frame.
#[cfg(feature = "ros2")]
#[derive(Debug, Args)]
pub struct Ros2NodeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Gas readings topic.
    #[arg(long, default_value = "gas")]
    reading_topic: String,
    /// Their type: float64 (std_msgs/Float64) or float32.
    #[arg(long, value_enum, default_value_t = ReadingTypeArg::Float64)]
    reading_type: ReadingTypeArg,
    /// Robot pose topic.
    #[arg(long, default_value = "pose")]
    pose_topic: String,
    /// Its type: pose-stamped (geometry_msgs/PoseStamped) or odometry (nav_msgs/Odometry).
    #[arg(long, value_enum, default_value_t = PoseTypeArg::PoseStamped)]
    pose_type: PoseTypeArg,
    /// Where the next goal goes (geometry_msgs/PoseStamped).
    #[arg(long, default_value = "goal_pose")]
    goal_topic: String,
    /// Where the belief goes (nav_msgs/OccupancyGrid).
    #[arg(long, default_value = "gas_source/belief")]
    belief_topic: String,
    /// Where the estimate goes (geometry_msgs/PointStamped).
    #[arg(long, default_value = "gas_source/estimate")]
    estimate_topic: String,
    /// Frame of poses, goals, grid and estimate.
    #[arg(long, default_value = "map")]
    frame_id: String,
    /// The node's namespace.
    #[arg(long, default_value = "/")]
    namespace: String,
    /// The node's name.
    #[arg(long, default_value = "plumenet")]
    name: String,
    /// How close the robot must come to its goal before the next iteration (m).
    #[arg(long, default_value_t = 0.2)]
    goal_tolerance: f64,
}

/// The gas reading message type on the command line.
#[cfg(feature = "ros2")]
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum ReadingTypeArg {
    Float64,
    Float32,
}

/// The pose message type on the command line.
#[cfg(feature = "ros2")]
#[derive(Debug, Clone, Copy, clap::ValueEnum)]
pub enum PoseTypeArg {
    PoseStamped,
    Odometry,
}

#[cfg(feature = "ros2")]
pub fn ros2_node(a: Ros2NodeArgs) -> Result<()> {
    use plumenet::ros::node::{NodeSettings, PoseType, ReadingType, SteNode};
    let (session, name, model) = a.session.session()?;
    let settings = NodeSettings {
        namespace: a.namespace,
        name: a.name,
        reading_topic: a.reading_topic,
        reading_type: match a.reading_type {
            ReadingTypeArg::Float64 => ReadingType::Float64,
            ReadingTypeArg::Float32 => ReadingType::Float32,
        },
        pose_topic: a.pose_topic,
        pose_type: match a.pose_type {
            PoseTypeArg::PoseStamped => PoseType::PoseStamped,
            PoseTypeArg::Odometry => PoseType::Odometry,
        },
        goal_topic: a.goal_topic,
        belief_topic: a.belief_topic,
        estimate_topic: a.estimate_topic,
        frame_id: a.frame_id,
        spacing_m: a.session.plume.spacing(),
        goal_tolerance_m: a.goal_tolerance,
    };
    let mut node = SteNode::new(session, settings)?;
    eprintln!("ROS 2 node up: {name}, model {model}");
    let stop = std::sync::atomic::AtomicBool::new(false);
    node.run(std::time::Duration::from_millis(20), &stop)?;
    let it = node.session().estimator();
    println!(
        "done: estimate ({:.2}, {:.2})",
        it.estimate()[0],
        it.estimate()[1]
    );
    Ok(())
}

#[derive(Debug, Args)]
pub struct BenchServeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Readings at which one iteration (100 new readings, then planning) is timed.
    #[arg(long, value_delimiter = ',', default_values_t = [1000, 3000, 10000])]
    sizes: Vec<usize>,
    /// Readings per simulated second in the load test.
    #[arg(long, default_value_t = 100)]
    rate: usize,
    /// Simulated seconds streamed in the load test.
    #[arg(long, default_value_t = 600)]
    seconds: usize,
    /// An iteration every this many simulated seconds.
    #[arg(long, default_value_t = 10)]
    iterate_every: usize,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn bench_serve(a: BenchServeArgs) -> Result<()> {
    let (room, model) = a.session.room()?;
    let config = a.session.config(&room);
    println!(
        "one session iteration (100 new readings, then planning; all cores), {} candidates, {model}:",
        room.sampler.len()
    );
    let mut sizes = Vec::new();
    for &n in &a.sizes {
        let s = plumenet::bench::time_session_iteration(&room, config, n, 100)?;
        println!("  at {n:6} readings: {:8.1} ms", s * 1e3);
        sizes.push(json!({"readings": n, "iteration_ms": s * 1e3}));
    }
    let load = plumenet::bench::serve_load(&room, config, a.rate, a.seconds, a.iterate_every)?;
    let rt = &load.round_trips_s;
    let ms = |k: usize| rt.get(k).map_or(f64::NAN, |s| s * 1e3);
    println!(
        "load over TCP on loopback: {} readings sent ({} a simulated second for {} s), {} counted by the server, {} errors, {:.1} s wall",
        load.sent, a.rate, a.seconds, load.accepted, load.errors, load.wall_s
    );
    println!(
        "  readings + iterate round trip: {:.1} ms at the first iteration, {:.1} ms at the last ({} iterations)",
        ms(0),
        ms(rt.len().saturating_sub(1)),
        rt.len()
    );
    if let (Some(first), Some(last)) = (load.resident_bytes.first(), load.resident_bytes.last()) {
        let per = (*last as f64 - *first as f64)
            / (load.sent as f64 * (1.0 - 1.0 / rt.len().max(1) as f64)).max(1.0);
        println!(
            "  resident memory {:.0} MB after the first iteration, {:.0} MB after the last: {per:.0} bytes a reading",
            *first as f64 / 1e6,
            *last as f64 / 1e6
        );
    }
    if let Some(path) = &a.json {
        io::write_json(path, &json!({"iterations": sizes, "load": load}))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
