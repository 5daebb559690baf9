//! Arena layouts: the JSON contract, validation, the occupancy grid and the signed distance.
//!
//! A layout is a rectangle `width_m x height_m` discretised into square cells of `cell_m`,
//! with axis-aligned rectangular obstacles and wind entering through the whole wall it comes
//! from (`west` by default: at `x = 0` along `+x`, leaving at `x = width_m`, side walls at
//! `y = 0` and `y = height_m`; `y` points north). The solvers work in the canonical frame where
//! the wind comes from the west ([`crate::frame`]). Arrays over the grid have
//! shape `[ny, nx]`: row `j` is the `y` index, column `i` the `x` index, and cell `(j, i)` has its
//! centre at `((i + 0.5) * cell_m, (j + 0.5) * cell_m)`. A cell is solid when its centre lies
//! inside (or on the edge of) an obstacle.

use std::collections::VecDeque;
use std::path::Path;

use ndarray::Array2;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::io;

/// Default effective (turbulent) diffusivity of the gas in m^2/s.
///
/// Chosen so that the cell Peclet number `U dx / D` stays below 2 at the default 0.75 m/s and
/// 0.125 m grid, where the transport scheme is second-order accurate.
pub const DEFAULT_DIFFUSIVITY_M2PS: f64 = 0.05;
/// Default effective (eddy) viscosity of the air in m^2/s.
///
/// With 1 m obstacles at 0.75 m/s this gives an obstacle Reynolds number of 15, below the onset
/// of vortex shedding, so the flow has a steady state (a turbulent Schmidt number of 1).
pub const DEFAULT_EDDY_VISCOSITY_M2PS: f64 = 0.05;
/// Smallest number of cells allowed along each side of the grid.
pub const MIN_CELLS: usize = 4;

/// The wall the wind comes from (`y` points north).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WindFrom {
    /// Inlet at `x = 0`, wind along `+x` (the default).
    #[default]
    West,
    /// Inlet at `x = width`, wind along `-x`.
    East,
    /// Inlet at `y = 0`, wind along `+y`.
    South,
    /// Inlet at `y = height`, wind along `-y`.
    North,
}

impl WindFrom {
    /// Every direction, in the order of the JSON contract.
    pub const ALL: [WindFrom; 4] = [
        WindFrom::West,
        WindFrom::East,
        WindFrom::South,
        WindFrom::North,
    ];

    /// Whether this is the default (omitted from JSON, so old files stay byte-identical).
    pub fn is_west(&self) -> bool {
        *self == WindFrom::West
    }

    /// Unit vector the wind blows along.
    pub fn downwind(&self) -> [f64; 2] {
        match self {
            WindFrom::West => [1.0, 0.0],
            WindFrom::East => [-1.0, 0.0],
            WindFrom::South => [0.0, 1.0],
            WindFrom::North => [0.0, -1.0],
        }
    }

    /// The JSON name.
    pub fn name(&self) -> &'static str {
        match self {
            WindFrom::West => "west",
            WindFrom::East => "east",
            WindFrom::South => "south",
            WindFrom::North => "north",
        }
    }
}

/// Inlet wind.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Wind {
    /// Uniform inlet speed, in m/s.
    pub speed_mps: f64,
    /// The wall the wind enters through (`west` when omitted).
    #[serde(default, skip_serializing_if = "WindFrom::is_west")]
    pub from: WindFrom,
}

/// An axis-aligned rectangular obstacle, in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Obstacle {
    /// Left edge.
    pub x_min: f64,
    /// Bottom edge.
    pub y_min: f64,
    /// Right edge.
    pub x_max: f64,
    /// Top edge.
    pub y_max: f64,
}

impl Obstacle {
    /// Whether the point lies inside or on the edge of the rectangle.
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x_min && x <= self.x_max && y >= self.y_min && y <= self.y_max
    }

    /// Signed Euclidean distance from the point to the rectangle's boundary (negative inside).
    pub fn signed_distance(&self, x: f64, y: f64) -> f64 {
        let dx = (self.x_min - x).max(x - self.x_max);
        let dy = (self.y_min - y).max(y - self.y_max);
        let outside = dx.max(0.0).hypot(dy.max(0.0));
        outside + dx.max(dy).min(0.0)
    }
}

/// The layout as written in JSON (the DESIGN.md contract), before validation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LayoutSpec {
    /// Arena side along `x` (west to east), in metres.
    pub width_m: f64,
    /// Arena side along `y` (south to north), in metres.
    pub height_m: f64,
    /// Grid cell size, in metres; must divide both sides.
    pub cell_m: f64,
    /// Inlet wind.
    pub wind: Wind,
    /// Obstacles (may be empty).
    #[serde(default)]
    pub obstacles: Vec<Obstacle>,
    /// Effective gas diffusivity in m^2/s (default [`DEFAULT_DIFFUSIVITY_M2PS`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffusivity_m2ps: Option<f64>,
    /// Effective eddy viscosity in m^2/s (default [`DEFAULT_EDDY_VISCOSITY_M2PS`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eddy_viscosity_m2ps: Option<f64>,
}

/// A validated layout with its rasterised occupancy grid.
#[derive(Debug, Clone, PartialEq)]
pub struct Layout {
    spec: LayoutSpec,
    nx: usize,
    ny: usize,
    solid: Array2<bool>,
}

impl LayoutSpec {
    /// Checks every rule and rasterises the obstacles.
    ///
    /// # Errors
    /// [`Error::Layout`] naming the first broken rule: non-finite or non-positive sizes, speeds or
    /// coefficients, a cell size that does not divide the arena, fewer than [`MIN_CELLS`] cells
    /// along a side, an inverted or out-of-arena obstacle, an obstacle that covers no cell centre,
    /// no free path from inlet to outlet, or a free pocket enclosed by obstacles.
    pub fn check(self) -> Result<Layout> {
        let bad = |msg: String| Err(Error::Layout(msg));
        for (name, v) in [
            ("width_m", self.width_m),
            ("height_m", self.height_m),
            ("cell_m", self.cell_m),
            ("wind.speed_mps", self.wind.speed_mps),
            ("diffusivity_m2ps", self.diffusivity()),
            ("eddy_viscosity_m2ps", self.eddy_viscosity()),
        ] {
            if !v.is_finite() || v <= 0.0 {
                return bad(format!("{name} must be a positive finite number, got {v}"));
            }
        }
        let cells = |side: f64, name: &str| -> Result<usize> {
            let n = side / self.cell_m;
            let rounded = n.round();
            if (n - rounded).abs() > 1e-9 * n.max(1.0) {
                return Err(Error::Layout(format!(
                    "cell_m = {} does not divide {name} = {side} ({n:.6} cells)",
                    self.cell_m
                )));
            }
            let count = rounded as usize;
            if count < MIN_CELLS {
                return Err(Error::Layout(format!(
                    "{name} = {side} gives {count} cells; at least {MIN_CELLS} are needed"
                )));
            }
            Ok(count)
        };
        let nx = cells(self.width_m, "width_m")?;
        let ny = cells(self.height_m, "height_m")?;
        let mut solid = Array2::from_elem((ny, nx), false);
        for (k, o) in self.obstacles.iter().enumerate() {
            let coords = [o.x_min, o.y_min, o.x_max, o.y_max];
            if coords.iter().any(|c| !c.is_finite()) {
                return bad(format!("obstacle {k} has a non-finite coordinate"));
            }
            if o.x_min >= o.x_max || o.y_min >= o.y_max {
                return bad(format!(
                    "obstacle {k} needs x_min < x_max and y_min < y_max"
                ));
            }
            if o.x_min < 0.0 || o.y_min < 0.0 || o.x_max > self.width_m || o.y_max > self.height_m {
                return bad(format!(
                    "obstacle {k} [{}, {}] x [{}, {}] leaves the arena [0, {}] x [0, {}]",
                    o.x_min, o.x_max, o.y_min, o.y_max, self.width_m, self.height_m
                ));
            }
            let mut covered = false;
            for ((j, i), s) in solid.indexed_iter_mut() {
                let (x, y) = cell_centre(self.cell_m, i, j);
                if o.contains(x, y) {
                    *s = true;
                    covered = true;
                }
            }
            if !covered {
                return bad(format!(
                    "obstacle {k} is smaller than a cell and covers no cell centre"
                ));
            }
        }
        check_connectivity(&solid, self.cell_m, self.wind.from)?;
        Ok(Layout {
            spec: self,
            nx,
            ny,
            solid,
        })
    }

    fn diffusivity(&self) -> f64 {
        self.diffusivity_m2ps.unwrap_or(DEFAULT_DIFFUSIVITY_M2PS)
    }

    fn eddy_viscosity(&self) -> f64 {
        self.eddy_viscosity_m2ps
            .unwrap_or(DEFAULT_EDDY_VISCOSITY_M2PS)
    }
}

fn cell_centre(cell: f64, i: usize, j: usize) -> (f64, f64) {
    ((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell)
}

/// Every free cell must be reachable from a free inlet cell, and some free outlet cell must be.
fn check_connectivity(solid: &Array2<bool>, cell: f64, from: WindFrom) -> Result<()> {
    let (ny, nx) = solid.dim();
    // The cells along the inlet wall and along the outlet wall opposite it.
    let column = |i: usize| -> Vec<(usize, usize)> { (0..ny).map(|j| (j, i)).collect() };
    let row = |j: usize| -> Vec<(usize, usize)> { (0..nx).map(|i| (j, i)).collect() };
    let (inlet, outlet) = match from {
        WindFrom::West => (column(0), column(nx - 1)),
        WindFrom::East => (column(nx - 1), column(0)),
        WindFrom::South => (row(0), row(ny - 1)),
        WindFrom::North => (row(ny - 1), row(0)),
    };
    let mut seen = Array2::from_elem((ny, nx), false);
    let mut queue: VecDeque<(usize, usize)> = inlet.into_iter().filter(|&c| !solid[c]).collect();
    for &c in &queue {
        seen[c] = true;
    }
    while let Some((j, i)) = queue.pop_front() {
        let neighbours = [
            (j.wrapping_sub(1), i),
            (j + 1, i),
            (j, i.wrapping_sub(1)),
            (j, i + 1),
        ];
        for (nj, ni) in neighbours {
            if nj < ny && ni < nx && !solid[[nj, ni]] && !seen[[nj, ni]] {
                seen[[nj, ni]] = true;
                queue.push_back((nj, ni));
            }
        }
    }
    if !outlet.into_iter().any(|c| seen[c]) {
        return Err(Error::Layout(format!(
            "obstacles block the channel: no free path from the inlet (the {} wall) to the outlet",
            from.name()
        )));
    }
    if let Some(((j, i), _)) = solid
        .indexed_iter()
        .find(|&((j, i), &s)| !s && !seen[[j, i]])
    {
        let (x, y) = cell_centre(cell, i, j);
        return Err(Error::Layout(format!(
            "the free cell at ({x}, {y}) is enclosed by obstacles; \
             no air or gas can reach it (extend an obstacle to fill the pocket)"
        )));
    }
    Ok(())
}

impl Layout {
    /// Parses and validates a layout from JSON text.
    ///
    /// # Errors
    /// [`Error::Layout`] for malformed JSON or any rule in [`LayoutSpec::check`].
    pub fn from_json(text: &str) -> Result<Self> {
        let spec: LayoutSpec = serde_json::from_str(text)
            .map_err(|e| Error::Layout(format!("malformed JSON: {e}")))?;
        spec.check()
    }

    /// Reads and validates a layout file.
    ///
    /// # Errors
    /// [`Error::Io`] when the file cannot be read, [`Error::Layout`] when it is not a valid layout.
    pub fn load(path: &Path) -> Result<Self> {
        let text = io::read_to_string(path)?;
        Self::from_json(&text).map_err(|e| match e {
            Error::Layout(msg) => Error::Layout(format!("{}: {msg}", path.display())),
            other => other,
        })
    }

    /// The layout as written in JSON.
    pub fn spec(&self) -> &LayoutSpec {
        &self.spec
    }

    /// Arena extent along x (m): along the wind when it blows from west or east.
    pub fn width(&self) -> f64 {
        self.spec.width_m
    }

    /// Arena extent along y (m): across the wind when it blows from west or east.
    pub fn height(&self) -> f64 {
        self.spec.height_m
    }

    /// Cell size (m).
    pub fn cell(&self) -> f64 {
        self.spec.cell_m
    }

    /// The floor area outside the obstacles (m^2).
    pub fn free_area_m2(&self) -> f64 {
        let free = self.solid().iter().filter(|&&s| !s).count();
        free as f64 * self.cell() * self.cell()
    }

    /// Inlet wind speed (m/s).
    pub fn wind_speed(&self) -> f64 {
        self.spec.wind.speed_mps
    }

    /// Effective gas diffusivity (m^2/s), defaulted.
    pub fn diffusivity(&self) -> f64 {
        self.spec.diffusivity()
    }

    /// Effective eddy viscosity (m^2/s), defaulted.
    pub fn eddy_viscosity(&self) -> f64 {
        self.spec.eddy_viscosity()
    }

    /// Number of cells along x (columns).
    pub fn nx(&self) -> usize {
        self.nx
    }

    /// Number of cells along y (rows).
    pub fn ny(&self) -> usize {
        self.ny
    }

    /// Grid shape `[ny, nx]`.
    pub fn shape(&self) -> (usize, usize) {
        (self.ny, self.nx)
    }

    /// Occupancy grid `[ny, nx]`, `true` in obstacle cells.
    pub fn solid(&self) -> &Array2<bool> {
        &self.solid
    }

    /// Whether cell `(j, i)` is an obstacle cell.
    pub fn is_solid(&self, j: usize, i: usize) -> bool {
        self.solid[[j, i]]
    }

    /// Numbers the free cells in row-major order: returns the index grid (`usize::MAX` in
    /// obstacle cells) and the number of free cells. Solvers use it to map cells to unknowns.
    pub fn free_cell_index(&self) -> (Array2<usize>, usize) {
        let mut index = Array2::from_elem((self.ny, self.nx), usize::MAX);
        let mut n = 0;
        for (idx, &solid) in index.iter_mut().zip(&self.solid) {
            if !solid {
                *idx = n;
                n += 1;
            }
        }
        (index, n)
    }

    /// Centre of cell `(j, i)` in metres.
    pub fn cell_centre(&self, j: usize, i: usize) -> (f64, f64) {
        cell_centre(self.cell(), i, j)
    }

    /// The cell `(j, i)` containing the point, clamped to the grid.
    pub fn cell_of(&self, x: f64, y: f64) -> (usize, usize) {
        let i = ((x / self.cell()).floor().max(0.0) as usize).min(self.nx - 1);
        let j = ((y / self.cell()).floor().max(0.0) as usize).min(self.ny - 1);
        (j, i)
    }

    /// Whether the point lies in free space: strictly inside the arena, outside every obstacle
    /// and in a free cell.
    pub fn is_free(&self, x: f64, y: f64) -> bool {
        self.check_source(x, y).is_ok()
    }

    /// Checks that a source (or robot) position is usable.
    ///
    /// # Errors
    /// [`Error::Source`] when the point is not finite, not strictly inside the arena, inside an
    /// obstacle rectangle or in an obstacle cell.
    pub fn check_source(&self, x: f64, y: f64) -> Result<()> {
        let reject = |reason: String| Err(Error::Source { x, y, reason });
        if !x.is_finite() || !y.is_finite() {
            return reject("coordinates must be finite numbers".into());
        }
        if x <= 0.0 || x >= self.width() || y <= 0.0 || y >= self.height() {
            return reject(format!(
                "outside the arena (0, {}) x (0, {})",
                self.width(),
                self.height()
            ));
        }
        if let Some(k) = self.spec.obstacles.iter().position(|o| o.contains(x, y)) {
            return reject(format!("inside obstacle {k}"));
        }
        let (j, i) = self.cell_of(x, y);
        if self.is_solid(j, i) {
            return reject("inside an obstacle cell".into());
        }
        Ok(())
    }

    /// The wall the wind comes from.
    pub fn wind_from(&self) -> WindFrom {
        self.spec.wind.from
    }

    /// The fully mixed concentration `q / (U H)` of a release of `rate` per second: the rate
    /// over the inlet speed times the arena's extent across the wind (its height for wind from
    /// west or east, its width for wind from south or north).
    pub fn fully_mixed(&self, rate: f64) -> f64 {
        let across = match self.wind_from() {
            WindFrom::West | WindFrom::East => self.height(),
            WindFrom::South | WindFrom::North => self.width(),
        };
        rate / (self.wind_speed() * across)
    }

    /// Distance (m) from a point to the nearest of the arena's four edges (walls, inlet, outlet).
    pub fn edge_distance(&self, x: f64, y: f64) -> f64 {
        x.min(y).min(self.width() - x).min(self.height() - y)
    }

    /// Signed distance (m) from a point to the nearest obstacle, negative inside one; infinite
    /// without obstacles.
    pub fn obstacle_distance(&self, x: f64, y: f64) -> f64 {
        self.spec
            .obstacles
            .iter()
            .map(|o| o.signed_distance(x, y))
            .fold(f64::INFINITY, f64::min)
    }

    /// Signed distance (m) from each cell centre to the nearest solid surface (obstacles and the
    /// side walls, the two walls along the wind), negative inside obstacles. Shape `[ny, nx]`.
    pub fn signed_distance(&self) -> Array2<f64> {
        let across_y = self.wind_from().downwind()[0] != 0.0;
        Array2::from_shape_fn((self.ny, self.nx), |(j, i)| {
            let (x, y) = self.cell_centre(j, i);
            let wall = if across_y {
                y.min(self.height() - y)
            } else {
                x.min(self.width() - x)
            };
            self.spec
                .obstacles
                .iter()
                .map(|o| o.signed_distance(x, y))
                .fold(wall, f64::min)
        })
    }

    /// Candidate source positions on a regular grid of spacing `spacing_m` (cell centres of that
    /// coarser grid), keeping those in free space. Spacing must be a multiple of the cell size.
    ///
    /// # Errors
    /// [`Error::Parameter`] when the spacing is not a positive multiple of the cell size that
    /// divides the arena.
    pub fn candidates(&self, spacing_m: f64) -> Result<Vec<[f64; 2]>> {
        let ratio = spacing_m / self.cell();
        if !ratio.is_finite() || ratio < 1.0 - 1e-9 || (ratio - ratio.round()).abs() > 1e-9 {
            return Err(Error::Parameter(format!(
                "candidate spacing {spacing_m} m must be a positive multiple of the cell size {} m",
                self.cell()
            )));
        }
        let r = ratio.round() as usize;
        if self.nx % r != 0 || self.ny % r != 0 {
            return Err(Error::Parameter(format!(
                "candidate spacing {spacing_m} m does not divide the arena"
            )));
        }
        let mut out = Vec::new();
        for j in 0..self.ny / r {
            for i in 0..self.nx / r {
                let (x, y) = ((i as f64 + 0.5) * spacing_m, (j as f64 + 0.5) * spacing_m);
                if self.is_free(x, y) {
                    out.push([x, y]);
                }
            }
        }
        Ok(out)
    }

    /// Serialises the layout back to pretty JSON (defaults made explicit).
    pub fn to_json(&self) -> String {
        let mut spec = self.spec.clone();
        spec.diffusivity_m2ps = Some(self.diffusivity());
        spec.eddy_viscosity_m2ps = Some(self.eddy_viscosity());
        serde_json::to_string_pretty(&spec).unwrap_or_default()
    }
}
