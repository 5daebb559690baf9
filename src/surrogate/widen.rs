//! Widening a trained PlumeNet without changing what it computes.
//!
//! A network with more channels at some levels starts from a trained one (`train --init-from
//! MODEL --filters WIDER`): every old weight is copied to its place, the new channels get
//! seeded random weights into them (as [`PlumeNetConfig::init_seeded`] draws them) and zero
//! weights out of them into every old channel, so the widened network's output equals the
//! trained one's exactly, while the gradient reaches the new channels' outgoing weights at the
//! first step (their activations are not zero) and training can use them.

use burn::module::Param;
use burn::nn::conv::{Conv2d, ConvTranspose2d};
use burn::prelude::*;

use super::model::{PlumeNet, PlumeNetConfig};
use crate::error::{Error, Result};

impl PlumeNetConfig {
    /// Whether `self` is `from` with at least as many channels at every level and nothing
    /// else changed (a widening that [`PlumeNet::widened`] can start from `from`'s weights).
    pub fn widens(&self, from: &PlumeNetConfig) -> bool {
        self.filters.len() == from.filters.len()
            && self.filters.iter().zip(&from.filters).all(|(n, o)| n >= o)
            && self.in_channels == from.in_channels
            && self.kernel_size == from.kernel_size
            && self.convs_per_level == from.convs_per_level
            && self.skips_prior() == from.skips_prior()
    }
}

/// A parameter's values and dimensions.
fn values<const D: usize>(p: &Param<Tensor<D>>) -> Result<(Vec<f32>, [usize; D])> {
    let t = p.val();
    let dims = t.dims();
    let v = t
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| Error::Model(format!("cannot read a weight tensor: {e:?}")))?;
    Ok((v, dims))
}

/// A parameter of `dims` holding `v`, on `device`.
fn param<const D: usize>(v: Vec<f32>, dims: [usize; D], device: &Device) -> Param<Tensor<D>> {
    Param::from_tensor(Tensor::from_data(TensorData::new(v, dims), device))
}

/// Copies `old`'s weights into `new` (a convolution with at least as many inputs and outputs):
/// old output `o` from old input `i` goes to output `o` from input `map[i]`, every other input
/// into an old output gets zero, and the new outputs keep their weights.
fn embed_conv(new: &mut Conv2d, old: &Conv2d, map: &[usize], device: &Device) -> Result<()> {
    let (ow, [ocout, ocin, kh, kw]) = values(&old.weight)?;
    let (mut nw, ndims) = values(&new.weight)?;
    let ncin = ndims[1];
    let area = kh * kw;
    for o in 0..ocout {
        let row = &mut nw[o * ncin * area..(o + 1) * ncin * area];
        row.fill(0.0);
        for (i, &j) in map.iter().enumerate().take(ocin) {
            row[j * area..(j + 1) * area]
                .copy_from_slice(&ow[(o * ocin + i) * area..(o * ocin + i + 1) * area]);
        }
    }
    new.weight = param(nw, ndims, device);
    embed_bias(&mut new.bias, &old.bias, device)
}

/// As [`embed_conv`] for a transposed convolution, whose weights are `[in, out, kh, kw]`.
fn embed_up(
    new: &mut ConvTranspose2d,
    old: &ConvTranspose2d,
    map: &[usize],
    device: &Device,
) -> Result<()> {
    let (ow, [ocin, ocout, kh, kw]) = values(&old.weight)?;
    let (mut nw, ndims) = values(&new.weight)?;
    let (ncin, ncout) = (ndims[0], ndims[1]);
    let area = kh * kw;
    for j in 0..ncin {
        for o in 0..ocout {
            let at = (j * ncout + o) * area;
            nw[at..at + area].fill(0.0);
        }
    }
    for (i, &j) in map.iter().enumerate().take(ocin) {
        for o in 0..ocout {
            let (to, from) = ((j * ncout + o) * area, (i * ocout + o) * area);
            nw[to..to + area].copy_from_slice(&ow[from..from + area]);
        }
    }
    new.weight = param(nw, ndims, device);
    embed_bias(&mut new.bias, &old.bias, device)
}

/// Copies the old outputs' biases into the first entries of the new bias.
fn embed_bias(
    new: &mut Option<Param<Tensor<1>>>,
    old: &Option<Param<Tensor<1>>>,
    device: &Device,
) -> Result<()> {
    if let (Some(n), Some(o)) = (new.as_mut(), old) {
        let (ov, _) = values(o)?;
        let (mut nv, dims) = values(n)?;
        nv[..ov.len()].copy_from_slice(&ov);
        *n = param(nv, dims, device);
    }
    Ok(())
}

impl PlumeNet {
    /// This network (of architecture `from`) widened to `to` (which must widen `from`, see
    /// [`PlumeNetConfig::widens`]), the new channels' incoming weights drawn from `seed`: its
    /// output is this network's.
    ///
    /// # Errors
    /// [`Error::Model`] when `to` does not widen `from` or a weight cannot be read.
    pub fn widened(
        &self,
        from: &PlumeNetConfig,
        to: &PlumeNetConfig,
        seed: u64,
        device: &Device,
    ) -> Result<PlumeNet> {
        if !to.widens(from) {
            return Err(Error::Model(format!(
                "filters {:?} do not widen the start's {:?} (same levels, at least as many \
                 channels at each, same kernel, convolutions per level, inputs and prior skip)",
                to.filters, from.filters
            )));
        }
        let mut net = to.init_seeded(device, seed);
        let (fo, levels) = (&from.filters, from.filters.len());
        let identity = |n: usize| (0..n).collect::<Vec<_>>();
        for l in 0..levels {
            let (new, old) = (&mut net.encoders[l].convs, &self.encoders[l].convs);
            for (k, (n, o)) in new.iter_mut().zip(old).enumerate() {
                let cin = match (k, l) {
                    (0, 0) => from.in_channels,
                    (0, _) => fo[l - 1],
                    _ => fo[l],
                };
                embed_conv(n, o, &identity(cin), device)?;
            }
        }
        // Decoder d works at level l = levels - 2 - d; its input is [up (f_l), skip (f_l)].
        for d in 0..levels - 1 {
            let l = levels - 2 - d;
            embed_up(&mut net.ups[d], &self.ups[d], &identity(fo[l + 1]), device)?;
            let wide = to.filters[l];
            let concat: Vec<usize> = (0..fo[l]).chain(wide..wide + fo[l]).collect();
            let (new, old) = (&mut net.decoders[d].convs, &self.decoders[d].convs);
            for (k, (n, o)) in new.iter_mut().zip(old).enumerate() {
                let map = if k == 0 {
                    concat.clone()
                } else {
                    identity(fo[l])
                };
                embed_conv(n, o, &map, device)?;
            }
        }
        // The head reads level 0 (and the prior, after it, when it skips).
        let head: Vec<usize> = (0..fo[0])
            .chain(from.skips_prior().then_some(to.filters[0]))
            .collect();
        embed_conv(&mut net.head, &self.head, &head, device)?;
        Ok(net)
    }
}
