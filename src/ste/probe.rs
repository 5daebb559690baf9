//! The upwind probe: where the robot must have sensed before a run may declare convergence.
//!
//! A posterior that settles on a cell downwind of the true source, where the plume still runs
//! narrow (along a wall, say), explains every reading the robot took downwind of both as well
//! as the source does. What tells them apart lies between them: a source at the estimate
//! leaves clean air just upwind of it, a source further upwind leaves gas there. So a run that
//! would stop, unless it has sensed the point [`Termination::upwind_probe_m`] upwind of its
//! estimate already, first drives upwind beyond that point and back downwind through it to the
//! estimate, and stops only when the posterior, with those readings, still holds. The return
//! from upwind matters: readings taken while driving upwind out of the estimate's plume are
//! lagged by the sensor's slow recovery, which the rank likelihood cannot tell from gas.
//!
//! [`Termination::upwind_probe_m`]: crate::ste::termination::Termination::upwind_probe_m

use crate::layout::Layout;
use crate::ste::posterior::Sample;
use crate::ste::robot::Occupancy;

/// Readings within this distance (m) of the probe point sense it: about the width of a plume
/// 1 m downwind of its source (`sqrt(2 D x / U)` with the default diffusivity, 0.05 m²/s, at
/// 0.75 m/s), one and a half candidate cells.
pub const PROBE_RADIUS_M: f64 = 0.375;

/// Where the robot must have sensed before it stops with its estimate at `estimate`: the point
/// `distance_m` upwind of it along the inlet's wind, or the nearest point the robot may stand
/// on. `None` when that lies farther than [`PROBE_RADIUS_M`] from it (upwind lies beyond the
/// inlet or inside an obstacle: there is nothing there to sense) or `distance_m` is 0.
pub fn probe_point(
    layout: &Layout,
    occupancy: &Occupancy,
    estimate: [f64; 2],
    distance_m: f64,
) -> Option<[f64; 2]> {
    if distance_m <= 0.0 {
        return None;
    }
    let upwind = upwind_of(layout, estimate, distance_m);
    let point = occupancy.free_or_nearest(upwind);
    (distance(point, upwind) <= PROBE_RADIUS_M).then_some(point)
}

/// The point `distance_m` upwind of `p` along the inlet's wind.
fn upwind_of(layout: &Layout, p: [f64; 2], distance_m: f64) -> [f64; 2] {
    let [dx, dy] = layout.wind_from().downwind();
    [p[0] - distance_m * dx, p[1] - distance_m * dy]
}

/// How far (m) beyond the probe point the robot drives upwind before it returns to it: about
/// two of Sensor II's recovery time constants (4.6 s) at the robot's 0.27 m/s, so that when it
/// senses the probe the sensor has forgotten the estimate's plume, which it may have crossed
/// on its way.
pub const PROBE_RUN_UP_M: f64 = 2.5;

/// The probe's leg from `from`: upwind to [`PROBE_RUN_UP_M`] beyond `point`, then back
/// downwind through it to `end`; straight to `point` when that cannot be driven; `None` when
/// `point` is unreachable.
pub fn probe_path(
    layout: &Layout,
    occupancy: &Occupancy,
    from: [f64; 2],
    point: [f64; 2],
    end: [f64; 2],
) -> Option<Vec<[f64; 2]>> {
    let run_up = occupancy.free_or_nearest(upwind_of(layout, point, PROBE_RUN_UP_M));
    let there = occupancy.plan(from, run_up);
    let back = occupancy.plan(run_up, end);
    match (there, back) {
        (Some(mut path), Some(back)) => {
            path.extend(back.into_iter().skip(1));
            path.dedup();
            Some(path)
        }
        _ => occupancy.plan(from, point),
    }
}

/// Whether a reading lies within [`PROBE_RADIUS_M`] of `point`.
pub fn sensed(readings: &[Sample], point: [f64; 2]) -> bool {
    readings
        .iter()
        .any(|s| distance([s.x, s.y], point) <= PROBE_RADIUS_M)
}

fn distance(a: [f64; 2], b: [f64; 2]) -> f64 {
    (a[0] - b[0]).hypot(a[1] - b[1])
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arena() -> Layout {
        Layout::load(std::path::Path::new("data/layouts/wind-tunnel.json")).expect("the arena")
    }

    #[test]
    fn the_probe_lies_upwind_where_the_robot_can_stand() {
        let layout = arena();
        let occupancy = Occupancy::new(&layout, 0.12).expect("room for the robot");
        // The arena's wind comes from the west: upwind is -x.
        let p = probe_point(&layout, &occupancy, [12.625, 1.0], 1.0).expect("a probe");
        assert!(
            (p[0] - 11.625).abs() < 1e-9 && (p[1] - 1.0).abs() < 1e-9,
            "{p:?}"
        );
        // By the south wall the robot stands off it, within the probe's reach.
        let p = probe_point(&layout, &occupancy, [12.625, 0.125], 1.0).expect("a probe");
        assert!(occupancy.is_free(p[0], p[1]));
        assert!(distance(p, [11.625, 0.125]) <= PROBE_RADIUS_M, "{p:?}");
        // Upwind of an estimate by the inlet lies outside the room: nothing to sense.
        assert_eq!(probe_point(&layout, &occupancy, [0.5, 2.0], 1.0), None);
        // No distance, no probe.
        assert_eq!(probe_point(&layout, &occupancy, [12.625, 1.0], 0.0), None);
    }

    #[test]
    fn the_probe_leg_runs_up_beyond_the_probe_and_returns_downwind_through_it() {
        let layout = arena();
        let occupancy = Occupancy::new(&layout, 0.12).expect("room for the robot");
        let (estimate, from) = ([14.0, 1.0], [16.0, 1.0]);
        let point = probe_point(&layout, &occupancy, estimate, 1.0).expect("a probe");
        let path = probe_path(&layout, &occupancy, from, point, estimate).expect("a path");
        assert_eq!(path.first(), Some(&from));
        assert_eq!(path.last(), Some(&estimate));
        // It reaches the run-up, upwind (west) of the probe...
        let west = path.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
        assert!(
            (west - (point[0] - PROBE_RUN_UP_M)).abs() < 1e-9,
            "{path:?}"
        );
        // ...and every waypoint is one the robot may stand on.
        assert!(
            path.iter().all(|p| occupancy.is_free(p[0], p[1])),
            "{path:?}"
        );
    }

    #[test]
    fn a_reading_within_the_radius_senses_the_probe() {
        let at = |x: f64, y: f64| Sample {
            t: 0.0,
            x,
            y,
            value: 0.0,
        };
        let p = [5.0, 2.0];
        assert!(!sensed(&[], p));
        assert!(sensed(&[at(8.0, 1.0), at(5.3, 2.2)], p));
        assert!(!sensed(&[at(5.0, 2.0 + PROBE_RADIUS_M + 1e-6)], p));
    }
}
