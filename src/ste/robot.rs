//! The robot: a Khepera IV-like disc that drives obstacle-free paths and senses at 10 Hz.
//!
//! Paths are planned with A* ([`pathfinding`]) on the layout's grid, 8-connected without corner
//! cutting, over the cells whose centre is at least `radius + clearance` from every obstacle,
//! side wall, inlet and outlet (the inflated occupancy grid). The cell path is then shortened
//! by string pulling: a waypoint is dropped whenever the straight segment that skips it stays
//! in inflated free space. The robot drives the resulting polyline at its maximum speed.

use ndarray::Array2;
use pathfinding::prelude::astar;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::layout::Layout;

/// How the robot collects readings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", tag = "mode")]
pub enum Sampling {
    /// Every 0.1 s tick while driving is a sample (the paper's choice).
    InMotion,
    /// Drive without recording; stop every `spacing_m` along the path and at the goal, wait
    /// `settle_s`, then record the mean of the readings over `dwell_s` as one sample.
    StopSenseGo {
        /// Distance between stops (m).
        spacing_m: f64,
        /// Waiting time before recording at a stop (s).
        settle_s: f64,
        /// Recording time at a stop (s).
        dwell_s: f64,
    },
}

impl Sampling {
    /// Stop-sense-go with the crate's defaults: a stop every metre, 10 s settling (about two
    /// recovery time constants), 10 s of averaging.
    pub fn stop_sense_go() -> Self {
        Self::StopSenseGo {
            spacing_m: 1.0,
            settle_s: 10.0,
            dwell_s: 10.0,
        }
    }
}

/// The robot's physical settings.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RobotParams {
    /// Maximum speed (m/s), the Khepera IV's 0.27.
    pub max_speed_mps: f64,
    /// Disc radius (m).
    pub radius_m: f64,
    /// Extra clearance kept from obstacles and walls (m).
    pub clearance_m: f64,
    /// Sampling (and simulation) period (s): 0.1 for 10 Hz.
    pub tick_s: f64,
    /// How readings are collected.
    pub sampling: Sampling,
    /// What one more leg costs the robot (stopping, updating the posterior, turning), in
    /// metres of driving: the planner scores a leg by its expected gain over its length plus
    /// this, so a larger cost makes fewer, longer legs. A config without the field reads as
    /// [`LEG_COST_M`].
    #[serde(default = "default_leg_cost_m")]
    pub leg_cost_m: f64,
    /// The radius (m) within which the planner counts the readings already taken around each
    /// point it predicts along a leg: a point where one pass's readings lie weighs half a
    /// fresh one's evidence, where `n` passes' `1 / (1 + n)`, since a reading taken where the
    /// robot has sensed before shares those readings' errors and tells less. 0 (what a config
    /// without the field reads as) counts every predicted point in full.
    #[serde(default)]
    pub revisit_radius_m: f64,
}

/// The default cost of one more leg (m of driving).
pub const LEG_COST_M: f64 = 2.0;

fn default_leg_cost_m() -> f64 {
    LEG_COST_M
}

/// Checks a leg cost ([`RobotParams::leg_cost_m`]): a finite number of metres, zero or more.
///
/// # Errors
/// [`Error::Parameter`] otherwise.
pub fn check_leg_cost(m: f64) -> Result<()> {
    check_metres("leg cost", m)
}

/// Checks a length named `what`: a finite number of metres, zero or more.
pub(crate) fn check_metres(what: &str, m: f64) -> Result<()> {
    if m.is_finite() && m >= 0.0 {
        Ok(())
    } else {
        Err(Error::Parameter(format!(
            "the {what} must be a finite number of metres, zero or more, got {m}"
        )))
    }
}

/// Checks a revisit radius ([`RobotParams::revisit_radius_m`]): a finite number of metres,
/// zero or more.
///
/// # Errors
/// [`Error::Parameter`] otherwise.
pub fn check_revisit_radius(m: f64) -> Result<()> {
    check_metres("revisit radius", m)
}

impl Default for RobotParams {
    fn default() -> Self {
        Self {
            max_speed_mps: 0.27,
            radius_m: 0.07,
            clearance_m: 0.05,
            tick_s: 0.1,
            sampling: Sampling::InMotion,
            leg_cost_m: LEG_COST_M,
            revisit_radius_m: 0.0,
        }
    }
}

impl RobotParams {
    /// The readings one pass leaves per metre of path: one per tick at full speed in motion,
    /// one per stop with stop-sense-go.
    pub fn readings_per_m(&self) -> f64 {
        match self.sampling {
            Sampling::InMotion => 1.0 / (self.max_speed_mps * self.tick_s),
            Sampling::StopSenseGo { spacing_m, .. } => 1.0 / spacing_m,
        }
    }

    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::Parameter`] for non-positive speed, tick or radius, negative clearance, leg
    /// cost or revisit radius, or stop-sense-go times that are negative or record nothing.
    pub fn check(&self) -> Result<()> {
        let mut ok = [self.max_speed_mps, self.radius_m, self.tick_s]
            .iter()
            .all(|v| v.is_finite() && *v > 0.0)
            && self.clearance_m.is_finite()
            && self.clearance_m >= 0.0
            && check_leg_cost(self.leg_cost_m).is_ok()
            && check_revisit_radius(self.revisit_radius_m).is_ok();
        if let Sampling::StopSenseGo {
            spacing_m,
            settle_s,
            dwell_s,
        } = self.sampling
        {
            ok &= spacing_m > 0.0 && settle_s >= 0.0 && dwell_s >= self.tick_s;
        }
        if ok {
            Ok(())
        } else {
            Err(Error::Parameter(format!("bad robot settings {self:?}")))
        }
    }
}

/// The inflated occupancy grid and the path planner over it.
#[derive(Debug, Clone)]
pub struct Occupancy {
    free: Array2<bool>,
    cell: f64,
}

type Cell = (usize, usize);

impl Occupancy {
    /// Inflates the layout's obstacles, walls, inlet and outlet by `inflate_m`.
    ///
    /// # Errors
    /// [`Error::Parameter`] when nothing is left free.
    pub fn new(layout: &Layout, inflate_m: f64) -> Result<Self> {
        let free = Array2::from_shape_fn(layout.shape(), |(j, i)| {
            let (x, y) = layout.cell_centre(j, i);
            let clearance = layout
                .obstacle_distance(x, y)
                .min(layout.edge_distance(x, y));
            clearance >= inflate_m && !layout.is_solid(j, i)
        });
        if !free.iter().any(|&f| f) {
            return Err(Error::Parameter(format!(
                "no room for the robot: inflating by {inflate_m} m fills the arena"
            )));
        }
        Ok(Self {
            free,
            cell: layout.cell(),
        })
    }

    fn cell_of(&self, x: f64, y: f64) -> Option<Cell> {
        let (ny, nx) = self.free.dim();
        let (i, j) = ((x / self.cell).floor(), (y / self.cell).floor());
        (i >= 0.0 && j >= 0.0 && (i as usize) < nx && (j as usize) < ny)
            .then_some((j as usize, i as usize))
    }

    fn centre(&self, (j, i): Cell) -> [f64; 2] {
        [(i as f64 + 0.5) * self.cell, (j as f64 + 0.5) * self.cell]
    }

    /// Whether the robot may stand at the point.
    pub fn is_free(&self, x: f64, y: f64) -> bool {
        self.cell_of(x, y).is_some_and(|c| self.free[c])
    }

    /// The centre of the free cell nearest to the point.
    pub fn nearest_free(&self, x: f64, y: f64) -> [f64; 2] {
        let (mut best, mut best_d) = ([x, y], f64::INFINITY);
        for ((j, i), &f) in self.free.indexed_iter() {
            if f {
                let [cx, cy] = self.centre((j, i));
                let d = (cx - x).hypot(cy - y);
                if d < best_d {
                    (best, best_d) = ([cx, cy], d);
                }
            }
        }
        best
    }

    /// The point itself when the robot may stand there, else the centre of the nearest free
    /// cell ([`Occupancy::nearest_free`]).
    pub fn free_or_nearest(&self, [x, y]: [f64; 2]) -> [f64; 2] {
        if self.is_free(x, y) {
            [x, y]
        } else {
            self.nearest_free(x, y)
        }
    }

    /// Whether the straight segment stays in free space (checked every quarter cell).
    pub fn segment_free(&self, a: [f64; 2], b: [f64; 2]) -> bool {
        let len = (b[0] - a[0]).hypot(b[1] - a[1]);
        let steps = (len / (0.25 * self.cell)).ceil().max(1.0) as usize;
        (0..=steps).all(|s| {
            let t = s as f64 / steps as f64;
            self.is_free(a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]))
        })
    }

    fn neighbours(&self, (j, i): Cell) -> Vec<(Cell, u32)> {
        let (ny, nx) = self.free.dim();
        let mut out = Vec::with_capacity(8);
        for dj in -1i64..=1 {
            for di in -1i64..=1 {
                if dj == 0 && di == 0 {
                    continue;
                }
                let (nj, ni) = (j as i64 + dj, i as i64 + di);
                if nj < 0 || ni < 0 || nj >= ny as i64 || ni >= nx as i64 {
                    continue;
                }
                let c = (nj as usize, ni as usize);
                let diagonal = dj != 0 && di != 0;
                // No corner cutting: both orthogonal neighbours must be free too.
                if !self.free[c]
                    || (diagonal && (!self.free[(j, ni as usize)] || !self.free[(nj as usize, i)]))
                {
                    continue;
                }
                out.push((c, if diagonal { 1414 } else { 1000 }));
            }
        }
        out
    }

    /// An obstacle-free path from `from` to `to` (both snapped to the nearest free cell when
    /// they are not free), as a polyline starting at `from`; `None` when the goal is unreachable.
    pub fn plan(&self, from: [f64; 2], to: [f64; 2]) -> Option<Vec<[f64; 2]>> {
        let start_pt = self.free_or_nearest(from);
        let goal_pt = self.free_or_nearest(to);
        let start = self.cell_of(start_pt[0], start_pt[1])?;
        let goal = self.cell_of(goal_pt[0], goal_pt[1])?;
        let octile = |&(j, i): &Cell| {
            let (dj, di) = (j.abs_diff(goal.0) as u32, i.abs_diff(goal.1) as u32);
            1000 * dj.max(di) + 414 * dj.min(di)
        };
        let (cells, _) = astar(&start, |&c| self.neighbours(c), octile, |&c| c == goal)?;
        let mut raw: Vec<[f64; 2]> = vec![from, start_pt];
        raw.extend(cells.iter().skip(1).map(|&c| self.centre(c)));
        raw.push(goal_pt);
        raw.dedup();
        Some(self.string_pull(&raw))
    }

    /// Drops every waypoint whose neighbours can see each other.
    fn string_pull(&self, raw: &[[f64; 2]]) -> Vec<[f64; 2]> {
        let mut out = vec![raw[0]];
        let mut k = 0;
        while k + 1 < raw.len() {
            let mut next = k + 1;
            for cand in (k + 2..raw.len()).rev() {
                if self.segment_free(raw[k], raw[cand]) {
                    next = cand;
                    break;
                }
            }
            out.push(raw[next]);
            k = next;
        }
        out
    }
}

/// Length of a polyline (m).
pub fn path_length(path: &[[f64; 2]]) -> f64 {
    path.windows(2)
        .map(|w| (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]))
        .sum()
}

/// The point at arc length `s` along a polyline (clamped to its ends).
pub fn point_at(path: &[[f64; 2]], s: f64) -> [f64; 2] {
    let mut left = s.max(0.0);
    for w in path.windows(2) {
        let seg = (w[1][0] - w[0][0]).hypot(w[1][1] - w[0][1]);
        if left <= seg && seg > 0.0 {
            let t = left / seg;
            return [
                w[0][0] + t * (w[1][0] - w[0][0]),
                w[0][1] + t * (w[1][1] - w[0][1]),
            ];
        }
        left -= seg;
    }
    *path.last().unwrap_or(&[0.0, 0.0])
}
