//! Analytic reference: a steady point source in uniform wind between two parallel walls.
//!
//! In an unbounded plane, steady advection-diffusion `U dc/dx = D lap(c) + q delta` has the
//! solution `c = q / (2 pi D) * exp(a x') * K0(a r)` with `a = U / (2 D)`, `x'` the downwind
//! distance and `r` the distance to the source. Zero-flux walls at `y = 0` and `y = H` are
//! represented by image sources at `2kH +- y_s`. The inlet and outlet are not modelled: the
//! reference is accurate where the numerical domain's `c = 0` inlet is far upwind (the upwind
//! solution decays like `exp(-U |x'| / D)`).

use std::f64::consts::PI;

/// Above this argument `K0` is evaluated with its asymptotic series, scaled by `exp(a x')`
/// analytically so nothing overflows.
const ASYMPTOTIC_FROM: f64 = 50.0;

/// `exp(a x') K0(a r)` evaluated without overflow (requires `x' <= r`).
fn scaled_k0(a: f64, dx: f64, r: f64) -> f64 {
    let z = a * r;
    if z < ASYMPTOTIC_FROM {
        (a * dx).exp() * puruspe::Kn(0, z)
    } else {
        let series = 1.0 - 1.0 / (8.0 * z) + 9.0 / (128.0 * z * z);
        (PI / (2.0 * z)).sqrt() * (a * (dx - r)).exp() * series
    }
}

/// Concentration (units/m^2) at `(x, y)` of a source of `rate` units/s at `(xs, ys)` in uniform
/// wind `speed` along `+x`, diffusivity `diffusivity`, between zero-flux walls at `y = 0` and
/// `y = height`. Returns `f64::INFINITY` at the source itself.
pub fn point_source_between_walls(
    (x, y): (f64, f64),
    (xs, ys): (f64, f64),
    speed: f64,
    diffusivity: f64,
    height: f64,
    rate: f64,
) -> f64 {
    let a = speed / (2.0 * diffusivity);
    let dx = x - xs;
    let image = |yi: f64| {
        let r = dx.hypot(y - yi);
        if r == 0.0 { f64::INFINITY } else { scaled_k0(a, dx, r) }
    };
    let mut sum = image(ys) + image(-ys);
    // Images at 2kH +- ys for k != 0; stop once a whole ring is negligible.
    for k in 1.. {
        let shift = 2.0 * k as f64 * height;
        let ring = image(shift + ys) + image(-shift + ys) + image(shift - ys) + image(-shift - ys);
        sum += ring;
        if ring <= 1e-12 * sum || k > 10_000 {
            break;
        }
    }
    rate / (2.0 * PI * diffusivity) * sum
}
