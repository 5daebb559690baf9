//! Wind: uniform flow in an empty arena, mass conservation, no flow through obstacles.

use plumenet::layout::Layout;
use plumenet::physics::wind::{WindConfig, WindField};

use crate::common::{empty_tunnel, wind_tunnel};

#[test]
fn empty_arena_gives_exactly_uniform_wind() {
    let w = WindField::solve(&empty_tunnel()).unwrap();
    assert!(w.u.iter().all(|u| (u - 0.75).abs() < 1e-9));
    assert!(w.v.iter().all(|v| v.abs() < 1e-9));
}

/// Every face of every obstacle cell carries no flow.
fn assert_no_flow_into_obstacles(l: &Layout, w: &WindField) {
    let (ny, nx) = l.shape();
    for j in 0..ny {
        for i in (0..nx).filter(|&i| l.is_solid(j, i)) {
            let faces = [w.u[[j, i]], w.u[[j, i + 1]], w.v[[j, i]], w.v[[j + 1, i]]];
            assert_eq!(faces, [0.0; 4], "flow into solid cell ({j}, {i})");
        }
    }
}

#[test]
fn obstacles_are_impermeable_and_the_flow_speeds_up_beside_them() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    assert!(w.residual < WindConfig::default().tolerance);
    assert_no_flow_into_obstacles(&l, &w);
    // At x = 7 m obstacle 0 blocks 1.25 of the 4 m, so the free part of the section carries the
    // inflow at the mean speed U H / (H - 1.25) (mass conservation, to round-off); with no slip
    // on the obstacle the fastest face there is faster still, and the slowest (against the
    // obstacle's wall) slower than U.
    let column = w.u.column((7.0 / l.cell()) as usize);
    let free: Vec<f64> = column.iter().copied().filter(|&u| u != 0.0).collect();
    let mean = free.iter().sum::<f64>() / free.len() as f64;
    let gap_mean = 0.75 * 4.0 / (4.0 - 1.25);
    assert!((mean - gap_mean).abs() < 1e-10, "{mean} against {gap_mean}");
    let (fastest, slowest) = free
        .iter()
        .fold((f64::MIN, f64::MAX), |(a, b), &u| (a.max(u), b.min(u)));
    assert!(
        fastest > gap_mean && slowest < 0.75,
        "{slowest} .. {fastest}"
    );
}

#[test]
fn interpolated_velocity_matches_the_faces() {
    let w = WindField::solve(&wind_tunnel()).unwrap();
    // u face (j = 16, i = 40) sits at x = 5.0, y = 2.0625.
    let (u, _) = w.velocity_at(5.0, 2.0625);
    assert!((u - w.u[[16, 40]]).abs() < 1e-12);
}

#[test]
fn default_tolerance_is_close_to_the_fully_converged_flow() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let tight = WindConfig {
        tolerance: 1e-7,
        ..WindConfig::default()
    };
    let reference = WindField::solve_with(&l, &tight).unwrap();
    assert!(reference.steps > w.steps);
    let diff =
        w.u.iter()
            .zip(&reference.u)
            .chain(w.v.iter().zip(&reference.v))
            .fold(0.0_f64, |m, (a, b)| m.max((a - b).abs()));
    assert!(diff < 1e-4 * 0.75, "max velocity difference {diff} m/s");
}

#[test]
fn a_turned_wind_straightens_between_side_walls() {
    for (name, l) in [("empty", empty_tunnel()), ("paper arena", wind_tunnel())] {
        let w = WindField::solve(&l).unwrap();
        let c = w.crosswind(&l).unwrap();
        let (ny, nx) = l.shape();
        // Divergence-free in every free cell, no flow through the walls or the obstacles.
        assert_no_flow_into_obstacles(&l, &c);
        for j in 0..ny {
            for i in (0..nx).filter(|&i| !l.is_solid(j, i)) {
                let div = c.u[[j, i + 1]] - c.u[[j, i]] + c.v[[j + 1, i]] - c.v[[j, i]];
                assert!(div.abs() < 1e-9, "{name}: divergence {div} at ({j}, {i})");
            }
        }
        assert!(
            c.v.row(0)
                .iter()
                .chain(c.v.row(ny).iter())
                .all(|&v| v == 0.0)
        );
        assert!(c.u.column(0).iter().all(|&u| u == 0.0));
    }
    // In the empty room the crosswind is the gradient of the harmonic function that equals
    // U (y - H/2) on the outlet with no flux elsewhere: by separation of variables
    // v = sum over odd n of (4 U / n pi) sin(n pi y / H) cosh(n pi x / H) / cosh(n pi L / H).
    // Column by column, the mean |v| over the horizontal faces matches the series to the
    // discretisation's relative error, here O((pi h / H)^2) below 1%.
    let l = empty_tunnel();
    let c = WindField::solve(&l).unwrap().crosswind(&l).unwrap();
    let ny = l.ny();
    let (dx, height, length) = (l.cell(), l.height(), l.width());
    let series = |x: f64, y: f64| {
        (0..100)
            .map(|m| {
                let n = f64::from(2 * m + 1);
                let k = n * std::f64::consts::PI / height;
                // cosh(k x) / cosh(k L), computed without overflow.
                let ratio = (k * (x - length)).exp() * (1.0 + (-2.0 * k * x).exp())
                    / (1.0 + (-2.0 * k * length).exp());
                4.0 / (n * std::f64::consts::PI) * (k * y).sin() * ratio
            })
            .sum::<f64>()
    };
    for x in [9.0, 13.0, 15.0, 16.0, 17.0] {
        let i = (x / dx) as usize;
        let xc = (i as f64 + 0.5) * dx;
        let mean = |f: &dyn Fn(usize) -> f64| (1..ny).map(f).sum::<f64>() / (ny - 1) as f64;
        let solved = mean(&|j| c.v[[j, i]].abs() / 0.75);
        let exact = mean(&|j| series(xc, j as f64 * dx).abs());
        assert!(
            (solved / exact - 1.0).abs() < 0.01,
            "x = {xc}: mean |v| / U {solved:.3e}, series {exact:.3e}"
        );
    }
    // Wind from the east: the crosswind is the west wind's turned half a circle.
    let west = empty_tunnel();
    let east = Layout::from_json(
        r#"{"width_m":18,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75,"from":"east"}}"#,
    )
    .unwrap();
    let cw = WindField::solve(&west).unwrap().crosswind(&west).unwrap();
    let ce = WindField::solve(&east).unwrap().crosswind(&east).unwrap();
    for (x, y) in [(17.0, 1.0), (16.0, 3.1), (14.5, 2.2)] {
        let (uw, vw) = cw.velocity_at(x, y);
        let (ue, ve) = ce.velocity_at(18.0 - x, 4.0 - y);
        assert!(
            (ue + uw).abs() < 1e-9 && (ve + vw).abs() < 1e-9,
            "at ({x}, {y})"
        );
    }
}
