//! Direct stride-1 "same" convolutions on f32 NCHW tensors: forward (bias and ReLU fused),
//! input gradient, weight gradient and bias gradient.
//!
//! Every plane is first copied into a zero-padded frame `wp = w + 2p` cells wide (`p = k / 2`),
//! so that the output cell `q = y wp + x` reads input cell `q + ky wp + kx` for tap `(ky, kx)`:
//! one flat index with no bounds to check. Outputs are computed over the whole frame (the `2p`
//! extra columns of each row are discarded) in tiles of `XW` vectors times `COB` output
//! channels held in registers; each tap broadcasts `COB` weights and loads `XW` input vectors.
//! The blocking is chosen per instruction set so that the accumulators, the broadcasts and one
//! input vector fit the vector registers with no spill (16 on AVX2: 2 x 6 accumulators; 32 on
//! AVX-512: 4 x 6) and give at least as many independent FMAs as the FMA latency needs.
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

/// The largest block of output channels of any kernel: gradient planes are allocated in
/// multiples of it.
const MAX_COB: usize = 4;

/// The longest forward tile (16 lanes x 6 vectors).
const TILE_MAX: usize = 96;

/// Extra zero cells after every padded plane: at least one tile plus a kernel row's overhang,
/// so that the last tile's reads stay inside the buffer.
const SLACK: usize = TILE_MAX + 16;

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

    /// Panics unless the kernels take this shape and `x` and `w` hold its input and weights.
    fn check(&self, x: &[f32], w: &[f32]) {
        assert!(self.supported(), "unsupported convolution {self:?}");
        assert_eq!(x.len(), self.batch * self.cin * self.h * self.w);
        assert_eq!(w.len(), self.cout * self.cin * self.k * self.k);
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

    /// Writes `images x channels` planes of `h x w` as zero-padded planes into `out` (resized
    /// to `images x channels_alloc` planes; the extra ones zero), every cell once; with `mask`,
    /// cells where the mask is not positive become zero (the ReLU derivative).
    fn pad_into(
        &self,
        out: &mut Vec<f32>,
        src: &[f32],
        mask: Option<&[f32]>,
        [images, channels, channels_alloc]: [usize; 3],
    ) {
        let (h, w, p, wp) = (self.h, self.w, self.p, self.wp);
        out.resize(images * channels_alloc * self.plane, 0.0);
        out.truncate(images * channels_alloc * self.plane);
        out.par_chunks_mut(self.plane)
            .enumerate()
            .for_each(|(i, dst)| {
                if i % channels_alloc >= channels {
                    dst.fill(0.0);
                    return;
                }
                let plane = i / channels_alloc * channels + i % channels_alloc;
                // Top padding and the left padding of the first row.
                dst[..p * wp + p].fill(0.0);
                for y in 0..h {
                    let at = (plane * h + y) * w;
                    let start = (y + p) * wp + p;
                    let d = &mut dst[start..][..w];
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
                    // This row's right padding and the next row's left padding.
                    dst[start + w..][..2 * p].fill(0.0);
                }
                // Bottom padding and slack.
                dst[(h + p) * wp + p..].fill(0.0);
            });
    }
}

/// Reusable padded buffers of the calling thread (a training step pads the same sizes over and
/// over; fresh buffers cost page faults and zeroing).
fn with_buffer<T>(slot: usize, f: impl FnOnce(&mut Vec<f32>) -> T) -> T {
    thread_local! {
        static BUFFERS: std::cell::RefCell<[Vec<f32>; 2]> = const {
            std::cell::RefCell::new([Vec::new(), Vec::new()])
        };
    }
    let mut buffer = BUFFERS.with(|b| std::mem::take(&mut b.borrow_mut()[slot]));
    let result = f(&mut buffer);
    BUFFERS.with(|b| b.borrow_mut()[slot] = buffer);
    result
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

    /// Output channels per forward block and per weight-gradient block: as many accumulators
    /// as the registers hold (32 vector registers on AVX-512, 16 otherwise).
    fn cob(self) -> usize {
        if self == Isa::Avx512 { 4 } else { 2 }
    }

    /// Runs `op` compiled for this instruction set (portable code if the CPU lacks it).
    pub(crate) fn run<Op: WithSimd>(self, op: Op) -> Op::Output {
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
pub(crate) unsafe fn load<S: Simd>(ptr: *const f32) -> S::f32s {
    // SAFETY: the caller guarantees the range; `f32s` is plain old data.
    unsafe { ptr.cast::<S::f32s>().read_unaligned() }
}

/// Unaligned vector store at `ptr`.
///
/// # Safety
/// `ptr .. ptr + S::F32_LANES` must be writable.
#[inline(always)]
pub(crate) unsafe fn store<S: Simd>(ptr: *mut f32, value: S::f32s) {
    // SAFETY: the caller guarantees the range.
    unsafe { ptr.cast::<S::f32s>().write_unaligned(value) }
}

/// Packs `[cout, cin, k, k]` weights as `[cout / cob][ins_alloc][k][k][cob]` (zeros past
/// `cout` and past `cin`). With `transpose_flip`, packs the weights of the input gradient
/// instead: output channel `i` and input channel `o` of the result are `w[o][i]` rotated by
/// 180 degrees.
fn pack(
    w: &[f32],
    [cout, cin, k]: [usize; 3],
    cob: usize,
    transpose_flip: bool,
    ins_alloc: usize,
) -> Vec<f32> {
    let (outs, ins) = if transpose_flip {
        (cin, cout)
    } else {
        (cout, cin)
    };
    let blocks = outs.div_ceil(cob);
    let mut packed = vec![0.0f32; blocks * ins_alloc * k * k * cob];
    for o in 0..outs {
        for i in 0..ins {
            for ky in 0..k {
                for kx in 0..k {
                    let value = if transpose_flip {
                        w[((i * cin + o) * k + (k - 1 - ky)) * k + (k - 1 - kx)]
                    } else {
                        w[((o * cin + i) * k + ky) * k + kx]
                    };
                    packed[((((o / cob) * ins_alloc + i) * k + ky) * k + kx) * cob + o % cob] =
                        value;
                }
            }
        }
    }
    packed
}

/// One image and one block of `cob` output channels over the whole frame.
struct ForwardTask<'a> {
    frame: Frame,
    cin: usize,
    cob: usize,
    /// `cin` padded planes of one image.
    xp: &'a [f32],
    /// Packed weights of this block, `[cin][k][k][cob]`.
    weights: &'a [f32],
    /// Bias of each channel of the block.
    bias: [f32; MAX_COB],
    relu: bool,
    /// The block's output planes of `h x w` (up to `cob` of them: the last block may be short).
    out: &'a mut [f32],
}

impl WithSimd for ForwardTask<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        match self.cob {
            4 => self.tiles::<S, 4, 6>(simd),
            _ => self.tiles::<S, 2, 6>(simd),
        }
    }
}

impl ForwardTask<'_> {
    #[inline(always)]
    fn tiles<S: Simd, const COB: usize, const XW: usize>(self, simd: S) {
        let lanes = S::F32_LANES;
        let tile = lanes * XW;
        let Frame { k, wp, plane, .. } = self.frame;
        let cells = self.frame.cells();
        assert!(self.cob == COB && COB <= MAX_COB && tile <= TILE_MAX);
        assert!(cells + tile + (k - 1) * (wp + 1) <= plane);
        assert!(self.xp.len() >= self.cin * plane);
        assert!(self.weights.len() >= self.cin * k * k * COB);
        let (h, w) = (self.frame.h, self.frame.w);
        let planes = self.out.len() / (h * w);
        let zero = simd.splat_f32s(0.0);
        let xp = self.xp.as_ptr();
        let wt = self.weights.as_ptr();
        let mut tile_out = [0.0f32; MAX_COB * TILE_MAX];
        let mut q0 = 0;
        while q0 < cells {
            let mut acc: [[S::f32s; XW]; COB] =
                std::array::from_fn(|c| [simd.splat_f32s(self.bias[c]); XW]);
            for ci in 0..self.cin {
                for ky in 0..k {
                    for kx in 0..k {
                        let offset = ci * plane + q0 + ky * wp + kx;
                        let tap = ((ci * k + ky) * k + kx) * COB;
                        // SAFETY: tap + COB <= weights.len(); offset + tile <= (ci + 1) plane
                        // because q0 < cells and cells + tile + (k - 1) (wp + 1) <= plane
                        // (both asserted).
                        let w: [S::f32s; COB] =
                            std::array::from_fn(|c| simd.splat_f32s(unsafe { *wt.add(tap + c) }));
                        for j in 0..XW {
                            let x = unsafe { load::<S>(xp.add(offset + j * lanes)) };
                            for (row, &wc) in acc.iter_mut().zip(&w) {
                                row[j] = simd.mul_add_e_f32s(wc, x, row[j]);
                            }
                        }
                    }
                }
            }
            for (c, row) in acc.iter().enumerate() {
                for (j, &a) in row.iter().enumerate() {
                    let a = if self.relu { simd.max_f32s(a, zero) } else { a };
                    // SAFETY: (c + 1) tile <= MAX_COB TILE_MAX (asserted).
                    unsafe { store::<S>(tile_out.as_mut_ptr().add(c * tile + j * lanes), a) };
                }
            }
            // Copy the tile's cells that lie inside the image (not in the padding columns).
            let end = (q0 + tile).min(cells);
            let mut q = q0;
            while q < end {
                let (y, x) = (q / wp, q % wp);
                if x >= w {
                    q += wp - x;
                    continue;
                }
                let run = (w - x).min(end - q);
                for c in 0..planes {
                    self.out[c * h * w + y * w + x..][..run]
                        .copy_from_slice(&tile_out[c * tile + q - q0..][..run]);
                }
                q += run;
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
    let cob = isa.cob();
    let block_weights = cin * frame.k * frame.k * cob;
    let image = cout * frame.h * frame.w;
    let mut out = vec![0.0f32; batch * image];
    out.par_chunks_mut(image)
        .enumerate()
        .for_each(|(b, planes)| {
            planes
                .par_chunks_mut(cob * frame.h * frame.w)
                .enumerate()
                .for_each(|(block, out)| {
                    let bias = std::array::from_fn(|c| {
                        let co = block * cob + c;
                        bias.filter(|_| c < cob && co < cout)
                            .map_or(0.0, |bias| bias[co])
                    });
                    isa.run(ForwardTask {
                        frame,
                        cin,
                        cob,
                        xp: &xp[b * cin * frame.plane..][..cin * frame.plane],
                        weights: &packed[block * block_weights..][..block_weights],
                        bias,
                        relu,
                        out,
                    });
                });
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
    shape.check(x, w);
    let ConvShape {
        batch,
        cin,
        cout,
        k,
        ..
    } = shape;
    assert!(bias.is_none_or(|b| b.len() == cout));
    let frame = shape.frame();
    let packed = pack(w, [cout, cin, k], isa.cob(), false, cin);
    with_buffer(0, |xp| {
        frame.pad_into(xp, x, None, [batch, cin, cin]);
        let input = Padded {
            frame,
            data: xp,
            batch,
            channels: cin,
        };
        convolve_padded(isa, input, cout, &packed, bias, relu)
    })
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
    shape.check(x, w);
    let ConvShape {
        batch,
        cin,
        cout,
        h,
        w: width,
        k,
    } = shape;
    assert_eq!(grad.len(), batch * cout * h * width);
    assert!(relu_out.is_none_or(|o| o.len() == grad.len()));
    let frame = shape.frame();
    // The output gradient (ReLU applied) on padded planes, a multiple of the largest block per
    // image so that every block of the weight gradient reads whole blocks. Shifted by
    // `p wp + p`, a padded plane is the gradient on the output frame with zeros in the extra
    // columns.
    let cob = isa.cob();
    let blocks = cout.div_ceil(cob);
    let gplanes = cout.div_ceil(MAX_COB) * MAX_COB;
    with_buffer(1, |gp| {
        frame.pad_into(gp, grad, relu_out, [batch, cout, gplanes]);
        let gp = &gp[..];
        let dx = need_x.then(|| {
            let packed = pack(w, [cout, cin, k], cob, true, gplanes);
            let input = Padded {
                frame,
                data: gp,
                batch,
                channels: gplanes,
            };
            convolve_padded(isa, input, cin, &packed, None, false)
        });
        let tasks: Vec<(usize, usize)> = (0..blocks)
            .flat_map(|block| (0..cin).map(move |ci| (block, ci)))
            .collect();
        let per_task: Vec<Vec<f32>> = with_buffer(0, |xp| {
            frame.pad_into(xp, x, None, [batch, cin, cin]);
            let xp = &xp[..];
            tasks
                .par_iter()
                .map(|&(block, ci)| {
                    let mut out = vec![0.0f32; cob * k * k];
                    isa.run(WeightTask {
                        frame,
                        cob,
                        batch,
                        gp,
                        gplanes,
                        block,
                        xp,
                        cin,
                        ci,
                        out: &mut out,
                    });
                    out
                })
                .collect()
        });
        let mut dw = vec![0.0f32; cout * cin * k * k];
        for (&(block, ci), values) in tasks.iter().zip(&per_task) {
            for c in 0..cob {
                let co = block * cob + c;
                if co < cout {
                    dw[(co * cin + ci) * k * k..][..k * k]
                        .copy_from_slice(&values[c * k * k..][..k * k]);
                }
            }
        }
        let db = (0..cout)
            .into_par_iter()
            .map(|co| {
                (0..batch)
                    .map(|b| {
                        grad_plane_sum(
                            &frame,
                            &gp[(b * gplanes + co) * frame.plane..][..frame.plane],
                        )
                    })
                    .sum::<f64>() as f32
            })
            .collect();
        ConvGrads {
            x: dx,
            weight: dw,
            bias: db,
        }
    })
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

/// The weight gradient of one block of `cob` output channels and one input channel, summed
/// over the batch.
struct WeightTask<'a> {
    frame: Frame,
    cob: usize,
    batch: usize,
    /// Padded output-gradient planes, `gplanes` per image.
    gp: &'a [f32],
    gplanes: usize,
    block: usize,
    /// Padded input planes, `cin` per image.
    xp: &'a [f32],
    cin: usize,
    ci: usize,
    /// `[cob][k][k]`.
    out: &'a mut [f32],
}

impl WithSimd for WeightTask<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        match (self.cob, self.frame.k) {
            (4, 1) => self.taps::<S, 4, 1>(simd),
            (4, 3) => self.taps::<S, 4, 3>(simd),
            (4, 5) => self.taps::<S, 4, 5>(simd),
            (4, _) => self.taps::<S, 4, 7>(simd),
            (_, 1) => self.taps::<S, 2, 1>(simd),
            (_, 3) => self.taps::<S, 2, 3>(simd),
            (_, 5) => self.taps::<S, 2, 5>(simd),
            _ => self.taps::<S, 2, 7>(simd),
        }
    }
}

impl WeightTask<'_> {
    /// `K` taps of one kernel row at a time in registers.
    #[inline(always)]
    fn taps<S: Simd, const COB: usize, const K: usize>(self, simd: S) {
        let lanes = S::F32_LANES;
        let Frame { p, wp, plane, .. } = self.frame;
        let cells = self.frame.cells();
        let shift = p * wp + p;
        assert!(
            self.cob == COB && self.frame.k == K && cells + lanes + (K - 1) * (wp + 1) <= plane
        );
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
