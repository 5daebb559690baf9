//! Verification of the physics against independent references: manufactured solutions for the
//! transport and the wind (observed order of accuracy against the schemes' formal order of 2),
//! plane Poiseuille flow for the wind solver, the discrete conservation laws to round-off, and
//! the bank sampler's interpolation and the rank correlation against values known by hand.
//!
//! `cargo test --release --locked --test tests verification -- --nocapture` prints the error
//! tables.

use faer::Mat;
use plumenet::frame::Frame;
use plumenet::layout::{Layout, WindFrom};
use plumenet::physics::analytic::relative_l2_error;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::{SteadyFlow, WindConfig, WindField};
use plumenet::plume::PlumeBank;
use plumenet::ste::sampler::FieldSampler;
use plumenet::surrogate::eval::spearman;
use std::f64::consts::PI;

use crate::common::{empty_tunnel, turned, wind_tunnel};

/// Grid sizes of the refinement studies (m): each half the last.
const GRIDS: [f64; 4] = [1.0 / 8.0, 1.0 / 16.0, 1.0 / 32.0, 1.0 / 64.0];

/// The two norms of most refinement tables.
const MAX_RMS: [&str; 2] = ["max", "rms"];

/// Formal order of both schemes (central differences, power law at vanishing face Reynolds
/// numbers) and the allowed distance of the observed order from it.
const FORMAL_ORDER: f64 = 2.0;
const ORDER_TOLERANCE: f64 = 0.2;

/// An empty room of `width` x `height` m with the wind from the west.
fn room(width: f64, height: f64, cell: f64, extra: &str) -> Layout {
    Layout::from_json(&format!(
        r#"{{"width_m":{width},"height_m":{height},"cell_m":{cell},"wind":{{"speed_mps":0.75}}{extra}}}"#
    ))
    .unwrap()
}

/// Observed orders `log2(e_h / e_{h/2})` of a refinement by halves.
fn orders(errors: &[f64]) -> Vec<f64> {
    errors.windows(2).map(|e| (e[0] / e[1]).log2()).collect()
}

/// Prints a refinement table of two error norms and asserts the observed order of each on the
/// two finest pairs.
fn assert_order(name: &str, norms: [&str; 2], errors: &[(f64, f64)]) {
    let max: Vec<f64> = errors.iter().map(|e| e.0).collect();
    let rms: Vec<f64> = errors.iter().map(|e| e.1).collect();
    let (p_max, p_rms) = (orders(&max), orders(&rms));
    eprintln!("{name}: h | {} | order | {} | order", norms[0], norms[1]);
    for (k, h) in GRIDS.iter().enumerate().take(errors.len()) {
        let order = |p: &[f64]| {
            k.checked_sub(1)
                .map_or("-".into(), |i| format!("{:.3}", p[i]))
        };
        eprintln!(
            "  1/{:<3} {:.3e} {:>6} {:.3e} {:>6}",
            (1.0 / h).round(),
            max[k],
            order(&p_max),
            rms[k],
            order(&p_rms)
        );
    }
    let finest = |p: &[f64]| p[p.len().saturating_sub(2)..].to_vec();
    for p in finest(&p_max).into_iter().chain(finest(&p_rms)) {
        assert!(
            (p - FORMAL_ORDER).abs() <= ORDER_TOLERANCE,
            "{name}: observed orders {} {p_max:?}, {} {p_rms:?}",
            norms[0],
            norms[1]
        );
    }
}

/// `(max, rms)` of a set of errors.
fn norms(errors: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut max, mut sum, mut n) = (0.0_f64, 0.0, 0.0);
    for e in errors {
        max = max.max(e.abs());
        sum += e * e;
        n += 1.0;
    }
    (max, (sum / n).sqrt())
}

/// Cell average of `f` over the cell centred at `(x, y)` by the 2 x 2 Gauss rule (exact for
/// cubics, so the quadrature's own error is fourth order).
fn cell_average(f: impl Fn(f64, f64) -> f64, x: f64, y: f64, h: f64) -> f64 {
    let d = h / (2.0 * 3.0_f64.sqrt());
    [(-d, -d), (-d, d), (d, -d), (d, d)]
        .iter()
        .map(|&(a, b)| f(x + a, y + b))
        .sum::<f64>()
        / 4.0
}

#[test]
fn transport_converges_at_second_order_to_a_manufactured_solution() {
    // c = sin(pi x / 2L) (1 + cos(pi y / H) / 2) meets every boundary condition of the operator:
    // c = 0 at the inlet, no flux through the side walls (c_y = 0), no diffusive flux at the
    // outlet (c_x = 0). The uniform wind of an empty room carries it; the source is what the
    // equation u c_x - D lap c leaves.
    let (width, height, wind) = (4.0, 2.0, 0.75);
    let (a, b) = (PI / (2.0 * width), PI / height);
    let exact = |x: f64, y: f64| (a * x).sin() * (1.0 + 0.5 * (b * y).cos());
    let mut errors = Vec::new();
    for h in GRIDS {
        let l = room(width, height, h, "");
        let d = l.diffusivity();
        let source = |x: f64, y: f64| {
            let c_x = a * (a * x).cos() * (1.0 + 0.5 * (b * y).cos());
            let c_xx = -a * a * exact(x, y);
            let c_yy = -0.5 * b * b * (a * x).sin() * (b * y).cos();
            wind * c_x - d * (c_xx + c_yy)
        };
        let w = WindField::solve(&l).unwrap();
        let t = Transport::new(&l, &w).unwrap();
        let (index, n) = l.free_cell_index();
        let mut rhs = Mat::<f64>::zeros(n, 1);
        for ((j, i), &k) in index.indexed_iter() {
            let (x, y) = l.cell_centre(j, i);
            rhs[(k, 0)] = cell_average(source, x, y, h) * h * h;
        }
        t.solve_unknowns(&mut rhs);
        errors.push(norms(index.indexed_iter().map(|((j, i), &k)| {
            let (x, y) = l.cell_centre(j, i);
            rhs[(k, 0)] - cell_average(exact, x, y, h)
        })));
    }
    assert_order("transport, manufactured solution", MAX_RMS, &errors);
}

#[test]
fn transport_converges_at_second_order_to_the_analytic_point_source() {
    // The 2D point source in uniform wind between two walls (Bessel K0 with image sources),
    // away from the source (0.5 m) and the outlet (1 m, where the reference's unbounded
    // domain differs from the outflow condition). The sources sit on a cell corner of every
    // grid, so the cloud-in-cell spreading is the same at each refinement; one lies near a
    // wall, where the images matter.
    for source in [(3.0, 2.0), (2.0, 0.625)] {
        let errors: Vec<(f64, f64)> = GRIDS[..3]
            .iter()
            .map(|h| {
                let l = room(18.0, 4.0, *h, "");
                let w = WindField::solve(&l).unwrap();
                let field = Transport::new(&l, &w)
                    .unwrap()
                    .solve(source.0, source.1)
                    .unwrap();
                // The relative L2 error, and the same far from the source (beyond 1.5 m).
                (
                    relative_l2_error(&l, &field, source, 0.5, 1.0),
                    relative_l2_error(&l, &field, source, 1.5, 1.0),
                )
            })
            .collect();
        assert_order(
            &format!("transport, point source at {source:?}"),
            ["relative L2 beyond 0.5 m", "beyond 1.5 m"],
            &errors,
        );
    }
}

/// `g(s) = s^3 - 1.5 s^4 + 0.6 s^5` and its first three derivatives: `g(0) = g'(0) = 0` and
/// `g'(1) = g''(1) = 0`, the shape of the manufactured wind's disturbance along the room.
fn g(s: f64) -> [f64; 4] {
    [
        s.powi(3) - 1.5 * s.powi(4) + 0.6 * s.powi(5),
        3.0 * s * s * (1.0 - s) * (1.0 - s),
        6.0 * s * (1.0 - s) * (1.0 - 2.0 * s),
        6.0 * (1.0 - 6.0 * s + 6.0 * s * s),
    ]
}

#[test]
fn wind_converges_at_second_order_to_a_manufactured_solution() {
    // u = U (1 + e g(x/L) cos(k y)), v = -U e g'(x/L) sin(k y) / (L k), k = pi / H: divergence
    // free, uniform at the inlet, free slip on the side walls (v = 0, u_y = 0), zero normal
    // gradients at the outlet; the pressure is zero, so the body force is the whole steady
    // momentum balance (u . grad) u - nu lap u.
    let (width, height, speed, e) = (4.0, 2.0, 0.75, 0.3);
    let k = PI / height;
    let nu = 0.05;
    let fields = |x: f64, y: f64| {
        let [g0, g1, g2, g3] = g(x / width);
        let (c, s) = ((k * y).cos(), (k * y).sin());
        let l = width;
        let u = speed * (1.0 + e * g0 * c);
        let v = -speed * e * g1 * s / (l * k);
        let (u_x, u_y) = (speed * e * g1 * c / l, -speed * e * g0 * k * s);
        let lap_u = speed * e * (g2 / (l * l) - g0 * k * k) * c;
        let (v_x, v_y) = (-speed * e * g2 * s / (l * l * k), -speed * e * g1 * c / l);
        let lap_v = speed * e * (-g3 / (l * l * l * k) + g1 * k / l) * s;
        let force = (
            u * u_x + v * u_y - nu * lap_u,
            u * v_x + v * v_y - nu * lap_v,
        );
        (u, v, force)
    };
    let force = |x: f64, y: f64| fields(x, y).2;
    let config = WindConfig {
        tolerance: 1e-10,
        max_steps: 50_000,
        ..WindConfig::default()
    };
    let mut errors = Vec::new();
    for h in &GRIDS[..3] {
        let l = room(
            width,
            height,
            *h,
            &format!(r#","eddy_viscosity_m2ps":{nu}"#),
        );
        let flow = SteadyFlow::solve(&l, &config, Some(&force)).unwrap();
        let w = &flow.wind;
        // Every face but the inlet's (prescribed) and the side walls' (v = 0).
        let u_err =
            w.u.indexed_iter()
                .filter(|((_, i), _)| *i > 0)
                .map(|((j, i), &u)| u - fields(i as f64 * h, (j as f64 + 0.5) * h).0);
        let walls = [0, w.v.nrows() - 1];
        let v_err =
            w.v.indexed_iter()
                .filter(|((j, _), _)| !walls.contains(j))
                .map(|((j, i), &v)| v - fields((i as f64 + 0.5) * h, j as f64 * h).1);
        let (max, rms) = norms(u_err.chain(v_err));
        errors.push((max / speed, rms / speed));
    }
    assert_order("wind, manufactured solution (errors / U)", MAX_RMS, &errors);
}

#[test]
fn wind_reproduces_plane_poiseuille_flow() {
    // A channel of height H = 1 m between no-slip walls (obstacles 0.25 m thick) carries the
    // inlet's mean speed U; downstream of the entrance the flow is u = 6 U y (H - y) / H^2 with
    // the pressure gradient dp/dx = -12 nu U / H^2. Measured at x = 4 m, 2.6 entrance lengths
    // (0.6 + 0.056 Re) H downstream at Re = U H / nu = 15.
    //
    // The discrete fully developed flow is known in closed form too: the second difference of a
    // parabola is exact, and the no-slip ghost (u = -u across the wall) shifts it, so
    // u_j = a (y_j (H - y_j) + h^2 / 4) with a = 6 U / (H^2 + 2 h^2) (the cells' midpoint sum
    // carries U H), and dp/dx = -2 nu a. The solver must reach it to the iteration's tolerance,
    // and so differ from the continuous flow by 1.5 U h^2 / H^2 at the centre, at order 2.
    let (length, channel, wall, speed, nu) = (6.0, 1.0, 0.25, 0.75, 0.05);
    let config = WindConfig {
        tolerance: 1e-9,
        max_steps: 50_000,
        ..WindConfig::default()
    };
    let mut errors = Vec::new();
    for h in &GRIDS[..3] {
        let top = channel + wall;
        let l = room(
            length,
            channel + 2.0 * wall,
            *h,
            &format!(
                r#","eddy_viscosity_m2ps":{nu},"obstacles":[
                {{"x_min":0,"y_min":0,"x_max":{length},"y_max":{wall}}},
                {{"x_min":0,"y_min":{top},"x_max":{length},"y_max":{}}}]"#,
                top + wall
            ),
        );
        let flow = SteadyFlow::solve(&l, &config, None).unwrap();
        let a = 6.0 * speed / (channel * channel + 2.0 * h * h);
        let column = (4.0 / h).round() as usize;
        let (mut discrete, mut continuous) = (Vec::new(), Vec::new());
        for (j, &u) in flow.wind.u.column(column).indexed_iter() {
            let y = (j as f64 + 0.5) * h - wall;
            if y > 0.0 && y < channel {
                let parabola = y * (channel - y);
                discrete.push((u - a * (parabola + h * h / 4.0)) / speed);
                continuous.push((u - 6.0 * speed * parabola / (channel * channel)) / speed);
            }
        }
        let (to_discrete, _) = norms(discrete.into_iter());
        let (max, rms) = norms(continuous.into_iter());
        // The pressure gradient between the cells centred at x = 4 - h/2 and 5 - h/2, on a row
        // in the channel (the developed pressure is uniform across it).
        let (i4, i5, row) = (
            (4.0 / h) as usize - 1,
            (5.0 / h) as usize - 1,
            (0.75 / h) as usize,
        );
        let slope = (flow.pressure[[row, i5]] - flow.pressure[[row, i4]]) / ((i5 - i4) as f64 * h);
        let (gradient, discrete_gradient) =
            (-12.0 * nu * speed / (channel * channel), -2.0 * nu * a);
        eprintln!(
            "Poiseuille at h = 1/{}: against the continuous flow max {max:.3e} U, rms {rms:.3e} U, \
             centre bound {:.3e} U; against the discrete flow {to_discrete:.1e} U; \
             dp/dx {slope:.6} (discrete {discrete_gradient:.6}, continuous {gradient:.6}) m/s^2",
            (1.0 / h).round(),
            1.5 * (h / channel).powi(2),
        );
        assert!(
            to_discrete < 1e-6,
            "h = {h}: {to_discrete} U off the discrete flow"
        );
        assert!(
            (slope / discrete_gradient - 1.0).abs() < 1e-6,
            "h = {h}: dp/dx {slope} against {discrete_gradient}"
        );
        assert!(
            max <= 1.5 * (h / channel).powi(2),
            "h = {h}: {max} U off the continuous flow"
        );
        errors.push((max, rms));
    }
    assert_order("wind, plane Poiseuille flow (errors / U)", MAX_RMS, &errors);
}

#[test]
fn transport_conserves_mass_to_round_off() {
    // Every row of the operator is a flux balance, so summed over the room the interior faces
    // cancel: the release leaves through the outlet or upwind through the inlet, to the
    // round-off of the fields' storage.
    let north = turned(&wind_tunnel(), WindFrom::North);
    for l in [empty_tunnel(), wind_tunnel(), north] {
        let w = WindField::solve(&l).unwrap();
        let t = Transport::new(&l, &w).unwrap();
        for src in [(3.0, 2.0), (9.0, 0.3), (12.0, 3.8), (0.2, 1.0)] {
            let (x, y) = Frame::of(&l).from_canonical(src.0, src.1);
            let field = t.solve(x, y).unwrap();
            let (inlet, outlet) = (t.inlet_flux(&field), t.outlet_flux(&field));
            // Fields are stored in single precision: each value within half an f32 epsilon,
            // relatively, and the fluxes are sums of non-negative terms.
            assert!(
                (inlet + outlet - 1.0).abs() < 0.5 * f64::from(f32::EPSILON),
                "source ({x}, {y}): inlet {inlet} + outlet {outlet}"
            );
            assert!(
                inlet >= 0.0 && outlet > 0.5,
                "inlet {inlet}, outlet {outlet}"
            );
        }
    }
}

#[test]
fn wind_conserves_mass_to_round_off() {
    // Each iteration ends with an exact projection: the flux through every cross-section equals
    // the inflow and every free cell's divergence vanishes, to round-off.
    for l in [wind_tunnel(), turned(&wind_tunnel(), WindFrom::South)] {
        let w = WindField::solve(&l).unwrap();
        let canonical = w.to_canonical(&Frame::of(&l));
        let fluxes = canonical.section_fluxes();
        let inflow = fluxes[0];
        let (ny, _) = canonical.shape();
        assert!((inflow - 0.75 * ny as f64 * l.cell()).abs() < 1e-12 * inflow);
        for (i, flux) in fluxes.iter().enumerate() {
            assert!(
                (flux - inflow).abs() < 1e-10 * inflow,
                "section {i}: {flux} against {inflow}"
            );
        }
    }
}

#[test]
fn sampler_reproduces_bilinear_fields_and_renormalises_next_to_obstacles() {
    // Bilinear interpolation between cell centres is exact for every field a + b x + c y + d x y,
    // so a bank of such fields gives back the formula anywhere between the first and last
    // centres; next to an obstacle, the free corners' weights are renormalised.
    let l = Layout::from_json(
        r#"{"width_m":4,"height_m":2,"cell_m":0.25,"wind":{"speed_mps":0.5},
            "obstacles":[{"x_min":2,"y_min":0,"x_max":2.5,"y_max":0.5}]}"#,
    )
    .unwrap();
    let (ny, nx) = l.shape();
    let coefficients = [[1.0, 0.5, -0.25, 0.125], [3.0, -0.5, 2.0, 0.0]];
    let formula = |k: usize, x: f64, y: f64| {
        let [a, b, c, d] = coefficients[k];
        a + b * x + c * y + d * x * y
    };
    let fields = ndarray::Array3::from_shape_fn((2, ny, nx), |(k, j, i)| {
        let (x, y) = l.cell_centre(j, i);
        if l.is_solid(j, i) {
            0.0
        } else {
            formula(k, x, y) as f32
        }
    });
    let bank = PlumeBank {
        candidates: vec![[0.5, 1.0], [1.0, 1.5]],
        fields,
    };
    let sampler = FieldSampler::new(&l, &bank).unwrap();
    let mut out = [0.0f32; 2];
    for (x, y) in [
        (0.125, 0.125),
        (0.3, 1.7),
        (1.01, 0.99),
        (3.6, 1.2),
        (1.875, 1.875),
    ] {
        sampler.gather(x, y, 2.0, &mut out);
        for (k, gathered) in out.iter().enumerate() {
            let want = formula(k, x, y);
            assert!(
                (f64::from(sampler.value(k, x, y)) - want).abs() < 1e-5 * want.abs().max(1.0),
                "candidate {k} at ({x}, {y})"
            );
            assert!((f64::from(*gathered) - 2.0 * want).abs() < 2e-5 * want.abs().max(1.0));
        }
    }
    // At (1.9, 0.4) the corners are the centres (1.875 | 2.125, 0.375 | 0.625); the south-east
    // one (2.125, 0.375) lies in the obstacle, so the other three share its weight in
    // proportion to their own.
    let (x, y) = (1.9, 0.4);
    let (tx, ty) = ((x - 1.875) / 0.25, (y - 0.375) / 0.25);
    for k in 0..2 {
        let free = [
            ((1.0 - tx) * (1.0 - ty), formula(k, 1.875, 0.375)),
            ((1.0 - tx) * ty, formula(k, 1.875, 0.625)),
            (tx * ty, formula(k, 2.125, 0.625)),
        ];
        let total: f64 = free.iter().map(|c| c.0).sum();
        let want = free.iter().map(|c| c.0 * c.1).sum::<f64>() / total;
        assert!((f64::from(sampler.value(k, x, y)) - want).abs() < 1e-5 * want.abs());
        assert!(
            (want - formula(k, x, y)).abs() > 1e-3,
            "the obstacle changes the value"
        );
    }
    // Inside the obstacle every candidate reads zero.
    sampler.gather(2.2, 0.2, 1.0, &mut out);
    assert_eq!(out, [0.0, 0.0]);
}

#[test]
fn spearman_matches_known_values() {
    // The textbook example (IQ against hours of television, no ties): rho = -29/165.
    let iq = [106., 100., 86., 101., 99., 103., 97., 113., 112., 110.];
    let tv = [7., 27., 2., 50., 28., 29., 20., 12., 6., 17.];
    assert!((spearman(&iq, &tv) - (-29.0 / 165.0)).abs() < 1e-12);
    // Ties take the mean rank: ranks (1, 2.5, 2.5, 4) against (1, 2, 3, 4) give 3 / sqrt(10).
    let rho = spearman(&[1.0, 2.0, 2.0, 3.0], &[10.0, 20.0, 30.0, 40.0]);
    assert!((rho - 3.0 / 10f64.sqrt()).abs() < 1e-12);
    // Monotone transforms change nothing; reversal flips the sign exactly.
    let x = [0.3, 1.7, -2.0, 5.5, 0.0, 3.3];
    let cubed: Vec<f64> = x.iter().map(|v| v * v * v).collect();
    let reversed: Vec<f64> = x.iter().map(|v| -v.exp()).collect();
    assert_eq!(spearman(&x, &cubed), 1.0);
    assert_eq!(spearman(&x, &reversed), -1.0);
}
