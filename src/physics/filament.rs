//! The intermittent "reality" plume the robot senses: a Farrell-style filament model.
//!
//! Filaments (puffs) leave the source at a fixed rate, each carrying `rate / release_rate_hz`
//! units. Every time step a filament is advected by the mean wind (midpoint rule on the
//! interpolated staggered field) and takes an independent Gaussian random-walk step of
//! diffusivity `walk_fraction * D`; its own Gaussian width grows as
//! `sigma^2 = sigma_0^2 + 2 (1 - walk_fraction) D age`. The two parts add up to the layout's
//! diffusivity `D`, so the ensemble (time) average of the instantaneous field solves the same
//! advection-diffusion equation as [`crate::physics::transport`]: in uniform wind the average of
//! a Gaussian puff whose centre wanders with variance `2 D_w t` and whose width grows as
//! `2 D_g t` is the Green's function with `D = D_w + D_g`. Single readings, by contrast, see a few
//! narrow puffs at a time and are intermittent, like a real plume.
//!
//! The defaults (8 filaments/s, 5 cm initial width, 95% of `D` in the walk) make readings a few
//! metres downwind intermittent while a sensor's long-run average stays near the mean field
//! (the tests bound both).
//!
//! Two departures from the mean field are available for sim-to-real studies, both off by
//! default: the wind direction may wander (an Ornstein-Uhlenbeck angle, with standard deviation
//! `meander_deg` and correlation time `meander_time_s`, turns the velocity that advects every
//! filament: the whole field, walls included, or with `meander_walled` only what the walls let
//! through, [`WindField::crosswind`]), and a uniform background of recirculated gas may build
//! up in free space, rising as `background * q / (U H) * (1 - exp(-t / background_time_s))`
//! where `q / (U H)` is the fully mixed concentration (release rate over inlet speed times
//! arena width across the wind).
//!
//! Side walls and obstacle faces reflect filaments (and the side walls reflect their kernels by
//! images, so no mass leaks through a wall); filaments leave through the inlet (c = 0 there) and
//! the outlet. Gas never passes through an obstacle, however thin:
//! - a filament's move whose path passes an obstacle is taken in sub-steps of at most half a
//!   cell, each reflected off the obstacle face it crosses, so a long random-walk step cannot
//!   jump over a wall one or two cells thick;
//! - a kernel counts at a point only if the filament sees it: the segment between them crosses no
//!   obstacle cell (sampled every half cell, so no wall a cell thick is missed). The images across
//!   the side walls share their filament's line of sight;
//! - a kernel stops widening at `max_sigma_m`, after which the walk carries all of `D` (the
//!   ensemble average is unchanged, since `D_w + D_g = D` at every age), so that old filaments
//!   in slow dead zones do not grow into metre-wide kernels whose shadowed part the line of sight
//!   throws away.
//!
//! Every random draw comes from a seeded ChaCha8 generator; the sub-steps and the cap reuse the
//! draws of the whole step, so the random stream is the same as without them.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};

use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::physics::wind::WindField;

/// Settings of the filament model.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilamentConfig {
    /// Source release rate (units/s), the same unit rate as the mean field by default.
    pub source_rate: f64,
    /// Filaments released per second.
    pub release_rate_hz: f64,
    /// Share of the diffusivity carried by the filaments' random walk (the rest widens them).
    pub walk_fraction: f64,
    /// Initial filament width (m).
    pub initial_sigma_m: f64,
    /// Largest filament width (m): past it the kernel stops widening and the random walk
    /// carries the whole diffusivity.
    pub max_sigma_m: f64,
    /// Integration time step (s); 0.1 s matches the sensor's 10 Hz.
    pub dt_s: f64,
    /// Standard deviation of the wind direction's wander (degrees, at most 90; 0 keeps the
    /// direction steady, as the plume model assumes).
    pub meander_deg: f64,
    /// Correlation time of the wander (s).
    pub meander_time_s: f64,
    /// The wander turns only what the room's walls let through: the wind turned by `a` is
    /// `cos a * wind + sin a * crosswind` ([`WindField::crosswind`]), which never blows
    /// through a wall or an obstacle. Otherwise (the default) the whole field is rotated,
    /// walls included, and filaments pushed into a wall pile up against it.
    pub meander_walled: bool,
    /// Final level of the recirculated background, in units of the fully mixed concentration
    /// `q / (U H)` (0 = none).
    pub background: f64,
    /// Time constant of the background's rise after the release starts (s).
    pub background_time_s: f64,
}

impl Default for FilamentConfig {
    fn default() -> Self {
        Self {
            source_rate: 1.0,
            release_rate_hz: 8.0,
            walk_fraction: 0.95,
            initial_sigma_m: 0.05,
            max_sigma_m: 0.5,
            dt_s: 0.1,
            meander_deg: 0.0,
            meander_time_s: 20.0,
            meander_walled: false,
            background: 0.0,
            background_time_s: 60.0,
        }
    }
}

#[derive(Debug, Clone, Copy)]
struct Filament {
    x: f64,
    y: f64,
    age: f64,
}

/// A running filament plume. It runs in the layout's canonical frame ([`crate::frame`]), where
/// the inlet is the west wall; positions are turned in and out of it.
#[derive(Debug, Clone)]
pub struct FilamentPlume {
    frame: Frame,
    /// The canonical layout.
    layout: Layout,
    /// The canonical wind.
    wind: WindField,
    source: (f64, f64),
    config: FilamentConfig,
    filaments: Vec<Filament>,
    time: f64,
    pending: f64,
    /// The wind direction's current deviation (rad).
    meander: f64,
    /// The canonical crosswind of a walled wander.
    crosswind: Option<WindField>,
    rng: ChaCha8Rng,
}

impl FilamentPlume {
    /// Starts an empty plume (no filaments yet) at time 0.
    ///
    /// # Errors
    /// [`Error::Source`] when the source is not in free space; [`Error::Parameter`] for
    /// non-positive rates, widths, time step or time constants, a largest width below the
    /// initial one, a walk fraction outside `[0, 1]`, a meander outside `[0, 90]` degrees or a
    /// negative background.
    pub fn new(
        layout: &Layout,
        wind: &WindField,
        source: (f64, f64),
        config: FilamentConfig,
        seed: u64,
    ) -> Result<Self> {
        Self::with_crosswind(layout, wind, None, source, config, seed)
    }

    /// As [`FilamentPlume::new`], with the layout's [`WindField::crosswind`] of `wind` when the
    /// caller already has it (a walled wander computes it otherwise; it is not used unless
    /// the wander is walled), so that many plumes of one room share one projection.
    ///
    /// # Errors
    /// As [`FilamentPlume::new`].
    pub fn with_crosswind(
        layout: &Layout,
        wind: &WindField,
        crosswind: Option<&WindField>,
        source: (f64, f64),
        config: FilamentConfig,
        seed: u64,
    ) -> Result<Self> {
        layout.check_source(source.0, source.1)?;
        let positive = [
            config.source_rate,
            config.release_rate_hz,
            config.initial_sigma_m,
            config.dt_s,
            config.meander_time_s,
            config.background_time_s,
        ];
        let valid = positive.iter().all(|v| v.is_finite() && *v > 0.0)
            && config.max_sigma_m >= config.initial_sigma_m
            && (0.0..=1.0).contains(&config.walk_fraction)
            && (0.0..=90.0).contains(&config.meander_deg)
            && config.background.is_finite()
            && config.background >= 0.0;
        if !valid {
            return Err(Error::Parameter(format!(
                "bad filament settings {config:?}"
            )));
        }
        let frame = Frame::of(layout);
        let canonical = frame.layout_to_canonical(layout)?;
        let wind = wind.to_canonical(&frame);
        let crosswind = match (config.meander_walled && config.meander_deg > 0.0, crosswind) {
            (false, _) => None,
            (true, Some(c)) => Some(c.to_canonical(&frame)),
            (true, None) => Some(wind.crosswind(&canonical)?),
        };
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        // The wander starts in its stationary distribution; no draw when it is off, so a
        // steady plume's random stream is the same as before the option existed.
        let meander = if config.meander_deg > 0.0 {
            let n: f64 = StandardNormal.sample(&mut rng);
            config.meander_deg.to_radians() * n
        } else {
            0.0
        };
        Ok(Self {
            frame,
            layout: canonical,
            wind,
            source: frame.to_canonical(source.0, source.1),
            config,
            filaments: Vec::new(),
            time: 0.0,
            pending: 0.0,
            meander,
            crosswind,
            rng,
        })
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Number of live filaments.
    pub fn len(&self) -> usize {
        self.filaments.len()
    }

    /// Whether no filament is alive.
    pub fn is_empty(&self) -> bool {
        self.filaments.is_empty()
    }

    /// The wind direction's current deviation from the steady field (degrees).
    pub fn meander_deg(&self) -> f64 {
        self.meander.to_degrees()
    }

    /// The uniform background of recirculated gas in free space now (units/m^2).
    pub fn background_level(&self) -> f64 {
        let mixed = self.layout.fully_mixed(self.config.source_rate);
        self.config.background * mixed * (1.0 - (-self.time / self.config.background_time_s).exp())
    }

    /// Advances the wind direction's Ornstein-Uhlenbeck wander by one step (exact in
    /// distribution for any step) and returns its rotation `(cos, sin)`.
    fn turn_wind(&mut self) -> (f64, f64) {
        if self.config.meander_deg == 0.0 {
            return (1.0, 0.0);
        }
        let keep = (-self.config.dt_s / self.config.meander_time_s).exp();
        let n: f64 = StandardNormal.sample(&mut self.rng);
        self.meander = keep * self.meander
            + self.config.meander_deg.to_radians() * (1.0 - keep * keep).sqrt() * n;
        (self.meander.cos(), self.meander.sin())
    }

    /// Advances by one time step: release, advect, random-walk, reflect, remove.
    pub fn step(&mut self) {
        let dt = self.config.dt_s;
        let (cos, sin) = self.turn_wind();
        let crosswind = self.crosswind.as_ref();
        let velocity = |wind: &WindField, x: f64, y: f64| {
            let (u, v) = wind.velocity_at(x, y);
            match crosswind {
                Some(c) => {
                    let (uc, vc) = c.velocity_at(x, y);
                    (u * cos + uc * sin, v * cos + vc * sin)
                }
                None => (u * cos - v * sin, u * sin + v * cos),
            }
        };
        self.pending += self.config.release_rate_hz * dt;
        while self.pending >= 1.0 {
            self.pending -= 1.0;
            self.filaments.push(Filament {
                x: self.source.0,
                y: self.source.1,
                age: 0.0,
            });
        }
        let diffusivity = self.layout.diffusivity();
        let young_walk = (2.0 * self.config.walk_fraction * diffusivity * dt).sqrt();
        let old_walk = (2.0 * diffusivity * dt).sqrt();
        let widest = self.config.max_sigma_m * self.config.max_sigma_m;
        let mut kept = Vec::with_capacity(self.filaments.len());
        for f in std::mem::take(&mut self.filaments) {
            let (u1, v1) = velocity(&self.wind, f.x, f.y);
            let (u2, v2) = velocity(&self.wind, f.x + 0.5 * dt * u1, f.y + 0.5 * dt * v1);
            let nx: f64 = StandardNormal.sample(&mut self.rng);
            let ny: f64 = StandardNormal.sample(&mut self.rng);
            let walk = if self.kernel_variance(f.age) < widest {
                young_walk
            } else {
                old_walk
            };
            let step = (dt * u2 + walk * nx, dt * v2 + walk * ny);
            if let Some((x, y)) = self.walk((f.x, f.y), step) {
                kept.push(Filament {
                    x,
                    y,
                    age: f.age + dt,
                });
            }
        }
        self.filaments = kept;
        self.time += dt;
    }

    /// Runs whole steps for `seconds` of simulated time.
    pub fn advance(&mut self, seconds: f64) {
        let steps = (seconds / self.config.dt_s).round().max(0.0) as usize;
        for _ in 0..steps {
            self.step();
        }
    }

    /// The variance of a filament's kernel at an age (m^2): growing at `2 (1 - walk_fraction) D`
    /// up to `max_sigma_m` squared.
    fn kernel_variance(&self, age: f64) -> f64 {
        let s0 = self.config.initial_sigma_m * self.config.initial_sigma_m;
        let grow = 2.0 * (1.0 - self.config.walk_fraction) * self.layout.diffusivity();
        (s0 + grow * age).min(self.config.max_sigma_m * self.config.max_sigma_m)
    }

    /// Moves a filament by `step`, mirrored at the side walls and the obstacle faces it
    /// crosses; `None` when it leaves through the inlet or the outlet. A move whose path passes
    /// an obstacle is taken in sub-steps of at most half a cell, each mirrored (the rest of the
    /// move continues mirrored too), so that it cannot jump over a thin wall; any other move is
    /// taken whole, exactly as before the sub-steps existed.
    fn walk(&self, from: (f64, f64), step: (f64, f64)) -> Option<(f64, f64)> {
        let (to, _) = self.mirrored_move(from, step)?;
        if self.in_sight(from, to) {
            return Some(to);
        }
        let n = self.half_cells(step);
        let mut sub = (step.0 / n as f64, step.1 / n as f64);
        let mut at = from;
        for _ in 0..n {
            (at, sub) = self.mirrored_move(at, sub)?;
        }
        Some(at)
    }

    /// One straight move, mirrored at a side wall and at an obstacle face it ends beyond:
    /// the new position and the move's direction after the mirrors, or `None` when it leaves
    /// through the inlet or the outlet.
    fn mirrored_move(
        &self,
        at: (f64, f64),
        (dx, mut dy): (f64, f64),
    ) -> Option<((f64, f64), (f64, f64))> {
        let h = self.layout.height();
        let x = at.0 + dx;
        let mut y = at.1 + dy;
        if x <= 0.0 || x >= self.layout.width() {
            return None;
        }
        if y < 0.0 || y > h {
            y = if y < 0.0 { -y } else { 2.0 * h - y };
            dy = -dy;
        }
        let to = (x, y.clamp(0.0, h));
        let next = self.reflect_off_obstacles(at, to);
        let dx = if next.0 == to.0 { dx } else { -dx };
        let dy = if next.1 == to.1 { dy } else { -dy };
        Some((next, (dx, dy)))
    }

    /// How many pieces of at most half a cell along its longer axis a move takes (so that no
    /// piece steps over a wall one cell thick).
    fn half_cells(&self, (dx, dy): (f64, f64)) -> usize {
        (dx.abs().max(dy.abs()) / (0.5 * self.layout.cell())).ceil() as usize
    }

    /// Whether the segment between two points crosses no obstacle cell, sampled every half cell
    /// or closer along its longer axis (so a wall one cell thick is never stepped over).
    fn in_sight(&self, from: (f64, f64), to: (f64, f64)) -> bool {
        let (dx, dy) = (to.0 - from.0, to.1 - from.1);
        let n = self.half_cells((dx, dy));
        (1..n).all(|k| {
            let t = k as f64 / n as f64;
            let (j, i) = self.layout.cell_of(from.0 + t * dx, from.1 + t * dy);
            !self.layout.is_solid(j, i)
        })
    }

    /// Mirrors a move that ends in an obstacle cell across the face it crossed; if that still
    /// lands in an obstacle, the filament stays where it was.
    fn reflect_off_obstacles(&self, from: (f64, f64), to: (f64, f64)) -> (f64, f64) {
        let (jn, i_n) = self.layout.cell_of(to.0, to.1);
        if !self.layout.is_solid(jn, i_n) {
            return to;
        }
        let (jo, io) = self.layout.cell_of(from.0, from.1);
        let cell = self.layout.cell();
        let mirror = |old: usize, new: usize, coord: f64| {
            let face = if new > old {
                new as f64 * cell
            } else {
                (new + 1) as f64 * cell
            };
            2.0 * face - coord
        };
        let (mut x, mut y) = to;
        if i_n != io && self.layout.is_solid(jo, i_n) {
            x = mirror(io, i_n, x);
        }
        if jn != jo && self.layout.is_solid(jn, io) {
            y = mirror(jo, jn, y);
        }
        if i_n != io && jn != jo && x == to.0 && y == to.1 {
            // Diagonal hit on a corner: bounce both ways.
            x = mirror(io, i_n, x);
            y = mirror(jo, jn, y);
        }
        let (jr, ir) = self.layout.cell_of(x, y);
        let inside =
            x > 0.0 && x < self.layout.width() && (0.0..=self.layout.height()).contains(&y);
        if inside && !self.layout.is_solid(jr, ir) {
            (x, y)
        } else {
            from
        }
    }

    /// Instantaneous concentration (units/m^2) at a point, the background included; zero
    /// inside obstacles.
    pub fn concentration_at(&self, x: f64, y: f64) -> f64 {
        let (x, y) = self.frame.to_canonical(x, y);
        let (j, i) = self.layout.cell_of(x, y);
        if self.layout.is_solid(j, i) {
            return 0.0;
        }
        let mass = self.config.source_rate / self.config.release_rate_hz;
        let h = self.layout.height();
        let plume: f64 = self
            .filaments
            .iter()
            .map(|f| {
                let var = self.kernel_variance(f.age);
                let reach = 25.0 * var; // 5 sigma, squared
                let dx2 = (x - f.x) * (x - f.x);
                if dx2 > reach {
                    return 0.0;
                }
                // The filament and its images across the two side walls.
                let sum: f64 = [f.y, -f.y, 2.0 * h - f.y]
                    .iter()
                    .map(|&fy| {
                        let d2 = dx2 + (y - fy) * (y - fy);
                        if d2 > reach {
                            0.0
                        } else {
                            (-d2 / (2.0 * var)).exp()
                        }
                    })
                    .sum();
                if sum > 0.0 && self.in_sight((f.x, f.y), (x, y)) {
                    sum * mass / (2.0 * std::f64::consts::PI * var)
                } else {
                    0.0
                }
            })
            .sum();
        if self.config.background > 0.0 {
            plume + self.background_level()
        } else {
            plume
        }
    }
}
