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
use burn::tensor::activation::relu;
use burn::tensor::module::interpolate;
use burn::tensor::ops::{InterpolateMode, InterpolateOptions};
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
    /// decoder's channels, so the network learns a correction to it (a residual). `None` (what a
    /// config without this field reads as) means no.
    pub prior_skip: Option<bool>,
    /// Make the network an operator network ([`OperatorConfig`]): the U-Net sees the room alone,
    /// once, and the source enters in a light per-source head. `None` (what a config without
    /// this field reads as) means the U-Net sees room and source together, one pass per
    /// source.
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
    /// A coarse per-source network ([`CoarseConfig`]) in place of the bilinear form and its
    /// head. `None` (what a config without this field reads as) means the bilinear form.
    pub coarse: Option<CoarseConfig>,
}

/// The coarse form of an operator network's per-source part: a small U-Net that works at
/// pooling level `level` (cells of `2^level` grid cells a side) and gives a correction to the
/// analytic prior there, upsampled bilinearly to the grid and added to the prior.
///
/// The room pass's U-Net decodes only down to `level`, where its head gives `E` room planes.
/// The correction sees the source through its anchor, the centre of the network's cell that
/// holds it: the network reads the anchor's per-source planes pooled to `level`
/// ([`crate::surrogate::coarse::pooled_planes`]) and, added before the first ReLU, the room
/// planes' share of its first convolution, which is computed once per room. Sources of one
/// network cell (four candidates 0.25 m apart in a 0.5 m cell) therefore share one correction,
/// and a bank runs the network once per cell; the exact position enters through the prior.
/// The bilinear form's sizes (`groups`, `group_size`, `hidden`) are not used.
#[derive(Config, Debug, PartialEq)]
pub struct CoarseConfig {
    /// Pooling level of the per-source network.
    #[config(default = 2)]
    pub level: usize,
    /// Channels per level of the per-source network, shallow to deep.
    #[config(default = "vec![8, 16, 32]")]
    pub filters: Vec<usize>,
    /// Square kernel size of its convolutions.
    #[config(default = 3)]
    pub kernel_size: usize,
    /// Convolutions per block.
    #[config(default = 2)]
    pub convs_per_level: usize,
}

/// Planes a coarse per-source network reads per source: the means of the per-source planes
/// of the source's anchor over each coarse cell, the prior's maximum there, and the cell
/// centre's offset from the anchor along and across the wind in [`COARSE_OFFSET_CELLS`].
pub const COARSE_SOURCE_PLANES: usize = SOURCE_PLANES + 3;

/// Scale of a coarse per-source network's offset planes, in grid cells (10 m of 0.125 m): they
/// grow linearly across any room, where the per-source planes' `tanh(d / 2 m)` saturate.
pub const COARSE_OFFSET_CELLS: f32 = 80.0;

/// Channels of the per-source planes an operator network's head reads beside the room's: the
/// analytic prior and the source offset `tanh(dx / 2 m)`, `tanh(dy / 2 m)`.
pub const SOURCE_PLANES: usize = 3;

/// Scale of the source offset planes `tanh(d / OFFSET_SCALE_M)` of an operator network (m).
pub(crate) const OFFSET_SCALE_M: f64 = 2.0;

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

    /// Planes the U-Net's head gives: trunk and branch planes and the room planes (the room
    /// planes alone for the coarse form).
    pub fn room_outputs(&self) -> usize {
        if self.coarse.is_some() {
            self.room_planes
        } else {
            2 * self.terms() + self.room_planes
        }
    }

    /// The pooling level the room pass decodes down to: the coarse form's level, else 0.
    pub fn room_level(&self) -> usize {
        self.coarse.as_ref().map_or(0, |c| c.level)
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

/// The coarse per-source network of an operator network ([`CoarseConfig`]).
#[derive(Module, Debug)]
pub struct CoarseNet {
    /// The room planes' share of the first convolution (no bias), computed once per room.
    pub(super) room: Conv2d,
    pub(super) encoders: Vec<ConvBlock>,
    pool: MaxPool2d,
    pub(super) ups: Vec<ConvTranspose2d>,
    pub(super) decoders: Vec<ConvBlock>,
    /// 1x1 convolution to the correction.
    pub(super) out: Conv2d,
    level: usize,
}

/// Where an operator network reads each source: for source `n`, four flat indices into the
/// room batch's `[B H W]` cells and their bilinear weights (the bilinear form's branch planes),
/// or the pooled planes of its anchor (the coarse form's input).
#[derive(Debug, Clone)]
pub struct SourceTaps {
    /// `[4 S]` flat cell indices (corner `c` of source `n` at `c S + n`).
    pub cells: Tensor<1, Int>,
    /// `[4 S, 1]` bilinear weights, in the same order.
    pub weights: Tensor<2>,
    /// The coarse form's `[S, COARSE_SOURCE_PLANES, H / 2^l, W / 2^l]` pooled planes of the
    /// sources' anchors; `None` for the bilinear form.
    pub pooled: Option<Tensor<4>>,
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

    /// The block on `x`; `shift`, when given, is added to the first convolution's output
    /// before its ReLU.
    fn forward(&self, mut x: Tensor<4>, mut shift: Option<Tensor<4>>, imp: ConvImpl) -> Tensor<4> {
        for conv in &self.convs {
            x = match shift.take() {
                Some(shift) => relu(same_conv(conv, x, false, imp).add(shift)),
                None => same_conv(conv, x, true, imp),
            };
        }
        x
    }
}

/// The encoder blocks, transposed convolutions and decoder blocks of a U-Net on `cin` input
/// channels with `filters` per level, its decoder going back up to level `start` only.
fn unet_parts(
    cin: usize,
    filters: &[usize],
    (kernel, convs): (usize, usize),
    start: usize,
    device: &Device,
) -> (Vec<ConvBlock>, Vec<ConvTranspose2d>, Vec<ConvBlock>) {
    let f = filters;
    let encoders = f
        .iter()
        .enumerate()
        .map(|(l, &c)| {
            ConvBlock::new(
                if l == 0 { cin } else { f[l - 1] },
                c,
                kernel,
                convs,
                device,
            )
        })
        .collect();
    // Decoder level l (from deep to shallow) goes from f[l + 1] channels up to f[l].
    let ups = (start..f.len() - 1)
        .rev()
        .map(|l| {
            ConvTranspose2dConfig::new([f[l + 1], f[l]], [2, 2])
                .with_stride([2, 2])
                .with_initializer(Initializer::Zeros)
                .init(device)
        })
        .collect();
    let decoders = (start..f.len() - 1)
        .rev()
        .map(|l| ConvBlock::new(2 * f[l], f[l], kernel, convs, device))
        .collect();
    (encoders, ups, decoders)
}

/// A U-Net's encoder and decoder on `x` (sides whole pooling steps): each encoder block, a
/// max-pool between levels, then each decoder level's transposed convolution, concatenation
/// with the encoder's output at that level and block. `shift` is added to the first
/// convolution's output before its ReLU. Returns the last decoder block's output (the deepest
/// encoder's without decoders).
fn encode_decode(
    (encoders, pool, ups, decoders): (&[ConvBlock], &MaxPool2d, &[ConvTranspose2d], &[ConvBlock]),
    mut x: Tensor<4>,
    mut shift: Option<Tensor<4>>,
    imp: ConvImpl,
) -> Tensor<4> {
    let mut skips = Vec::with_capacity(encoders.len());
    for (l, enc) in encoders.iter().enumerate() {
        x = enc.forward(x, shift.take(), imp);
        if l + 1 < encoders.len() {
            skips.push(x.clone());
            x = pool.forward(x);
        }
    }
    for (up, dec) in ups.iter().zip(decoders) {
        let skip = skips.pop().expect("one skip per decoder level");
        x = dec.forward(Tensor::cat(vec![up.forward(x), skip], 1), None, imp);
    }
    x
}

/// Room planes `[B, C, H, W]` repeated for each of the `M` sources of every room,
/// `[B M, C, H, W]` (room-major).
fn per_source(room: Tensor<4>, m: usize) -> Tensor<4> {
    let [b, c, h, w] = room.dims();
    room.unsqueeze_dim::<5>(1)
        .expand([b, m, c, h, w])
        .reshape([b * m, c, h, w])
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
    pub(super) coarse: Option<CoarseNet>,
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
        let draw_conv = |rng: &mut ChaCha8Rng, conv: &mut Conv2d| {
            let [cout, cin, kh, kw] = conv.weight.dims();
            let fan_in = cin * kh * kw;
            conv.weight = uniform(rng, [cout, cin, kh, kw], fan_in, device);
            conv.bias = Some(uniform(rng, [cout], fan_in, device));
        };
        let draw_up = |rng: &mut ChaCha8Rng, up: &mut ConvTranspose2d| {
            let [cin, cout, kh, kw] = up.weight.dims();
            let fan_in = cout * kh * kw;
            up.weight = uniform(rng, [cin, cout, kh, kw], fan_in, device);
            up.bias = Some(uniform(rng, [cout], fan_in, device));
        };
        for block in net.encoders.iter_mut().chain(net.decoders.iter_mut()) {
            block.convs.iter_mut().for_each(|c| draw_conv(&mut rng, c));
        }
        draw_conv(&mut rng, &mut net.head);
        if let Some(op) = net.operator.as_mut() {
            draw_conv(&mut rng, &mut op.mix);
            draw_conv(&mut rng, &mut op.out);
        }
        net.ups.iter_mut().for_each(|u| draw_up(&mut rng, u));
        if let Some(coarse) = net.coarse.as_mut() {
            coarse.ups.iter_mut().for_each(|u| draw_up(&mut rng, u));
            for block in coarse.encoders.iter_mut().chain(coarse.decoders.iter_mut()) {
                block.convs.iter_mut().for_each(|c| draw_conv(&mut rng, c));
            }
            draw_conv(&mut rng, &mut coarse.out);
            // The room share has no bias: the first convolution's own is the block's.
            let [cout, cin, kh, kw] = coarse.room.weight.dims();
            coarse.room.weight = uniform(&mut rng, [cout, cin, kh, kw], cin * kh * kw, device);
        }
        net
    }

    /// Cells a side of a coarse operator network's cells ([`CoarseConfig`]): `2^level` for
    /// the coarse form, `None` for any other network.
    pub fn coarse_pooling(&self) -> Option<usize> {
        self.operator
            .as_ref()
            .and_then(|op| op.coarse.as_ref())
            .map(|c| 1 << c.level)
    }

    /// What makes a coarse per-source network ([`CoarseConfig`]) impossible to build on this
    /// room U-Net, if anything: no levels, a channel count of zero or an even kernel, or more
    /// pooling than the room's U-Net has (the grid is padded to whole pooling steps of the
    /// room's U-Net only).
    pub fn coarse_problem(&self) -> Option<String> {
        let c = self.operator.as_ref()?.coarse.as_ref()?;
        if c.filters.is_empty() || c.filters.contains(&0) || c.kernel_size % 2 == 0 {
            return Some(
                "a coarse per-source network needs non-empty, positive filters and an odd \
                 kernel size"
                    .into(),
            );
        }
        (c.level + c.filters.len() > self.filters.len()).then(|| {
            format!(
                "a coarse per-source network at level {} with {} levels pools deeper than the \
                 room's U-Net of {} levels",
                c.level,
                c.filters.len(),
                self.filters.len()
            )
        })
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
        let start = self.operator.as_ref().map_or(0, OperatorConfig::room_level);
        let (encoders, ups, decoders) = unet_parts(self.in_channels, f, (k, n), start, device);
        let pool = || MaxPool2dConfig::new([2, 2]).with_strides([2, 2]).init();
        let conv = |cin, cout, kernel: usize| {
            Conv2dConfig::new([cin, cout], [kernel, kernel])
                .with_padding(PaddingConfig2d::Same)
                .with_initializer(Initializer::Zeros)
        };
        PlumeNet {
            encoders,
            pool: pool(),
            ups,
            decoders,
            head: conv(
                f[start] + usize::from(self.skips_prior()),
                self.operator
                    .as_ref()
                    .map_or(1, OperatorConfig::room_outputs),
                1,
            )
            .init(device),
            prior_skip: self.skips_prior(),
            operator: self
                .operator
                .as_ref()
                .filter(|op| op.coarse.is_none())
                .map(|op| SourceHead {
                    mix: conv(op.head_inputs(), op.hidden, 1).init(device),
                    out: conv(op.hidden, 1, 1).init(device),
                    groups: op.groups,
                    group_size: op.group_size,
                }),
            coarse: self.operator.as_ref().and_then(|op| {
                let c = op.coarse.as_ref()?;
                let (encoders, ups, decoders) = unet_parts(
                    COARSE_SOURCE_PLANES,
                    &c.filters,
                    (c.kernel_size, c.convs_per_level),
                    0,
                    device,
                );
                Some(CoarseNet {
                    room: conv(op.room_planes, c.filters[0], c.kernel_size)
                        .with_bias(false)
                        .init(device),
                    encoders,
                    pool: pool(),
                    ups,
                    decoders,
                    out: conv(c.filters[0], 1, 1).init(device),
                    level: c.level,
                })
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
        let parts = (
            &self.encoders[..],
            &self.pool,
            &self.ups[..],
            &self.decoders[..],
        );
        x = encode_decode(parts, x, None, imp);
        if let Some(prior) = prior {
            x = Tensor::cat(vec![x, prior], 1);
        }
        same_conv(&self.head, x, false, imp)
    }

    /// Whether this is an operator network ([`OperatorConfig`]).
    pub fn is_operator(&self) -> bool {
        self.operator.is_some() || self.coarse.is_some()
    }

    /// Whether this is an operator network of the coarse form ([`CoarseConfig`]).
    pub fn is_coarse(&self) -> bool {
        self.coarse.is_some()
    }

    /// An operator network's room pass: `[B, ROOM_CHANNELS, H, W]` room inputs (sides whole
    /// pooling steps) to the room planes `[B, 2 K + E, H, W]` (the coarse form's `[B, E, H / 2^l,
    /// W / 2^l]` at its level `l`) that
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
        if let Some(coarse) = &self.coarse {
            let pooled = taps
                .pooled
                .clone()
                .expect("a coarse network's batch has the anchors' pooled planes");
            return coarse.fields(planes, sources, pooled, imp);
        }
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
        let room = per_source(planes.slice([0..b, 2 * k..outputs, 0..h, 0..w]), m);
        let prior = sources.clone().slice([0..bm, 0..1, 0..h, 0..w]);
        let x = Tensor::cat(vec![z, room, sources], 1);
        let hidden = same_conv(&op.mix, x, true, imp);
        same_conv(&op.out, hidden, false, imp).add(prior)
    }
}

impl CoarseNet {
    /// The room planes' share of the first convolution, `[B, C, H / 2^l, W / 2^l]` for room
    /// planes `[B, E, H / 2^l, W / 2^l]`: the same for every source of a room.
    pub fn room_share(&self, planes: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        same_conv(&self.room, planes, false, imp)
    }

    /// The transformed concentration `[B M, 1, H, W]` of `M` sources in each of `B` rooms,
    /// from the room planes `[B, E, H / 2^l, W / 2^l]`, the per-source planes
    /// `[B M, SOURCE_PLANES, H, W]` (room-major; channel 0, the transformed prior, is the one
    /// read) and the pooled planes of the sources' anchors
    /// ([`crate::surrogate::coarse::pooled_planes`]).
    pub fn fields(
        &self,
        planes: Tensor<4>,
        sources: Tensor<4>,
        pooled: Tensor<4>,
        imp: ConvImpl,
    ) -> Tensor<4> {
        let b = planes.dims()[0];
        let [bm, _, h, w] = sources.dims();
        let share = per_source(self.room_share(planes, imp), bm / b);
        let prior = sources.slice([0..bm, 0..1, 0..h, 0..w]);
        interpolate(
            self.correction(share, pooled, imp),
            InterpolateOptions::new(InterpolateMode::Bilinear)
                .with_align_corners(false)
                .with_output_size([h, w]),
        )
        .add(prior)
    }

    /// Cells of the grid a side of one of the network's cells: `2^level`.
    pub fn scale(&self) -> usize {
        1 << self.level
    }

    /// The correction `[n, 1, H / 2^l, W / 2^l]` to the transformed prior of `n` sources from
    /// the pooled planes of their anchors `[n, COARSE_SOURCE_PLANES, H / 2^l, W / 2^l]` and the
    /// room share, expanded to every source or of one room (`[1, C, ..]`, broadcast).
    pub fn correction(&self, share: Tensor<4>, pooled: Tensor<4>, imp: ConvImpl) -> Tensor<4> {
        let parts = (
            &self.encoders[..],
            &self.pool,
            &self.ups[..],
            &self.decoders[..],
        );
        let x = encode_decode(parts, pooled, Some(share), imp);
        same_conv(&self.out, x, false, imp)
    }
}
