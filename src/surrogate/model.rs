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
            head: Conv2dConfig::new([f[0] + usize::from(self.skips_prior()), 1], [1, 1])
                .with_initializer(Initializer::Zeros)
                .init(device),
            prior_skip: self.skips_prior(),
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
        let multiple = 1 << (self.encoders.len() - 1);
        let (ph, pw) = (
            h.div_ceil(multiple) * multiple - h,
            w.div_ceil(multiple) * multiple - w,
        );
        let [_, channels, _, _] = input.dims();
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
        let out = same_conv(&self.head, x, false, imp);
        if ph + pw > 0 {
            out.slice([0..b, 0..1, 0..h, 0..w])
        } else {
            out
        }
    }
}
