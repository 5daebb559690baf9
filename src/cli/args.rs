//! Flags shared by the STE commands: the plume model and its banks, the likelihood's
//! settings, the robot and stopping rule, the simulated reality, and where a run happens.

use std::path::PathBuf;

use anyhow::{Context, Result};
use clap::Args;

use plumenet::layout::Layout;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::sim::episode::StartRule;
use plumenet::sim::{EpisodeConfig, Mismatch, derive_seed};
use plumenet::ste::baseline::Guess;
use plumenet::ste::termination::REGION_RADIUS_M;
use plumenet::ste::{
    Baselines, Feature, PlannerKind, RobotParams, RoomBanks, Sampling, SensorPreset, Sigmas,
    SteParams, Termination, Uncertainty, ValidSteParams,
};
use plumenet::surrogate::Surrogate;

use super::parse_point;

/// Which plume model feeds the estimator, and where its banks are cached.
#[derive(Debug, Args)]
pub struct PlumeArgs {
    /// Use the physics solver as plume model instead of PlumeNet.
    #[arg(long, conflicts_with = "model")]
    pub(super) solver: bool,
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
        env = "PLUMENET_CACHE_DIR",
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
    /// The chosen plume model: the physics solver with `--solver`, else the PlumeNet model.
    pub(super) fn model(&self) -> Result<Box<dyn PlumeModel>> {
        self.model_of(self.solver)
    }

    /// The physics solver (`solver`) or the chosen PlumeNet model.
    pub(super) fn model_of(&self, solver: bool) -> Result<Box<dyn PlumeModel>> {
        Ok(if solver {
            Box::new(PhysicsSolver)
        } else {
            Box::new(Surrogate::load(&self.model).with_context(|| {
                format!(
                    "cannot load the plume model {} (or pass --solver)",
                    self.model.display()
                )
            })?)
        })
    }

    /// The layout's banks for the chosen model and the estimator's settings for `feature`,
    /// checked before the banks are computed; also returns the model (its name for reports).
    /// The note on the bank goes to standard output, or to standard error when `quiet`
    /// (standard output being a protocol's).
    pub(super) fn room(
        &self,
        layout: Layout,
        features: &FeatureArgs,
        feature: Feature,
        quiet: bool,
    ) -> Result<(RoomBanks, ValidSteParams, Box<dyn PlumeModel>)> {
        let model = self.model()?;
        let params = features.params(feature, model.rank_factor())?;
        let (room, note) = self.room_of(layout, model.as_ref())?;
        if quiet {
            eprintln!("{note}");
        } else {
            println!("{note}");
        }
        Ok((room, params, model))
    }

    /// The banks of `model` over the layout's candidates (through the cache, with the wind
    /// scales and spreads asked for), and a note on the bank for the user.
    pub(super) fn room_of(
        &self,
        layout: Layout,
        model: &dyn PlumeModel,
    ) -> Result<(RoomBanks, String)> {
        let cache = (!self.no_cache).then_some(self.cache_dir.as_path());
        let (room, hit) = RoomBanks::build(layout, model, self.spacing, cache)?;
        // The defaults (scale 1, spread 0) keep the layout's own bank.
        let room = room
            .with_wind_scales(model, &self.wind_scales, cache)?
            .with_wind_spreads(&self.wind_spreads)?;
        let note = format!(
            "plume model {}: {} candidates{}",
            model.name(),
            room.sampler.len(),
            if hit { " (bank from cache)" } else { "" }
        );
        Ok((room, note))
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
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning", default_value_t = SteParams::for_feature(Feature::Rank).rank.rank_tolerance)]
    rank_tolerance: f64,
    /// Rank only: the factor within which the plume model's concentrations are known when
    /// ranked; each candidate's expected ranks under that uncertainty are compared (default:
    /// 3 for PlumeNet; for the solver 1.5, or 1 with `--evidence-weight 1`; 1 compares exact
    /// ranks).
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
    /// The weight of each reading's evidence in (0, 1]: the log-likelihood is multiplied by
    /// it (1 treats readings as independent).
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    evidence_weight: Option<f64>,
    /// Let the evidence saturate at S readings: each of the n readings so far weighs the
    /// evidence weight times 2S / (S + n) [default: none, every reading weighs the evidence
    /// weight].
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    evidence_saturation: Option<f64>,
    /// The prior odds of each background rise against none [default: 0.01 with a tempered
    /// likelihood, else 1].
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    background_odds: Option<f64>,
    /// Take the readings' noise level from the data: a best fit per reading worse than this
    /// reference weighs every reading down by their ratio [default: 0.02 with the solver and a
    /// tempered likelihood, else none].
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    fit_reference: Option<f64>,
    /// Take the readings' noise level from the data: a best misfit over all readings (the
    /// sum of their squared standardised residuals) worse than this reference weighs every
    /// reading down by their ratio [default: 50 with a tempered likelihood, else none].
    #[arg(
        long,
        hide_short_help = true,
        help_heading = "Likelihood tuning",
        allow_negative_numbers = true
    )]
    misfit_reference: Option<f64>,
    /// Without the fit checks' defaults (`--misfit-reference`, and with the solver
    /// `--fit-reference`): the readings weigh the evidence weight alone, or with the checks
    /// whose references are set.
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning")]
    no_fit_check: bool,
    /// Rank only: the paper's rank likelihood, without our clean-air ties (of the readings and
    /// the model), rank tolerance, expected model ranks, background nuisance, and lag in the
    /// sensor's response with its lower floor (the other features' lag and floor instead);
    /// exactly invariant under every increasing transform of the readings.
    #[arg(long, hide_short_help = true, help_heading = "Likelihood tuning", conflicts_with_all = ["rank_tolerance", "model_rank_factor", "background_rise", "background_odds", "clean_air_model_ties", "clean_air_rank_floor", "wind_wander", "fit_reference", "misfit_reference"])]
    paper_rank: bool,
}

impl FeatureArgs {
    /// The estimator settings for a feature with these overrides, checked: the one place the
    /// command line turns its flags and the defaults into settings. `rank_factor` is the plume
    /// model's own ([`PlumeModel::rank_factor`]), the default of `--model-rank-factor`.
    ///
    /// # Errors
    /// A setting out of its range ([`SteParams::validate`]), named with its value.
    pub fn params(&self, feature: Feature, rank_factor: f64) -> Result<ValidSteParams> {
        let mut p = SteParams::for_model(feature, rank_factor);
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
        p.rank.rank_tolerance = self.rank_tolerance;
        p.rank.clean_air_window_s = self.clean_air_window;
        p.rank.clean_air_model_ties = self.clean_air_model_ties;
        p.rank.clean_air_rank_floor = self.clean_air_rank_floor;
        if let Some(a) = self.background_rise {
            p.background_rise = a;
        }
        p.background_time_s = self.background_time;
        if self.background_odds.is_some() {
            p.background_odds = self.background_odds;
        }
        p.wander_deg = self.wind_wander;
        if let Some(w) = self.evidence_weight {
            p.evidence_weight = w;
        }
        if self.evidence_saturation.is_some() {
            p.evidence_saturation = self.evidence_saturation;
        }
        // The model's factor resolved after the weight, whose floor goes with it.
        p.rank.model_rank_factor = self
            .model_rank_factor
            .unwrap_or_else(|| p.rank_factor_for(rank_factor));
        // The fit checks' defaults go with the weight, as the factor's does; a reference set
        // applies with or without them.
        let default = |d: Option<f64>| d.filter(|_| !self.no_fit_check);
        p.fit_reference = self
            .fit_reference
            .or(default(p.fit_reference_for(rank_factor)));
        p.misfit_reference = self.misfit_reference.or(default(p.misfit_reference_for()));
        if self.paper_rank {
            p = p.papers_rank();
        }
        if let Some(a) = self.lag_exponent {
            p.sensor_lag_exponent = a;
        }
        if let Some(f) = self.detection_floor {
            p.detection_floor_ppm = f;
        }
        Ok(p.validate()?)
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
    /// Iteration limit [default: 30, growing with the square root of the free floor beyond
    /// 72 m²].
    #[arg(long)]
    max_iterations: Option<usize>,
    /// Stop on the entropy rule: entropy (nats) below which the run may stop [default: 1.5,
    /// with an untempered likelihood].
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule")]
    entropy_threshold: Option<f64>,
    /// Stop when the 90% credible region covers at most this area (m²) [default: 1 with a
    /// tempered likelihood (rank), else the entropy rule].
    #[arg(
        long,
        value_name = "M2",
        hide_short_help = true,
        help_heading = "Robot and stopping rule",
        allow_negative_numbers = true
    )]
    target_area: Option<f64>,
    /// Consecutive concentrated iterations, around the same estimate, needed to stop
    /// (1 = the paper's rule alone).
    #[arg(long, hide_short_help = true, help_heading = "Robot and stopping rule", default_value_t = Termination::default().stable_iterations as u16, value_parser = clap::value_parser!(u16).range(1..))]
    stable_iterations: u16,
    /// What one more leg costs the robot (stopping, updating, turning), in metres of driving:
    /// a larger cost makes fewer, longer legs.
    #[arg(long, value_name = "M", hide_short_help = true, help_heading = "Robot and stopping rule", default_value_t = plumenet::ste::robot::LEG_COST_M, value_parser = |s: &str| parse_metres(s, plumenet::ste::robot::check_leg_cost), allow_negative_numbers = true)]
    leg_cost: f64,
    /// The radius (m) within which the planner counts the readings already taken around each
    /// point of a leg: a point where n passes' readings lie weighs 1 / (1 + n) of a fresh one.
    /// 0 counts every point in full [default: 0.25 with the solver, 0 with PlumeNet or
    /// --paper-rank].
    #[arg(long, value_name = "M", hide_short_help = true, help_heading = "Robot and stopping rule", value_parser = |s: &str| parse_metres(s, plumenet::ste::robot::check_revisit_radius), allow_negative_numbers = true)]
    revisit_radius: Option<f64>,
    /// Stop only once the robot has sensed this far (m) upwind of its estimate, driving there
    /// when the rest of the rule holds: a source further upwind leaves gas there. 0 probes
    /// nowhere [default: 0].
    #[arg(long, value_name = "M", hide_short_help = true, help_heading = "Robot and stopping rule", value_parser = |s: &str| parse_metres(s, plumenet::ste::termination::check_upwind_probe), allow_negative_numbers = true)]
    upwind_probe: Option<f64>,
}

/// A length in metres, checked as the library checks it (`check`: a leg cost or a revisit
/// radius, [`plumenet::ste::robot`], or an upwind probe, [`plumenet::ste::termination`]).
fn parse_metres(
    s: &str,
    check: fn(f64) -> plumenet::error::Result<()>,
) -> std::result::Result<f64, String> {
    let m: f64 = s.parse().map_err(|e| format!("{e}"))?;
    check(m).map(|()| m).map_err(|e| e.to_string())
}

impl RunArgs {
    /// Checks the stopping rule's flags for a room, before any bank is computed.
    ///
    /// # Errors
    /// A target area that is not positive or larger than the room.
    pub fn check(&self, layout: &Layout) -> Result<()> {
        let t = Termination {
            target_area_m2: self.target_area,
            ..Termination::default()
        };
        Ok(t.check(layout.width() * layout.height())?)
    }

    /// The run settings for a feature and sensor, with a plume model whose own rank factor is
    /// `model_factor` ([`PlumeModel::rank_factor`]; the revisit radius's default goes with it).
    pub fn config(
        &self,
        ste: ValidSteParams,
        sensor: SensorPreset,
        model_factor: f64,
    ) -> EpisodeConfig {
        let mut c = EpisodeConfig::new(ste.feature, sensor);
        c.ste = ste.into_inner();
        c.termination = Termination::for_params(&c.ste);
        c.planner = self.planner.into();
        c.sensor_noise = !self.noise_free;
        if let Some(n) = self.max_iterations {
            c.termination.max_iterations = n;
            c.termination.grow_with_room = false;
        }
        c.termination.stable_iterations = usize::from(self.stable_iterations);
        c.robot.leg_cost_m = self.leg_cost;
        c.robot.revisit_radius_m = self
            .revisit_radius
            .unwrap_or_else(|| c.ste.revisit_radius_for(model_factor));
        // An entropy threshold asks for the entropy rule; a target area for the area rule.
        if let Some(h) = self.entropy_threshold {
            c.termination.entropy_nats = h;
            c.termination.target_area_m2 = None;
        }
        if self.upwind_probe.is_some() {
            c.termination.upwind_probe_m = self.upwind_probe;
        }
        if self.target_area.is_some() {
            c.termination.target_area_m2 = self.target_area;
            c.termination.region_radius_m = Some(REGION_RADIUS_M);
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
    pub(super) reality_meander_walled: bool,
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
pub(super) fn layout_name(path: &std::path::Path) -> String {
    path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into(),
    )
}

/// How a run ended, in words: converged, or unresolved, saying so when the robot met no plume
/// or the estimate's plume misses the gas it met (`plume_reached`, where known).
pub(super) fn outcome(
    converged: bool,
    plume_signal: f64,
    plume_reached: Option<bool>,
) -> &'static str {
    if converged {
        "converged"
    } else if plume_signal < plumenet::ste::termination::PLUME_SIGNAL_NOISES {
        "unresolved (iteration budget spent, no plume met)"
    } else if plume_reached == Some(false) {
        "unresolved (iteration budget spent, the estimate's plume misses the gas met)"
    } else {
        "unresolved (iteration budget spent)"
    }
}

/// Prints an estimate, when there is one, with the two baselines under it, one per line, so
/// that a reader sees what the estimator is compared with.
pub(super) fn print_guesses(estimate: Option<Guess>, b: &Baselines) {
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

/// Prints the posterior's credible regions and expected distance from the estimate, and
/// whether each region holds the source when it is known.
pub(super) fn print_uncertainty(u: &Uncertainty) {
    let regions: Vec<String> = u
        .regions
        .iter()
        .map(|r| {
            let covers = match r.covers_source {
                Some(true) => ", holds the source",
                Some(false) => ", misses the source",
                None => "",
            };
            format!(
                "{:.0}% region {:.2} m² ({} cells{covers})",
                100.0 * r.level,
                r.area_m2,
                r.cells.len()
            )
        })
        .collect();
    println!(
        "  uncertainty      expected distance {:.2} m; {}",
        u.expected_distance_m,
        regions.join("; ")
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
    pub(super) fn layout_and_source(&self) -> Result<(Layout, [f64; 2])> {
        let layout = Layout::load(&self.layout)?;
        let source = [self.source.0, self.source.1];
        layout.check_source(source[0], source[1])?;
        Ok((layout, source))
    }

    /// The robot's start: as given, or drawn from the run seed's stream 4.
    pub(super) fn start(
        &self,
        layout: &Layout,
        robot: &RobotParams,
        seed: u64,
    ) -> Result<[f64; 2]> {
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
