//! A trained PlumeNet ([`super::saved`]) loaded for prediction and banks.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use burn::prelude::*;
use ndarray::{Array2, Array3};
use rayon::prelude::*;

use super::coarse;
use super::data::{RoomPlanes, padded_shape};
use super::head::{self, FusedHead, RoomTerms, SourceTables};
use super::model::{COARSE_SOURCE_PLANES, CoarseNet, ConvImpl, PlumeNet, ROOM_CHANNELS};
use super::saved::{LEGACY_MODEL_FORMAT, SavedModel};
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::io::sha256_hex;
use crate::layout::Layout;
use crate::physics::wind::WindField;
use crate::plume::{PlumeBank, PlumeModel};

/// Samples per forward pass in a bank (bounds memory: about 40 MB of activations per sample
/// chunk of 64 on the default grid).
pub const BANK_CHUNK: usize = 64;

/// A loaded PlumeNet ready for inference.
#[derive(Debug)]
pub struct Surrogate {
    net: PlumeNet,
    saved: SavedModel,
    dir: PathBuf,
    device: Device,
}

impl Surrogate {
    /// Loads `dir/config.json` and `dir/weights.bpk` ([`SavedModel::load`]).
    ///
    /// # Errors
    /// [`Error::Io`]/[`Error::Json`] for missing or malformed files, [`Error::Model`] for another
    /// format, a weights file that does not match its digest (truncated or replaced) or does not
    /// fit the architecture.
    pub fn load(dir: &Path) -> Result<Self> {
        let device = super::backend::device();
        let (saved, net) = SavedModel::load(dir, &device)?;
        Ok(Self {
            net,
            saved,
            dir: dir.to_path_buf(),
            device,
        })
    }

    /// The network.
    pub fn net(&self) -> &PlumeNet {
        &self.net
    }

    /// The saved configuration.
    pub fn saved(&self) -> &SavedModel {
        &self.saved
    }

    /// Checks that the model covers this layout: for an any-room model, its cell size, room
    /// sides, wind speed and coefficients lie in the trained ranges; for a one-room model
    /// (format `plumenet-model-v1`), its grid is the one grid the model knows.
    ///
    /// # Errors
    /// [`Error::Model`] naming the quantity, the trained range and how to retrain.
    pub fn check_layout(&self, layout: &Layout) -> Result<()> {
        let retrain = "to cover it, generate a dataset of such rooms and train a model on it \
                       (plumenet generate --out D ...; plumenet train --data D --out models/NAME)";
        match (&self.saved.ranges, self.saved.grid) {
            (Some(ranges), _) => ranges.check(layout).map_err(|e| {
                // The range check's own message, without a second "model:" prefix.
                let reason = match e {
                    Error::Model(reason) => reason,
                    other => other.to_string(),
                };
                Error::Model(format!(
                    "{} was not trained for this room: {reason}; {retrain}",
                    self.dir.display()
                ))
            }),
            (None, grid) => {
                let (ny, nx) = Frame::of(layout).canonical_shape();
                if grid != Some([ny, nx]) || (layout.cell() - self.saved.cell_m).abs() > 1e-12 {
                    return Err(Error::Model(format!(
                        "model {} is a one-room model ({LEGACY_MODEL_FORMAT}) and knows \
                         only a {:?} grid of {} m cells; the layout has {:?} cells of {} m \
                         (turned so that the wind comes from the west); {retrain}",
                        self.dir.display(),
                        grid.unwrap_or_default(),
                        self.saved.cell_m,
                        [ny, nx],
                        layout.cell()
                    )));
                }
                Ok(())
            }
        }
    }

    /// The padded canonical grid `[H, W]` the network runs on for `layout`.
    pub fn grid(&self, layout: &Layout) -> [usize; 2] {
        let (h, w) = padded_shape(
            Frame::of(layout).canonical_shape(),
            self.saved.training.pad_cells,
        );
        [h, w]
    }

    /// Input channels of the network.
    pub fn channels(&self) -> usize {
        self.saved.architecture.in_channels
    }

    /// The network inputs for `sources` in `layout`, chunks of at most [`BANK_CHUNK`] samples of
    /// `[n, channels, H, W]` row-major on the grid [`Surrogate::grid`] (what
    /// [`Surrogate::predict_many`] feeds the network, for the room as it is). Solves the wind
    /// first if the inputs need it.
    ///
    /// # Errors
    /// [`Error::Model`] for a layout the model does not cover, [`Error::Source`] for a source
    /// outside free space, [`Error::Solver`] when the wind cannot be solved.
    pub fn inputs(&self, layout: &Layout, sources: &[[f64; 2]]) -> Result<Vec<Vec<f32>>> {
        let room = self.room(layout, sources)?;
        let grid = self.grid(layout);
        canonical_sources(&Frame::of(layout), sources)
            .chunks(BANK_CHUNK)
            .map(|chunk| self.encode(&room, chunk, grid))
            .collect()
    }

    /// The canonical room of `layout` as the network sees it (wind solved if the inputs need
    /// it), after checking the layout and the sources.
    fn room(&self, layout: &Layout, sources: &[[f64; 2]]) -> Result<RoomPlanes> {
        self.check_layout(layout)?;
        for &[x, y] in sources {
            layout.check_source(x, y)?;
        }
        // The network sees the layout turned so that the wind comes from the west.
        let canonical = Frame::of(layout).layout_to_canonical(layout)?;
        let wind = if self.saved.training.inputs.needs_wind() {
            Some(WindField::solve(&canonical)?)
        } else {
            None
        };
        Ok(RoomPlanes::new(&canonical, wind.as_ref()))
    }

    /// The inputs of canonical `sources` in `room`, `[n, channels, H, W]` on grid `[H, W]`.
    fn encode(
        &self,
        room: &RoomPlanes,
        sources: &[[f64; 2]],
        [h, w]: [usize; 2],
    ) -> Result<Vec<f32>> {
        let per_sample = self.channels() * h * w;
        let mut input = vec![0.0f32; sources.len() * per_sample];
        // Samples are independent: encode them in parallel (the priors' Bessel functions are
        // a visible part of a large room's bank time).
        input
            .par_chunks_mut(per_sample)
            .zip(sources)
            .try_for_each(|(slot, &source)| {
                room.encode(
                    source,
                    self.saved.training.inputs,
                    self.saved.encoding,
                    &self.saved.normalization,
                    (h, w),
                    slot,
                )
            })?;
        Ok(input)
    }

    /// How many views of a room a prediction averages: 2 when the model averages the room and
    /// its mirror image ([`SavedModel::mirror_average`]), else 1.
    pub fn views(&self) -> usize {
        if self.saved.mirror_average { 2 } else { 1 }
    }

    /// The raw network output (transformed concentration) `[n, 1, H, W]` of `n` encoded inputs
    /// on grid `[H, W]`.
    ///
    /// # Errors
    /// [`Error::Model`] when `input` does not hold whole samples of this grid.
    pub fn forward_raw(&self, input: Vec<f32>, grid: [usize; 2]) -> Result<Vec<f32>> {
        self.forward_raw_with(input, grid, ConvImpl::Own)
    }

    /// [`Surrogate::forward_raw`] with the convolutions run by `imp`.
    ///
    /// # Errors
    /// As [`Surrogate::forward_raw`].
    pub fn forward_raw_with(
        &self,
        input: Vec<f32>,
        [h, w]: [usize; 2],
        imp: ConvImpl,
    ) -> Result<Vec<f32>> {
        let channels = self.channels();
        let per_sample = channels * h * w;
        if input.is_empty() || input.len() % per_sample != 0 {
            return Err(Error::Model(format!(
                "{} input values are not whole samples of {per_sample}",
                input.len()
            )));
        }
        let n = input.len() / per_sample;
        let x = Tensor::<4>::from_data(TensorData::new(input, [n, channels, h, w]), &self.device);
        self.net
            .forward_with(x, imp)
            .into_data()
            .try_to_vec::<f32>()
            .map_err(|e| Error::Model(format!("unexpected network output: {e:?}")))
    }

    /// Predicted fields `[N, H, W]` for sources in `layout`, in forward passes of
    /// [`BANK_CHUNK`] samples. A model with [`SavedModel::mirror_average`] predicts the room and
    /// its mirror image across the wind (`y -> H - y` in the canonical frame, an exact symmetry
    /// of the physics) and averages the two concentrations.
    ///
    /// # Errors
    /// As [`Surrogate::inputs`].
    pub fn predict_many(&self, layout: &Layout, sources: &[[f64; 2]]) -> Result<Array3<f32>> {
        self.predict_many_with(layout, sources, ConvImpl::Own)
    }

    /// [`Surrogate::predict_many`] with the convolutions run by `imp`.
    ///
    /// # Errors
    /// As [`Surrogate::predict_many`].
    pub fn predict_many_with(
        &self,
        layout: &Layout,
        sources: &[[f64; 2]],
        imp: ConvImpl,
    ) -> Result<Array3<f32>> {
        let (h, w) = layout.shape();
        let frame = Frame::of(layout);
        let grid = self.grid(layout);
        let solid = layout.solid();
        let norm = self.saved.normalization;
        let speed = layout.wind_speed();
        let room = self.room(layout, sources)?;
        let canonical = canonical_sources(&frame, sources);
        // The mirror image: the room flipped across the wind, each source with it; its output
        // row `jc` is the room's row `rows - 1 - jc`.
        let rows = room.shape().0;
        let mirror = (self.views() == 2).then(|| {
            let flipped: Vec<[f64; 2]> =
                canonical.iter().map(|&p| room.mirrored_point(p)).collect();
            (room.mirrored(), flipped)
        });
        let weight = 1.0 / self.views() as f32;
        // An operator network's room pass and room terms (the coarse form's room share), once
        // per view.
        let head = if self.net.operator.is_some() {
            Some(FusedHead::of(&self.net)?)
        } else {
            None
        };
        let room_input = |room: &RoomPlanes| -> Result<Tensor<4>> {
            let mut input = vec![0.0f32; ROOM_CHANNELS * grid[0] * grid[1]];
            room.encode_room(&norm, (grid[0], grid[1]), &mut input)?;
            Ok(Tensor::<4>::from_data(
                TensorData::new(input, [1, ROOM_CHANNELS, grid[0], grid[1]]),
                &self.device,
            ))
        };
        let pass = |room: &RoomPlanes, sources: &[[f64; 2]]| -> Result<Option<RoomPass>> {
            if let Some(coarse) = &self.net.coarse {
                let planes = self.net.room_planes(room_input(room)?, imp);
                let share = coarse.room_share(planes, imp);
                return self
                    .coarse_pass(coarse, (room, share), sources, grid, imp)
                    .map(Some);
            }
            let Some(head) = &head else {
                return Ok(None);
            };
            let planes = self
                .net
                .room_planes(room_input(room)?, imp)
                .into_data()
                .try_to_vec::<f32>()
                .map_err(|e| Error::Model(format!("unexpected network output: {e:?}")))?;
            let terms = head.room_terms(&planes, grid);
            let tables = SourceTables::new(room, &terms, sources, &norm);
            Ok(Some(RoomPass::Bilinear {
                planes,
                terms,
                tables,
            }))
        };
        let direct_pass = pass(&room, &canonical)?;
        let mirror_pass = match &mirror {
            Some((mroom, msources)) => pass(mroom, msources)?,
            None => None,
        };
        // Transformed outputs `[n, H', W']` on `[gh, gw]`: the network's grid, or the room
        // terms' (widened to whole tiles) for an operator network of the bilinear form.
        let [gh, gw] = match &direct_pass {
            Some(RoomPass::Bilinear { terms, .. }) => terms.grid,
            _ => grid,
        };
        let raw = |room: &RoomPlanes, pass: &Option<RoomPass>, sources: &[[f64; 2]]| match (
            pass, &head,
        ) {
            (
                Some(RoomPass::Bilinear {
                    planes,
                    terms,
                    tables,
                }),
                Some(head),
            ) => Ok(head::source_fields(
                terms,
                tables,
                sources,
                &head.coefficients(room, planes, grid, sources),
                &head.weights,
            )),
            (Some(RoomPass::Coarse(pass)), _) => Ok(coarse_raw(room, pass, sources, grid)),
            _ => self.forward_raw_with(self.encode(room, sources, grid)?, grid, imp),
        };
        // Where each real cell reads its canonical value and its mirror image's (row
        // `rows - 1 - jc` of the mirrored room's output), `None` in obstacles: each field is
        // then a plain gather.
        let cells: Vec<Option<[usize; 2]>> = solid
            .indexed_iter()
            .map(|((j, i), &s)| {
                (!s).then(|| {
                    let (jc, ic) = frame.cell_to_canonical(j, i);
                    [jc * gw + ic, (rows - 1 - jc) * gw + ic]
                })
            })
            .collect();
        let mut out = Array3::<f32>::zeros((sources.len(), h, w));
        for (k, mut fields) in out
            .axis_chunks_iter_mut(ndarray::Axis(0), BANK_CHUNK)
            .enumerate()
        {
            let chunk = k * BANK_CHUNK..k * BANK_CHUNK + fields.dim().0;
            // Concentrations on the canonical grid.
            let mut direct = raw(&room, &direct_pass, &canonical[chunk.clone()])?;
            norm.inverse_slice(&mut direct, speed);
            let mirrored = match &mirror {
                Some((mroom, msources)) => {
                    let mut values = raw(mroom, &mirror_pass, &msources[chunk])?;
                    norm.inverse_slice(&mut values, speed);
                    Some(values)
                }
                None => None,
            };
            fields
                .axis_iter_mut(ndarray::Axis(0))
                .into_par_iter()
                .enumerate()
                .for_each(|(n, mut field)| {
                    let base = n * gh * gw;
                    for (slot, cell) in field.iter_mut().zip(&cells) {
                        let Some([at, mirror_at]) = *cell else {
                            continue;
                        };
                        let mut c = direct[base + at];
                        if let Some(values) = &mirrored {
                            c += values[base + mirror_at];
                        }
                        *slot = weight * c;
                    }
                });
        }
        Ok(out)
    }

    /// The coarse network's pass over one view of a room, from the room's `share`
    /// ([`CoarseNet::room_share`]): the network runs once per block of cells that holds one of
    /// the canonical `sources` ([`coarse::anchor`]), in chunks of [`BANK_CHUNK`] anchors.
    fn coarse_pass(
        &self,
        coarse: &CoarseNet,
        (room, share): (&RoomPlanes, Tensor<4>),
        sources: &[[f64; 2]],
        [h, w]: [usize; 2],
        imp: ConvImpl,
    ) -> Result<RoomPass> {
        let (k, cell) = (coarse.scale(), room.cell_m);
        let mut blocks = BTreeMap::new();
        let mut anchors = Vec::new();
        for &source in sources {
            blocks
                .entry(coarse::block(source, cell, k))
                .or_insert_with(|| {
                    anchors.push(coarse::anchor(source, cell, k));
                    anchors.len() - 1
                });
        }
        let every: Vec<[f64; 2]> = sources.iter().chain(&anchors).copied().collect();
        let tables = SourceTables::with_width(room, w, &every, &self.saved.normalization);
        let (hs, ws) = (h / k, w / k);
        let per_anchor = COARSE_SOURCE_PLANES * hs * ws;
        let mut corrections = Vec::with_capacity(anchors.len() * hs * ws);
        for chunk in anchors.chunks(BANK_CHUNK) {
            let mut input = vec![0.0f32; chunk.len() * per_anchor];
            input
                .par_chunks_mut(per_anchor)
                .zip(chunk)
                .for_each(|(slot, &anchor)| {
                    let rows = |j| tables.row(anchor, j);
                    coarse::pooled_planes(rows, room, anchor, ((h, w), k), slot);
                });
            let x = Tensor::<4>::from_data(
                TensorData::new(input, [chunk.len(), COARSE_SOURCE_PLANES, hs, ws]),
                &self.device,
            );
            corrections.extend(
                coarse
                    .correction(share.clone(), x, imp)
                    .into_data()
                    .try_to_vec::<f32>()
                    .map_err(|e| Error::Model(format!("unexpected network output: {e:?}")))?,
            );
        }
        Ok(RoomPass::Coarse(CoarsePass {
            tables,
            blocks,
            corrections,
            k,
        }))
    }

    /// Predicted field `[H, W]` of one source.
    ///
    /// # Errors
    /// As [`Surrogate::predict_many`].
    pub fn predict(&self, layout: &Layout, source: [f64; 2]) -> Result<Array2<f64>> {
        let many = self.predict_many(layout, &[source])?;
        Ok(many.index_axis(ndarray::Axis(0), 0).mapv(f64::from))
    }
}

/// An operator network's pass over one view of a room.
enum RoomPass {
    /// The bilinear form's room planes, room terms and the tables of the sources.
    Bilinear {
        planes: Vec<f32>,
        terms: RoomTerms,
        tables: SourceTables,
    },
    /// The coarse form's corrections, one per block of sources.
    Coarse(CoarsePass),
}

/// The coarse form's pass over one view of a room: the tables of the sources and their
/// anchors, and the network's correction of each block that holds a source.
struct CoarsePass {
    tables: SourceTables,
    /// Index of each block ([`coarse::block`]) among the corrections.
    blocks: BTreeMap<(i64, i64), usize>,
    /// `[blocks, H / k, W / k]` corrections.
    corrections: Vec<f32>,
    /// Cells a side of the network's cells.
    k: usize,
}

/// The coarse form's transformed concentrations `[n, H, W]` of canonical `sources` (those of
/// `pass`) in `room` on `grid`: each source's prior plus its block's correction, upsampled.
fn coarse_raw(
    room: &RoomPlanes,
    pass: &CoarsePass,
    sources: &[[f64; 2]],
    [h, w]: [usize; 2],
) -> Vec<f32> {
    let (k, cell) = (pass.k, room.cell_m);
    let (hs, ws) = (h / k, w / k);
    let taps = (
        coarse::upsampling_taps(hs, h),
        coarse::upsampling_taps(ws, w),
    );
    let mut out = vec![0.0f32; sources.len() * h * w];
    out.par_chunks_mut(h * w)
        .zip(sources)
        .for_each(|(field, &source)| {
            let at = pass.blocks[&coarse::block(source, cell, k)] * hs * ws;
            coarse::fine_field(
                &pass.tables,
                room,
                source,
                (&pass.corrections[at..at + hs * ws], ws),
                (&taps.0, &taps.1),
                field,
            );
        });
    out
}

/// Canonical coordinates of real `sources`.
fn canonical_sources(frame: &Frame, sources: &[[f64; 2]]) -> Vec<[f64; 2]> {
    sources
        .iter()
        .map(|&[x, y]| {
            let (xc, yc) = frame.to_canonical(x, y);
            [xc, yc]
        })
        .collect()
}

/// The factor within which PlumeNet's concentrations are known when ranked: its relative
/// error is about a fifth to a third of the field (`docs/plumenet.md`), more far downwind,
/// where the plume is flat and a small error reverses the order of two cells. Chosen on the
/// STE's tuning seeds (`docs/method.md`).
pub const RANK_FACTOR: f64 = 3.0;

impl PlumeModel for Surrogate {
    fn rank_factor(&self) -> f64 {
        RANK_FACTOR
    }

    fn name(&self) -> String {
        format!("plumenet:{}", self.dir.display())
    }

    fn digest(&self) -> String {
        sha256_hex(
            serde_json::to_string(&self.saved)
                .unwrap_or_default()
                .as_bytes(),
        )
    }

    fn bank(&self, layout: &Layout, candidates: &[[f64; 2]]) -> Result<PlumeBank> {
        Ok(PlumeBank {
            candidates: candidates.to_vec(),
            fields: self.predict_many(layout, candidates)?,
        })
    }
}
