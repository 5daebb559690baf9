//! Wind: uniform flow in an empty arena, mass conservation, no flow through obstacles.

use plumenet::physics::wind::{WindConfig, WindField};

use crate::common::{empty_tunnel, wind_tunnel};

#[test]
fn empty_arena_gives_exactly_uniform_wind() {
    let w = WindField::solve(&empty_tunnel()).unwrap();
    assert!(w.u.iter().all(|u| (u - 0.75).abs() < 1e-9));
    assert!(w.v.iter().all(|v| v.abs() < 1e-9));
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
    let (ny, nx) = l.shape();
    for j in 0..ny {
        for i in 0..nx {
            if l.is_solid(j, i) {
                assert_eq!(
                    [w.u[[j, i]], w.u[[j, i + 1]], w.v[[j, i]], w.v[[j + 1, i]]],
                    [0.0; 4]
                );
            }
        }
    }
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
