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

/// The room channels of an operator network among the analytic inputs of a U-Net (mask,
/// signed distance, Peclet number, `u / U`, `v / U`; the U-Net's source bump and prior are
/// per-source planes in an operator network).
const ROOM_OF_ANALYTIC: [usize; 5] = [0, 1, 3, 4, 5];

impl PlumeNet {
    /// An operator network `to` that starts from this trained U-Net (of architecture `from`,
    /// analytic inputs, no prior skip, the same levels, filters, kernel and convolutions per
    /// level): every convolution of the U-Net's body is copied (of the decoder, the levels the
    /// operator network keeps), the first one reading only the room's channels; the head that
    /// gives the room planes and the per-source part are drawn from `seed`.
    ///
    /// # Errors
    /// [`Error::Model`] when the architectures do not fit or a weight cannot be read.
    pub fn operator_from(
        &self,
        from: &PlumeNetConfig,
        to: &PlumeNetConfig,
        seed: u64,
        device: &Device,
    ) -> Result<PlumeNet> {
        let body = |c: &PlumeNetConfig| (c.filters.clone(), c.kernel_size, c.convs_per_level);
        if to.operator.is_none()
            || from.operator.is_some()
            || from.skips_prior()
            || from.in_channels != 7
            || to.in_channels != ROOM_OF_ANALYTIC.len()
            || body(from) != body(to)
        {
            return Err(Error::Model(format!(
                "an operator network starts from a U-Net of the analytic inputs without the \
                 prior skip and with the same body (filters {:?}, kernel {}, {} convolutions \
                 per level)",
                to.filters, to.kernel_size, to.convs_per_level
            )));
        }
        let mut net = to.init_seeded(device, seed);
        let levels = from.filters.len();
        let identity = |n: usize| (0..n).collect::<Vec<_>>();
        for l in 0..levels {
            let (new, old) = (&mut net.encoders[l].convs, &self.encoders[l].convs);
            for (k, (n, o)) in new.iter_mut().zip(old).enumerate() {
                if (k, l) == (0, 0) {
                    select_inputs(n, o, &ROOM_OF_ANALYTIC, device)?;
                } else {
                    let cin = if k == 0 {
                        from.filters[l - 1]
                    } else {
                        from.filters[l]
                    };
                    embed_conv(n, o, &identity(cin), device)?;
                }
            }
        }
        // The coarse form decodes only down to its level: its shallower decoders stay out.
        for d in 0..net.decoders.len() {
            let l = levels - 2 - d;
            embed_up(
                &mut net.ups[d],
                &self.ups[d],
                &identity(from.filters[l + 1]),
                device,
            )?;
            let (new, old) = (&mut net.decoders[d].convs, &self.decoders[d].convs);
            for (k, (n, o)) in new.iter_mut().zip(old).enumerate() {
                let cin = if k == 0 {
                    2 * from.filters[l]
                } else {
                    from.filters[l]
                };
                embed_conv(n, o, &identity(cin), device)?;
            }
        }
        Ok(net)
    }
}

/// Copies `old`'s weights into `new`, whose input `c` is `old`'s input `inputs[c]`, bias too.
fn select_inputs(new: &mut Conv2d, old: &Conv2d, inputs: &[usize], device: &Device) -> Result<()> {
    let (ow, [cout, ocin, kh, kw]) = values(&old.weight)?;
    let area = kh * kw;
    let mut nw = Vec::with_capacity(cout * inputs.len() * area);
    for o in 0..cout {
        for &i in inputs {
            nw.extend_from_slice(&ow[(o * ocin + i) * area..(o * ocin + i + 1) * area]);
        }
    }
    new.weight = param(nw, [cout, inputs.len(), kh, kw], device);
    embed_bias(&mut new.bias, &old.bias, device)
}
