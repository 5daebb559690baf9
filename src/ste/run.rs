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
use crate::physics::filament::{FilamentConfig, FilamentPlume};
use crate::physics::wind::WindField;
use crate::plume::{PlumeModel, cached_bank};
use crate::ste::features::Feature;
use crate::ste::planner::{Planner, PlannerKind};
use crate::ste::posterior::{Estimator, Sample, SteParams, Termination, prior_support};
use crate::ste::robot::{Occupancy, RobotParams, Sampling, path_length, point_at};
use crate::ste::sampler::FieldSampler;
use crate::ste::sensor::{MoxSensor, SensorPreset};

/// Width of the boundary band the prior excludes (m): one candidate spacing.
pub const PRIOR_BAND_M: f64 = 0.25;

/// How long the robot stands at its start before the run, sensing (s): about four recovery
/// time constants, so the sensor has settled.
pub const SENSOR_SETTLE_S: f64 = 20.0;

/// The world a run happens in: the layout, its wind and the plume bank of the model.
#[derive(Debug, Clone)]
pub struct World {
    /// The arena.
    pub layout: Layout,
    /// Its steady wind (drives the filament plume).
    pub wind: WindField,
    /// The plume model's bank, ready for sampling.
    pub sampler: Arc<FieldSampler>,
}

impl World {
    /// Solves the layout's wind and gets the model's bank over the candidate grid of spacing
    /// `spacing_m`, from the cache directory when given (see [`cached_bank`]). Also returns
    /// whether the bank came from the cache.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a bad spacing or a layout without candidates, the solvers' and
    /// the model's errors, and cache write failures.
    pub fn build(
        layout: Layout,
        model: &dyn PlumeModel,
        spacing_m: f64,
        cache: Option<&Path>,
    ) -> Result<(Self, bool)> {
        let candidates = layout.candidates(spacing_m)?;
        if candidates.is_empty() {
            return Err(Error::Parameter(format!(
                "the layout has no free candidate cell at spacing {spacing_m} m"
            )));
        }
        let (bank, hit) = match cache {
            Some(dir) => cached_bank(model, &layout, &candidates, dir)?,
            None => (model.bank(&layout, &candidates)?, false),
        };
        let sampler = Arc::new(FieldSampler::new(&layout, &bank)?);
        let wind = WindField::solve(&layout)?;
        Ok((
            Self {
                layout,
                wind,
                sampler,
            },
            hit,
        ))
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
    /// The defaults: sense-in-motion, belief clustering, a noisy sensor, 60 s warm-up.
    pub fn new(feature: Feature, sensor: SensorPreset) -> Self {
        Self {
            ste: SteParams::for_feature(feature),
            sensor,
            sensor_noise: true,
            robot: RobotParams::default(),
            planner: PlannerKind::BeliefClustering,
            termination: Termination::default(),
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
    /// Wall-clock time of the run (s).
    pub wall_time_s: f64,
}

/// A seed for stream `stream` of a run seed (SplitMix64 finaliser, so nearby seeds diverge).
pub fn derive_seed(seed: u64, stream: u64) -> u64 {
    let mut z = seed
        .wrapping_add(stream.wrapping_mul(0x9E37_79B9_7F4A_7C15))
        .wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
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

/// The robot, the plume it senses and the sensor, advancing together tick by tick.
struct Field {
    plume: FilamentPlume,
    sensor: MoxSensor,
    noise: ChaCha8Rng,
    tick: f64,
    time: f64,
    position: [f64; 2],
    trajectory: Vec<[f64; 3]>,
}

impl Field {
    /// One tick at `position`: the plume moves, the robot is there, the sensor reads.
    fn tick(&mut self, position: [f64; 2]) -> Sample {
        self.plume.step();
        self.time += self.tick;
        self.position = position;
        self.trajectory.push([self.time, position[0], position[1]]);
        let c = self.plume.concentration_at(position[0], position[1]);
        let value = self.sensor.sample(c, self.tick, &mut self.noise);
        Sample {
            t: self.time,
            x: position[0],
            y: position[1],
            value,
        }
    }

    /// Drives a path and returns the recorded readings.
    fn drive(&mut self, path: &[[f64; 2]], robot: &RobotParams) -> Vec<Sample> {
        let len = path_length(path);
        let step = robot.max_speed_mps * robot.tick_s;
        let ticks = (len / step).ceil() as usize;
        match robot.sampling {
            Sampling::InMotion => (1..=ticks)
                .map(|k| self.tick(point_at(path, (k as f64 * step).min(len))))
                .collect(),
            Sampling::StopSenseGo {
                spacing_m,
                settle_s,
                dwell_s,
            } => {
                let stops = (len / spacing_m).ceil().max(1.0) as usize;
                let mut out = Vec::with_capacity(stops);
                let mut s = 0.0;
                for k in 1..=stops {
                    let target = (k as f64 * spacing_m).min(len);
                    while s < target {
                        s = (s + step).min(target);
                        self.tick(point_at(path, s));
                    }
                    let here = point_at(path, target);
                    for _ in 0..(settle_s / robot.tick_s).round() as usize {
                        self.tick(here);
                    }
                    let n = ((dwell_s / robot.tick_s).round() as usize).max(1);
                    let mean = (0..n).map(|_| self.tick(here).value).sum::<f64>() / n as f64;
                    out.push(Sample {
                        t: self.time,
                        x: here[0],
                        y: here[1],
                        value: mean,
                    });
                }
                out
            }
        }
    }
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
    let layout = &world.layout;
    config.robot.check()?;
    layout.check_source(source[0], source[1])?;
    let occupancy = Occupancy::new(layout, config.robot.radius_m + config.robot.clearance_m)?;
    if !occupancy.is_free(start[0], start[1]) {
        return Err(Error::Source {
            x: start[0],
            y: start[1],
            reason: format!(
                "the robot cannot start here: keep {} m from obstacles and walls",
                config.robot.radius_m + config.robot.clearance_m
            ),
        });
    }
    let filaments = FilamentConfig {
        dt_s: config.robot.tick_s,
        ..FilamentConfig::default()
    };
    let mut plume = FilamentPlume::new(
        layout,
        &world.wind,
        (source[0], source[1]),
        filaments,
        derive_seed(seed, 1),
    )?;
    // The robot waits at its start for the last part of the warm-up, so that its sensor is in
    // equilibrium with the air there when the run begins.
    let settle = SENSOR_SETTLE_S.min(config.warmup_s);
    plume.advance(config.warmup_s - settle);
    let mut field = Field {
        plume,
        sensor: MoxSensor::preset(config.sensor, config.sensor_noise)?,
        noise: ChaCha8Rng::seed_from_u64(derive_seed(seed, 2)),
        tick: config.robot.tick_s,
        time: 0.0,
        position: start,
        trajectory: Vec::new(),
    };
    for _ in 0..(settle / config.robot.tick_s).round() as usize {
        field.tick(start);
    }
    field.time = 0.0;
    field.trajectory = vec![[0.0, start[0], start[1]]];
    let support = prior_support(
        layout,
        world.sampler.candidates(),
        config.robot.radius_m,
        PRIOR_BAND_M,
    )?;
    let mut est = Estimator::new(world.sampler.clone(), &support, config.ste)?;
    let mut planner = Planner::new(config.planner, derive_seed(seed, 3));
    let mut history = Vec::new();
    let mut samples = Vec::new();
    let mut converged = false;
    let mut recent = Vec::new();
    for iteration in 1..=config.termination.max_iterations {
        let plan = planner.next(&est, &occupancy, field.position)?;
        let fresh = field.drive(&plan.path, &config.robot);
        est.update(&fresh)?;
        samples.extend(fresh);
        history.push(IterationRecord {
            iteration,
            goal: plan.goal,
            path_m: path_length(&plan.path),
            samples: samples.len(),
            entropy: est.entropy(),
            estimate: est.estimate(),
            posterior: keep_posteriors.then(|| est.posterior().to_vec()),
            trajectory_len: field.trajectory.len(),
        });
        if config.termination.converged(&est, &recent) {
            converged = true;
            break;
        }
        recent.push((config.termination.concentrated(&est), est.estimate()));
    }
    let estimate = est.estimate();
    Ok(Episode {
        source,
        start,
        estimate,
        error_m: (estimate[0] - source[0]).hypot(estimate[1] - source[1]),
        iterations: history.len(),
        converged,
        config: *config,
        seed,
        trajectory: field.trajectory,
        samples,
        edf: est.measured_edf().to_vec(),
        history,
        posterior: est.posterior().to_vec(),
        wall_time_s: clock.elapsed().as_secs_f64(),
    })
}
