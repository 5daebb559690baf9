//! Steady, incompressible 2D wind around the obstacles.
//!
//! **Model.** The incompressible Navier-Stokes equations with a constant effective (eddy)
//! viscosity `nu` (see [`crate::layout::DEFAULT_EDDY_VISCOSITY_M2PS`]), whose steady state exists
//! for the obstacle Reynolds numbers of an indoor arena.
//!
//! **Boundary conditions** (in the canonical frame, [`crate::frame`]: a layout whose wind comes
//! from another wall is solved turned and the field turned back). Uniform inlet `u = U, v = 0`
//! at `x = 0`; outflow at `x = width`
//! (zero normal gradient of the velocity, pressure 0); free-slip side walls (`v = 0`,
//! `du/dy = 0`), so an empty arena gives exactly uniform wind; no-slip, no-through-flow
//! obstacles.
//!
//! **Method.** A staggered (MAC) finite-volume grid: `u` on vertical faces (`[ny, nx + 1]`), `v`
//! on horizontal faces (`[ny + 1, nx]`); advection-diffusion with Patankar's power-law scheme
//! (continuous in the face Reynolds number, close to central differencing below 2). The steady
//! equations are reached by pseudo-time iteration in delta form with an incremental pressure
//! projection: the steady momentum residual `R(u) - grad p` is smoothed by an approximate (ADI)
//! factorisation `(I - dt A_x)(I - dt A_y) delta = dt R` of the linearised operator (line
//! tridiagonal solves, stable far beyond the explicit limit), then `u + delta` is projected onto
//! divergence-free fields by a pressure Poisson solve and `p += phi / dt`. The Poisson matrix
//! (`p = 0` on the outlet face, Neumann elsewhere) depends only on the geometry, so it is
//! factorised once (sparse LU) and each iteration is one back-substitution. The iteration starts
//! from the discrete potential flow (the projection of uniform wind). A fixed point of the
//! iteration satisfies the discrete steady equations exactly, whatever `dt` and the
//! approximate factorisation.
//!
//! **Convergence.** The iteration stops when the steady momentum residual
//! `max |R(u) - grad p|` (an acceleration, m/s^2) falls below `tolerance * U^2 / height`
//! (default `1e-2`), and fails after `max_steps`. The residual is a conservative measure: on the
//! default arena the velocities at the default tolerance differ from a field converged to `1e-7`
//! by less than `1e-4 U` (checked by a test).
//!
//! **Cost.** A few hundred iterations, each one back-substitution and the line sweeps; this is
//! the bulk of a new layout's bank with the solver (`plumenet bench`, `docs/performance.md`).
//! Mass is conserved to round-off across every cross-section because each iteration ends with
//! an exact projection.

use ndarray::{Array2, Array3, Axis};

use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::physics::scheme::Scheme;
use crate::physics::sparse::{SparseLu, Workload, assemble};

/// Settings of the wind solver.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct WindConfig {
    /// Convergence threshold on the steady momentum residual, in units of `U^2 / height`.
    pub tolerance: f64,
    /// Give up after this many pseudo-time steps.
    pub max_steps: usize,
    /// Pseudo-time step as a Courant number `max|u| dt / dx` (4 converges fastest here).
    pub courant: f64,
}

impl Default for WindConfig {
    fn default() -> Self {
        Self {
            tolerance: 1e-2,
            max_steps: 5_000,
            courant: 4.0,
        }
    }
}

/// A converged wind field on the staggered grid.
#[derive(Debug, Clone, PartialEq)]
pub struct WindField {
    /// `u` (m/s) on vertical faces: `u[[j, i]]` sits at `x = i dx`, `y = (j + 0.5) dx`.
    pub u: Array2<f64>,
    /// `v` (m/s) on horizontal faces: `v[[j, i]]` sits at `x = (i + 0.5) dx`, `y = j dx`.
    pub v: Array2<f64>,
    /// Cell size (m).
    pub cell: f64,
    /// Iterations taken.
    pub steps: usize,
    /// Final steady momentum residual in units of `U^2 / height`.
    pub residual: f64,
}

/// Role of a face in the solver.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Face {
    /// Velocity is an unknown.
    Free,
    /// Velocity is prescribed (inlet, wall, obstacle surface).
    Fixed,
}

/// Geometry shared by every step: face roles and the factorised pressure operator.
struct Mac<'a> {
    layout: &'a Layout,
    nx: usize,
    ny: usize,
    dx: f64,
    u_face: Array2<Face>,
    v_face: Array2<Face>,
    /// Pressure unknown index of each cell (`usize::MAX` in solid cells).
    p_index: Array2<usize>,
    n_p: usize,
    poisson: SparseLu,
}

impl<'a> Mac<'a> {
    fn new(layout: &'a Layout) -> Result<Self> {
        let (ny, nx) = layout.shape();
        let solid = |j: usize, i: usize| layout.is_solid(j, i);
        let u_face = Array2::from_shape_fn((ny, nx + 1), |(j, i)| {
            let blocked = i == 0 || solid(j, i - 1) || (i < nx && solid(j, i));
            if blocked { Face::Fixed } else { Face::Free }
        });
        let v_face = Array2::from_shape_fn((ny + 1, nx), |(j, i)| {
            let blocked = j == 0 || j == ny || solid(j - 1, i) || solid(j, i);
            if blocked { Face::Fixed } else { Face::Free }
        });
        let (p_index, n_p) = layout.free_cell_index();
        // -dx^2 * div(grad p): positive definite thanks to p = 0 at the outlet.
        let mut trip = Vec::with_capacity(5 * n_p);
        for j in 0..ny {
            for i in 0..nx {
                let c = p_index[[j, i]];
                if c == usize::MAX {
                    continue;
                }
                let mut diag = 0.0;
                let mut link = |face: Face, nb: Option<(usize, usize)>| {
                    if face == Face::Free {
                        diag += 1.0;
                        if let Some((nj, ni)) = nb {
                            trip.push((c, p_index[[nj, ni]], -1.0));
                        }
                    }
                };
                link(u_face[[j, i]], i.checked_sub(1).map(|w| (j, w)));
                link(v_face[[j, i]], j.checked_sub(1).map(|s| (s, i)));
                link(v_face[[j + 1, i]], Some((j + 1, i)).filter(|_| j + 1 < ny));
                if i + 1 < nx {
                    link(u_face[[j, i + 1]], Some((j, i + 1)));
                } else if u_face[[j, nx]] == Face::Free {
                    // Dirichlet p = 0 on the outlet face, half a cell away.
                    diag += 2.0;
                }
                trip.push((c, c, diag));
            }
        }
        let poisson = SparseLu::factorize(&assemble(n_p, &trip)?, Workload::SingleRhs)?;
        Ok(Self {
            layout,
            nx,
            ny,
            dx: layout.cell(),
            u_face,
            v_face,
            p_index,
            n_p,
            poisson,
        })
    }

    /// Makes `(u, v)` discretely divergence-free: `u -= grad(phi)` with `div(grad(phi)) = div(u)`.
    /// Returns `phi` (per free cell).
    fn project(&self, u: &mut Array2<f64>, v: &mut Array2<f64>) -> Vec<f64> {
        let (nx, ny, dx) = (self.nx, self.ny, self.dx);
        let mut rhs = vec![0.0; self.n_p];
        for j in 0..ny {
            for i in 0..nx {
                let c = self.p_index[[j, i]];
                if c != usize::MAX {
                    // -dx^2 div(u), matching the scaling of the assembled operator.
                    rhs[c] = -dx * (u[[j, i + 1]] - u[[j, i]] + v[[j + 1, i]] - v[[j, i]]);
                }
            }
        }
        let phi = self.poisson.solve(&rhs);
        self.add_gradient(u, v, &phi, -1.0);
        phi
    }

    /// Adds `scale * grad(p)` to every free face (`p = 0` on the outlet face).
    fn add_gradient(&self, u: &mut Array2<f64>, v: &mut Array2<f64>, p: &[f64], scale: f64) {
        let (nx, ny, dx) = (self.nx, self.ny, self.dx);
        let at = |j: usize, i: usize| p[self.p_index[[j, i]]];
        for j in 0..ny {
            for i in 1..=nx {
                if self.u_face[[j, i]] == Face::Free {
                    let east = if i < nx { at(j, i) } else { -at(j, i - 1) };
                    u[[j, i]] += scale * (east - at(j, i - 1)) / dx;
                }
            }
        }
        for j in 1..ny {
            for i in 0..nx {
                if self.v_face[[j, i]] == Face::Free {
                    v[[j, i]] += scale * (at(j, i) - at(j - 1, i)) / dx;
                }
            }
        }
    }

    /// `u` one row up or down from face `(j, i)`, with wall ghosts: free slip at the side walls,
    /// no slip (antisymmetric ghost) against an obstacle face.
    fn u_neighbour_y(&self, u: &Array2<f64>, j: usize, i: usize, up: bool) -> f64 {
        let here = u[[j, i]];
        let nj = if up { j + 1 } else { j.wrapping_sub(1) };
        if nj >= self.ny {
            return here;
        }
        if self.u_face[[nj, i]] == Face::Fixed && i > 0 {
            let wall =
                self.layout.is_solid(nj, i - 1) && (i == self.nx || self.layout.is_solid(nj, i));
            if wall {
                return -here;
            }
        }
        u[[nj, i]]
    }

    /// `v` one column left or right of face `(j, i)`: `v = 0` ghost at the inlet, zero gradient
    /// at the outlet, no slip against an obstacle face.
    fn v_neighbour_x(&self, v: &Array2<f64>, j: usize, i: usize, right: bool) -> f64 {
        let here = v[[j, i]];
        let ni = if right { i + 1 } else { i.wrapping_sub(1) };
        if ni >= self.nx {
            return if right { here } else { -here };
        }
        if self.v_face[[j, ni]] == Face::Fixed
            && self.layout.is_solid(j - 1, ni)
            && self.layout.is_solid(j, ni)
        {
            return -here;
        }
        v[[j, ni]]
    }
}

/// Coefficients `(plus, minus)` of `nu d2phi/ds2 - a dphi/ds ~ plus (phi+ - phi) + minus
/// (phi- - phi)` from Patankar's power-law scheme, which is continuous in the face Reynolds
/// number (a switching hybrid scheme can lock the iteration into a two-step limit cycle) and
/// close to central differencing at the small face Reynolds numbers of the default arena.
fn coefficients(a: f64, dx: f64, nu: f64) -> (f64, f64) {
    let diffusion = nu / (dx * dx) * Scheme::PowerLaw.profile(a * dx / nu);
    (diffusion + (-a).max(0.0) / dx, diffusion + a.max(0.0) / dx)
}

/// Solves `(I - dt A) x = rhs` along every grid line of `axis` in place (Thomas algorithm),
/// where `A` is tridiagonal with off-diagonals `minus` (towards lower indices) and `plus`; fixed
/// faces keep `x = 0`. This is one factor of the approximate (ADI) factorisation. Works on the
/// arrays' contiguous row-major storage with a stride, which is several times faster than
/// ndarray's strided lanes for the column sweeps.
fn sweep(
    rhs: &mut Array2<f64>,
    faces: &Array2<Face>,
    minus: &Array2<f64>,
    plus: &Array2<f64>,
    dt: f64,
    axis: Axis,
) {
    let (rows, cols) = rhs.dim();
    let (n, lanes, stride, lane_step) = if axis == Axis(1) {
        (cols, rows, 1, cols)
    } else {
        (rows, cols, cols, 1)
    };
    let (Some(x), Some(f), Some(m), Some(p)) = (
        rhs.as_slice_mut(),
        faces.as_slice(),
        minus.as_slice(),
        plus.as_slice(),
    ) else {
        unreachable!("solver arrays are allocated in standard layout");
    };
    // All lines advance together (line index innermost), so the serial Thomas recurrences of
    // different lines overlap instead of waiting on each other's divisions.
    let at = |lane: usize, k: usize| lane * lane_step + k * stride;
    let mut c_prime = vec![0.0; n * lanes];
    let mut prev_c = vec![0.0; lanes];
    let mut prev_x = vec![0.0; lanes];
    for k in 0..n {
        for lane in 0..lanes {
            let idx = at(lane, k);
            if f[idx] == Face::Fixed {
                x[idx] = 0.0;
                (prev_c[lane], prev_x[lane]) = (0.0, 0.0);
                continue;
            }
            let prev_free = k > 0 && f[at(lane, k - 1)] == Face::Free;
            let lower = if prev_free { -dt * m[idx] } else { 0.0 };
            let next_free = k + 1 < n && f[at(lane, k + 1)] == Face::Free;
            let upper = if next_free { -dt * p[idx] } else { 0.0 };
            let inv = 1.0 / (1.0 + dt * (m[idx] + p[idx]) - lower * prev_c[lane]);
            x[idx] = (x[idx] - lower * prev_x[lane]) * inv;
            prev_c[lane] = upper * inv;
            c_prime[k * lanes + lane] = prev_c[lane];
            prev_x[lane] = x[idx];
        }
    }
    for k in (0..n.saturating_sub(1)).rev() {
        for lane in 0..lanes {
            let next = x[at(lane, k + 1)];
            x[at(lane, k)] -= c_prime[k * lanes + lane] * next;
        }
    }
}

impl WindField {
    /// The real wind field of a field `canonical` solved in `frame`'s canonical frame.
    pub fn from_canonical(frame: &Frame, canonical: &WindField) -> WindField {
        if frame.is_identity() {
            return canonical.clone();
        }
        let (ny, nx) = frame.real_shape();
        let pick = |v_face: bool, j: usize, i: usize| {
            let (to_v, idx, sign) = frame.face_to_canonical(v_face, j, i);
            sign * if to_v {
                canonical.v[idx]
            } else {
                canonical.u[idx]
            }
        };
        WindField {
            u: Array2::from_shape_fn((ny, nx + 1), |(j, i)| pick(false, j, i)),
            v: Array2::from_shape_fn((ny + 1, nx), |(j, i)| pick(true, j, i)),
            ..canonical.clone()
        }
    }

    /// This real wind field in `frame`'s canonical frame (the inverse of
    /// [`WindField::from_canonical`]: every canonical face is the image of one real face).
    pub fn to_canonical(&self, frame: &Frame) -> WindField {
        if frame.is_identity() {
            return self.clone();
        }
        let (nyc, nxc) = frame.canonical_shape();
        let mut out = WindField {
            u: Array2::zeros((nyc, nxc + 1)),
            v: Array2::zeros((nyc + 1, nxc)),
            ..self.clone()
        };
        for (v_face, array) in [(false, &self.u), (true, &self.v)] {
            for ((j, i), &value) in array.indexed_iter() {
                let (to_v, idx, sign) = frame.face_to_canonical(v_face, j, i);
                let target = if to_v { &mut out.v } else { &mut out.u };
                target[idx] = sign * value;
            }
        }
        out
    }

    /// Solves the steady wind of a layout with the default settings.
    ///
    /// # Errors
    /// [`Error::Solver`] when the pressure matrix is singular or the iteration does not converge.
    pub fn solve(layout: &Layout) -> Result<Self> {
        Self::solve_with(layout, &WindConfig::default())
    }

    /// Solves the steady wind of a layout.
    ///
    /// # Errors
    /// [`Error::Solver`] when the pressure matrix is singular or the iteration does not converge
    /// within `config.max_steps`; [`Error::Parameter`] for a bad configuration.
    pub fn solve_with(layout: &Layout, config: &WindConfig) -> Result<Self> {
        Ok(SteadyFlow::solve(layout, config, None)?.wind)
    }

    /// The part of this wind turned a right angle to its left (`(u, v)` to `(-v, u)`) that the
    /// room lets through: its projection onto divergence-free fields with no flow through the
    /// walls, the obstacles or the inlet (the outlet stays open). A wind turned by an angle
    /// `a` inside the room is then `cos a * self + sin a * crosswind`: divergence-free, with no
    /// flow through a wall or an obstacle, whatever `a`. Between side walls the crosswind
    /// vanishes (air cannot cross a corridor whose walls it cannot pass) except within a few
    /// room widths of the open outlet, where the flow may turn.
    ///
    /// # Errors
    /// [`Error::Solver`] when the pressure matrix is singular; the layout's errors when it
    /// cannot be turned into its canonical frame.
    pub fn crosswind(&self, layout: &Layout) -> Result<Self> {
        let frame = Frame::of(layout);
        if !frame.is_identity() {
            let canonical = self
                .to_canonical(&frame)
                .crosswind(&frame.layout_to_canonical(layout)?)?;
            return Ok(Self::from_canonical(&frame, &canonical));
        }
        let mac = Mac::new(layout)?;
        let h = self.cell;
        let mut u = Array2::from_shape_fn(self.u.dim(), |(j, i)| match mac.u_face[[j, i]] {
            Face::Free => -self.velocity_at(i as f64 * h, (j as f64 + 0.5) * h).1,
            Face::Fixed => 0.0,
        });
        let mut v = Array2::from_shape_fn(self.v.dim(), |(j, i)| match mac.v_face[[j, i]] {
            Face::Free => self.velocity_at((i as f64 + 0.5) * h, j as f64 * h).0,
            Face::Fixed => 0.0,
        });
        mac.project(&mut u, &mut v);
        Ok(Self {
            u,
            v,
            cell: h,
            steps: 0,
            residual: 0.0,
        })
    }

    /// Grid shape `[ny, nx]` of the cells.
    pub fn shape(&self) -> (usize, usize) {
        (self.u.nrows(), self.v.ncols())
    }

    /// Volumetric flux per unit depth (m^2/s) through each vertical grid line `x = i dx`,
    /// `i = 0..=nx`: the quantity that mass conservation keeps constant.
    pub fn section_fluxes(&self) -> Vec<f64> {
        (0..self.u.ncols())
            .map(|i| self.u.column(i).sum() * self.cell)
            .collect()
    }

    /// Velocities at the cell centres, shape `[2, ny, nx]` (u then v), zero in obstacle cells.
    pub fn centred(&self) -> Array3<f64> {
        let (ny, nx) = self.shape();
        Array3::from_shape_fn((2, ny, nx), |(k, j, i)| {
            if k == 0 {
                0.5 * (self.u[[j, i]] + self.u[[j, i + 1]])
            } else {
                0.5 * (self.v[[j, i]] + self.v[[j + 1, i]])
            }
        })
    }

    /// Velocity (m/s) at a point by bilinear interpolation of the staggered components.
    pub fn velocity_at(&self, x: f64, y: f64) -> (f64, f64) {
        let h = self.cell;
        (
            bilinear(&self.u, x / h, y / h - 0.5),
            bilinear(&self.v, x / h - 0.5, y / h),
        )
    }
}

/// A body force per unit mass (m/s^2) at a point `(x, y)`, as `(f_x, f_y)`.
pub type BodyForce<'a> = &'a (dyn Fn(f64, f64) -> (f64, f64) + Sync);

/// A steady solution of the wind solver with its pressure.
#[derive(Debug, Clone, PartialEq)]
pub struct SteadyFlow {
    /// The velocity field.
    pub wind: WindField,
    /// Kinematic pressure (m^2/s^2, pressure over density) at the cell centres, `[ny, nx]`, zero
    /// on the outlet face, NaN in obstacle cells.
    pub pressure: Array2<f64>,
}

impl SteadyFlow {
    /// Solves the steady wind of a layout, optionally driven by a body force as well as the
    /// inlet: `(u . grad) u = -grad p + nu lap u + f`. The force serves verification with
    /// manufactured solutions (any smooth field is the steady solution of the force that its
    /// residual calls for); the room's wind has none.
    ///
    /// # Errors
    /// [`Error::Solver`] when the pressure matrix is singular or the iteration does not converge
    /// within `config.max_steps`; [`Error::Parameter`] for a bad configuration.
    pub fn solve(layout: &Layout, config: &WindConfig, force: Option<BodyForce>) -> Result<Self> {
        let frame = Frame::of(layout);
        if !frame.is_identity() {
            // The force is turned with the room: canonical point and components.
            let turned = force.map(|f| {
                move |xc: f64, yc: f64| {
                    let (x, y) = frame.from_canonical(xc, yc);
                    let (fx, fy) = f(x, y);
                    frame.vector_to_canonical(fx, fy)
                }
            });
            let canonical = Self::solve(
                &frame.layout_to_canonical(layout)?,
                config,
                turned
                    .as_ref()
                    .map(|f| f as &(dyn Fn(f64, f64) -> (f64, f64) + Sync)),
            )?;
            return Ok(Self {
                wind: WindField::from_canonical(&frame, &canonical.wind),
                pressure: frame.cells_from_canonical(canonical.pressure.view()),
            });
        }
        if !(config.tolerance > 0.0 && config.courant > 0.0) {
            return Err(Error::Parameter(format!(
                "bad wind solver settings {config:?}"
            )));
        }
        let mac = Mac::new(layout)?;
        let (nx, ny, dx) = (mac.nx, mac.ny, mac.dx);
        let speed = layout.wind_speed();
        let nu = layout.eddy_viscosity();
        let mut u = Array2::from_shape_fn((ny, nx + 1), |(j, i)| {
            let inlet_open = i > 0 || !layout.is_solid(j, 0);
            if mac.u_face[[j, i]] == Face::Free || (i == 0 && inlet_open) {
                speed
            } else {
                0.0
            }
        });
        let mut v = Array2::zeros((ny + 1, nx));
        mac.project(&mut u, &mut v);
        // The body force on every free face, when there is one.
        let forcing = force.map(|f| {
            let on_faces = |faces: &Array2<Face>,
                            offset: (f64, f64),
                            pick: fn((f64, f64)) -> f64| {
                Array2::from_shape_fn(faces.dim(), |(j, i)| match faces[[j, i]] {
                    Face::Free => pick(f((i as f64 + offset.0) * dx, (j as f64 + offset.1) * dx)),
                    Face::Fixed => 0.0,
                })
            };
            (
                on_faces(&mac.u_face, (0.0, 0.5), |f| f.0),
                on_faces(&mac.v_face, (0.5, 0.0), |f| f.1),
            )
        });

        let scale = speed * speed / layout.height();
        let mut pressure = vec![0.0; mac.n_p];
        let mut ru = Array2::zeros(u.dim());
        let mut rv = Array2::zeros(v.dim());
        let [mut ue, mut uw, mut un, mut us] = std::array::from_fn(|_| Array2::zeros(u.dim()));
        let [mut ve, mut vw, mut vn, mut vs] = std::array::from_fn(|_| Array2::zeros(v.dim()));
        for step in 1..=config.max_steps {
            let umax = u.iter().chain(v.iter()).fold(speed, |m, &x| m.max(x.abs()));
            let dt = config.courant * dx / umax;
            for j in 0..ny {
                for i in 1..=nx {
                    if mac.u_face[[j, i]] == Face::Fixed {
                        continue;
                    }
                    let c = u[[j, i]];
                    let east = if i < nx { u[[j, i + 1]] } else { c };
                    let (il, ir) = (i - 1, i.min(nx - 1));
                    let vbar = 0.25 * (v[[j, il]] + v[[j, ir]] + v[[j + 1, il]] + v[[j + 1, ir]]);
                    let (e, w) = coefficients(c, dx, nu);
                    let (n, s) = coefficients(vbar, dx, nu);
                    (ue[[j, i]], uw[[j, i]], un[[j, i]], us[[j, i]]) = (e, w, n, s);
                    ru[[j, i]] = e * (east - c)
                        + w * (u[[j, i - 1]] - c)
                        + n * (mac.u_neighbour_y(&u, j, i, true) - c)
                        + s * (mac.u_neighbour_y(&u, j, i, false) - c);
                }
            }
            for j in 1..ny {
                for i in 0..nx {
                    if mac.v_face[[j, i]] == Face::Fixed {
                        continue;
                    }
                    let c = v[[j, i]];
                    let ubar =
                        0.25 * (u[[j - 1, i]] + u[[j - 1, i + 1]] + u[[j, i]] + u[[j, i + 1]]);
                    let (e, w) = coefficients(ubar, dx, nu);
                    let (n, s) = coefficients(c, dx, nu);
                    (ve[[j, i]], vw[[j, i]], vn[[j, i]], vs[[j, i]]) = (e, w, n, s);
                    rv[[j, i]] = e * (mac.v_neighbour_x(&v, j, i, true) - c)
                        + w * (mac.v_neighbour_x(&v, j, i, false) - c)
                        + n * (v[[j + 1, i]] - c)
                        + s * (v[[j - 1, i]] - c);
                }
            }
            // Steady momentum residual with the current pressure and the body force.
            if let Some((fu, fv)) = &forcing {
                ru += fu;
                rv += fv;
            }
            mac.add_gradient(&mut ru, &mut rv, &pressure, -1.0);
            let residual = ru
                .iter()
                .chain(rv.iter())
                .fold(0.0_f64, |m, &r| m.max(r.abs()))
                / scale;
            if !residual.is_finite() {
                return Err(Error::Solver(format!(
                    "wind iteration diverged at step {step}"
                )));
            }
            if residual < config.tolerance {
                let pressure = mac
                    .p_index
                    .mapv(|k| pressure.get(k).copied().unwrap_or(f64::NAN));
                return Ok(Self {
                    wind: WindField {
                        u,
                        v,
                        cell: dx,
                        steps: step,
                        residual,
                    },
                    pressure,
                });
            }
            // Delta form: (I - dt Ax)(I - dt Ay) delta = dt R, then project; p += phi / dt.
            ru *= dt;
            rv *= dt;
            sweep(&mut ru, &mac.u_face, &uw, &ue, dt, Axis(1));
            sweep(&mut ru, &mac.u_face, &us, &un, dt, Axis(0));
            sweep(&mut rv, &mac.v_face, &vw, &ve, dt, Axis(1));
            sweep(&mut rv, &mac.v_face, &vs, &vn, dt, Axis(0));
            u += &ru;
            v += &rv;
            let phi = mac.project(&mut u, &mut v);
            for (p, f) in pressure.iter_mut().zip(&phi) {
                *p += f / dt;
            }
        }
        Err(Error::Solver(format!(
            "wind did not reach a steady state in {} steps (raise the eddy viscosity)",
            config.max_steps
        )))
    }
}

/// Bilinear interpolation of `a` at fractional index `(col, row)`, clamped to the array.
fn bilinear(a: &Array2<f64>, col: f64, row: f64) -> f64 {
    let (rows, cols) = a.dim();
    let c = col.clamp(0.0, (cols - 1) as f64);
    let r = row.clamp(0.0, (rows - 1) as f64);
    let (c0, r0) = (c.floor() as usize, r.floor() as usize);
    let (c1, r1) = ((c0 + 1).min(cols - 1), (r0 + 1).min(rows - 1));
    let (fc, fr) = (c - c0 as f64, r - r0 as f64);
    let bottom = a[[r0, c0]] * (1.0 - fc) + a[[r0, c1]] * fc;
    let top = a[[r1, c0]] * (1.0 - fc) + a[[r1, c1]] * fc;
    bottom * (1.0 - fr) + top * fr
}
