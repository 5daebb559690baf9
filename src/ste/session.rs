//! A live STE session: what a robot talks to. No I/O here; `localize`'s simulated robot and
//! the `serve` protocol both drive this same type, so they cannot drift apart.
//!
//! The robot sends its readings `(t, x, y, value)` in time order, in batches of any size
//! ([`Session::add_readings`]), and asks for an iteration ([`Session::iterate`]): the posterior
//! is brought up to date with the readings that arrived since the last iteration, the
//! termination rule is checked, and unless the session is done the planner picks the next goal
//! and its path from the robot's position. An iteration without new readings only plans (the
//! first one plans from the prior).

use std::sync::Arc;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::ste::banks::{PRIOR_BAND_M, RoomBanks};
use crate::ste::credible::region_cells;
use crate::ste::planner::{Plan, Planner, PlannerKind};
use crate::ste::posterior::{Estimator, Sample, SteParams, prior_support};
use crate::ste::probe::{probe_path, probe_point, sensed};
use crate::ste::robot::{Occupancy, RobotParams};
use crate::ste::sampler::FieldSampler;
use crate::ste::termination::{PLUME_SIGNAL_NOISES, Termination};

/// Mass of the credible region an iteration reports.
pub const CREDIBLE_MASS: f64 = 0.9;

/// The settings of a session.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SessionConfig {
    /// Feature, sigmas and thresholds.
    pub ste: SteParams,
    /// The planner.
    pub planner: PlannerKind,
    /// The stopping rule.
    pub termination: Termination,
    /// The robot (its size decides where it may drive and the prior's inflation).
    pub robot: RobotParams,
    /// Seed of the planner's random draws.
    pub planner_seed: u64,
    /// Keep only about the most recent this many readings, so that memory stays flat in a
    /// session of hours: the posterior uses the readings from the start of the half-window
    /// block that holds the `N`-th latest (between `N` and `1.5 N` of them), so the oldest half
    /// window is dropped at a time and the window depends only on how many readings came.
    /// `None` keeps them all, the paper's form.
    pub max_readings: Option<usize>,
}

/// What an iteration reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Iteration {
    /// Posterior updates so far (iterations with new readings).
    pub iteration: usize,
    /// Readings accepted so far.
    pub readings: usize,
    /// The MAP estimate (m).
    pub estimate: [f64; 2],
    /// Posterior entropy (nats).
    pub entropy: f64,
    /// Goodness of fit of the most probable candidate ([`Estimator::fit`]): about 1 or below
    /// when it explains the readings; `None` before the first reading.
    pub fit: Option<f64>,
    /// How far the highest reading stands above the readings' median, in noise levels
    /// ([`Estimator::plume_signal`]): below [`PLUME_SIGNAL_NOISES`] the robot has met no
    /// plume yet, and the default rule does not stop.
    #[serde(default)]
    pub plume_signal: f64,
    /// Whether the estimate's plume reaches a reading that holds the plume
    /// ([`Estimator::reaches_plume`]): the default rule does not stop while it does not.
    /// A reply without it reads as `false`.
    #[serde(default)]
    pub plume_reached: bool,
    /// The candidates of the smallest set holding 90% of the posterior, most probable first.
    pub credible_region: Vec<[f64; 2]>,
    /// Where the robot must sense before the run may stop ([`crate::ste::probe`]): set when
    /// the rest of the rule holds and the robot has not sensed there yet; the path then runs
    /// upwind beyond it and back through it to the estimate, the goal. A reply without it
    /// reads as `None`.
    #[serde(default)]
    pub probe: Option<[f64; 2]>,
    /// Whether the termination rule holds.
    pub converged: bool,
    /// Whether the session is over: converged, or at the iteration limit.
    pub done: bool,
    /// The next goal (none once done).
    pub goal: Option<[f64; 2]>,
    /// The planned path from the robot's position to the goal (empty once done).
    pub path: Vec<[f64; 2]>,
}

/// A live session over one room's banks.
#[derive(Debug, Clone)]
pub struct Session {
    config: SessionConfig,
    samplers: Vec<Arc<FieldSampler>>,
    support: Vec<bool>,
    occupancy: Occupancy,
    est: Estimator,
    planner: Planner,
    readings: Vec<Sample>,
    /// Index (in arrival order) of `readings[0]`.
    first: usize,
    accepted: usize,
    pending: usize,
    iterations: usize,
    converged: bool,
    /// The upwind probe the last update left to sense before the run may stop.
    probe: Option<[f64; 2]>,
    recent: Vec<(bool, [f64; 2])>,
}

impl Session {
    /// A fresh session (uniform prior, no readings) over `room`'s banks.
    ///
    /// # Errors
    /// [`Error::Parameter`] for bad robot, STE or stopping settings, or a layout with no room for the
    /// robot or no candidate in the prior.
    pub fn new(room: &RoomBanks, config: SessionConfig) -> Result<Self> {
        config.robot.check()?;
        let layout = &room.layout;
        config.termination.check(layout.width() * layout.height())?;
        let occupancy = Occupancy::new(layout, config.robot.radius_m + config.robot.clearance_m)?;
        let support = prior_support(
            layout,
            room.sampler.candidates(),
            config.robot.radius_m,
            PRIOR_BAND_M,
        )?;
        Self::start(config, room.samplers(), support, occupancy)
    }

    /// A session at its start (uniform prior, no readings), from its parts.
    fn start(
        config: SessionConfig,
        samplers: Vec<Arc<FieldSampler>>,
        support: Vec<bool>,
        occupancy: Occupancy,
    ) -> Result<Self> {
        Ok(Self {
            est: Estimator::with_banks(samplers.clone(), &support, config.ste)?,
            planner: Planner::new(config.planner, &config.robot, config.planner_seed),
            config,
            samplers,
            support,
            occupancy,
            readings: Vec::new(),
            first: 0,
            accepted: 0,
            pending: 0,
            iterations: 0,
            converged: false,
            probe: None,
            recent: Vec::new(),
        })
    }

    /// The layout.
    pub fn layout(&self) -> &Layout {
        self.samplers[0].layout()
    }

    /// The estimator (posterior, candidates, readings' features) as of the last iteration.
    pub fn estimator(&self) -> &Estimator {
        &self.est
    }

    /// The readings the posterior uses (every one accepted, or the most recent
    /// [`SessionConfig::max_readings`] of them after an update), in time order.
    pub fn readings(&self) -> &[Sample] {
        &self.readings
    }

    /// Where the robot may drive.
    pub fn occupancy(&self) -> &Occupancy {
        &self.occupancy
    }

    /// Checks a batch of readings without taking it: every reading finite, inside the arena
    /// and no earlier than the one before it.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the first reading that is not finite, lies outside the arena
    /// or goes back in time.
    pub fn check_readings(&self, batch: &[Sample]) -> Result<()> {
        let layout = self.layout();
        let mut last_t = self.readings.last().map_or(f64::NEG_INFINITY, |s| s.t);
        for (k, s) in batch.iter().enumerate() {
            let bad = |why: &str| {
                Err(Error::Parameter(format!(
                    "reading {k} of the batch (t {}, x {}, y {}, value {}) {why}",
                    s.t, s.x, s.y, s.value
                )))
            };
            if ![s.t, s.x, s.y, s.value].iter().all(|v| v.is_finite()) {
                return bad("is not finite");
            }
            if !(0.0..=layout.width()).contains(&s.x) || !(0.0..=layout.height()).contains(&s.y) {
                return bad("lies outside the arena");
            }
            if s.t < last_t {
                return bad("goes back in time");
            }
            last_t = s.t;
        }
        Ok(())
    }

    /// Accepts a batch of readings and returns the number accepted so far. The batch is
    /// checked whole first ([`Session::check_readings`]): on error nothing is added.
    ///
    /// # Errors
    /// As [`Session::check_readings`].
    pub fn add_readings(&mut self, batch: &[Sample]) -> Result<usize> {
        self.check_readings(batch)?;
        self.readings.extend_from_slice(batch);
        self.pending += batch.len();
        self.accepted += batch.len();
        Ok(self.accepted)
    }

    /// Runs an iteration: updates the posterior with the readings since the last one (when
    /// there are any: that counts as an iteration and checks the termination rule), then,
    /// unless the session is done, plans the next goal from `position` (by default the last
    /// reading's position).
    ///
    /// # Errors
    /// [`Error::Parameter`] when there is no position to plan from (no reading and none
    /// given), or when no goal is reachable from it.
    pub fn iterate(&mut self, position: Option<[f64; 2]>) -> Result<Iteration> {
        self.update()?;
        self.plan(position)
    }

    /// The first half of an iteration: brings the posterior up to date with the readings since
    /// the last one and checks the termination rule (nothing happens without new readings).
    ///
    /// # Errors
    /// None in practice: the readings were checked when they arrived.
    pub fn update(&mut self) -> Result<()> {
        if self.pending > 0 {
            let start = self.config.max_readings.map_or(0, |cap| {
                let block = (cap / 2).max(1);
                self.accepted.saturating_sub(cap) / block * block
            });
            if start > self.first {
                // The window moved on: the posterior of the readings from `start` on, rebuilt.
                self.readings.drain(..start - self.first);
                self.first = start;
                self.est =
                    Estimator::with_banks(self.samplers.clone(), &self.support, self.config.ste)?;
                self.est.update(&self.readings)?;
            } else {
                let fresh = &self.readings[self.readings.len() - self.pending..];
                self.est.update(fresh)?;
            }
            self.pending = 0;
            self.iterations += 1;
            let holds = self.config.termination.converged(&self.est, &self.recent);
            self.probe = holds.then(|| self.unsensed_probe()).flatten();
            self.converged = holds && self.probe.is_none();
            if !self.converged {
                self.recent.push((
                    self.config.termination.concentrated(&self.est),
                    self.est.estimate(),
                ));
            }
        }
        Ok(())
    }

    fn plan(&mut self, position: Option<[f64; 2]>) -> Result<Iteration> {
        let done = self.converged || self.iterations >= self.budget();
        let plan = if done {
            None
        } else {
            let from = position
                .or_else(|| self.readings.last().map(|s| [s.x, s.y]))
                .ok_or_else(|| {
                    Error::Parameter(
                        "no position to plan from: send a reading or the robot's position".into(),
                    )
                })?;
            // The probe's leg, where the robot can drive there; the planner's otherwise.
            let probe = self.probe.and_then(|point| {
                let goal = self.est.estimate();
                let path = probe_path(self.layout(), &self.occupancy, from, point, goal)?;
                Some(Plan {
                    goal,
                    path,
                    score: 0.0,
                })
            });
            Some(match probe {
                Some(plan) => plan,
                None => self.planner.next(&self.est, &self.occupancy, from)?,
            })
        };
        let candidates = self.est.candidates();
        Ok(Iteration {
            iteration: self.iterations,
            readings: self.accepted,
            estimate: self.est.estimate(),
            entropy: self.est.entropy(),
            fit: self.est.fit(),
            plume_signal: self.est.plume_signal(),
            plume_reached: self.est.reaches_plume(PLUME_SIGNAL_NOISES),
            credible_region: region_cells(candidates, self.est.posterior(), CREDIBLE_MASS),
            probe: self.probe,
            converged: self.converged,
            done,
            goal: plan.as_ref().map(|p| p.goal),
            path: plan.map_or_else(Vec::new, |p| p.path),
        })
    }

    /// The upwind probe of the estimate ([`Termination::upwind_probe_m`]) when the robot has
    /// not sensed there yet and can drive there from its last reading; `None` otherwise.
    fn unsensed_probe(&self) -> Option<[f64; 2]> {
        let distance = self.config.termination.upwind_probe_m?;
        let point = probe_point(
            self.layout(),
            &self.occupancy,
            self.est.estimate(),
            distance,
        )?;
        let last = self.readings.last()?;
        (!sensed(&self.readings, point) && self.occupancy.plan([last.x, last.y], point).is_some())
            .then_some(point)
    }

    /// The iteration limit in this room ([`Termination::budget`] of its free floor).
    pub fn budget(&self) -> usize {
        let layout = self.samplers[0].layout();
        self.config.termination.budget(layout.free_area_m2())
    }

    /// Forgets every reading and starts again from the prior (the planner's random stream
    /// starts again too).
    ///
    /// # Errors
    /// None in practice: the settings were checked when the session was made.
    pub fn reset(&mut self) -> Result<()> {
        *self = Self::start(
            self.config,
            self.samplers.clone(),
            self.support.clone(),
            self.occupancy.clone(),
        )?;
        Ok(())
    }
}
