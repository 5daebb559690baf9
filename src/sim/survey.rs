//! Raster surveys flown through reality: paths the STE did not choose, written as the
//! `t,x,y,value` logs that [`crate::ste::replay`] reads.
//!
//! A lawnmower survey flies crosswind lanes `spacing` apart, the first half a spacing before
//! the outlet and the rest upwind from there, sweeping each lane's free stretches in alternating
//! directions (boustrophedon). Lanes keep the robot's radius and clearance from every wall and
//! obstacle; the robot drives from one stretch to the next along an A* path, and a stretch it
//! cannot reach from the one before is skipped (and counted).

use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::sim::reality::{Field, Flight, Reality};
use crate::ste::posterior::Sample;
use crate::ste::robot::{Occupancy, RobotParams};

/// A survey's planned path.
#[derive(Debug, Clone, PartialEq)]
pub struct SurveyPath {
    /// The polyline the robot drives (m).
    pub path: Vec<[f64; 2]>,
    /// Crosswind lanes with room for the robot.
    pub lanes: usize,
    /// Free stretches left out because the robot could not reach them.
    pub skipped: usize,
}

/// Plans a lawnmower survey of `layout` with crosswind lanes `spacing_m` apart.
///
/// # Errors
/// [`Error::Parameter`] for a spacing that is not a finite number between one cell and the
/// arena's length along the wind, or when no lane has room for the robot.
pub fn lawnmower(layout: &Layout, robot: &RobotParams, spacing_m: f64) -> Result<SurveyPath> {
    let frame = Frame::of(layout);
    let (length, across) = frame.canonical_sides();
    if !(spacing_m.is_finite() && spacing_m >= layout.cell() && spacing_m <= length) {
        return Err(Error::Parameter(format!(
            "--spacing {spacing_m} does not fit the arena: it must lie between one cell ({} m) and the arena's length along the wind ({length} m)",
            layout.cell()
        )));
    }
    let occupancy = Occupancy::new(layout, robot.radius_m + robot.clearance_m)?;
    let step = 0.25 * layout.cell();
    let points = (across / step).floor() as usize;
    let real = |x: f64, y: f64| {
        let (a, b) = frame.from_canonical(x, y);
        [a, b]
    };
    let mut stretches: Vec<([f64; 2], [f64; 2])> = Vec::new();
    let mut lanes = 0;
    let mut x = length - 0.5 * spacing_m;
    while x > 0.0 {
        let free = |k: usize| {
            let p = real(x, k as f64 * step);
            occupancy.is_free(p[0], p[1])
        };
        let mut lane = Vec::new();
        let mut open: Option<usize> = None;
        for k in 0..=points + 1 {
            let here = k <= points && free(k);
            match (open, here) {
                (None, true) => open = Some(k),
                (Some(a), false) => {
                    lane.push((real(x, a as f64 * step), real(x, (k - 1) as f64 * step)));
                    open = None;
                }
                _ => {}
            }
        }
        if !lane.is_empty() {
            if lanes % 2 == 1 {
                lane = lane.into_iter().rev().map(|(a, b)| (b, a)).collect();
            }
            stretches.extend(lane);
            lanes += 1;
        }
        x -= spacing_m;
    }
    let Some(&(first, _)) = stretches.first() else {
        return Err(Error::Parameter(format!(
            "the survey cannot be flown: no lane {spacing_m} m apart has room for the robot"
        )));
    };
    let mut path = vec![first];
    let mut skipped = 0;
    for (a, b) in stretches {
        let here = *path.last().expect("the path starts with a point");
        if here != a {
            match occupancy.plan(here, a) {
                Some(leg) => path.extend(leg.into_iter().skip(1)),
                None => {
                    skipped += 1;
                    continue;
                }
            }
        }
        path.push(b);
    }
    path.dedup();
    if path.len() < 2 {
        return Err(Error::Parameter(
            "the survey cannot be flown: its path has no length".into(),
        ));
    }
    Ok(SurveyPath {
        path,
        lanes,
        skipped,
    })
}

/// Flies `path` through `reality` with the source at `source`, and returns the readings. The
/// plume and the sensor noise draw from the same streams of `seed` as a localisation run's.
///
/// # Errors
/// [`Error::Source`] when the source is not in free space, [`Error::Parameter`] for bad robot
/// settings or an empty path.
pub fn fly(
    reality: &Reality,
    path: &[[f64; 2]],
    source: [f64; 2],
    flight: &Flight,
    seed: u64,
) -> Result<Vec<Sample>> {
    flight.robot.check()?;
    let Some(&start) = path.first() else {
        return Err(Error::Parameter("an empty survey path".into()));
    };
    let mut field = Field::start(reality, flight, source, start, seed)?;
    Ok(field.drive(path, &flight.robot))
}
