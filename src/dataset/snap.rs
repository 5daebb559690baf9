//! The grid that generated obstacles snap to.

use rand::RngExt;
use rand_chacha::ChaCha8Rng;

/// Obstacle corners and sizes are multiples of this (m), so that candidate source points
/// (centres of the 0.25 m grid) never lie on an obstacle edge.
pub(super) const SNAP_M: f64 = 0.25;

/// A multiple of [`SNAP_M`] in `[lo, hi]`, uniformly (`lo` rounded up to a multiple when the
/// range holds none).
pub(super) fn snapped(rng: &mut ChaCha8Rng, lo: f64, hi: f64) -> f64 {
    let lo = (lo / SNAP_M).ceil() * SNAP_M;
    let steps = ((hi - lo) / SNAP_M + 1e-9).floor().max(0.0) as u32;
    lo + SNAP_M * f64::from(rng.random_range(0..=steps))
}
