//! Our convolution (src/surrogate/conv): forward and gradients against Burn's `Conv2d` and
//! autodiff on random shapes, against a brute-force f64 convolution for every instruction set
//! the CPU has, a finite-difference check, and the shipped model's bank unchanged.

use burn::nn::PaddingConfig2d;
use burn::nn::conv::Conv2dConfig;
use burn::prelude::*;
use burn::tensor::activation::relu;
use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use plumenet::plume::PlumeModel;
use plumenet::surrogate::Surrogate;
use plumenet::surrogate::backend::device;
use plumenet::surrogate::conv::conv2d_same;
use plumenet::surrogate::conv::kernel::{self, ConvShape, Isa};
use plumenet::surrogate::model::ConvImpl;

use crate::common::{repo_path, wind_tunnel};

fn random(n: usize, rng: &mut ChaCha8Rng) -> Vec<f32> {
    (0..n).map(|_| rng.random_range(-1.0f32..1.0)).collect()
}

/// Largest absolute difference, relative to the largest magnitude of the reference.
fn rel_diff(ours: &[f32], reference: &[f32]) -> f64 {
    assert_eq!(ours.len(), reference.len());
    let scale = reference
        .iter()
        .map(|v| f64::from(v.abs()))
        .fold(1e-30, f64::max);
    ours.iter()
        .zip(reference)
        .map(|(a, b)| f64::from((a - b).abs()))
        .fold(0.0, f64::max)
        / scale
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().try_to_vec::<f32>().unwrap()
}

/// Operands of one random convolution.
struct Case {
    shape: ConvShape,
    x: Vec<f32>,
    w: Vec<f32>,
    b: Vec<f32>,
    /// Weights of the loss `sum(out * r)` for gradient checks.
    r: Vec<f32>,
}

impl Case {
    fn new(shape: ConvShape, seed: u64) -> Self {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let ConvShape {
            batch,
            cin,
            cout,
            h,
            w,
            k,
        } = shape;
        Self {
            shape,
            x: random(batch * cin * h * w, &mut rng),
            w: random(cout * cin * k * k, &mut rng),
            b: random(cout, &mut rng),
            r: random(batch * cout * h * w, &mut rng),
        }
    }

    /// The case's input, weights and bias, and `r` (the upstream gradient) as tensors.
    fn tensors(&self, r: &[f32], device: &Device) -> (Tensor<4>, Tensor<4>, Tensor<1>, Tensor<4>) {
        let ConvShape {
            batch,
            cin,
            cout,
            h,
            w,
            k,
        } = self.shape;
        let t4 = |v: &[f32], s: [usize; 4]| {
            Tensor::<4>::from_data(TensorData::new(v.to_vec(), s), device)
        };
        (
            t4(&self.x, [batch, cin, h, w]),
            t4(&self.w, [cout, cin, k, k]),
            Tensor::<1>::from_data(TensorData::new(self.b.clone(), [cout]), device),
            t4(r, [batch, cout, h, w]),
        )
    }

    /// Burn's `nn::Conv2d` with these weights (and ReLU).
    fn burn_forward(&self, x: Tensor<4>, w: Tensor<4>, b: Tensor<1>, relu_on: bool) -> Tensor<4> {
        let s = self.shape;
        let mut conv = Conv2dConfig::new([s.cin, s.cout], [s.k, s.k])
            .with_padding(PaddingConfig2d::Same)
            .init(&x.device());
        conv.weight = burn::module::Param::from_tensor(w);
        conv.bias = Some(burn::module::Param::from_tensor(b));
        let out = conv.forward(x);
        if relu_on { relu(out) } else { out }
    }

    /// Forward outputs (ours, Burn's) and gradients of `sum(out * r)` with respect to x, w and
    /// b (ours, Burn's).
    fn compare(&self, relu_on: bool) -> [(Vec<f32>, Vec<f32>); 4] {
        let dev = device().autodiff();
        // Where a pre-activation lies within rounding of ReLU's kink, the two forward passes
        // may round to either side of it and pass that output's gradient back or not: no
        // gradient comes back from those outputs in either.
        let kinks: Vec<bool> = match relu_on {
            true => {
                let (x, w, b, _) = self.tensors(&self.r, &dev);
                let pre = values(self.burn_forward(x, w, b, false).inner());
                let top = pre.iter().fold(0f32, |m, v| m.max(v.abs()));
                pre.iter().map(|p| p.abs() < 1e-5 * top).collect()
            }
            false => vec![false; self.r.len()],
        };
        let r: Vec<f32> = self
            .r
            .iter()
            .zip(&kinks)
            .map(|(&r, &k)| if k { 0.0 } else { r })
            .collect();
        let run = |own: bool| {
            let (x, w, b, r) = self.tensors(&r, &dev);
            let (x, w, b) = (x.require_grad(), w.require_grad(), b.require_grad());
            let out = if own {
                conv2d_same(x.clone(), w.clone(), b.clone(), relu_on)
            } else {
                self.burn_forward(x.clone(), w.clone(), b.clone(), relu_on)
            };
            let grads = (out.clone() * r).sum().backward();
            (
                values(out.inner()),
                values(x.grad(&grads).unwrap()),
                values(w.grad(&grads).unwrap()),
                values(b.grad(&grads).unwrap()),
            )
        };
        let (o1, x1, w1, b1) = run(true);
        let (o2, x2, w2, b2) = run(false);
        [(o1, o2), (x1, x2), (w1, w2), (b1, b2)]
    }
}

fn shapes() -> impl Strategy<Value = ConvShape> {
    (
        1usize..4,
        1usize..65,
        1usize..65,
        1usize..21,
        1usize..40,
        prop::sample::select(vec![1usize, 3, 5]),
    )
        .prop_map(|(batch, cin, cout, h, w, k)| ConvShape {
            batch,
            cin,
            cout,
            h,
            w,
            k,
        })
}

proptest! {
    #![proptest_config(crate::common::proptest_config(24))]

    /// Forward equals Burn's Conv2d within 1e-5 and the three gradients equal Burn's autodiff
    /// gradients within 1e-4 (relative to the largest magnitude), with and without ReLU.
    #[test]
    fn matches_burn_forward_and_backward(shape in shapes(), seed in 0u64..1000, relu_on in any::<bool>()) {
        let case = Case::new(shape, seed);
        let [out, dx, dw, db] = case.compare(relu_on);
        prop_assert!(rel_diff(&out.0, &out.1) < 1e-5, "forward {}", rel_diff(&out.0, &out.1));
        prop_assert!(rel_diff(&dx.0, &dx.1) < 1e-4, "dx {}", rel_diff(&dx.0, &dx.1));
        prop_assert!(rel_diff(&dw.0, &dw.1) < 1e-4, "dw {}", rel_diff(&dw.0, &dw.1));
        prop_assert!(rel_diff(&db.0, &db.1) < 1e-4, "db {}", rel_diff(&db.0, &db.1));
    }
}

/// PlumeNet's own layer shapes (tile multiples and not), through Burn, forward and backward.
#[test]
fn matches_burn_on_plumenet_layers() {
    for (i, &(cin, cout, h, w)) in [
        (3, 8, 32, 144),
        (16, 8, 32, 144),
        (64, 32, 8, 36),
        (32, 32, 4, 18),
    ]
    .iter()
    .enumerate()
    {
        let shape = ConvShape {
            batch: 2,
            cin,
            cout,
            h,
            w,
            k: 5,
        };
        let [out, dx, dw, db] = Case::new(shape, i as u64).compare(true);
        assert!(rel_diff(&out.0, &out.1) < 1e-5, "{shape:?}");
        assert!(rel_diff(&dx.0, &dx.1) < 1e-4, "{shape:?}");
        assert!(rel_diff(&dw.0, &dw.1) < 1e-4, "{shape:?}");
        assert!(rel_diff(&db.0, &db.1) < 1e-4, "{shape:?}");
    }
}

/// Brute-force f64 forward (with ReLU) of a case.
fn brute_forward(case: &Case, relu_on: bool) -> Vec<f32> {
    let ConvShape {
        batch,
        cin,
        cout,
        h,
        w,
        k,
    } = case.shape;
    let p = (k / 2) as isize;
    let mut out = vec![0.0f32; batch * cout * h * w];
    for b in 0..batch {
        for co in 0..cout {
            for y in 0..h {
                for x in 0..w {
                    let mut sum = f64::from(case.b[co]);
                    for ci in 0..cin {
                        for ky in 0..k {
                            for kx in 0..k {
                                let (yy, xx) =
                                    (y as isize + ky as isize - p, x as isize + kx as isize - p);
                                if yy >= 0 && xx >= 0 && (yy as usize) < h && (xx as usize) < w {
                                    sum += f64::from(case.w[((co * cin + ci) * k + ky) * k + kx])
                                        * f64::from(
                                            case.x[((b * cin + ci) * h + yy as usize) * w
                                                + xx as usize],
                                        );
                                }
                            }
                        }
                    }
                    out[((b * cout + co) * h + y) * w + x] = if relu_on {
                        sum.max(0.0) as f32
                    } else {
                        sum as f32
                    };
                }
            }
        }
    }
    out
}

/// Every instruction set this CPU has (AVX-512, AVX2 + FMA, portable) agrees with a
/// brute-force f64 convolution and with the others, forward and backward.
#[test]
fn instruction_sets_agree_with_brute_force_and_each_other() {
    let isas = Isa::available();
    assert!(isas.contains(&Isa::Portable));
    eprintln!("instruction sets tested: {isas:?}");
    for (seed, shape) in [
        ConvShape {
            batch: 2,
            cin: 3,
            cout: 8,
            h: 7,
            w: 19,
            k: 5,
        },
        ConvShape {
            batch: 1,
            cin: 5,
            cout: 6,
            h: 9,
            w: 13,
            k: 3,
        },
        ConvShape {
            batch: 3,
            cin: 4,
            cout: 1,
            h: 4,
            w: 33,
            k: 1,
        },
        ConvShape {
            batch: 1,
            cin: 2,
            cout: 3,
            h: 6,
            w: 5,
            k: 7,
        },
    ]
    .into_iter()
    .enumerate()
    {
        let case = Case::new(shape, 100 + seed as u64);
        let expected = brute_forward(&case, true);
        let mut results = Vec::new();
        for &isa in &isas {
            let out = kernel::forward(isa, shape, &case.x, &case.w, Some(&case.b), true);
            assert!(rel_diff(&out, &expected) < 1e-5, "{isa:?} {shape:?}");
            let grads = kernel::backward(isa, shape, &case.x, &case.w, Some(&out), &case.r, true);
            results.push((isa, grads));
        }
        let (_, first) = &results[0];
        for (isa, g) in &results[1..] {
            assert!(
                rel_diff(g.x.as_ref().unwrap(), first.x.as_ref().unwrap()) < 1e-5,
                "{isa:?}"
            );
            assert!(rel_diff(&g.weight, &first.weight) < 1e-5, "{isa:?}");
            assert!(rel_diff(&g.bias, &first.bias) < 1e-5, "{isa:?}");
        }
    }
}

/// Central finite differences of `sum(conv(x, w, b) * r)` (no ReLU: the loss is linear in
/// each operand, so the difference quotient is exact up to rounding) match the gradients.
#[test]
fn gradients_match_finite_differences() {
    let shape = ConvShape {
        batch: 2,
        cin: 2,
        cout: 3,
        h: 4,
        w: 5,
        k: 3,
    };
    let case = Case::new(shape, 7);
    let loss = |x: &[f32], w: &[f32], b: &[f32]| -> f64 {
        kernel::forward(Isa::best(), shape, x, w, Some(b), false)
            .iter()
            .zip(&case.r)
            .map(|(o, r)| f64::from(*o) * f64::from(*r))
            .sum()
    };
    let g = kernel::backward(Isa::best(), shape, &case.x, &case.w, None, &case.r, true);
    let eps = 1e-2f32;
    let check = |analytic: f32, plus: f64, minus: f64, what: &str| {
        let numeric = (plus - minus) / (2.0 * f64::from(eps));
        assert!(
            (numeric - f64::from(analytic)).abs() < 2e-3 * (1.0 + numeric.abs()),
            "{what}: numeric {numeric}, analytic {analytic}"
        );
    };
    let dx = g.x.as_ref().unwrap();
    for i in (0..case.x.len()).step_by(7) {
        let (mut xp, mut xm) = (case.x.clone(), case.x.clone());
        xp[i] += eps;
        xm[i] -= eps;
        check(
            dx[i],
            loss(&xp, &case.w, &case.b),
            loss(&xm, &case.w, &case.b),
            "x",
        );
    }
    for i in 0..case.w.len() {
        let (mut wp, mut wm) = (case.w.clone(), case.w.clone());
        wp[i] += eps;
        wm[i] -= eps;
        check(
            g.weight[i],
            loss(&case.x, &wp, &case.b),
            loss(&case.x, &wm, &case.b),
            "w",
        );
    }
    for i in 0..case.b.len() {
        let (mut bp, mut bm) = (case.b.clone(), case.b.clone());
        bp[i] += eps;
        bm[i] -= eps;
        check(
            g.bias[i],
            loss(&case.x, &case.w, &bp),
            loss(&case.x, &case.w, &bm),
            "b",
        );
    }
}

/// The shipped model gives the same fields through our kernels as through Burn's `Conv2d`.
#[test]
fn shipped_model_bank_unchanged() {
    let model = Surrogate::load(&repo_path("models/default")).unwrap();
    let layout = wind_tunnel();
    let candidates = layout.candidates(0.25).unwrap();
    let sources: Vec<[f64; 2]> = candidates.iter().step_by(97).copied().collect();
    let inputs = model.inputs(&layout, &sources).unwrap();
    let [h, w] = model.grid(&layout);
    let n = sources.len();
    let input = Tensor::<4>::from_data(
        TensorData::new(inputs.concat(), [n, model.channels(), h, w]),
        &device(),
    );
    let own = values(model.net().forward_with(input.clone(), ConvImpl::Own));
    let burn = values(model.net().forward_with(input, ConvImpl::Burn));
    let diff = rel_diff(&own, &burn);
    assert!(diff < 1e-4, "bank differs by {diff}");
    // And the bank through the PlumeModel trait is the one from our kernels.
    let bank = model.bank(&layout, &sources).unwrap();
    // (cropped from the padded grid the network runs on to the layout's own)
    assert_eq!(bank.fields.shape(), &[n, layout.ny(), layout.nx()]);
    // The shipped config.json names its weights by the tensor digest.
    assert_eq!(
        plumenet::surrogate::saved::weights_digest(model.net()).unwrap(),
        model.saved().weights_digest
    );
}
