//! `exp(y) - 1` over slices, vectorised: the inverse of the target transform
//! ([`super::data::Normalization::inverse_slice`]) is applied to every cell of every bank, and
//! libm's scalar `expm1f` cost as much as an operator network's whole per-source head.
//!
//! Below `y = 1/2` a Taylor polynomial of `exp(y) - 1` to degree 8 (no cancellation near 0);
//! above it `exp(y) = 2^n exp(r)` with `n = round(y / ln 2)` (by the add-and-subtract-`1.5 2^23`
//! rounding), `r = y - n ln 2` in two parts (Cody and Waite), `exp(r)` by its Taylor
//! polynomial to degree 7 and `2^n` built in the exponent bits. The relative error stays within
//! a few units in the last place of f32 (tested against f64 over the whole range).

use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::conv::kernel::{Isa, load, store};

/// The largest argument kept (`exp(80)` is still finite in f32).
const MAX_ARG: f32 = 80.0;

/// Values per parallel task.
const CHUNK: usize = 1 << 14;

/// Replaces every `v` of `values` by `scale * (exp(clamp(v, 0, 80)) - 1)`.
pub fn expm1_scaled(values: &mut [f32], scale: f32) {
    expm1_scaled_on(Isa::best(), values, scale);
}

/// [`expm1_scaled`] compiled for `isa` (portable code if the CPU lacks it).
pub fn expm1_scaled_on(isa: Isa, values: &mut [f32], scale: f32) {
    values.par_chunks_mut(CHUNK).for_each(|chunk| {
        isa.run(Expm1 {
            values: chunk,
            scale,
        })
    });
}

struct Expm1<'a> {
    values: &'a mut [f32],
    scale: f32,
}

impl WithSimd for Expm1<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let lanes = S::F32_LANES;
        let whole = self.values.len() / lanes * lanes;
        let (body, tail) = self.values.split_at_mut(whole);
        for vector in body.chunks_exact_mut(lanes) {
            // SAFETY: `vector` holds `lanes` values.
            let y = unsafe { load::<S>(vector.as_ptr()) };
            let c = simd.mul_f32s(simd.splat_f32s(self.scale), expm1(simd, y));
            // SAFETY: as above.
            unsafe { store::<S>(vector.as_mut_ptr(), c) };
        }
        for v in tail {
            *v = self.scale * v.clamp(0.0, MAX_ARG).exp_m1();
        }
    }
}

/// `1/8!, 1/7!, ..., 1/1!, 1/0!`: the Taylor coefficients of `exp`, highest first.
const INVERSE_FACTORIALS: [f32; 9] = [
    1.0 / 40320.0,
    1.0 / 5040.0,
    1.0 / 720.0,
    1.0 / 120.0,
    1.0 / 24.0,
    1.0 / 6.0,
    0.5,
    1.0,
    1.0,
];

/// Horner's rule for `sum_k c_k t^k` with the coefficients highest first.
#[inline(always)]
fn horner<S: Simd>(simd: S, t: S::f32s, coefficients: &[f32]) -> S::f32s {
    let mut acc = simd.splat_f32s(0.0);
    for &c in coefficients {
        acc = simd.mul_add_f32s(acc, t, simd.splat_f32s(c));
    }
    acc
}

/// `exp(y) - 1` of `clamp(y, 0, 80)`, lane by lane (no closures: they would not be inlined
/// into the instruction set's code).
#[inline(always)]
fn expm1<S: Simd>(simd: S, y: S::f32s) -> S::f32s {
    let x = simd.min_f32s(
        simd.max_f32s(y, simd.splat_f32s(0.0)),
        simd.splat_f32s(MAX_ARG),
    );
    // Small arguments: x (1 + x/2 + x^2/6 + ... + x^7/8!).
    let small = simd.mul_f32s(x, horner(simd, x, &INVERSE_FACTORIALS[..8]));
    // Large arguments: 2^n exp(r) - 1.
    const SHIFTER: f32 = 12_582_912.0; // 1.5 * 2^23: adding it rounds to an integer
    const LN2_HI: f32 = 0.693_359_4;
    const LN2_LO: f32 = -2.121_944_4e-4;
    let shifter = simd.splat_f32s(SHIFTER);
    let t = simd.mul_add_f32s(x, simd.splat_f32s(std::f32::consts::LOG2_E), shifter);
    let n = simd.sub_f32s(t, shifter);
    let r = simd.mul_add_f32s(n, simd.splat_f32s(-LN2_HI), x);
    let r = simd.mul_add_f32s(n, simd.splat_f32s(-LN2_LO), r);
    // exp(r) to degree 7.
    let exp_r = horner(simd, r, &INVERSE_FACTORIALS[1..]);
    // The integer n sits in the low mantissa bits of t; 2^n has exponent bits n + 127.
    let bits = simd.sub_u32s(
        simd.transmute_u32s_f32s(t),
        simd.transmute_u32s_f32s(shifter),
    );
    let two_n = simd.transmute_f32s_u32s(simd.wrapping_dyn_shl_u32s(
        simd.add_u32s(bits, simd.splat_u32s(127)),
        simd.splat_u32s(23),
    ));
    let large = simd.sub_f32s(simd.mul_f32s(exp_r, two_n), simd.splat_f32s(1.0));
    simd.select_f32s(simd.less_than_f32s(x, simd.splat_f32s(0.5)), small, large)
}
