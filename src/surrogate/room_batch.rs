//! An operator network's batches ([`crate::surrogate::model::OperatorConfig`]): the room
//! inputs, the per-source planes and where each source reads its branch planes, for training
//! (whole rooms with all their sources) and for banks.

use std::collections::BTreeMap;

use burn::prelude::*;

use super::coarse;
use super::data::{Normalization, RoomPlanes, TrainingData, padded_shape};
use super::model::{
    COARSE_SOURCE_PLANES, OFFSET_SCALE_M, ROOM_CHANNELS, SOURCE_PLANES, SourceTaps,
};
use crate::error::{Error, Result};

/// The samples of one layout: an operator network's unit of batching.
pub type RoomSamples = Vec<usize>;

/// An operator network's batch: `B` rooms with `M` sources each
/// ([`crate::surrogate::model::PlumeNet::source_fields`]).
#[derive(Debug, Clone)]
pub struct RoomBatch {
    /// Room inputs `[B, ROOM_CHANNELS, H, W]`.
    pub rooms: Tensor<4>,
    /// Where each source reads its branch planes.
    pub taps: SourceTaps,
    /// Per-source planes `[B M, SOURCE_PLANES, H, W]`, room-major.
    pub sources: Tensor<4>,
}

impl SourceTaps {
    /// The taps of `S` sources, one row of four per source, with the coarse form's pooled
    /// planes of their anchors, as tensors on `device`.
    pub fn new(rows: &[[(i64, f32); 4]], pooled: Option<Tensor<4>>, device: &Device) -> Self {
        let s = rows.len();
        let (mut cells, mut weights) = (vec![0i64; 4 * s], vec![0.0f32; 4 * s]);
        for (n, row) in rows.iter().enumerate() {
            for (c, &(cell, weight)) in row.iter().enumerate() {
                cells[c * s + n] = cell;
                weights[c * s + n] = weight;
            }
        }
        Self {
            cells: Tensor::<1, Int>::from_data(TensorData::new(cells, [4 * s]), device),
            weights: Tensor::<2>::from_data(TensorData::new(weights, [4 * s, 1]), device),
            pooled,
        }
    }
}

impl RoomPlanes {
    /// Writes an operator network's room inputs ([`crate::surrogate::model::ROOM_CHANNELS`]:
    /// mask, signed distance, Peclet number, `u / U`, `v / U`) into `out`, a zeroed buffer of
    /// that many planes of `padded` shape.
    ///
    /// # Errors
    /// [`Error::Model`] when the room has no solved wind.
    pub fn encode_room(
        &self,
        norm: &Normalization,
        (hp, wp): (usize, usize),
        out: &mut [f32],
    ) -> Result<()> {
        let Some([u, v]) = &self.wind else {
            return Err(Error::Model(
                "an operator network needs the solved wind, which was not given".into(),
            ));
        };
        let plane = hp * wp;
        for ((j, i), &m) in self.mask.indexed_iter() {
            let k = j * wp + i;
            out[k] = m;
            out[plane + k] = self.sdf[[j, i]] / norm.sdf_scale_m;
            out[2 * plane + k] = self.peclet as f32;
            out[3 * plane + k] = u[[j, i]];
            out[4 * plane + k] = v[[j, i]];
        }
        Ok(())
    }

    /// Writes an operator network's per-source planes
    /// ([`crate::surrogate::model::SOURCE_PLANES`]) of a source at canonical `[sx, sy]` into
    /// `out` (zeroed, `padded` shape): the analytic prior transformed like the target in free
    /// cells, and `tanh(dx / 2 m)`, `tanh(dy / 2 m)` of the offset from the source in the room.
    pub fn encode_source(
        &self,
        [sx, sy]: [f64; 2],
        norm: &Normalization,
        (hp, wp): (usize, usize),
        out: &mut [f32],
    ) {
        let plane = hp * wp;
        let cell = self.cell_m;
        for ((j, i), &m) in self.mask.indexed_iter() {
            let k = j * wp + i;
            let (dx, dy) = ((i as f64 + 0.5) * cell - sx, (j as f64 + 0.5) * cell - sy);
            if m == 0.0 {
                let c = self.unbounded_prior(dx, dy);
                out[k] = norm.forward(c as f32, self.speed_mps);
            }
            out[plane + k] = (dx / OFFSET_SCALE_M).tanh() as f32;
            out[2 * plane + k] = (dy / OFFSET_SCALE_M).tanh() as f32;
        }
    }

    /// Where an operator network reads the branch planes of a source at canonical `[sx, sy]`
    /// in this room, placed as room `b` of a batch on the `padded` grid: the four cells around
    /// the point (clamped into the room) as flat indices into `[B H W]`, with their bilinear
    /// weights.
    pub fn taps(&self, [sx, sy]: [f64; 2], b: usize, (hp, wp): (usize, usize)) -> [(i64, f32); 4] {
        let (h, w) = self.shape();
        let corner = |t: f64, n: usize| {
            let hi = n.saturating_sub(2) as f64;
            let t0 = t.floor().clamp(0.0, hi);
            (t0 as usize, (t - t0).clamp(0.0, 1.0) as f32)
        };
        let (i0, fx) = corner(sx / self.cell_m - 0.5, w);
        let (j0, fy) = corner(sy / self.cell_m - 0.5, h);
        let (i1, j1) = ((i0 + 1).min(w - 1), (j0 + 1).min(h - 1));
        let flat = |j: usize, i: usize| (b * hp * wp + j * wp + i) as i64;
        [
            (flat(j0, i0), (1.0 - fx) * (1.0 - fy)),
            (flat(j0, i1), fx * (1.0 - fy)),
            (flat(j1, i0), (1.0 - fx) * fy),
            (flat(j1, i1), fx * fy),
        ]
    }
}

impl TrainingData {
    /// `samples` grouped by layout, in the order of each layout's first sample: the rooms of
    /// an operator network's batches ([`TrainingData::room_batch`]).
    pub fn rooms_of(&self, samples: &[usize]) -> Vec<RoomSamples> {
        let mut rooms: Vec<RoomSamples> = Vec::new();
        let mut slot: BTreeMap<usize, usize> = BTreeMap::new();
        for &s in samples {
            let l = self.source_layout[s];
            let k = *slot.entry(l).or_insert_with(|| {
                rooms.push(Vec::new());
                rooms.len() - 1
            });
            rooms[k].push(s);
        }
        rooms
    }

    /// `rooms` (groups of samples of one layout each) grouped by padded canonical grid and by
    /// their number of sources, in that order, each group in the order given.
    pub fn room_buckets(&self, rooms: &[RoomSamples], pad_cells: usize) -> Vec<Vec<RoomSamples>> {
        let mut groups: BTreeMap<((usize, usize), usize), Vec<RoomSamples>> = BTreeMap::new();
        for room in rooms {
            let Some(&first) = room.first() else { continue };
            let shape = padded_shape(self.room(self.source_layout[first]).shape(), pad_cells);
            groups
                .entry((shape, room.len()))
                .or_default()
                .push(room.clone());
        }
        groups.into_values().collect()
    }

    /// An operator network's batch ([`RoomBatch`]) of `rooms`, each the samples of one layout,
    /// every room with the same number of sources `M`, padded to the largest padded grid among
    /// them, with target and weight tensors `[B M, 1, H, W]` as in [`TrainingData::batch`].
    /// With `mirror`, the rooms whose entry is true are mirrored across the wind (with their
    /// sources and targets). With `pool = Some(k)` (a coarse network pooling by `k`), the taps
    /// hold the pooled planes of the sources' anchors ([`coarse::pooled_planes`]).
    ///
    /// # Errors
    /// [`Error::Dataset`] for rooms of different source counts or samples of different
    /// layouts in one room; as [`RoomPlanes::encode_room`].
    pub fn room_batch(
        &self,
        rooms: &[RoomSamples],
        mirror: Option<&[bool]>,
        (norm, pad_cells, pool): (&Normalization, usize, Option<usize>),
        device: &Device,
    ) -> Result<(RoomBatch, Tensor<4>, Tensor<4>)> {
        let m = rooms.first().map_or(0, Vec::len);
        if rooms.iter().any(|r| r.len() != m || r.is_empty())
            || rooms.iter().any(|r| {
                r.iter()
                    .any(|&s| self.source_layout[s] != self.source_layout[r[0]])
            })
        {
            return Err(Error::Dataset(
                "an operator network's batch needs rooms of one layout each with equal source \
                 counts"
                    .into(),
            ));
        }
        let (h, w) = rooms
            .iter()
            .map(|r| padded_shape(self.room(self.source_layout[r[0]]).shape(), pad_cells))
            .fold((0, 0), |(a, b), (c, d)| (a.max(c), b.max(d)));
        let plane = h * w;
        let b = rooms.len();
        let mut room_in = vec![0.0f32; b * ROOM_CHANNELS * plane];
        let mut source_in = vec![0.0f32; b * m * SOURCE_PLANES * plane];
        let pooled_size = pool.map_or(0, |k| COARSE_SOURCE_PLANES * plane / (k * k));
        let mut pooled = vec![0.0f32; b * m * pooled_size];
        let mut anchor_planes = vec![0.0f32; pool.map_or(0, |_| SOURCE_PLANES * plane)];
        let mut target = vec![0.0f32; b * m * plane];
        let mut free = vec![0.0f32; b * m * plane];
        let mut taps = Vec::with_capacity(b * m);
        for (r, samples) in rooms.iter().enumerate() {
            let flip = mirror.is_some_and(|f| f[r]);
            let original = self.room(self.source_layout[samples[0]]);
            let mirrored;
            let room = if flip {
                mirrored = original.mirrored();
                &mirrored
            } else {
                original
            };
            room.encode_room(
                norm,
                (h, w),
                &mut room_in[r * ROOM_CHANNELS * plane..(r + 1) * ROOM_CHANNELS * plane],
            )?;
            for (k, &s) in samples.iter().enumerate() {
                let n = r * m + k;
                let source = if flip {
                    original.mirrored_point(self.source_xy[s])
                } else {
                    self.source_xy[s]
                };
                room.encode_source(
                    source,
                    norm,
                    (h, w),
                    &mut source_in[n * SOURCE_PLANES * plane..(n + 1) * SOURCE_PLANES * plane],
                );
                taps.push(room.taps(source, r, (h, w)));
                if let Some(k) = pool {
                    let anchor = coarse::anchor(source, room.cell_m, k);
                    anchor_planes.fill(0.0);
                    room.encode_source(anchor, norm, (h, w), &mut anchor_planes);
                    let rows = |j: usize| {
                        let at = j * w;
                        (
                            &anchor_planes[at..at + w],
                            &anchor_planes[plane + at..plane + at + w],
                            anchor_planes[2 * plane + at],
                        )
                    };
                    coarse::pooled_planes(
                        rows,
                        room,
                        anchor,
                        ((h, w), k),
                        &mut pooled[n * pooled_size..(n + 1) * pooled_size],
                    );
                }
                let mut concentration = self.concentration(s);
                if flip {
                    concentration.invert_axis(ndarray::Axis(0));
                }
                for (((j, i), &c), &solid) in concentration.indexed_iter().zip(room.mask.iter()) {
                    let at = n * plane + j * w + i;
                    target[at] = norm.forward(c, room.speed_mps);
                    free[at] = 1.0 - solid;
                }
            }
        }
        let t = |v: Vec<f32>, n: usize, c: usize| {
            Tensor::<4>::from_data(TensorData::new(v, [n, c, h, w]), device)
        };
        Ok((
            RoomBatch {
                rooms: t(room_in, b, ROOM_CHANNELS),
                taps: SourceTaps::new(
                    &taps,
                    pool.map(|k| {
                        let (hs, ws) = (h / k, w / k);
                        Tensor::<4>::from_data(
                            TensorData::new(pooled, [b * m, COARSE_SOURCE_PLANES, hs, ws]),
                            device,
                        )
                    }),
                    device,
                ),
                sources: t(source_in, b * m, SOURCE_PLANES),
            },
            t(target, b * m, 1),
            t(free, b * m, 1),
        ))
    }
}
