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
fn mass_is_conserved_across_every_section_and_obstacles_are_impermeable() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    assert!(w.residual < WindConfig::default().tolerance);
    let inflow = 0.75 * l.height();
    for (i, flux) in w.section_fluxes().iter().enumerate() {
        assert!(
            (flux - inflow).abs() < 0.01 * inflow,
            "section {i}: {flux} vs {inflow}"
        );
    }
    assert_no_flow_into_obstacles(&l, &w);
    // The flow speeds up through the gaps beside the obstacles and slows in their wakes.
    let centred = w.centred();
    let gap = centred[[0, 2, 56]]; // below obstacle 0 (0 < y < 0.6 m at x = 7 m)
    let wake = centred[[0, 9, 62]]; // just behind obstacle 0
    assert!(gap > 0.75 && wake < 0.3, "gap {gap}, wake {wake}");
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
        let dx = l.cell();
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
        // By column: the mean |v| of the crosswind against the wind speed.
        let profile: Vec<f64> = (0..nx)
            .map(|i| (1..ny).map(|j| c.v[[j, i]].abs()).sum::<f64>() / (ny - 1) as f64 / 0.75)
            .collect();
        let at = |x: f64| profile[((x / dx) as usize).min(nx - 1)];
        println!(
            "{name}: crosswind |v| / U at x = 0.5, 1, 2, 4, 9, 14, 16, 17, 17.5 m: {:.3} {:.3} {:.3} {:.3} {:.3} {:.3} {:.3} {:.3} {:.3}",
            at(0.5),
            at(1.0),
            at(2.0),
            at(4.0),
            at(9.0),
            at(14.0),
            at(16.0),
            at(17.0),
            at(17.5)
        );
        if name == "empty" {
            assert!(at(9.0) < 1e-3, "{name}: mid-tunnel crosswind {}", at(9.0));
        }
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
