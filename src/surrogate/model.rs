//! PlumeNet: DeepCFD's UNetEx as a Burn module.
//!
//! Encoder: at each level a block of `convs_per_level` 5x5 convolutions ("same" padding, ReLU)
//! with `filters[level]` channels, then a 2x2 max-pool (none after the deepest level). Decoder:
//! a 2x2 stride-2 transposed convolution up, concatenation with the encoder's skip tensor at that
//! level, and a block of 5x5 convolutions with ReLU. A final 1x1 convolution gives one channel
//! with no activation. Inputs whose sides are not multiples of `2^(levels - 1)` are padded with
//! zeros and the output is cropped back, so any grid works.

use burn::module::{Module, Param};
use burn::nn::conv::{Conv2d, Conv2dConfig, ConvTranspose2d, ConvTranspose2dConfig};
use burn::nn::pool::{MaxPool2d, MaxPool2dConfig};
use burn::nn::{Initializer, PaddingConfig2d};
use burn::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::conv::{burn_conv2d_same, conv2d_same};

/// Architecture of PlumeNet (saved in `config.json`).
#[derive(Config, Debug, PartialEq)]
pub struct PlumeNetConfig {
    /// Input channels ([`crate::surrogate::data::InputSet::channels`]).
    #[config(default = 7)]
    pub in_channels: usize,
    /// Channels per level, shallow to deep (DeepCFD: `[8, 16, 32, 32]`; one level more here,
    /// so that the receptive field spans a 30 m room: about 460 cells with 5x5 kernels).
    #[config(default = "vec![8, 16, 32, 32, 32]")]
    pub filters: Vec<usize>,
    /// Square kernel size of the convolutions (DeepCFD: 5).
    #[config(default = 5)]
    pub kernel_size: usize,
    /// Convolutions per block (DeepCFD: 3).
    #[config(default = 3)]
    pub convs_per_level: usize,
    /// Hand the last input channel (the analytic prior) straight to the 1x1 head beside the
    /// decoder's channels, so the network learns a correction to it (a residual). `None` (as in
    /// models saved before it existed) means no.
    pub prior_skip: Option<bool>,
    /// Make the network an operator network ([`OperatorConfig`]): the U-Net sees the room alone,
    /// once, and the source enters in a light per-source head. `None` (as in models saved
    /// before it existed) means the U-Net sees room and source together, one pass per source.
    pub operator: Option<OperatorConfig>,
}

/// The source-late form of PlumeNet: everything that does not depend on the source (walls,
/// obstacles, wind) is computed once per room, so a bank costs one U-Net pass per room and a
/// few multiply-adds per cell and candidate.
///
/// The U-Net's head gives `2 K + E` planes for the room (`K = groups * group_size`): trunk
/// planes `T(x)`, branch planes `A` read at the source (bilinearly, `a(s) = A(s)`), and `E`
/// room planes `R(x)`. For a source `s` each group `j` gives one plane
/// `z_j(x) = sum_g a_jg(s) T_jg(x)` (a learned low-rank Green's function); the head, two 1x1
/// convolutions with ReLU between them, maps `[z, R, prior, tanh(dx / 2 m), tanh(dy / 2 m)]`
/// at every cell to the transformed concentration, added to the analytic prior.
#[derive(Config, Debug, PartialEq)]
pub struct OperatorConfig {
    /// Groups `J` of the bilinear form (planes `z_j` per source).
    #[config(default = 16)]
    pub groups: usize,
    /// Terms `G` per group.
    #[config(default = 8)]
    pub group_size: usize,
    /// Room planes `E` handed to the per-source head.
    #[config(default = 8)]
    pub room_planes: usize,
    /// Hidden channels of the per-source head.
    #[config(default = 16)]
    pub hidden: usize,
}

/// Channels of the per-source planes an operator network's head reads beside the room's: the
/// analytic prior and the source offset `tanh(dx / 2 m)`, `tanh(dy / 2 m)`.
pub const SOURCE_PLANES: usize = 3;

/// Added to each room plane's mean square before it is normalised ([`PlumeNet::room_planes`]).
const PLANE_EPS: f32 = 1e-6;

/// Room input channels of an operator network: mask, signed distance, Peclet number, `u / U`,
/// `v / U` ([`crate::surrogate::data::RoomPlanes::encode_room`]).
pub const ROOM_CHANNELS: usize = 5;

impl OperatorConfig {
    /// Bilinear terms `K = groups * group_size`.
    pub fn terms(&self) -> usize {
        self.groups * self.group_size
    }

    /// Planes the U-Net's head gives: trunk and branch planes and the room planes.
    pub fn room_outputs(&self) -> usize {
        2 * self.terms() + self.room_planes
    }

    /// Input channels of the per-source head.
    fn head_inputs(&self) -> usize {
        self.groups + self.room_planes + SOURCE_PLANES
    }
}

/// The per-source head of an operator network ([`OperatorConfig`]).
#[derive(Module, Debug)]
pub struct SourceHead {
    pub(super) mix: Conv2d,
    pub(super) out: Conv2d,
    pub(super) groups: usize,
    pub(super) group_size: usize,
}

/// Where an operator network reads each source's branch planes: for source `n`, four flat
/// indices into the room batch's `[B H W]` cells and their bilinear weights.
#[derive(Debug, Clone)]
pub struct SourceTaps {
    /// `[4 S]` flat cell indices (corner `c` of source `n` at `c S + n`).
    pub cells: Tensor<1, Int>,
    /// `[4 S, 1]` bilinear weights, in the same order.
    pub weights: Tensor<2>,
}

/// Which implementation runs PlumeNet's convolutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConvImpl {
    /// Our fused kernels ([`conv2d_same`]; Burn's convolution on backends they do not cover).
    Own,
    /// Burn's convolution followed by `relu`, as before our kernels (for comparisons).
    Burn,
}

/// `conv` ("same" padding, stride 1, with bias) applied to `x`, then ReLU if `relu`.
fn same_conv(conv: &Conv2d, x: Tensor<4>, relu: bool, imp: ConvImpl) -> Tensor<4> {
    let bias = match &conv.bias {
        Some(bias) => bias.val(),
        None => Tensor::zeros([conv.weight.dims()[0]], &x.device()),
    };
    match imp {
        ConvImpl::Own => conv2d_same(x, conv.weight.val(), bias, relu),
        ConvImpl::Burn => burn_conv2d_same(x, conv.weight.val(), bias, relu),
    }
}

/// A parameter of `shape` uniform in `+-1 / sqrt(fan_in)`, drawn from `rng`.
fn uniform<const D: usize>(
    rng: &mut ChaCha8Rng,
    shape: [usize; D],
    fan_in: usize,
    device: &Device,
) -> Param<Tensor<D>> {
    let bound = 1.0 / (fan_in as f32).sqrt();
    let values: Vec<f32> = (0..shape.iter().product())
        .map(|_| rng.random_range(-bound..bound))
        .collect();
    Param::from_tensor(Tensor::from_data(TensorData::new(values, shape), device))
}

/// A block of convolutions with ReLU.
#[derive(Module, Debug)]
pub struct ConvBlock {
    pub(super) convs: Vec<Conv2d>,
}

impl ConvBlock {
    fn new(cin: usize, cout: usize, kernel: usize, count: usize, device: &Device) -> Self {
        let convs = (0..count)
            .map(|k| {
                Conv2dConfig::new([if k == 0 { cin } else { cout }, cout], [kernel, kernel])
                    .with_padding(PaddingConfig2d::Same)
                    .with_initializer(Initializer::Zeros)
                    .init(device)
            })
            .collect();
        Self { convs }
    }

    fn forward(&self, mut x: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        for conv in &self.convs {
            x = same_conv(conv, x, true, imp);
        }
        x
    }
}

/// The U-Net.
#[derive(Module, Debug)]
pub struct PlumeNet {
    pub(super) encoders: Vec<ConvBlock>,
    pool: MaxPool2d,
    pub(super) ups: Vec<ConvTranspose2d>,
    pub(super) decoders: Vec<ConvBlock>,
    pub(super) head: Conv2d,
    prior_skip: bool,
    pub(super) operator: Option<SourceHead>,
}

impl PlumeNetConfig {
    /// Builds the network with weights drawn from a ChaCha8 stream seeded with `seed`, from
    /// Burn's default distributions: every weight and bias uniform in `+-1 / sqrt(fan_in)`, with
    /// `fan_in` the input channels times the kernel area (the output channels times the kernel
    /// area for the transposed convolutions). The same seed gives the same network on any
    /// thread, whatever other networks are initialised meanwhile.
    pub fn init_seeded(&self, device: &Device, seed: u64) -> PlumeNet {
        let mut net = self.init(device);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut draw_conv = |conv: &mut Conv2d| {
            let [cout, cin, kh, kw] = conv.weight.dims();
            let fan_in = cin * kh * kw;
            conv.weight = uniform(&mut rng, [cout, cin, kh, kw], fan_in, device);
            conv.bias = Some(uniform(&mut rng, [cout], fan_in, device));
        };
        for block in net.encoders.iter_mut() {
            block.convs.iter_mut().for_each(&mut draw_conv);
        }
        for block in net.decoders.iter_mut() {
            block.convs.iter_mut().for_each(&mut draw_conv);
        }
        draw_conv(&mut net.head);
        if let Some(op) = net.operator.as_mut() {
            draw_conv(&mut op.mix);
            draw_conv(&mut op.out);
        }
        for up in net.ups.iter_mut() {
            let [cin, cout, kh, kw] = up.weight.dims();
            let fan_in = cout * kh * kw;
            up.weight = uniform(&mut rng, [cin, cout, kh, kw], fan_in, device);
            up.bias = Some(uniform(&mut rng, [cout], fan_in, device));
        }
        net
    }

    /// Whether the analytic prior skips to the head.
    pub fn skips_prior(&self) -> bool {
        self.prior_skip == Some(true)
    }

    /// Builds the network with zero weights on `device` (to be replaced by a loaded record or
    /// by [`PlumeNetConfig::init_seeded`]).
    pub fn init(&self, device: &Device) -> PlumeNet {
        let k = self.kernel_size;
        let n = self.convs_per_level;
        let f = &self.filters;
        let encoders = f
            .iter()
            .enumerate()
            .map(|(l, &c)| {
                ConvBlock::new(
                    if l == 0 { self.in_channels } else { f[l - 1] },
                    c,
                    k,
                    n,
                    device,
                )
            })
            .collect();
        // Decoder level l (from deep to shallow) goes from f[l + 1] channels up to f[l].
        let ups = (0..f.len() - 1)
            .rev()
            .map(|l| {
                ConvTranspose2dConfig::new([f[l + 1], f[l]], [2, 2])
                    .with_stride([2, 2])
                    .with_initializer(Initializer::Zeros)
                    .init(device)
            })
            .collect();
        let decoders = (0..f.len() - 1)
            .rev()
            .map(|l| ConvBlock::new(2 * f[l], f[l], k, n, device))
            .collect();
        PlumeNet {
            encoders,
            pool: MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init(),
            ups,
            decoders,
            head: Conv2dConfig::new(
                [
                    f[0] + usize::from(self.skips_prior()),
                    self.operator
                        .as_ref()
                        .map_or(1, OperatorConfig::room_outputs),
                ],
                [1, 1],
            )
            .with_initializer(Initializer::Zeros)
            .init(device),
            prior_skip: self.skips_prior(),
            operator: self.operator.as_ref().map(|op| {
                let conv = |cin, cout| {
                    Conv2dConfig::new([cin, cout], [1, 1])
                        .with_initializer(Initializer::Zeros)
                        .init(device)
                };
                SourceHead {
                    mix: conv(op.head_inputs(), op.hidden),
                    out: conv(op.hidden, 1),
                    groups: op.groups,
                    group_size: op.group_size,
                }
            }),
        }
    }
}

impl PlumeNet {
    /// `[B, in_channels, H, W]` inputs to `[B, 1, H, W]` transformed concentrations.
    pub fn forward(&self, input: Tensor<4>) -> Tensor<4> {
        self.forward_with(input, ConvImpl::Own)
    }

    /// [`PlumeNet::forward`] with the convolutions run by `imp`.
    pub fn forward_with(&self, input: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        let [b, _, h, w] = input.dims();
        let out = self.unet(input, imp);
        let [_, c, hp, wp] = out.dims();
        if hp != h || wp != w {
            out.slice([0..b, 0..c, 0..h, 0..w])
        } else {
            out
        }
    }

    /// The U-Net on inputs padded to whole pooling steps: `[B, outputs, H', W']` with `H'`, `W'`
    /// the padded sides.
    fn unet(&self, input: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        let [b, channels, h, w] = input.dims();
        let multiple = 1 << (self.encoders.len() - 1);
        let (ph, pw) = (
            h.div_ceil(multiple) * multiple - h,
            w.div_ceil(multiple) * multiple - w,
        );
        let mut x = if ph + pw > 0 {
            input.pad((0, pw, 0, ph), 0.0)
        } else {
            input
        };
        let [_, _, hp, wp] = x.dims();
        let prior = self.prior_skip.then(|| {
            x.clone()
                .slice([0..b, channels - 1..channels, 0..hp, 0..wp])
        });
        let mut skips = Vec::with_capacity(self.encoders.len());
        for (l, enc) in self.encoders.iter().enumerate() {
            x = enc.forward(x, imp);
            if l + 1 < self.encoders.len() {
                skips.push(x.clone());
                x = self.pool.forward(x);
            }
        }
        for (up, dec) in self.ups.iter().zip(&self.decoders) {
            let skip = skips.pop().expect("one skip per decoder level");
            x = dec.forward(Tensor::cat(vec![up.forward(x), skip], 1), imp);
        }
        if let Some(prior) = prior {
            x = Tensor::cat(vec![x, prior], 1);
        }
        same_conv(&self.head, x, false, imp)
    }

    /// Whether this is an operator network ([`OperatorConfig`]).
    pub fn is_operator(&self) -> bool {
        self.operator.is_some()
    }

    /// An operator network's room pass: `[B, ROOM_CHANNELS, H, W]` room inputs (sides whole
    /// pooling steps) to the room planes `[B, 2 K + E, H, W]` that
    /// [`PlumeNet::source_fields`] reads.
    pub fn room_planes(&self, rooms: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        // Each plane is divided by its root mean square over the grid, so that the bilinear
        // form starts at unit scale however deep the U-Net (its raw outputs start near zero,
        // and a product of two near-zero factors would barely learn).
        let planes = self.unet(rooms, imp);
        let rms = planes
            .clone()
            .powi_scalar(2)
            .mean_dim(3)
            .mean_dim(2)
            .add_scalar(PLANE_EPS)
            .sqrt();
        planes.div(rms)
    }

    /// An operator network's fields of `M` sources in each of the `B` rooms of `planes`
    /// ([`PlumeNet::room_planes`]): `taps` reads each source's branch planes, `sources` holds
    /// the `[B M, SOURCE_PLANES, H, W]` per-source planes (room-major). Returns the transformed
    /// concentration `[B M, 1, H, W]`.
    ///
    /// # Panics
    /// When the network is not an operator network, or the shapes disagree.
    pub fn source_fields(
        &self,
        planes: Tensor<4>,
        taps: &SourceTaps,
        sources: Tensor<4>,
        imp: ConvImpl,
    ) -> Tensor<4> {
        let op = self.operator.as_ref().expect("an operator network");
        let [b, outputs, h, w] = planes.dims();
        let [bm, _, _, _] = sources.dims();
        let m = bm / b;
        let (j, g) = (op.groups, op.group_size);
        let k = j * g;
        let cells = h * w;
        let trunk = planes
            .clone()
            .slice([0..b, 0..k, 0..h, 0..w])
            .reshape([b, j, g, cells]);
        // Branch planes as rows of cells: [B H W, K].
        let branch = planes
            .clone()
            .slice([0..b, k..2 * k, 0..h, 0..w])
            .permute([0, 2, 3, 1])
            .reshape([b * cells, k]);
        let taps4 = branch
            .select(0, taps.cells.clone())
            .mul(taps.weights.clone());
        let a = taps4.reshape([4, bm, k]).sum_dim(0).reshape([b, m, j, g]);
        let z = a
            .swap_dims(1, 2)
            .matmul(trunk)
            .swap_dims(1, 2)
            .reshape([bm, j, h, w]);
        let room = planes
            .slice([0..b, 2 * k..outputs, 0..h, 0..w])
            .unsqueeze_dim::<5>(1)
            .expand([b, m, outputs - 2 * k, h, w])
            .reshape([bm, outputs - 2 * k, h, w]);
        let prior = sources.clone().slice([0..bm, 0..1, 0..h, 0..w]);
        let x = Tensor::cat(vec![z, room, sources], 1);
        let hidden = same_conv(&op.mix, x, true, imp);
        same_conv(&op.out, hidden, false, imp).add(prior)
    }
}
