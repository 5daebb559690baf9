//! Random rooms for any-room datasets: the arena's size, its wind speed and direction, and
//! groups of obstacles of several kinds whose number grows with the floor area.
//!
//! A room is drawn in its canonical frame ([`crate::frame`]: wind from the west, `x` along the
//! wind, `y` across it), where every rule is simple to state, then turned to its wind direction.
//! Rules, all in the canonical frame:
//! - groups stay `inlet_clearance_m` from the inlet and the outlet (so the inlet and outlet
//!   walls are whole), and `spacing_m` from each other;
//! - a rectangle either touches a side wall or keeps `spacing_m` from it, so there are no slits
//!   narrower than the spacing;
//! - every cross-section across the wind keeps at least `min_gap_m` free;
//! - the whole layout passes [`LayoutSpec::check`] (a free path from inlet to outlet, no
//!   enclosed pocket); a room that fails is drawn again from the same stream.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::snap::{SNAP_M, snapped};
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::{Layout, LayoutSpec, Obstacle, Wind, WindFrom};

/// Give up on a room after this many redraws, and on one group after this many placements.
const MAX_ROOM_ATTEMPTS: usize = 1_000;
const MAX_GROUP_ATTEMPTS: usize = 50;

/// The kinds of obstacle groups.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum GroupKind {
    /// One free-standing block (a cabinet, a machine, a table).
    Block,
    /// One block against a side wall.
    WallBlock,
    /// Two thin rectangles joined at a corner.
    LShape,
    /// Two thin walls along the wind with a passage between them.
    Corridor,
    /// A thin wall across the wind from a side wall, leaving a doorway.
    Partition,
    /// Two to four parallel shelves with aisles between them, along or across the wind.
    Shelves,
}

impl GroupKind {
    /// Every kind, in the order of [`RoomParams::kind_weights`].
    pub const ALL: [GroupKind; 6] = [
        GroupKind::Block,
        GroupKind::WallBlock,
        GroupKind::LShape,
        GroupKind::Corridor,
        GroupKind::Partition,
        GroupKind::Shelves,
    ];
}

/// The distribution of rooms (recorded in the manifest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RoomParams {
    /// Arena width (along `x`), whole metres drawn uniformly from `[min, max]`.
    pub width_m: [u32; 2],
    /// Arena height (along `y`), whole metres drawn uniformly from `[min, max]`.
    pub height_m: [u32; 2],
    /// Grid cell (m), the same for every room.
    pub cell_m: f64,
    /// Inlet wind speed (m/s), uniform in `[min, max]`, rounded to 0.01.
    pub speed_mps: [f64; 2],
    /// Wind directions, drawn with equal chances.
    pub directions: Vec<WindFrom>,
    /// Obstacle groups per square metre of floor: the count is the floor area times a rate
    /// drawn uniformly from `[min, max]`, rounded, at least one.
    pub groups_per_m2: [f64; 2],
    /// Relative chances of the kinds in [`GroupKind::ALL`] order.
    pub kind_weights: [f64; 6],
    /// Groups stay this far from the inlet and outlet walls (m), at most a sixth of the length.
    pub inlet_clearance_m: f64,
    /// Least free width of every cross-section across the wind (m).
    pub min_gap_m: f64,
    /// Least distance between groups, and between a rectangle and a wall it does not touch (m).
    pub spacing_m: f64,
    /// Sources keep this distance from walls and obstacles (m).
    pub source_margin_m: f64,
}

impl Default for RoomParams {
    fn default() -> Self {
        Self {
            width_m: [6, 30],
            height_m: [3, 12],
            cell_m: 0.125,
            speed_mps: [0.25, 1.5],
            directions: WindFrom::ALL.to_vec(),
            groups_per_m2: [1.0 / 40.0, 1.0 / 15.0],
            kind_weights: [3.0, 2.0, 1.0, 1.0, 1.0, 1.0],
            inlet_clearance_m: 1.5,
            min_gap_m: 1.0,
            spacing_m: 0.5,
            source_margin_m: 0.25,
        }
    }
}

impl RoomParams {
    /// Checks that the parameters can produce rooms.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the bad parameter.
    pub fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Parameter(format!("room parameters: {m}")));
        let ordered = |[lo, hi]: [f64; 2]| lo.is_finite() && hi.is_finite() && lo <= hi;
        if self.width_m[0] < 3 || self.height_m[0] < 3 || self.width_m[0] > self.width_m[1] {
            return bad(format!("bad width range {:?}", self.width_m));
        }
        if self.height_m[0] > self.height_m[1] {
            return bad(format!("bad height range {:?}", self.height_m));
        }
        if !(self.cell_m > 0.0 && (1.0 / self.cell_m).fract() == 0.0) {
            return bad(format!(
                "cell_m = {} must divide one metre exactly",
                self.cell_m
            ));
        }
        if !ordered(self.speed_mps) || self.speed_mps[0] <= 0.0 {
            return bad(format!("bad speed range {:?}", self.speed_mps));
        }
        if self.directions.is_empty() {
            return bad("no wind direction".into());
        }
        if !ordered(self.groups_per_m2) || self.groups_per_m2[0] < 0.0 {
            return bad(format!("bad group density {:?}", self.groups_per_m2));
        }
        if self
            .kind_weights
            .iter()
            .any(|w| !(w.is_finite() && *w >= 0.0))
            || self.kind_weights.iter().sum::<f64>() <= 0.0
        {
            return bad(format!("bad kind weights {:?}", self.kind_weights));
        }
        let lengths = [
            self.inlet_clearance_m,
            self.min_gap_m,
            self.spacing_m,
            self.source_margin_m,
        ];
        if lengths.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return bad("negative or non-finite clearance, gap, spacing or margin".into());
        }
        if self.min_gap_m + 2.0 * SNAP_M > f64::from(self.height_m[0].min(self.width_m[0])) {
            return bad(format!(
                "min_gap_m = {} leaves no room for obstacles in the smallest room",
                self.min_gap_m
            ));
        }
        Ok(())
    }
}

/// A whole-metre draw from `[lo, hi]`.
fn metres(rng: &mut ChaCha8Rng, [lo, hi]: [u32; 2]) -> f64 {
    f64::from(rng.random_range(lo..=hi))
}

fn rect(x_min: f64, y_min: f64, w: f64, h: f64) -> Obstacle {
    Obstacle {
        x_min,
        y_min,
        x_max: x_min + w,
        y_max: y_min + h,
    }
}

/// Gap between two rectangles (0 when they touch or overlap).
fn gap(a: &Obstacle, b: &Obstacle) -> f64 {
    let dx = (a.x_min - b.x_max).max(b.x_min - a.x_max).max(0.0);
    let dy = (a.y_min - b.y_max).max(b.y_min - a.y_max).max(0.0);
    dx.hypot(dy)
}

/// The canonical room being filled: length `l` along the wind, width `c` across it.
struct Room<'a> {
    params: &'a RoomParams,
    l: f64,
    c: f64,
    obstacles: Vec<Obstacle>,
    /// Blocked length of each cross-section (one per cell column).
    blocked: Vec<f64>,
}

impl Room<'_> {
    fn clearance(&self) -> f64 {
        self.params.inlet_clearance_m.min(self.l / 6.0)
    }

    /// Draws one group of `kind` (rectangles in canonical coordinates, not yet checked).
    fn draw(&self, kind: GroupKind, rng: &mut ChaCha8Rng) -> Vec<Obstacle> {
        let (c, s) = (self.c, self.params.spacing_m);
        let (x0, x1) = (self.clearance(), self.l - self.clearance());
        let thin = |rng: &mut ChaCha8Rng| snapped(rng, 0.25, 0.5);
        match kind {
            GroupKind::Block | GroupKind::WallBlock => {
                let w = snapped(rng, 0.5, 2.5f64.min(x1 - x0));
                let h = snapped(rng, 0.5, 2.5f64.min(c / 3.0));
                let x = snapped(rng, x0, x1 - w);
                let y = if kind == GroupKind::WallBlock {
                    if rng.random_bool(0.5) { 0.0 } else { c - h }
                } else {
                    snapped(rng, s, c - s - h)
                };
                vec![rect(x, y, w, h)]
            }
            GroupKind::LShape => {
                let t = thin(rng);
                let a = snapped(rng, 1.0, 3.5f64.min(x1 - x0));
                let b = snapped(rng, 1.0, 3.0f64.min(c / 2.0));
                let x = snapped(rng, x0, x1 - a);
                let y = snapped(rng, s, c - s - b);
                // Leg along x at the bottom or top of the box, leg along y at its left or right.
                let (bottom, left) = (rng.random_bool(0.5), rng.random_bool(0.5));
                let along = rect(x, if bottom { y } else { y + b - t }, a, t);
                let across = rect(if left { x } else { x + a - t }, y, t, b);
                vec![along, across]
            }
            GroupKind::Corridor => {
                let t = thin(rng);
                let len = snapped(rng, 3.0, 10f64.min(x1 - x0));
                let passage = snapped(rng, 1.0, 2.0);
                let x = snapped(rng, x0, x1 - len);
                let y = snapped(rng, 0.0, c - 2.0 * t - passage);
                let y = if y > 0.0 && y < s { 0.0 } else { y };
                vec![rect(x, y, len, t), rect(x, y + t + passage, len, t)]
            }
            GroupKind::Partition => {
                let t = thin(rng);
                let door = snapped(rng, self.params.min_gap_m.max(1.0), 2.0f64.max(c / 3.0));
                let x = snapped(rng, x0, x1 - t);
                let len = (c - door).max(0.0);
                if rng.random_bool(0.5) {
                    vec![rect(x, 0.0, t, len)]
                } else {
                    vec![rect(x, c - len, t, len)]
                }
            }
            GroupKind::Shelves => {
                let rows = rng.random_range(2..=4usize);
                let depth = snapped(rng, 0.25, 0.75);
                let aisle = snapped(rng, 1.0, 2.0);
                let span = rows as f64 * depth + (rows - 1) as f64 * aisle;
                if rng.random_bool(0.5) {
                    // Rows along the wind, stacked across it.
                    let len = snapped(rng, 2.0, 6f64.min(x1 - x0));
                    let x = snapped(rng, x0, x1 - len);
                    let y = snapped(rng, s, c - s - span);
                    (0..rows)
                        .map(|k| rect(x, y + k as f64 * (depth + aisle), len, depth))
                        .collect()
                } else {
                    // Rows across the wind, one behind the other.
                    let len = snapped(rng, 1.0, 4f64.min(c - 2.0 * s - self.params.min_gap_m));
                    let x = snapped(rng, x0, x1 - span);
                    let y = snapped(rng, s, c - s - len);
                    (0..rows)
                        .map(|k| rect(x + k as f64 * (depth + aisle), y, depth, len))
                        .collect()
                }
            }
        }
    }

    /// Whether `group` obeys the rules against the walls and the groups placed so far, and
    /// keeps every cross-section open; if so, the blocked lengths it would give.
    fn admits(&self, group: &[Obstacle]) -> Option<Vec<f64>> {
        let (c, s) = (self.c, self.params.spacing_m);
        let (x0, x1) = (self.clearance(), self.l - self.clearance());
        for o in group {
            let inside = o.x_min >= x0 - 1e-9
                && o.x_max <= x1 + 1e-9
                && o.y_min >= -1e-9
                && o.y_max <= c + 1e-9
                && o.x_max - o.x_min >= SNAP_M - 1e-9
                && o.y_max - o.y_min >= SNAP_M - 1e-9;
            let near_bottom = o.y_min > 1e-9 && o.y_min < s - 1e-9;
            let near_top = o.y_max < c - 1e-9 && o.y_max > c - s + 1e-9;
            if !inside || near_bottom || near_top {
                return None;
            }
            if self.obstacles.iter().any(|p| gap(o, p) < s - 1e-9) {
                return None;
            }
        }
        let cell = self.params.cell_m;
        let mut blocked = self.blocked.clone();
        for (i, b) in blocked.iter_mut().enumerate() {
            let x = (i as f64 + 0.5) * cell;
            // Rectangles of one group may overlap (an L's corner): count covered cells once.
            let mut spans: Vec<(f64, f64)> = group
                .iter()
                .filter(|o| o.x_min <= x && x <= o.x_max)
                .map(|o| (o.y_min, o.y_max))
                .collect();
            spans.sort_by(|a, b| a.0.total_cmp(&b.0));
            let mut end = f64::NEG_INFINITY;
            for (lo, hi) in spans {
                let lo = lo.max(end);
                if hi > lo {
                    *b += hi - lo;
                    end = hi;
                }
            }
            if c - *b < self.params.min_gap_m - 1e-9 {
                return None;
            }
        }
        Some(blocked)
    }
}

/// Draws a kind with the chances of `weights`.
fn draw_kind(weights: &[f64; 6], rng: &mut ChaCha8Rng) -> GroupKind {
    let total: f64 = weights.iter().sum();
    let mut r = rng.random_range(0.0..total);
    for (kind, w) in GroupKind::ALL.iter().zip(weights) {
        if r < *w {
            return *kind;
        }
        r -= w;
    }
    GroupKind::Block
}

/// Draws a random room (see the module docs).
///
/// # Errors
/// [`Error::Parameter`] for parameters that [`RoomParams::check`] refuses, or when no valid
/// room is found in many attempts.
pub fn random_room(params: &RoomParams, rng: &mut ChaCha8Rng) -> Result<Layout> {
    params.check()?;
    for _ in 0..MAX_ROOM_ATTEMPTS {
        let width = metres(rng, params.width_m);
        let height = metres(rng, params.height_m);
        let speed =
            (rng.random_range(params.speed_mps[0]..=params.speed_mps[1]) * 100.0).round() / 100.0;
        let from = params.directions[rng.random_range(0..params.directions.len())];
        let (l, c) = if from.downwind()[0] != 0.0 {
            (width, height)
        } else {
            (height, width)
        };
        let rate = rng.random_range(params.groups_per_m2[0]..=params.groups_per_m2[1]);
        let groups = ((l * c * rate).round() as usize).max(1);
        let mut room = Room {
            params,
            l,
            c,
            obstacles: Vec::new(),
            blocked: vec![0.0; (l / params.cell_m).round() as usize],
        };
        for _ in 0..groups {
            let kind = draw_kind(&params.kind_weights, rng);
            for _ in 0..MAX_GROUP_ATTEMPTS {
                let group = room.draw(kind, rng);
                if let Some(blocked) = room.admits(&group) {
                    room.blocked = blocked;
                    room.obstacles.extend(group);
                    break;
                }
            }
        }
        let canonical = LayoutSpec {
            width_m: l,
            height_m: c,
            cell_m: params.cell_m,
            wind: Wind {
                speed_mps: speed,
                from: WindFrom::West,
            },
            obstacles: room.obstacles,
            diffusivity_m2ps: None,
            eddy_viscosity_m2ps: None,
        };
        let Ok(canonical) = canonical.check() else {
            continue;
        };
        if let Ok(layout) = Frame::turning(&canonical, from).layout_from_canonical(&canonical) {
            return Ok(layout);
        }
    }
    Err(Error::Parameter(
        "no valid random room found: relax the room parameters".into(),
    ))
}
