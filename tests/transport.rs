//! Mean concentration: analytic point source, obstacles, bank consistency (convergence order and
//! mass balance are verified in `verification`).

use plumenet::physics::analytic::{point_source_between_walls, relative_l2_error};
use plumenet::physics::scheme::Scheme;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;

use crate::common::{assert_err, empty_tunnel, wind_tunnel};

#[test]
fn central_scheme_is_more_accurate_than_upwind() {
    let l = empty_tunnel();
    let w = WindField::solve(&l).unwrap();
    let err = |s| {
        let t = Transport::with_scheme(&l, &w, s).unwrap();
        relative_l2_error(&l, &t.solve(3.0, 2.0).unwrap(), (3.0, 2.0), 0.5, 1.0)
    };
    // Central differences are second order (`verification`); first-order upwinding adds a
    // numerical diffusivity of U h / 2, here nearly the physical one.
    let (central, upwind) = (err(Scheme::Central), err(Scheme::Upwind));
    assert!(central < upwind, "central {central}, upwind {upwind}");
}

#[test]
fn analytic_reference_is_mirror_symmetric_about_both_walls() {
    // Even symmetry about y = 0 and y = H is exactly the zero-flux condition on the walls.
    let c = |x, y| point_source_between_walls((x, y), (3.0, 1.0), 0.75, 0.05, 4.0, 1.0);
    for x in [3.5, 4.0, 8.0, 15.0] {
        for d in [0.01, 0.3] {
            let (below, above) = (c(x, -d), c(x, d));
            assert!(
                (below - above).abs() <= 1e-9 * above,
                "x = {x}, d = {d}: {below} vs {above}"
            );
            let (outside, inside) = (c(x, 4.0 + d), c(x, 4.0 - d));
            assert!(
                (outside - inside).abs() <= 1e-9 * inside,
                "x = {x}, d = {d}"
            );
        }
    }
}

#[test]
fn fields_are_non_negative_and_zero_inside_obstacles() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let t = Transport::new(&l, &w).unwrap();
    let field = t.solve(6.0, 1.2).unwrap();
    for ((j, i), &c) in field.indexed_iter() {
        assert!(c >= -1e-12, "negative concentration {c} at ({j}, {i})");
        if l.is_solid(j, i) {
            assert_eq!(c, 0.0);
        }
    }
    // Upwind of the source the plume is nearly absent; downwind it is strong.
    assert!(field[[9, 20]] < 1e-6 && field[[9, 60]] > 0.1);
}

#[test]
fn bank_equals_individual_solves_and_rejects_bad_sources() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let t = Transport::new(&l, &w).unwrap();
    let cands = l.candidates(0.25).unwrap();
    let bank = t.bank(&cands).unwrap();
    assert_eq!(bank.dim(), (cands.len(), 32, 144));
    for k in [0, 77, cands.len() - 1] {
        let single = t.solve(cands[k][0], cands[k][1]).unwrap();
        let diff = single
            .indexed_iter()
            .map(|((j, i), &v)| (v as f32 - bank[[k, j, i]]).abs())
            .fold(0.0_f32, f32::max);
        assert!(diff < 1e-6, "candidate {k}: difference {diff}");
    }
    assert_err(
        t.bank(&[[3.0, 2.0], [7.0, 1.2]]),
        "invalid source position (7, 1.2): inside obstacle 0",
    );
    assert_err(
        t.solve(f64::NAN, 1.0),
        "invalid source position (NaN, 1): coordinates must be finite numbers",
    );
}
