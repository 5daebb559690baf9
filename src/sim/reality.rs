//! The simulated reality a robot senses, the ways it may depart from the plume model, and the
//! robot, plume and sensor advancing together tick by tick.
//!
//! By default reality is the filament plume of [`crate::physics::filament`] in the layout's own
//! wind, whose time average is exactly the plume model. A [`Mismatch`] makes it differ the ways
//! real rooms do: the wind is faster or slower than the layout says, turbulence spreads the gas
//! more or less than the model's diffusivity, the wind direction wanders, and gas that left the
//! plume recirculates into a background. The model side (the bank) never sees any of it.

use std::fmt;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::physics::filament::{FilamentConfig, FilamentPlume};
use crate::physics::wind::WindField;
use crate::sim::seed::derive_seed;
use crate::ste::posterior::Sample;
use crate::ste::robot::{RobotParams, Sampling, path_length, point_at};
use crate::ste::sensor::{MoxSensor, SensorPreset};

/// How long the robot stands at its start before the run, sensing (s): about four recovery
/// time constants, so the sensor has settled.
pub const SENSOR_SETTLE_S: f64 = 20.0;

/// How reality departs from the plume model (every knob neutral by default).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Mismatch {
    /// Reality's inlet wind speed as a multiple of the layout's.
    pub wind_scale: f64,
    /// Reality's diffusivity as a multiple of the layout's.
    pub diffusivity_scale: f64,
    /// Standard deviation of the wind direction's wander (degrees, 20 s correlation time).
    pub meander_deg: f64,
    /// The wander turns only the flow the room's walls let through
    /// ([`crate::physics::wind::WindField::crosswind`]), not the whole field (a record without
    /// this field reads as `false`, the whole field).
    #[serde(default)]
    pub meander_walled: bool,
    /// Recirculated background, in units of the fully mixed concentration `q / (U H)`, rising
    /// with a 60 s time constant after the release starts.
    pub background: f64,
}

impl Default for Mismatch {
    fn default() -> Self {
        Self::NONE
    }
}

impl Mismatch {
    /// Reality is the plume model on average.
    pub const NONE: Mismatch = Mismatch {
        wind_scale: 1.0,
        diffusivity_scale: 1.0,
        meander_deg: 0.0,
        meander_walled: false,
        background: 0.0,
    };

    /// The strong settings of the mismatch suite, each knob alone: the wind at half the
    /// layout's speed, three times the diffusivity, a 30 degree wander, and a background as
    /// high as the fully mixed concentration.
    pub const STRONG: [Mismatch; 4] = [
        Mismatch {
            wind_scale: 0.5,
            ..Mismatch::NONE
        },
        Mismatch {
            diffusivity_scale: 3.0,
            ..Mismatch::NONE
        },
        Mismatch {
            meander_deg: 30.0,
            ..Mismatch::NONE
        },
        Mismatch {
            background: 1.0,
            ..Mismatch::NONE
        },
    ];

    /// The mismatch suite of `experiment --mismatch`: none, each strong knob alone, and all of
    /// them together.
    pub fn suite() -> Vec<Mismatch> {
        let [w, d, m, b] = Self::STRONG;
        vec![
            Self::NONE,
            w,
            d,
            m,
            b,
            Mismatch {
                wind_scale: w.wind_scale,
                diffusivity_scale: d.diffusivity_scale,
                meander_deg: m.meander_deg,
                meander_walled: m.meander_walled,
                background: b.background,
            },
        ]
    }

    /// Whether every knob is neutral.
    pub fn is_none(&self) -> bool {
        *self == Self::NONE
    }

    /// Validates the knobs.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the flag for a non-positive or non-finite scale, a wander
    /// outside 0-90 degrees, or a negative background.
    pub fn check(&self) -> Result<()> {
        let bad = |msg: String| Err(Error::Parameter(msg));
        for (flag, v) in [
            ("--reality-wind-scale", self.wind_scale),
            ("--reality-diffusivity-scale", self.diffusivity_scale),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return bad(format!("{flag} must be a positive number, got {v}"));
            }
        }
        if !(0.0..=90.0).contains(&self.meander_deg) {
            return bad(format!(
                "--reality-meander-deg must be between 0 and 90 degrees, got {}",
                self.meander_deg
            ));
        }
        if self.meander_walled && self.meander_deg == 0.0 {
            return bad("--reality-meander-walled needs a wander (--reality-meander-deg)".into());
        }
        if !(self.background.is_finite() && self.background >= 0.0) {
            return bad(format!(
                "--reality-background must be zero or positive, got {}",
                self.background
            ));
        }
        Ok(())
    }
}

impl fmt::Display for Mismatch {
    /// A short label: `none`, or the knobs that are on, e.g. `wind x0.5, meander 30°`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut parts = Vec::new();
        if self.wind_scale != 1.0 {
            parts.push(format!("wind x{}", self.wind_scale));
        }
        if self.diffusivity_scale != 1.0 {
            parts.push(format!("diffusivity x{}", self.diffusivity_scale));
        }
        if self.meander_deg != 0.0 {
            let walled = if self.meander_walled { " walled" } else { "" };
            parts.push(format!("meander {}°{walled}", self.meander_deg));
        }
        if self.background != 0.0 {
            parts.push(format!("background {}", self.background));
        }
        if parts.is_empty() {
            write!(f, "none")
        } else {
            write!(f, "{}", parts.join(", "))
        }
    }
}

/// Reality of one layout under one mismatch: its own wind and diffusivity, and the filament
/// settings that add the wander and the background.
#[derive(Debug, Clone)]
pub struct Reality {
    layout: Layout,
    wind: WindField,
    /// The wind's crosswind, for a walled wander (computed once for all its plumes).
    crosswind: Option<WindField>,
    mismatch: Mismatch,
}

impl Reality {
    /// Reality of `layout`, whose own wind field (the one the plume model assumes) is `wind`;
    /// the wind is solved again only when the mismatch changes its speed.
    ///
    /// # Errors
    /// The mismatch's [`Mismatch::check`] errors, and the wind solver's.
    pub fn new(layout: &Layout, wind: &WindField, mismatch: Mismatch) -> Result<Self> {
        mismatch.check()?;
        let (layout, wind) = if mismatch.wind_scale == 1.0 && mismatch.diffusivity_scale == 1.0 {
            (layout.clone(), wind.clone())
        } else {
            let mut spec = layout.spec().clone();
            spec.wind.speed_mps *= mismatch.wind_scale;
            spec.diffusivity_m2ps = Some(layout.diffusivity() * mismatch.diffusivity_scale);
            let real = spec.check()?;
            let wind = if mismatch.wind_scale == 1.0 {
                wind.clone()
            } else {
                WindField::solve(&real)?
            };
            (real, wind)
        };
        let crosswind = match mismatch.meander_walled {
            true => Some(wind.crosswind(&layout)?),
            false => None,
        };
        Ok(Self {
            layout,
            wind,
            crosswind,
            mismatch,
        })
    }

    /// How this reality departs from the model.
    pub fn mismatch(&self) -> Mismatch {
        self.mismatch
    }

    /// Reality's layout: the model's, with the mismatch's wind speed and diffusivity.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// A filament plume of this reality from `source`, stepping every `dt_s`.
    ///
    /// # Errors
    /// [`Error::Source`] when the source is not in free space.
    pub fn plume(&self, source: [f64; 2], dt_s: f64, seed: u64) -> Result<FilamentPlume> {
        let config = FilamentConfig {
            dt_s,
            meander_deg: self.mismatch.meander_deg,
            meander_walled: self.mismatch.meander_walled,
            background: self.mismatch.background,
            ..FilamentConfig::default()
        };
        FilamentPlume::with_crosswind(
            &self.layout,
            &self.wind,
            self.crosswind.as_ref(),
            (source[0], source[1]),
            config,
            seed,
        )
    }
}

/// How the robot senses reality: its sensor, and how it moves.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Flight {
    /// The sensor.
    pub sensor: SensorPreset,
    /// Whether the sensor is noisy.
    pub sensor_noise: bool,
    /// The robot (its speed, tick and sampling).
    pub robot: RobotParams,
    /// Plume time before the robot starts (s).
    pub warmup_s: f64,
}

/// The robot, the plume it senses and the sensor, advancing together tick by tick.
pub(crate) struct Field {
    plume: FilamentPlume,
    sensor: MoxSensor,
    noise: ChaCha8Rng,
    tick: f64,
    time: f64,
    position: [f64; 2],
    trajectory: Vec<[f64; 3]>,
}

impl Field {
    /// Releases gas at `source` in `reality` and warms the plume up for the flight's warm-up,
    /// the last [`SENSOR_SETTLE_S`] of it with the robot sensing at `start`
    /// (so its sensor is in equilibrium with the air there), then starts the clock at 0 with
    /// the robot at `start`. The plume and the sensor noise draw from streams 1 and 2 of `seed`.
    ///
    /// # Errors
    /// [`Error::Source`] when the source is not in free space, and bad sensor settings.
    pub(crate) fn start(
        reality: &Reality,
        flight: &Flight,
        source: [f64; 2],
        start: [f64; 2],
        seed: u64,
    ) -> Result<Self> {
        let mut plume = reality.plume(source, flight.robot.tick_s, derive_seed(seed, 1))?;
        let settle = SENSOR_SETTLE_S.min(flight.warmup_s);
        plume.advance(flight.warmup_s - settle);
        let mut field = Field {
            plume,
            sensor: MoxSensor::preset(flight.sensor, flight.sensor_noise)?,
            noise: ChaCha8Rng::seed_from_u64(derive_seed(seed, 2)),
            tick: flight.robot.tick_s,
            time: 0.0,
            position: start,
            trajectory: Vec::new(),
        };
        for _ in 0..(settle / flight.robot.tick_s).round() as usize {
            field.tick(start);
        }
        field.time = 0.0;
        field.trajectory = vec![[0.0, start[0], start[1]]];
        Ok(field)
    }

    /// Where the robot is.
    pub(crate) fn position(&self) -> [f64; 2] {
        self.position
    }

    /// The robot's poses `[t, x, y]` so far.
    pub(crate) fn trajectory(&self) -> &[[f64; 3]] {
        &self.trajectory
    }

    /// Ends the run, giving back the poses.
    pub(crate) fn into_trajectory(self) -> Vec<[f64; 3]> {
        self.trajectory
    }

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
    pub(crate) fn drive(&mut self, path: &[[f64; 2]], robot: &RobotParams) -> Vec<Sample> {
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
