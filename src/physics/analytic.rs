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
/// wind `speed` along `+x`, diffusivity `diffusivity`, in an unbounded plane, with the distance
/// to the source kept at least `r_min` (which cuts off the logarithmic singularity; with
/// `r_min = 0` the source point itself gives `f64::INFINITY`).
pub fn point_source_unbounded(
    (x, y): (f64, f64),
    (xs, ys): (f64, f64),
    speed: f64,
    diffusivity: f64,
    rate: f64,
    r_min: f64,
) -> f64 {
    let a = speed / (2.0 * diffusivity);
    let dx = x - xs;
    let r = dx.hypot(y - ys).max(r_min);
    if r == 0.0 {
        return f64::INFINITY;
    }
    rate / (2.0 * PI * diffusivity) * scaled_k0(a, dx, r)
}

/// Concentration (units/m^2) at `(x, y)` of a source of `rate` units/s at `(xs, ys)` in uniform
/// wind `speed` along `+x`, diffusivity `diffusivity`, between zero-flux walls at `y = 0` and
/// `y = height` (the sum of [`point_source_unbounded`] over the mirror images). Returns
/// `f64::INFINITY` at the source itself.
pub fn point_source_between_walls(
    point: (f64, f64),
    source: (f64, f64),
    speed: f64,
    diffusivity: f64,
    height: f64,
    rate: f64,
) -> f64 {
    let plume = Plume {
        speed,
        diffusivity,
        rate,
    };
    plume.between_walls(point, source, height, 0.0, 1e-12)
}

/// A point source's physics, for the image sums of [`Plume::between_walls`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plume {
    /// Wind speed along `+x` (m/s).
    pub speed: f64,
    /// Diffusivity (m^2/s).
    pub diffusivity: f64,
    /// Release rate (units/s).
    pub rate: f64,
}

impl Plume {
    /// Concentration at `point` of the source at `(xs, ys)` between zero-flux walls at `y = 0`
    /// and `y = height`: [`point_source_unbounded`] (each image's distance kept at least
    /// `r_min`) summed over the images at `2kH +- ys`, ring by ring until a ring adds at most
    /// `tolerance` times the sum.
    pub fn between_walls(
        &self,
        point: (f64, f64),
        (xs, ys): (f64, f64),
        height: f64,
        r_min: f64,
        tolerance: f64,
    ) -> f64 {
        let image = |yi: f64| {
            point_source_unbounded(
                point,
                (xs, yi),
                self.speed,
                self.diffusivity,
                self.rate,
                r_min,
            )
        };
        let mut sum = image(ys) + image(-ys);
        // Images at 2kH +- ys for k != 0; stop once a whole ring is negligible.
        for k in 1.. {
            let shift = 2.0 * k as f64 * height;
            let ring =
                image(shift + ys) + image(-shift + ys) + image(shift - ys) + image(-shift - ys);
            sum += ring;
            if ring <= tolerance * sum || k > 10_000 {
                break;
            }
        }
        sum
    }
}

/// Relative L2 error of a numerical field against [`point_source_between_walls`] over the free
/// cells farther than `exclusion_m` from the source and at least `outlet_band_m` upwind of the
/// outlet (where the reference's unbounded domain differs from the outflow condition). The
/// layout should have no obstacles; the wind speed, diffusivity and height are taken from it.
pub fn relative_l2_error(
    layout: &crate::layout::Layout,
    field: &ndarray::Array2<f64>,
    source: (f64, f64),
    exclusion_m: f64,
    outlet_band_m: f64,
) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for ((j, i), &value) in field.indexed_iter() {
        let (x, y) = layout.cell_centre(j, i);
        let near = (x - source.0).hypot(y - source.1) < exclusion_m;
        if near || layout.is_solid(j, i) || x > layout.width() - outlet_band_m {
            continue;
        }
        let exact = point_source_between_walls(
            (x, y),
            source,
            layout.wind_speed(),
            layout.diffusivity(),
            layout.height(),
            1.0,
        );
        num += (value - exact).powi(2);
        den += exact.powi(2);
    }
    (num / den).sqrt()
}
