//! From dataset arrays to network tensors: input encoding, target transform, batches.
//!
//! **Inputs** (`[B, 3, H, W]`): the obstacle mask (1 in obstacles), the signed distance divided
//! by `sdf_scale_m`, and the source encoding ([`SourceEncoding`]), computed from the source
//! coordinates so every encoding can be tried on one dataset.
//!
//! **Target transform.** The network learns `y = ln(1 + c / concentration_scale)`, which tames
//! the four decades between the source and the far field; predictions are mapped back with
//! `c = concentration_scale * (exp(max(y, 0)) - 1)` (non-negative) and set to zero in obstacles.

use std::path::Path;

use burn::prelude::*;
use ndarray::{Array3, ArrayView2, Ix1, Ix2, Ix3};
use serde::{Deserialize, Serialize};

use crate::dataset::Manifest;
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::io;
use crate::io::sha256_hex;
use crate::layout::Layout;

/// How the source position is given to the network.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum SourceEncoding {
    /// A Gaussian bump of one cell's width at the source.
    #[default]
    Gaussian,
    /// Distance to the source, divided by the arena height.
    Distance,
}

/// Scales of the input and target transforms (saved in `config.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// The signed distance is divided by this (m).
    pub sdf_scale_m: f32,
    /// `y = ln(1 + c / concentration_scale)`.
    pub concentration_scale: f32,
}

impl Default for Normalization {
    fn default() -> Self {
        Self {
            sdf_scale_m: 1.0,
            concentration_scale: 0.01,
        }
    }
}

impl Normalization {
    /// Concentration to network target.
    pub fn forward(&self, c: f32) -> f32 {
        (c.max(0.0) / self.concentration_scale).ln_1p()
    }

    /// Network output to concentration (non-negative).
    pub fn inverse(&self, y: f32) -> f32 {
        self.concentration_scale * y.max(0.0).exp_m1()
    }
}

/// Number of input channels.
pub const INPUT_CHANNELS: usize = 3;

/// Writes the `3 x H x W` input channels of one sample into `out`.
pub fn encode_input(
    mask: ArrayView2<f32>,
    sdf: ArrayView2<f32>,
    [sx, sy]: [f64; 2],
    cell: f64,
    encoding: SourceEncoding,
    norm: &Normalization,
    out: &mut [f32],
) {
    let (h, w) = mask.dim();
    let plane = h * w;
    let height = h as f64 * cell;
    for ((j, i), &m) in mask.indexed_iter() {
        let k = j * w + i;
        out[k] = m;
        out[plane + k] = sdf[[j, i]] / norm.sdf_scale_m;
        let (x, y) = ((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
        let d2 = (x - sx).powi(2) + (y - sy).powi(2);
        out[2 * plane + k] = match encoding {
            SourceEncoding::Gaussian => (-d2 / (2.0 * cell * cell)).exp() as f32,
            SourceEncoding::Distance => (d2.sqrt() / height) as f32,
        };
    }
}

/// Obstacle mask and scaled-free signed distance of a layout, as the network sees them.
pub fn layout_planes(layout: &Layout) -> (ndarray::Array2<f32>, ndarray::Array2<f32>) {
    (
        layout.solid().mapv(|s| f32::from(u8::from(s))),
        layout.signed_distance().mapv(|d| d as f32),
    )
}

/// A dataset held in memory for training and evaluation, in the canonical frame of its base
/// layout ([`crate::frame`]: turned so that the wind comes from the west, as the network sees
/// every layout).
#[derive(Debug, Clone)]
pub struct TrainingData {
    /// The dataset's manifest.
    pub manifest: Manifest,
    /// SHA-256 of `manifest.json`, recorded with a trained model.
    pub digest: String,
    masks: Array3<f32>,
    sdf: Array3<f32>,
    /// Layout index of each sample.
    pub source_layout: Vec<usize>,
    /// Source position of each sample (m).
    pub source_xy: Vec<[f64; 2]>,
    /// Target concentrations `[S, H, W]`.
    pub concentration: Array3<f32>,
    /// Canonical grid `[H, W]`.
    grid: [usize; 2],
}

impl TrainingData {
    /// Loads a complete dataset directory.
    ///
    /// # Errors
    /// Any error of [`Manifest::load`]; [`Error::Dataset`] for a shard or inconsistent indices.
    pub fn load(dir: &Path) -> Result<Self> {
        let manifest = Manifest::load(dir)?;
        if manifest.shard.is_some() {
            return Err(Error::Dataset(format!(
                "{} is one shard; merge the shards first (plumenet merge)",
                dir.display()
            )));
        }
        let text = io::read_to_string(&dir.join("manifest.json"))?;
        let digest = sha256_hex(text.as_bytes());
        let masks = io::read_npy::<f32, Ix3>(&dir.join("obstacle_mask.npy"))?;
        let sdf = io::read_npy::<f32, Ix3>(&dir.join("signed_distance.npy"))?;
        let owner = io::read_npy::<u32, Ix1>(&dir.join("source_layout.npy"))?;
        let xy = io::read_npy::<f32, Ix2>(&dir.join("source_xy.npy"))?;
        let concentration = io::read_npy::<f32, Ix3>(&dir.join("concentration.npy"))?;
        let layouts = masks.dim().0;
        if owner.iter().any(|&k| k as usize >= layouts) || xy.nrows() != owner.len() {
            return Err(Error::Dataset(format!(
                "{}: source indices do not match the layouts",
                dir.display()
            )));
        }
        if concentration.iter().any(|c| !c.is_finite()) {
            return Err(Error::Dataset(format!(
                "{}: concentration.npy holds NaN or infinity",
                dir.display()
            )));
        }
        let base = &manifest.base;
        let [ny, nx] = manifest.grid;
        let frame = Frame::new(base.wind.from, [base.width_m, base.height_m], [nx, ny]);
        let (hc, wc) = frame.canonical_shape();
        let turn = |a: Array3<f32>| -> Array3<f32> {
            if frame.is_identity() {
                return a;
            }
            let mut out = Array3::zeros((a.dim().0, hc, wc));
            for (mut dst, src) in out.outer_iter_mut().zip(a.outer_iter()) {
                dst.assign(&frame.cells_to_canonical(src));
            }
            out
        };
        Ok(Self {
            digest,
            masks: turn(masks),
            sdf: turn(sdf),
            source_layout: owner.iter().map(|&k| k as usize).collect(),
            source_xy: xy
                .outer_iter()
                .map(|r| {
                    let (x, y) = frame.to_canonical(f64::from(r[0]), f64::from(r[1]));
                    [x, y]
                })
                .collect(),
            concentration: turn(concentration),
            manifest,
            grid: [hc, wc],
        })
    }

    /// Number of samples.
    pub fn len(&self) -> usize {
        self.source_layout.len()
    }

    /// Whether there is no sample.
    pub fn is_empty(&self) -> bool {
        self.source_layout.is_empty()
    }

    /// Grid `[H, W]` (canonical: the base layout turned so that the wind comes from the west).
    pub fn grid(&self) -> [usize; 2] {
        self.grid
    }

    /// Cell size (m).
    pub fn cell(&self) -> f64 {
        self.manifest.base.cell_m
    }

    /// Obstacle mask `[H, W]` of sample `s`.
    pub fn mask(&self, s: usize) -> ArrayView2<'_, f32> {
        self.masks
            .index_axis(ndarray::Axis(0), self.source_layout[s])
    }

    /// Splits samples by layout: the last `ceil(fraction * L)` layouts (at least one when there
    /// are two or more) are for validation, so validation measures unseen layouts.
    pub fn split_by_layout(&self, fraction: f64) -> (Vec<usize>, Vec<usize>) {
        let layouts = self.masks.dim().0;
        let held = if layouts < 2 {
            0
        } else {
            ((fraction * layouts as f64).ceil() as usize).clamp(1, layouts - 1)
        };
        let first_val = layouts - held;
        (0..self.len()).partition(|&s| self.source_layout[s] < first_val)
    }

    /// Input, target and free-cell weight tensors `[B, C, H, W]` for the given samples.
    pub fn batch(
        &self,
        samples: &[usize],
        encoding: SourceEncoding,
        norm: &Normalization,
        device: &Device,
    ) -> (Tensor<4>, Tensor<4>, Tensor<4>) {
        let [h, w] = self.grid();
        let plane = h * w;
        let b = samples.len();
        let mut input = vec![0.0f32; b * INPUT_CHANNELS * plane];
        let mut target = vec![0.0f32; b * plane];
        let mut free = vec![0.0f32; b * plane];
        for (n, &s) in samples.iter().enumerate() {
            let layout = self.source_layout[s];
            encode_input(
                self.masks.index_axis(ndarray::Axis(0), layout),
                self.sdf.index_axis(ndarray::Axis(0), layout),
                self.source_xy[s],
                self.cell(),
                encoding,
                norm,
                &mut input[n * INPUT_CHANNELS * plane..(n + 1) * INPUT_CHANNELS * plane],
            );
            let c = self.concentration.index_axis(ndarray::Axis(0), s);
            for (k, (&cv, &m)) in c.iter().zip(self.mask(s).iter()).enumerate() {
                target[n * plane + k] = norm.forward(cv);
                free[n * plane + k] = 1.0 - m;
            }
        }
        let t = |v: Vec<f32>, c: usize| {
            Tensor::<4>::from_data(TensorData::new(v, [b, c, h, w]), device)
        };
        (t(input, INPUT_CHANNELS), t(target, 1), t(free, 1))
    }
}
