//! The canonical frame of a layout: the arena turned so that the wind comes from the west.
//!
//! The physics solvers, the filament plume and PlumeNet are written for wind entering at
//! `x = 0` along `+x`. A layout whose wind comes from another wall is turned into that frame by
//! a rotation (180 degrees for `east`, a quarter turn for `south` and `north`), solved there,
//! and its results turned back; [`Frame`] holds the maps for points, vectors, cell arrays, the
//! staggered wind field and the layout itself. Rotations (not reflections) keep the handedness,
//! so a layout turned by a quarter turn together with its wind gives the turned field exactly.
//!
//! Coordinates: the real arena is `[0, W] x [0, H]` with `nx x ny` cells; the canonical one is
//! `[0, W'] x [0, H']` (`W' = H`, `H' = W` for a quarter turn).
//!
//! | wind from | canonical `(x', y')` of real `(x, y)` | canonical `(u', v')` of real `(u, v)` |
//! |---|---|---|
//! | west | `(x, y)` | `(u, v)` |
//! | east | `(W - x, H - y)` | `(-u, -v)` |
//! | south | `(y, W - x)` | `(v, -u)` |
//! | north | `(H - y, x)` | `(-v, u)` |

use ndarray::{Array2, ArrayView2};

use crate::error::{Error, Result};
use crate::layout::{Layout, LayoutSpec, Obstacle, WindFrom};

/// The rotation between a layout's arena and its canonical frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Frame {
    from: WindFrom,
    width: f64,
    height: f64,
    nx: usize,
    ny: usize,
}

impl Frame {
    /// The frame of `layout`.
    pub fn of(layout: &Layout) -> Self {
        Self::new(
            layout.wind_from(),
            [layout.width(), layout.height()],
            [layout.nx(), layout.ny()],
        )
    }

    /// The frame of an arena of `[width, height]` metres and `[nx, ny]` cells with wind `from`.
    pub fn new(from: WindFrom, [width, height]: [f64; 2], [nx, ny]: [usize; 2]) -> Self {
        Self {
            from,
            width,
            height,
            nx,
            ny,
        }
    }

    /// Whether the canonical frame is the real one (wind from the west).
    pub fn is_identity(&self) -> bool {
        self.from == WindFrom::West
    }

    /// Whether the canonical frame swaps the arena's sides (a quarter turn).
    pub fn swaps_sides(&self) -> bool {
        matches!(self.from, WindFrom::South | WindFrom::North)
    }

    /// The arena's sides in the canonical frame: its length along the wind and its width across
    /// it (m).
    pub fn canonical_sides(&self) -> (f64, f64) {
        if self.swaps_sides() {
            (self.height, self.width)
        } else {
            (self.width, self.height)
        }
    }

    /// Canonical coordinates of a real point.
    pub fn to_canonical(&self, x: f64, y: f64) -> (f64, f64) {
        let (w, h) = (self.width, self.height);
        match self.from {
            WindFrom::West => (x, y),
            WindFrom::East => (w - x, h - y),
            WindFrom::South => (y, w - x),
            WindFrom::North => (h - y, x),
        }
    }

    /// Real coordinates of a canonical point.
    pub fn from_canonical(&self, xc: f64, yc: f64) -> (f64, f64) {
        let (w, h) = (self.width, self.height);
        match self.from {
            WindFrom::West => (xc, yc),
            WindFrom::East => (w - xc, h - yc),
            WindFrom::South => (w - yc, xc),
            WindFrom::North => (yc, h - xc),
        }
    }

    /// Canonical components of a real vector.
    pub fn vector_to_canonical(&self, u: f64, v: f64) -> (f64, f64) {
        match self.from {
            WindFrom::West => (u, v),
            WindFrom::East => (-u, -v),
            WindFrom::South => (v, -u),
            WindFrom::North => (-v, u),
        }
    }

    /// Real components of a canonical vector.
    pub fn vector_from_canonical(&self, uc: f64, vc: f64) -> (f64, f64) {
        match self.from {
            WindFrom::West => (uc, vc),
            WindFrom::East => (-uc, -vc),
            WindFrom::South => (-vc, uc),
            WindFrom::North => (vc, -uc),
        }
    }

    /// Shape `[ny, nx]` of real cell arrays.
    pub fn real_shape(&self) -> (usize, usize) {
        (self.ny, self.nx)
    }

    /// Shape `[ny', nx']` of canonical cell arrays.
    pub fn canonical_shape(&self) -> (usize, usize) {
        if self.swaps_sides() {
            (self.nx, self.ny)
        } else {
            (self.ny, self.nx)
        }
    }

    /// Canonical index `(j', i')` of real cell `(j, i)`.
    pub fn cell_to_canonical(&self, j: usize, i: usize) -> (usize, usize) {
        let (nx, ny) = (self.nx, self.ny);
        match self.from {
            WindFrom::West => (j, i),
            WindFrom::East => (ny - 1 - j, nx - 1 - i),
            WindFrom::South => (nx - 1 - i, j),
            WindFrom::North => (i, ny - 1 - j),
        }
    }

    /// A real cell array `[ny, nx]` from its canonical counterpart `[ny', nx']`.
    pub fn cells_from_canonical<T: Clone>(&self, canonical: ArrayView2<T>) -> Array2<T> {
        assert_eq!(canonical.dim(), self.canonical_shape());
        Array2::from_shape_fn((self.ny, self.nx), |(j, i)| {
            canonical[self.cell_to_canonical(j, i)].clone()
        })
    }

    /// The canonical cell array `[ny', nx']` of a real one `[ny, nx]`.
    pub fn cells_to_canonical<T: Clone>(&self, real: ArrayView2<T>) -> Array2<T> {
        assert_eq!(real.dim(), (self.ny, self.nx));
        let mut out = Array2::from_elem(self.canonical_shape(), real[[0, 0]].clone());
        for ((j, i), v) in real.indexed_iter() {
            out[self.cell_to_canonical(j, i)] = v.clone();
        }
        out
    }

    /// The frame of the arena that `canonical` (wind from the west) becomes when turned so that
    /// the wind comes from `from`.
    pub fn turning(canonical: &Layout, from: WindFrom) -> Self {
        let quarter = matches!(from, WindFrom::South | WindFrom::North);
        let (w, h, nx, ny) = (
            canonical.width(),
            canonical.height(),
            canonical.nx(),
            canonical.ny(),
        );
        if quarter {
            Self::new(from, [h, w], [ny, nx])
        } else {
            Self::new(from, [w, h], [nx, ny])
        }
    }

    /// The canonical layout: the arena, its obstacles and its wind turned so that the wind
    /// comes from the west (grid, speed and coefficients unchanged).
    ///
    /// # Errors
    /// [`Error::Layout`] in the rare case that rounding of the turned obstacle edges moves one
    /// across a cell centre, so that the turned layout would rasterise differently.
    pub fn layout_to_canonical(&self, layout: &Layout) -> Result<Layout> {
        if self.is_identity() {
            return Ok(layout.clone());
        }
        let (w, h) = self.canonical_sides();
        let spec = turn_spec(
            layout.spec(),
            |x, y| self.to_canonical(x, y),
            [w, h],
            WindFrom::West,
        );
        let expected = self.cells_to_canonical(layout.solid().view());
        checked(spec, &expected)
    }

    /// The layout of this frame's arena whose canonical layout is `canonical` (the inverse of
    /// [`Frame::layout_to_canonical`]; build the frame with [`Frame::turning`]).
    ///
    /// # Errors
    /// As [`Frame::layout_to_canonical`], and [`Error::Layout`] when `canonical` does not fit
    /// this frame's canonical grid.
    pub fn layout_from_canonical(&self, canonical: &Layout) -> Result<Layout> {
        if canonical.shape() != self.canonical_shape() || !canonical.wind_from().is_west() {
            return Err(Error::Layout(format!(
                "a {:?} layout with wind from the {} is not the canonical layout of this arena",
                canonical.shape(),
                canonical.wind_from().name()
            )));
        }
        let spec = turn_spec(
            canonical.spec(),
            |x, y| self.from_canonical(x, y),
            [self.width, self.height],
            self.from,
        );
        let expected = self.cells_from_canonical(canonical.solid().view());
        checked(spec, &expected)
    }

    /// The canonical face of real face `(j, i)` of the `u` (`horizontal = false`) or `v` array:
    /// which canonical array (`false` for `u'`), its index, and the sign relating the two
    /// components. Faces: `u[j, i]` sits at `(i dx, (j + 1/2) dx)`, `v[j, i]` at
    /// `((i + 1/2) dx, j dx)`.
    pub fn face_to_canonical(&self, v_face: bool, j: usize, i: usize) -> (bool, [usize; 2], f64) {
        let (nx, ny) = (self.nx, self.ny);
        match (self.from, v_face) {
            (WindFrom::West, _) => (v_face, [j, i], 1.0),
            (WindFrom::East, false) => (false, [ny - 1 - j, nx - i], -1.0),
            (WindFrom::East, true) => (true, [ny - j, nx - 1 - i], -1.0),
            // x' = y, y' = W - x: u = -v', v = u'.
            (WindFrom::South, false) => (true, [nx - i, j], -1.0),
            (WindFrom::South, true) => (false, [nx - 1 - i, j], 1.0),
            // x' = H - y, y' = x: u = v', v = -u'.
            (WindFrom::North, false) => (true, [i, ny - 1 - j], 1.0),
            (WindFrom::North, true) => (false, [i, ny - j], -1.0),
        }
    }
}

/// `spec` with its obstacles' corners mapped by `map` onto an arena of `[width, height]` with
/// wind from `from`.
fn turn_spec(
    spec: &LayoutSpec,
    map: impl Fn(f64, f64) -> (f64, f64),
    [width_m, height_m]: [f64; 2],
    from: WindFrom,
) -> LayoutSpec {
    let obstacles = spec
        .obstacles
        .iter()
        .map(|o| {
            let (ax, ay) = map(o.x_min, o.y_min);
            let (bx, by) = map(o.x_max, o.y_max);
            Obstacle {
                x_min: ax.min(bx),
                y_min: ay.min(by),
                x_max: ax.max(bx),
                y_max: ay.max(by),
            }
        })
        .collect();
    let mut wind = spec.wind;
    wind.from = from;
    LayoutSpec {
        width_m,
        height_m,
        obstacles,
        wind,
        ..spec.clone()
    }
}

/// Validates a turned layout and checks that it rasterises to the turned grid `expected` (a
/// rotation maps cell centres onto cell centres, so only rounding can break this).
fn checked(spec: LayoutSpec, expected: &Array2<bool>) -> Result<Layout> {
    let layout = spec.check()?;
    if layout.solid() != expected {
        return Err(Error::Layout(
            "turned into the wind's frame, an obstacle edge lands on a cell centre differently \
             (move the obstacle edges off the cell centres)"
                .into(),
        ));
    }
    Ok(layout)
}
