//! Direct stride-1 "same" convolutions on f32 NCHW tensors: forward (bias and ReLU fused),
//! input gradient, weight gradient and bias gradient.
//!
//! Every plane is first copied into a zero-padded frame `wp = w + 2p` cells wide (`p = k / 2`),
//! so that the output cell `q = y wp + x` reads input cell `q + ky wp + kx` for tap `(ky, kx)`:
//! one flat index with no bounds to check. Outputs are computed over the whole frame (the `2p`
//! extra columns of each row are discarded) in tiles of `XW` vectors times [`COB`] output
//! channels held in registers; each tap loads `XW` input vectors and broadcasts `COB` weights.
//! The input gradient is the same convolution of the padded output gradient with the weights
//! transposed and flipped; the weight gradient is, for each tap, the dot product of an output
//! gradient plane with the shifted input plane, `COB` output channels times `k` taps of one row
//! at a time in registers.
//!
//! The instruction set is chosen at run time ([`Isa::best`]): AVX-512, AVX2 + FMA, or portable
//! code, all from the same generic kernels through `pulp`. Work is split over rayon tasks that
//! each own disjoint outputs and sum in a fixed order, so results do not depend on the thread
//! count or scheduling.

use std::sync::OnceLock;

use pulp::{Simd, WithSimd};
use rayon::prelude::*;

/// Output channels computed together by one kernel call.
pub const COB: usize = 4;

/// Extra zero cells after every padded plane: at least one tile (16 lanes x 4 vectors) plus a
/// kernel row, so that the last tile's reads stay inside the buffer.
const SLACK: usize = 128;

/// Kernel sides the kernels take (odd; the slack above bounds them).
pub const KERNELS: [usize; 4] = [1, 3, 5, 7];

/// Shape of one stride-1 "same" convolution of `[batch, cin, h, w]` by `[cout, cin, k, k]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ConvShape {
    /// Images.
    pub batch: usize,
    /// Input channels.
    pub cin: usize,
    /// Output channels.
    pub cout: usize,
    /// Rows.
    pub h: usize,
    /// Columns.
    pub w: usize,
    /// Kernel side (odd).
    pub k: usize,
}

impl ConvShape {
    /// Whether the kernels here compute this shape (a kernel side in [`KERNELS`], no empty
    /// dimension).
    pub fn supported(&self) -> bool {
        KERNELS.contains(&self.k)
            && self.batch > 0
            && self.cin > 0
            && self.cout > 0
            && self.h > 0
            && self.w > 0
    }

    fn frame(&self) -> Frame {
        let p = self.k / 2;
        let wp = self.w + 2 * p;
        Frame {
            h: self.h,
            w: self.w,
            k: self.k,
            p,
            wp,
            plane: (self.h + 2 * p) * wp + SLACK,
        }
    }

    /// Multiply-adds of the forward pass.
    pub fn macs(&self) -> usize {
        self.batch * self.cin * self.cout * self.h * self.w * self.k * self.k
    }
}

/// Geometry of the padded planes of one shape.
#[derive(Debug, Clone, Copy)]
struct Frame {
    h: usize,
    w: usize,
    k: usize,
    /// Padding on each side.
    p: usize,
    /// Padded row length.
    wp: usize,
    /// Length of one padded plane, slack included.
    plane: usize,
}

impl Frame {
    /// Output cells of the frame (`h` rows of `wp`).
    fn cells(&self) -> usize {
        self.h * self.wp
    }

    /// Copies `images x channels` planes of `h x w` into zero-padded planes, `channels_alloc`
    /// of them per image (the extra ones zero); with `mask`, cells where the mask is not
    /// positive become zero (the ReLU derivative).
    fn pad(
        &self,
        src: &[f32],
        mask: Option<&[f32]>,
        images: usize,
        channels: usize,
        channels_alloc: usize,
    ) -> Vec<f32> {
        let (h, w, p, wp) = (self.h, self.w, self.p, self.wp);
        let mut out = vec![0.0f32; images * channels_alloc * self.plane];
        out.par_chunks_mut(self.plane)
            .enumerate()
            .filter(|(i, _)| i % channels_alloc < channels)
            .for_each(|(i, dst)| {
                let plane = i / channels_alloc * channels + i % channels_alloc;
                for y in 0..h {
                    let at = (plane * h + y) * w;
                    let d = &mut dst[(y + p) * wp + p..][..w];
                    match mask {
                        None => d.copy_from_slice(&src[at..][..w]),
                        Some(m) => {
                            for ((d, &s), &m) in
                                d.iter_mut().zip(&src[at..][..w]).zip(&m[at..][..w])
                            {
                                *d = if m > 0.0 { s } else { 0.0 };
                            }
                        }
                    }
                }
            });
        out
    }
}

/// Instruction set of the kernels.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Isa {
    /// Portable code (8-wide arrays the compiler vectorises for the baseline target).
    Portable,
    /// AVX2 + FMA (x86-64-v3).
    Avx2,
    /// AVX-512 (x86-64-v4).
    Avx512,
}

impl Isa {
    /// The widest instruction set this CPU runs (detected once).
    pub fn best() -> Isa {
        static BEST: OnceLock<Isa> = OnceLock::new();
        *BEST.get_or_init(|| Isa::available().into_iter().last().unwrap_or(Isa::Portable))
    }

    /// Every instruction set this CPU runs, narrowest first.
    pub fn available() -> Vec<Isa> {
        let mut isas = vec![Isa::Portable];
        #[cfg(target_arch = "x86_64")]
        {
            if pulp::x86::V3::try_new().is_some() {
                isas.push(Isa::Avx2);
            }
            if pulp::x86::V4::try_new().is_some() {
                isas.push(Isa::Avx512);
            }
        }
        isas
    }

    /// Runs `op` compiled for this instruction set (portable code if the CPU lacks it).
    fn run<Op: WithSimd>(self, op: Op) -> Op::Output {
        #[cfg(target_arch = "x86_64")]
        match self {
            Isa::Avx512 => {
                if let Some(simd) = pulp::x86::V4::try_new() {
                    return Simd::vectorize(simd, op);
                }
            }
            Isa::Avx2 => {
                if let Some(simd) = pulp::x86::V3::try_new() {
                    return Simd::vectorize(simd, op);
                }
            }
            Isa::Portable => {}
        }
        Simd::vectorize(pulp::Scalar256b, op)
    }
}

/// Unaligned vector load of `S::F32_LANES` values at `ptr`.
///
/// # Safety
/// `ptr .. ptr + S::F32_LANES` must be readable.
#[inline(always)]
unsafe fn load<S: Simd>(ptr: *const f32) -> S::f32s {
    // SAFETY: the caller guarantees the range; `f32s` is plain old data.
    unsafe { ptr.cast::<S::f32s>().read_unaligned() }
}

/// Unaligned vector store at `ptr`.
///
/// # Safety
/// `ptr .. ptr + S::F32_LANES` must be writable.
#[inline(always)]
unsafe fn store<S: Simd>(ptr: *mut f32, value: S::f32s) {
    // SAFETY: the caller guarantees the range.
    unsafe { ptr.cast::<S::f32s>().write_unaligned(value) }
}

/// Packs `[cout, cin, k, k]` weights as `[cout / COB][ins_alloc][k][k][COB]` (zeros past
/// `cout` and past `cin`). With `transpose_flip`, packs the weights of the input gradient
/// instead: output channel `i` and input channel `o` of the result are `w[o][i]` rotated by
/// 180 degrees.
fn pack(
    w: &[f32],
    cout: usize,
    cin: usize,
    k: usize,
    transpose_flip: bool,
    ins_alloc: usize,
) -> Vec<f32> {
    let (outs, ins) = if transpose_flip {
        (cin, cout)
    } else {
        (cout, cin)
    };
    let blocks = outs.div_ceil(COB);
    let mut packed = vec![0.0f32; blocks * ins_alloc * k * k * COB];
    for o in 0..outs {
        for i in 0..ins {
            for ky in 0..k {
                for kx in 0..k {
                    let value = if transpose_flip {
                        w[((i * cin + o) * k + (k - 1 - ky)) * k + (k - 1 - kx)]
                    } else {
                        w[((o * cin + i) * k + ky) * k + kx]
                    };
                    packed[((((o / COB) * ins_alloc + i) * k + ky) * k + kx) * COB + o % COB] =
                        value;
                }
            }
        }
    }
    packed
}

/// One image and one block of [`COB`] output channels over the whole frame.
struct ForwardTask<'a> {
    frame: Frame,
    cin: usize,
    /// `cin` padded planes of one image.
    xp: &'a [f32],
    /// Packed weights of this block, `[cin][k][k][COB]`.
    weights: &'a [f32],
    bias: [f32; COB],
    relu: bool,
    /// `COB` output planes of `frame.plane` cells.
    out: &'a mut [f32],
}

impl WithSimd for ForwardTask<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        if S::F32_LANES >= 16 {
            self.tiles::<S, 2>(simd)
        } else {
            self.tiles::<S, 3>(simd)
        }
    }
}

impl ForwardTask<'_> {
    #[inline(always)]
    fn tiles<S: Simd, const XW: usize>(self, simd: S) {
        let lanes = S::F32_LANES;
        let tile = lanes * XW;
        let Frame { k, wp, plane, .. } = self.frame;
        let cells = self.frame.cells();
        assert!(tile <= 64 && cells + tile + (k - 1) * (wp + 1) <= plane);
        assert!(self.xp.len() >= self.cin * plane && self.out.len() >= COB * plane);
        assert!(self.weights.len() >= self.cin * k * k * COB);
        let zero = simd.splat_f32s(0.0);
        let xp = self.xp.as_ptr();
        let wt = self.weights.as_ptr();
        let out = self.out.as_mut_ptr();
        let mut q0 = 0;
        while q0 < cells {
            let mut acc = [[zero; XW]; COB];
            for (c, row) in acc.iter_mut().enumerate() {
                *row = [simd.splat_f32s(self.bias[c]); XW];
            }
            for ci in 0..self.cin {
                for ky in 0..k {
                    for kx in 0..k {
                        let offset = ci * plane + q0 + ky * wp + kx;
                        let tap = ((ci * k + ky) * k + kx) * COB;
                        // SAFETY: offset + tile <= (ci + 1) * plane because q0 < cells and
                        // cells + tile + (k - 1) (wp + 1) <= plane; tap + COB <= weights.len()
                        // (both asserted).
                        let v: [S::f32s; XW] = std::array::from_fn(|j| unsafe {
                            load::<S>(xp.add(offset + j * lanes))
                        });
                        for (c, row) in acc.iter_mut().enumerate() {
                            let wc = simd.splat_f32s(unsafe { *wt.add(tap + c) });
                            for (a, &x) in row.iter_mut().zip(&v) {
                                *a = simd.mul_add_e_f32s(wc, x, *a);
                            }
                        }
                    }
                }
            }
            for (c, row) in acc.iter().enumerate() {
                for (j, &a) in row.iter().enumerate() {
                    let a = if self.relu { simd.max_f32s(a, zero) } else { a };
                    // SAFETY: c * plane + q0 + tile <= COB * plane (asserted).
                    unsafe { store::<S>(out.add(c * plane + q0 + j * lanes), a) };
                }
            }
            q0 += tile;
        }
    }
}

/// Padded planes of a batch: `channels` per image.
#[derive(Clone, Copy)]
struct Padded<'a> {
    frame: Frame,
    data: &'a [f32],
    batch: usize,
    channels: usize,
}

/// Convolves padded planes with packed weights, adds `bias`,
/// applies ReLU if asked and returns `[batch, cout, h, w]`.
fn convolve_padded(
    isa: Isa,
    input: Padded<'_>,
    cout: usize,
    packed: &[f32],
    bias: Option<&[f32]>,
    relu: bool,
) -> Vec<f32> {
    let Padded {
        frame,
        data: xp,
        batch,
        channels: cin,
    } = input;
    let blocks = cout.div_ceil(COB);
    let block_weights = cin * frame.k * frame.k * COB;
    let mut scratch = vec![0.0f32; batch * blocks * COB * frame.plane];
    scratch
        .par_chunks_mut(COB * frame.plane)
        .enumerate()
        .for_each(|(task, out)| {
            let (b, block) = (task / blocks, task % blocks);
            let bias = std::array::from_fn(|c| {
                let co = block * COB + c;
                bias.filter(|_| co < cout).map_or(0.0, |bias| bias[co])
            });
            isa.run(ForwardTask {
                frame,
                cin,
                xp: &xp[b * cin * frame.plane..][..cin * frame.plane],
                weights: &packed[block * block_weights..][..block_weights],
                bias,
                relu,
                out,
            });
        });
    let (h, w, wp) = (frame.h, frame.w, frame.wp);
    let mut out = vec![0.0f32; batch * cout * h * w];
    out.par_chunks_mut(h * w).enumerate().for_each(|(i, dst)| {
        let (b, co) = (i / cout, i % cout);
        let src = &scratch[(b * blocks * COB + co) * frame.plane..];
        for (y, row) in dst.chunks_mut(w).enumerate() {
            row.copy_from_slice(&src[y * wp..][..w]);
        }
    });
    out
}

/// Forward pass: `[batch, cin, h, w]` input, `[cout, cin, k, k]` weights, optional `[cout]`
/// bias; returns `[batch, cout, h, w]`, through ReLU if `relu`.
///
/// # Panics
/// If the shape is not [`ConvShape::supported`] or a slice does not match it.
pub fn forward(
    isa: Isa,
    shape: ConvShape,
    x: &[f32],
    w: &[f32],
    bias: Option<&[f32]>,
    relu: bool,
) -> Vec<f32> {
    let ConvShape {
        batch,
        cin,
        cout,
        h,
        w: width,
        k,
    } = shape;
    assert!(shape.supported(), "unsupported convolution {shape:?}");
    assert_eq!(x.len(), batch * cin * h * width);
    assert_eq!(w.len(), cout * cin * k * k);
    assert!(bias.is_none_or(|b| b.len() == cout));
    let frame = shape.frame();
    let xp = frame.pad(x, None, batch, cin, cin);
    let packed = pack(w, cout, cin, k, false, cin);
    let input = Padded {
        frame,
        data: &xp,
        batch,
        channels: cin,
    };
    convolve_padded(isa, input, cout, &packed, bias, relu)
}

/// Gradients of one convolution.
#[derive(Debug, Clone, PartialEq)]
pub struct ConvGrads {
    /// Of the input, `[batch, cin, h, w]` (when asked for).
    pub x: Option<Vec<f32>>,
    /// Of the weights, `[cout, cin, k, k]`.
    pub weight: Vec<f32>,
    /// Of the bias, `[cout]`.
    pub bias: Vec<f32>,
}

/// Backward pass of [`forward`]: `grad` is the gradient of the output `[batch, cout, h, w]`;
/// `relu_out`, the forward output, when the forward applied ReLU (its zeros block the
/// gradient). The input gradient is computed only if `need_x`.
///
/// # Panics
/// If the shape is not [`ConvShape::supported`] or a slice does not match it.
pub fn backward(
    isa: Isa,
    shape: ConvShape,
    x: &[f32],
    w: &[f32],
    relu_out: Option<&[f32]>,
    grad: &[f32],
    need_x: bool,
) -> ConvGrads {
    let ConvShape {
        batch,
        cin,
        cout,
        h,
        w: width,
        k,
    } = shape;
    assert!(shape.supported(), "unsupported convolution {shape:?}");
    assert_eq!(x.len(), batch * cin * h * width);
    assert_eq!(w.len(), cout * cin * k * k);
    assert_eq!(grad.len(), batch * cout * h * width);
    assert!(relu_out.is_none_or(|o| o.len() == grad.len()));
    let frame = shape.frame();
    let blocks = cout.div_ceil(COB);
    // The output gradient (ReLU applied) on padded planes, `blocks * COB` planes per image so
    // that every block of the weight gradient reads whole blocks. Shifted by `p wp + p`, a
    // padded plane is the gradient on the output frame with zeros in the extra columns.
    let gplanes = blocks * COB;
    let gp = frame.pad(grad, relu_out, batch, cout, gplanes);
    let dx = need_x.then(|| {
        let packed = pack(w, cout, cin, k, true, gplanes);
        let input = Padded {
            frame,
            data: &gp,
            batch,
            channels: gplanes,
        };
        convolve_padded(isa, input, cin, &packed, None, false)
    });
    let xp = frame.pad(x, None, batch, cin, cin);
    let tasks: Vec<(usize, usize)> = (0..blocks)
        .flat_map(|block| (0..cin).map(move |ci| (block, ci)))
        .collect();
    let per_task: Vec<Vec<f32>> = tasks
        .par_iter()
        .map(|&(block, ci)| {
            let mut out = vec![0.0f32; COB * k * k];
            isa.run(WeightTask {
                frame,
                batch,
                gp: &gp,
                gplanes,
                block,
                xp: &xp,
                cin,
                ci,
                out: &mut out,
            });
            out
        })
        .collect();
    let mut dw = vec![0.0f32; cout * cin * k * k];
    for (&(block, ci), values) in tasks.iter().zip(&per_task) {
        for c in 0..COB {
            let co = block * COB + c;
            if co < cout {
                dw[(co * cin + ci) * k * k..][..k * k]
                    .copy_from_slice(&values[c * k * k..][..k * k]);
            }
        }
    }
    let db = (0..cout)
        .into_par_iter()
        .map(|co| {
            let mut sum = 0.0f64;
            for b in 0..batch {
                sum += grad_plane_sum(
                    &frame,
                    &gp[(b * gplanes + co) * frame.plane..][..frame.plane],
                );
            }
            sum as f32
        })
        .collect();
    ConvGrads {
        x: dx,
        weight: dw,
        bias: db,
    }
}

/// Sum of the gradient over the valid cells of one padded plane.
fn grad_plane_sum(frame: &Frame, plane: &[f32]) -> f64 {
    (0..frame.h)
        .map(|y| {
            plane[(y + frame.p) * frame.wp + frame.p..][..frame.w]
                .iter()
                .map(|&v| f64::from(v))
                .sum::<f64>()
        })
        .sum()
}

/// The weight gradient of one block of [`COB`] output channels and one input channel, summed
/// over the batch.
struct WeightTask<'a> {
    frame: Frame,
    batch: usize,
    /// Padded output-gradient planes, `gplanes` per image.
    gp: &'a [f32],
    gplanes: usize,
    block: usize,
    /// Padded input planes, `cin` per image.
    xp: &'a [f32],
    cin: usize,
    ci: usize,
    /// `[COB][k][k]`.
    out: &'a mut [f32],
}

impl WithSimd for WeightTask<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        match self.frame.k {
            1 => self.taps::<S, 1>(simd),
            3 => self.taps::<S, 3>(simd),
            5 => self.taps::<S, 5>(simd),
            _ => self.taps::<S, 7>(simd),
        }
    }
}

impl WeightTask<'_> {
    /// `K` taps of one kernel row at a time in registers.
    #[inline(always)]
    fn taps<S: Simd, const K: usize>(self, simd: S) {
        let lanes = S::F32_LANES;
        let Frame { p, wp, plane, .. } = self.frame;
        let cells = self.frame.cells();
        let shift = p * wp + p;
        assert!(self.frame.k == K && cells + lanes + (K - 1) * (wp + 1) <= plane);
        assert!(self.gp.len() >= self.batch * self.gplanes * plane);
        assert!(self.xp.len() >= self.batch * self.cin * plane);
        assert!((self.block + 1) * COB <= self.gplanes && self.out.len() >= COB * K * K);
        let zero = simd.splat_f32s(0.0);
        let gp = self.gp.as_ptr();
        let xp = self.xp.as_ptr();
        for ky in 0..K {
            let mut acc = [[zero; COB]; K];
            for b in 0..self.batch {
                let g0 = (b * self.gplanes + self.block * COB) * plane + shift;
                let x0 = (b * self.cin + self.ci) * plane + ky * wp;
                let mut q = 0;
                while q < cells {
                    // SAFETY: g0 + c * plane + q + lanes <= (b gplanes + block COB + c + 1) plane
                    // because shift + cells + lanes <= plane; x0 + q + kx + lanes stays inside
                    // plane (ci) of image b because (K - 1)(wp + 1) + cells + lanes <= plane
                    // (both asserted).
                    let g: [S::f32s; COB] =
                        std::array::from_fn(|c| unsafe { load::<S>(gp.add(g0 + c * plane + q)) });
                    for (kx, row) in acc.iter_mut().enumerate() {
                        let xv = unsafe { load::<S>(xp.add(x0 + q + kx)) };
                        for (a, &g) in row.iter_mut().zip(&g) {
                            *a = simd.mul_add_e_f32s(g, xv, *a);
                        }
                    }
                    q += lanes;
                }
            }
            for (kx, row) in acc.iter().enumerate() {
                for (c, &a) in row.iter().enumerate() {
                    self.out[(c * K + ky) * K + kx] = simd.reduce_sum_f32s(a);
                }
            }
        }
    }
}
