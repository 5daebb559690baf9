//! One simulated localisation run: the filament plume as reality, the MOX sensor on the robot,
//! the estimator, the planner and the termination rule.
//!
//! Each iteration the planner picks a goal from the current belief, the robot drives the A*
//! path while the plume and the sensor advance in 0.1 s ticks (sense-in-motion records every
//! tick; stop-sense-go records averaged stops), the new readings update the posterior, and the
//! run stops when the belief is concentrated or after the maximum number of iterations. The
//! plume is warmed up before the robot starts so that it fills the arena.
//!
//! Seeds: the plume, the sensor noise and the planner draw from three independent streams
//! derived from the run's seed, so a run is reproducible bit for bit.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::physics::wind::WindField;
use crate::plume::PlumeModel;
use crate::sim::reality::{Field, Flight, Mismatch, Reality};
use crate::sim::seed::derive_seed;
use crate::ste::banks::{PRIOR_BAND_M, RoomBanks};
use crate::ste::baseline::Baselines;
use crate::ste::credible::Uncertainty;
use crate::ste::features::Feature;
use crate::ste::planner::PlannerKind;
use crate::ste::posterior::{Sample, SteParams};
use crate::ste::robot::{Occupancy, RobotParams, path_length};
use crate::ste::sensor::SensorPreset;
use crate::ste::session::{Iteration, Session, SessionConfig};
use crate::ste::termination::{PLUME_SIGNAL_NOISES, Termination};

/// The world a simulated run happens in: the room as the estimator sees it, the room's wind,
/// and the reality the robot senses.
#[derive(Debug, Clone)]
pub struct World {
    /// The layout and the plume model's banks.
    pub room: RoomBanks,
    /// The room's steady wind, as the plume model assumes it.
    pub wind: WindField,
    /// What the robot senses (the model on average unless a [`Mismatch`] is set).
    pub reality: Arc<Reality>,
}

impl World {
    /// The room's banks ([`RoomBanks::build`]), its solved wind and a reality without
    /// mismatch. Also returns whether the bank came from the cache.
    ///
    /// # Errors
    /// As [`RoomBanks::build`], and the wind solver's errors.
    pub fn build(
        layout: Layout,
        model: &dyn PlumeModel,
        spacing_m: f64,
        cache: Option<&Path>,
    ) -> Result<(Self, bool)> {
        let (room, hit) = RoomBanks::build(layout, model, spacing_m, cache)?;
        Ok((Self::new(room)?, hit))
    }

    /// The world of `room`: its wind solved, reality as the model on average.
    ///
    /// # Errors
    /// The wind solver's errors.
    pub fn new(room: RoomBanks) -> Result<Self> {
        let wind = WindField::solve(&room.layout)?;
        let reality = Arc::new(Reality::new(&room.layout, &wind, Mismatch::NONE)?);
        Ok(Self {
            room,
            wind,
            reality,
        })
    }

    /// The same world with the estimator marginalising over the model's wind speed
    /// ([`RoomBanks::with_wind_scales`]).
    ///
    /// # Errors
    /// As [`RoomBanks::with_wind_scales`].
    pub fn with_wind_scales(
        &self,
        model: &dyn PlumeModel,
        scales: &[f64],
        cache: Option<&Path>,
    ) -> Result<Self> {
        Ok(Self {
            room: self.room.with_wind_scales(model, scales, cache)?,
            ..self.clone()
        })
    }

    /// The same world with the estimator marginalising over the spread of the wind's
    /// direction ([`RoomBanks::with_wind_spreads`]).
    ///
    /// # Errors
    /// As [`RoomBanks::with_wind_spreads`].
    pub fn with_wind_spreads(&self, spreads: &[f64]) -> Result<Self> {
        Ok(Self {
            room: self.room.with_wind_spreads(spreads)?,
            ..self.clone()
        })
    }

    /// The same world with reality departing from the model by `mismatch`.
    ///
    /// # Errors
    /// [`Error::Parameter`] for bad knobs, and the wind solver's errors.
    pub fn with_mismatch(&self, mismatch: Mismatch) -> Result<Self> {
        Ok(Self {
            reality: Arc::new(Reality::new(&self.room.layout, &self.wind, mismatch)?),
            ..self.clone()
        })
    }
}

/// Settings of one run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpisodeConfig {
    /// Feature, sigmas and thresholds.
    pub ste: SteParams,
    /// The sensor.
    pub sensor: SensorPreset,
    /// Whether the sensor is noisy.
    pub sensor_noise: bool,
    /// The robot.
    pub robot: RobotParams,
    /// The planner.
    pub planner: PlannerKind,
    /// The stopping rule.
    pub termination: Termination,
    /// Plume time before the robot starts (s).
    pub warmup_s: f64,
}

impl EpisodeConfig {
    /// The live session's settings for a run of seed `seed` (the planner draws from its stream
    /// 3), as `localize`, `serve` and `robot-sim` share them.
    pub fn session(&self, seed: u64) -> SessionConfig {
        SessionConfig {
            ste: self.ste,
            planner: self.planner,
            termination: self.termination,
            robot: self.robot,
            planner_seed: derive_seed(seed, 3),
            max_readings: None,
        }
    }

    /// How the robot senses in these settings.
    pub fn flight(&self) -> Flight {
        Flight {
            sensor: self.sensor,
            sensor_noise: self.sensor_noise,
            robot: self.robot,
            warmup_s: self.warmup_s,
        }
    }

    /// The defaults: sense-in-motion, belief clustering, a noisy sensor, 60 s warm-up, and the
    /// stopping rule that goes with the feature's settings ([`Termination::for_params`]).
    pub fn new(feature: Feature, sensor: SensorPreset) -> Self {
        let ste = SteParams::for_feature(feature);
        Self {
            ste,
            sensor,
            sensor_noise: true,
            robot: RobotParams::default(),
            planner: PlannerKind::BeliefClustering,
            termination: Termination::for_params(&ste),
            warmup_s: 60.0,
        }
    }
}

/// What happened in one iteration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IterationRecord {
    /// 1-based iteration.
    pub iteration: usize,
    /// The goal the robot drove to.
    pub goal: [f64; 2],
    /// Length of the driven path (m).
    pub path_m: f64,
    /// Readings so far.
    pub samples: usize,
    /// Posterior entropy after the update (nats).
    pub entropy: f64,
    /// Goodness of fit after the update ([`crate::ste::posterior::Estimator::fit`]).
    pub fit: Option<f64>,
    /// MAP estimate after the update.
    pub estimate: [f64; 2],
    /// Posterior of every candidate after the update (kept only when asked for pictures).
    #[serde(skip)]
    pub posterior: Option<Vec<f64>>,
    /// Robot poses so far (kept with the posterior).
    #[serde(skip)]
    pub trajectory_len: usize,
}

/// The outcome of a run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Episode {
    /// True source (m).
    pub source: [f64; 2],
    /// Robot start (m).
    pub start: [f64; 2],
    /// MAP estimate at the end (m).
    pub estimate: [f64; 2],
    /// Distance from estimate to source (m).
    pub error_m: f64,
    /// Iterations run.
    pub iterations: usize,
    /// Whether the termination rule fired before the iteration limit.
    pub converged: bool,
    /// Settings used (feature, sigmas, sensor, robot, planner, termination).
    pub config: EpisodeConfig,
    /// The run's seed.
    pub seed: u64,
    /// Robot poses `[t, x, y]` every tick.
    pub trajectory: Vec<[f64; 3]>,
    /// The recorded readings.
    pub samples: Vec<Sample>,
    /// The readings' EDF values at the end (for colouring).
    pub edf: Vec<f32>,
    /// Per-iteration record.
    pub history: Vec<IterationRecord>,
    /// Final posterior over the candidates.
    pub posterior: Vec<f64>,
    /// The simple guesses beside the estimate (highest reading, arena centre), with errors.
    pub baselines: Baselines,
    /// How reality departed from the plume model.
    pub reality: Mismatch,
    /// The model wind speeds marginalised over (factors of the layout's) and their posterior
    /// at the end.
    pub wind_scales: Vec<[f64; 2]>,
    /// The spreads of the wind's direction marginalised over (degrees) and their posterior at
    /// the end.
    #[serde(default)]
    pub wind_spreads: Vec<[f64; 2]>,
    /// The background rises marginalised over (in fully mixed concentrations, see
    /// [`crate::ste::SteParams::background_rise`]) and their posterior at the end.
    #[serde(default)]
    pub backgrounds: Vec<[f64; 2]>,
    /// The posterior probability of a steady wind against a wandering one at the end, when
    /// the estimator weighs a wander ([`crate::ste::SteParams::wander_deg`]).
    #[serde(default)]
    pub steady_wind: Option<f64>,
    /// The final posterior's credible regions, expected distance from the estimate and score
    /// of the true source ([`crate::ste::Uncertainty`]; `None` in a record without it).
    #[serde(default)]
    pub uncertainty: Option<Uncertainty>,
    /// Whether the final estimate's plume reaches a reading that holds the plume
    /// ([`crate::ste::Estimator::reaches_plume`]); `None` in a record without it.
    #[serde(default)]
    pub plume_reached: Option<bool>,
    /// Wall-clock time of the run (s).
    pub wall_time_s: f64,
}

/// What `localize --json` writes: the run with the plume model's name, the likelihood's
/// standard deviations and the candidates (the posterior's cells, in its order).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunReport {
    /// The run.
    #[serde(flatten)]
    pub episode: Episode,
    /// The plume model's name.
    pub model: String,
    /// The likelihood's standard deviations.
    pub sigmas: crate::ste::Sigmas,
    /// The candidates (m), in the order of [`Episode::posterior`].
    pub candidates: Vec<[f64; 2]>,
}

/// Draws a point uniformly until `accept` takes it (at most 100 000 tries).
fn draw_point(
    layout: &Layout,
    seed: u64,
    what: &str,
    accept: impl Fn(f64, f64) -> bool,
) -> Result<[f64; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    for _ in 0..100_000 {
        let x = rng.random_range(0.0..layout.width());
        let y = rng.random_range(0.0..layout.height());
        if accept(x, y) {
            return Ok([x, y]);
        }
    }
    Err(Error::Parameter(format!(
        "no room for a {what} in the layout"
    )))
}

/// Where a random robot start may lie.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum StartRule {
    /// Anywhere the robot may be.
    #[default]
    Anywhere,
    /// Within [`DOWNWIND_BAND_M`] of the outlet, the far downwind end (where a robot entering
    /// through the outlet's door, or one searching upwind, starts).
    Downwind,
}

/// Depth (m) of the band before the outlet where [`StartRule::Downwind`] starts lie.
pub const DOWNWIND_BAND_M: f64 = 1.5;

/// A random robot start: uniform over the positions the robot may occupy that obey `rule`.
///
/// # Errors
/// [`Error::Parameter`] when the robot fits nowhere there.
pub fn random_start(
    layout: &Layout,
    robot: &RobotParams,
    rule: StartRule,
    seed: u64,
) -> Result<[f64; 2]> {
    let occupancy = Occupancy::new(layout, robot.radius_m + robot.clearance_m)?;
    let frame = Frame::of(layout);
    let length = frame.canonical_sides().0;
    draw_point(layout, seed, "robot", |x, y| {
        let near_outlet = length - frame.to_canonical(x, y).0 <= DOWNWIND_BAND_M;
        occupancy.is_free(x, y) && (rule == StartRule::Anywhere || near_outlet)
    })
}

/// A random source: uniform over free space at least [`PRIOR_BAND_M`] from the walls, the
/// inlet, the outlet and every obstacle (where the prior is non-zero).
///
/// # Errors
/// [`Error::Parameter`] when there is no such point.
pub fn random_source(layout: &Layout, seed: u64) -> Result<[f64; 2]> {
    draw_point(layout, seed, "source", |x, y| {
        layout.edge_distance(x, y) >= PRIOR_BAND_M
            && layout.obstacle_distance(x, y) >= PRIOR_BAND_M
            && layout.is_free(x, y)
    })
}

/// What steers the robot: a [`Session`] in this process, or one behind `plumenet serve`.
pub trait Steering {
    /// Sends readings; returns the number accepted so far.
    ///
    /// # Errors
    /// When the readings are refused or cannot be delivered.
    fn send_readings(&mut self, batch: &[Sample]) -> Result<usize>;

    /// Asks for an iteration from `position`.
    ///
    /// # Errors
    /// When no goal is reachable or the request cannot be delivered.
    fn iterate(&mut self, position: [f64; 2]) -> Result<Iteration>;
}

impl Steering for Session {
    fn send_readings(&mut self, batch: &[Sample]) -> Result<usize> {
        self.add_readings(batch)
    }

    fn iterate(&mut self, position: [f64; 2]) -> Result<Iteration> {
        Session::iterate(self, Some(position))
    }
}

/// One leg of a steered run, as `steer_robot` reports it.
#[derive(Debug, Clone, PartialEq)]
pub struct Leg {
    /// The goal the robot drove to.
    pub goal: [f64; 2],
    /// Length of the path driven (m).
    pub path_m: f64,
    /// Robot poses so far.
    pub trajectory_len: usize,
    /// The iteration after the leg's readings.
    pub iteration: Iteration,
}

/// Drives the robot of `field` where `steer` sends it, sensing in motion, until the session is
/// done (or after `max_iterations` legs, a guard against a planner that would stand still);
/// `leg` is told about each leg. Returns the last iteration.
///
/// # Errors
/// The steering's errors.
pub(crate) fn steer_robot<S: Steering>(
    field: &mut Field,
    robot: &RobotParams,
    max_iterations: usize,
    steer: &mut S,
    mut leg: impl FnMut(&Leg, &S),
) -> Result<Iteration> {
    let mut next = steer.iterate(field.position())?;
    // Every drive brings readings (goals lie away from the robot), so each leg is one
    // iteration.
    for _ in 0..max_iterations {
        let Some(goal) = next.goal else { break };
        let fresh = field.drive(&next.path, robot);
        steer.send_readings(&fresh)?;
        let path_m = path_length(&next.path);
        next = steer.iterate(field.position())?;
        let step = Leg {
            goal,
            path_m,
            trajectory_len: field.trajectory().len(),
            iteration: next.clone(),
        };
        leg(&step, steer);
    }
    Ok(next)
}

/// What a robot steered from elsewhere ([`simulate_robot`]) saw.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RobotRun {
    /// The last iteration (estimate, entropy, whether converged).
    pub last: Iteration,
    /// Legs driven.
    pub legs: usize,
    /// Readings sent.
    pub readings: usize,
    /// Distance from the last estimate to the source (m).
    pub error_m: f64,
}

/// Plays the robot in `reality` (filament plume, MOX sensor, motion along the goals it gets)
/// for `steer`: the same robot, plume and sensor streams of `seed` as [`run_episode`], so a
/// server with the same settings (planner seed `derive_seed(seed, 3)`) steers it to the same
/// result.
///
/// # Errors
/// [`Error::Source`] when the source is not in free space, and the steering's errors.
pub fn simulate_robot<S: Steering>(
    reality: &Reality,
    flight: &Flight,
    [source, start]: [[f64; 2]; 2],
    seed: u64,
    max_iterations: usize,
    steer: &mut S,
) -> Result<RobotRun> {
    flight.robot.check()?;
    let mut field = Field::start(reality, flight, source, start, seed)?;
    let mut legs = 0;
    let last = steer_robot(&mut field, &flight.robot, max_iterations, steer, |_, _| {
        legs += 1;
    })?;
    let error_m = (last.estimate[0] - source[0]).hypot(last.estimate[1] - source[1]);
    Ok(RobotRun {
        readings: last.readings,
        last,
        legs,
        error_m,
    })
}

/// Checks that the robot can stand at `start` in `layout`.
///
/// # Errors
/// [`Error::Source`] when `start` is closer to an obstacle or a wall than the robot's radius and
/// clearance (or outside the room); [`Error::Parameter`] for bad robot settings.
pub fn check_start(layout: &Layout, robot: &RobotParams, start: [f64; 2]) -> Result<()> {
    let keep = robot.radius_m + robot.clearance_m;
    if Occupancy::new(layout, keep)?.is_free(start[0], start[1]) {
        return Ok(());
    }
    Err(Error::Source {
        x: start[0],
        y: start[1],
        reason: format!("the robot cannot start here: keep {keep:.2} m from obstacles and walls"),
    })
}

/// Runs one localisation episode.
///
/// # Errors
/// [`Error::Source`] when the source or the start is not in free space (the start must leave
/// room for the robot), [`Error::Parameter`] for bad settings or when the planner finds no
/// reachable goal.
pub fn run_episode(
    world: &World,
    config: &EpisodeConfig,
    source: [f64; 2],
    start: [f64; 2],
    seed: u64,
    keep_posteriors: bool,
) -> Result<Episode> {
    let clock = Instant::now();
    let layout = &world.room.layout;
    config.robot.check()?;
    layout.check_source(source[0], source[1])?;
    check_start(layout, &config.robot, start)?;
    let mut field = Field::start(&world.reality, &config.flight(), source, start, seed)?;
    let mut session = Session::new(&world.room, config.session(seed))?;
    let mut history = Vec::new();
    let budget = session.budget();
    let next = steer_robot(
        &mut field,
        &config.robot,
        budget,
        &mut session,
        |step, session| {
            history.push(IterationRecord {
                iteration: step.iteration.iteration,
                goal: step.goal,
                path_m: step.path_m,
                samples: step.iteration.readings,
                entropy: step.iteration.entropy,
                fit: step.iteration.fit,
                estimate: step.iteration.estimate,
                posterior: keep_posteriors.then(|| session.estimator().posterior().to_vec()),
                trajectory_len: step.trajectory_len,
            });
        },
    )?;
    let converged = next.converged;
    let est = session.estimator();
    let samples = session.readings().to_vec();
    let estimate = est.estimate();
    let baselines = Baselines::new(layout, &samples, Some(source))?;
    Ok(Episode {
        source,
        start,
        estimate,
        error_m: (estimate[0] - source[0]).hypot(estimate[1] - source[1]),
        iterations: history.len(),
        converged,
        config: *config,
        seed,
        trajectory: field.into_trajectory(),
        samples,
        edf: est.measured_edf().to_vec(),
        history,
        posterior: est.posterior().to_vec(),
        baselines,
        reality: world.reality.mismatch(),
        wind_scales: world.room.marginal(est.bank_posterior(), |b| b.wind_scale),
        wind_spreads: world.room.marginal(est.bank_posterior(), |b| b.spread_deg),
        backgrounds: est.backgrounds(),
        steady_wind: est.steady_posterior(),
        uncertainty: Some(est.uncertainty(Some(source))),
        plume_reached: Some(est.reaches_plume(PLUME_SIGNAL_NOISES)),
        wall_time_s: clock.elapsed().as_secs_f64(),
    })
}
