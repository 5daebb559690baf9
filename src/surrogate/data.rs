//! From layouts and dataset arrays to network tensors: input encoding, target transform,
//! padding and batches.
//!
//! **Inputs** (`[B, C, H, W]`, [`InputSet`]): the obstacle mask (1 in obstacles), the signed
//! distance divided by `sdf_scale_m`, the source encoding ([`SourceEncoding`], computed from the
//! source coordinates so every encoding can be tried on one dataset), then, for
//! [`InputSet::Physics`] and [`InputSet::Wind`], the room's cell Peclet number `U dx / D`
//! (a constant plane inside the room) and, for [`InputSet::Wind`], the solved wind `u / U` and
//! `v / U` at cell centres. The network always sees a room in its canonical frame (wind from the
//! west, [`crate::frame`]), padded with zeros on the east and north sides to a multiple of
//! `pad_cells` cells; zero in every channel means "outside the room", which the Peclet plane
//! tells apart from a free cell.
//!
//! **Target transform.** The network learns `y = ln(1 + c f / concentration_scale)` with
//! `f = U / reference_speed_mps` (a faster wind dilutes a source of the same strength, so `c U`
//! varies less across rooms than `c`), which tames the four decades between the source and the
//! far field; predictions are mapped back with `c = concentration_scale * (exp(max(y, 0)) - 1)
//! / f` (non-negative) and set to zero in obstacles. One-room models (format `plumenet-model-v1`) have
//! no reference speed (`f = 1`).

use std::collections::BTreeMap;
use std::path::Path;

use burn::prelude::*;
use ndarray::{Array2, ArrayView2, Ix1, Ix2, IxDyn};
use serde::{Deserialize, Serialize};

use crate::dataset::{Manifest, grid_of};
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::io;
use crate::io::sha256_hex;
use crate::layout::{Layout, LayoutSpec};
use crate::physics::analytic::{Plume, point_source_unbounded};
use crate::physics::wind::WindField;

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

/// Which input channels the network gets.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum InputSet {
    /// Mask, signed distance, source (one-room models, format `plumenet-model-v1`).
    Geometry,
    /// Geometry plus the cell Peclet number plane.
    Physics,
    /// Physics plus the solved wind `u / U`, `v / U` (the wind solve counts in the bank time).
    Wind,
    /// Wind plus a physical prior: the analytic plume of the source in uniform wind in an
    /// unbounded plane ([`point_source_unbounded`], cut off at a quarter cell from the source),
    /// transformed like the target; walls, obstacles, inlet and outlet are the network's to
    /// learn. The default: it gave the lowest validation loss of the input sets (`docs/plumenet.md`).
    #[default]
    Analytic,
    /// As [`InputSet::Analytic`], but the prior is the plume between the room's two side walls
    /// (the walls along the wind in the canonical frame; [`Plume::between_walls`], images
    /// across the wind), so only the obstacles, inlet and outlet are the network's to learn.
    Walled,
}

impl InputSet {
    /// Number of input channels.
    pub fn channels(self) -> usize {
        match self {
            InputSet::Geometry => 3,
            InputSet::Physics => 4,
            InputSet::Wind => 6,
            InputSet::Analytic | InputSet::Walled => 7,
        }
    }

    /// Whether the inputs need the solved wind.
    pub fn needs_wind(self) -> bool {
        matches!(self, InputSet::Wind | InputSet::Analytic | InputSet::Walled)
    }

    /// Whether the inputs carry an analytic prior channel (the network's seventh).
    pub fn has_prior(self) -> bool {
        matches!(self, InputSet::Analytic | InputSet::Walled)
    }
}

/// Scales of the input and target transforms (saved in `config.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Normalization {
    /// The signed distance is divided by this (m).
    pub sdf_scale_m: f32,
    /// `y = ln(1 + c f / concentration_scale)`.
    pub concentration_scale: f32,
    /// `f = U / reference_speed_mps`; absent (`f = 1`) in one-room models (format `plumenet-model-v1`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_speed_mps: Option<f32>,
}

impl Default for Normalization {
    fn default() -> Self {
        Self {
            sdf_scale_m: 1.0,
            concentration_scale: 0.01,
            reference_speed_mps: Some(0.75),
        }
    }
}

impl Normalization {
    fn factor(&self, speed_mps: f64) -> f32 {
        self.reference_speed_mps
            .map_or(1.0, |r| (speed_mps / f64::from(r)) as f32)
    }

    /// Concentration in wind of `speed_mps` to network target.
    pub fn forward(&self, c: f32, speed_mps: f64) -> f32 {
        (c.max(0.0) * self.factor(speed_mps) / self.concentration_scale).ln_1p()
    }

    /// Network output to concentration (non-negative) in wind of `speed_mps`.
    pub fn inverse(&self, y: f32, speed_mps: f64) -> f32 {
        self.concentration_scale * y.max(0.0).exp_m1() / self.factor(speed_mps)
    }

    /// [`Normalization::inverse`] of every value, in place and vectorised (arguments above 80,
    /// far beyond any field, are taken as 80).
    pub fn inverse_slice(&self, values: &mut [f32], speed_mps: f64) {
        super::expm1::expm1_scaled(values, self.concentration_scale / self.factor(speed_mps));
    }
}

/// `(h, w)` rounded up to multiples of `multiple`.
pub fn padded_shape((h, w): (usize, usize), multiple: usize) -> (usize, usize) {
    let m = multiple.max(1);
    (h.div_ceil(m) * m, w.div_ceil(m) * m)
}

/// One room as the network sees it: its canonical planes and physics.
#[derive(Debug, Clone, PartialEq)]
pub struct RoomPlanes {
    /// 1 in obstacle cells, `[H, W]`.
    pub mask: Array2<f32>,
    /// Signed distance (m), `[H, W]`.
    pub sdf: Array2<f32>,
    /// Solved wind `u / U` and `v / U` at cell centres (canonical components), when known.
    pub wind: Option<[Array2<f32>; 2]>,
    /// Cell size (m).
    pub cell_m: f64,
    /// Inlet wind speed (m/s).
    pub speed_mps: f64,
    /// Cell Peclet number `U dx / D`.
    pub peclet: f64,
    /// Effective diffusivity (m^2/s).
    pub diffusivity_m2ps: f64,
}

impl RoomPlanes {
    /// The planes of a canonical layout (wind from the west), with its solved wind if given.
    pub fn new(canonical: &Layout, wind: Option<&WindField>) -> Self {
        let speed = canonical.wind_speed();
        let wind = wind.map(|w| {
            let c = w.centred();
            let plane = |k: usize| {
                c.index_axis(ndarray::Axis(0), k)
                    .mapv(|v| (v / speed) as f32)
            };
            [plane(0), plane(1)]
        });
        Self::with_planes(
            canonical,
            canonical.solid().mapv(|s| f32::from(u8::from(s))),
            canonical.signed_distance().mapv(|d| d as f32),
            wind,
        )
    }

    /// The room of a canonical layout with its planes already at hand (a dataset's, turned).
    fn with_planes(
        canonical: &Layout,
        mask: Array2<f32>,
        sdf: Array2<f32>,
        wind: Option<[Array2<f32>; 2]>,
    ) -> Self {
        let speed = canonical.wind_speed();
        Self {
            mask,
            sdf,
            wind,
            cell_m: canonical.cell(),
            speed_mps: speed,
            peclet: speed * canonical.cell() / canonical.diffusivity(),
            diffusivity_m2ps: canonical.diffusivity(),
        }
    }

    /// A canonical point of the room at its place in the mirrored room ([`RoomPlanes::mirrored`]).
    pub fn mirrored_point(&self, [x, y]: [f64; 2]) -> [f64; 2] {
        [x, self.shape().0 as f64 * self.cell_m - y]
    }

    /// The room mirrored across the wind (`y -> H - y`, canonical frame): the planes flipped
    /// north to south and the wind's across component negated. The mean field of a mirrored
    /// room is the mirrored field, so this is an exact symmetry of the data (training's
    /// `--mirror`).
    pub fn mirrored(&self) -> Self {
        let flip = |a: &Array2<f32>| a.slice(ndarray::s![..;-1, ..]).to_owned();
        Self {
            mask: flip(&self.mask),
            sdf: flip(&self.sdf),
            wind: self
                .wind
                .as_ref()
                .map(|[u, v]| [flip(u), flip(v).mapv(|c| -c)]),
            cell_m: self.cell_m,
            speed_mps: self.speed_mps,
            peclet: self.peclet,
            diffusivity_m2ps: self.diffusivity_m2ps,
        }
    }

    /// Grid `(H, W)`.
    pub fn shape(&self) -> (usize, usize) {
        self.mask.dim()
    }

    /// Writes the input channels of a source at canonical `[sx, sy]` into `out`, a zeroed buffer
    /// of `inputs.channels()` planes of `padded` shape (the room in its south-west corner).
    ///
    /// # Errors
    /// [`Error::Model`] when the inputs need the wind and the room has none.
    pub fn encode(
        &self,
        [sx, sy]: [f64; 2],
        inputs: InputSet,
        encoding: SourceEncoding,
        norm: &Normalization,
        (hp, wp): (usize, usize),
        out: &mut [f32],
    ) -> Result<()> {
        let h = self.shape().0;
        let plane = hp * wp;
        let cell = self.cell_m;
        let height = h as f64 * cell;
        let wind = match (inputs.needs_wind(), &self.wind) {
            (true, None) => {
                return Err(Error::Model(
                    "these inputs need the solved wind, which was not given".into(),
                ));
            }
            (true, Some(wind)) => Some(wind),
            (false, _) => None,
        };
        let plume = Plume {
            speed: self.speed_mps,
            diffusivity: self.diffusivity_m2ps,
            rate: 1.0,
        };
        for ((j, i), &m) in self.mask.indexed_iter() {
            let k = j * wp + i;
            out[k] = m;
            out[plane + k] = self.sdf[[j, i]] / norm.sdf_scale_m;
            let (x, y) = ((i as f64 + 0.5) * cell, (j as f64 + 0.5) * cell);
            let d2 = (x - sx).powi(2) + (y - sy).powi(2);
            out[2 * plane + k] = match encoding {
                SourceEncoding::Gaussian => (-d2 / (2.0 * cell * cell)).exp() as f32,
                SourceEncoding::Distance => (d2.sqrt() / height) as f32,
            };
            if inputs != InputSet::Geometry {
                out[3 * plane + k] = self.peclet as f32;
            }
            if let Some([u, v]) = wind {
                out[4 * plane + k] = u[[j, i]];
                out[5 * plane + k] = v[[j, i]];
            }
            if inputs.has_prior() && m == 0.0 {
                let c = if inputs == InputSet::Walled {
                    plume.between_walls((x, y), (sx, sy), height, 0.25 * cell, 1e-6)
                } else {
                    self.unbounded_prior(x - sx, y - sy)
                };
                out[6 * plane + k] = norm.forward(c as f32, self.speed_mps);
            }
        }
        Ok(())
    }

    /// The analytic plume of a unit source in this room's uniform wind in an unbounded plane
    /// ([`point_source_unbounded`], cut off a quarter cell from the source) at offset
    /// `(dx, dy)` from the source.
    pub(crate) fn unbounded_prior(&self, dx: f64, dy: f64) -> f64 {
        point_source_unbounded(
            (dx, dy),
            (0.0, 0.0),
            self.speed_mps,
            self.diffusivity_m2ps,
            1.0,
            0.25 * self.cell_m,
        )
    }
}

/// Room size classes for per-class reports: a name and the largest floor area (m^2) of the class.
pub const SIZE_CLASSES: [(&str, f64); 3] = [
    ("small (up to 60 m2)", 60.0),
    ("medium (60 to 150 m2)", 150.0),
    ("large (over 150 m2)", f64::INFINITY),
];

/// Index of the [`SIZE_CLASSES`] entry of a layout.
pub fn size_class(layout: &Layout) -> usize {
    let area = layout.width() * layout.height();
    SIZE_CLASSES
        .iter()
        .position(|(_, max)| area <= *max + 1e-9)
        .unwrap_or(SIZE_CLASSES.len() - 1)
}

/// Ranges of room physics seen in training, checked before a model is used (`config.json`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainedRanges {
    /// The one cell size (m).
    pub cell_m: f64,
    /// Room length along the wind (m), `[min, max]`.
    pub length_m: [f64; 2],
    /// Room width across the wind (m), `[min, max]`.
    pub across_m: [f64; 2],
    /// Inlet wind speed (m/s), `[min, max]`.
    pub speed_mps: [f64; 2],
    /// Effective gas diffusivity (m^2/s), `[min, max]`.
    pub diffusivity_m2ps: [f64; 2],
    /// Effective eddy viscosity (m^2/s), `[min, max]`.
    pub eddy_viscosity_m2ps: [f64; 2],
}

impl TrainedRanges {
    /// The ranges spanned by `layouts` (none empty).
    fn of(layouts: &[Layout]) -> Self {
        let span = |f: &dyn Fn(&Layout) -> f64| {
            layouts
                .iter()
                .fold([f64::INFINITY, f64::NEG_INFINITY], |[lo, hi], l| {
                    let v = f(l);
                    [lo.min(v), hi.max(v)]
                })
        };
        Self {
            cell_m: layouts.first().map_or(0.0, Layout::cell),
            length_m: span(&|l| Frame::of(l).canonical_sides().0),
            across_m: span(&|l| Frame::of(l).canonical_sides().1),
            speed_mps: span(&Layout::wind_speed),
            diffusivity_m2ps: span(&Layout::diffusivity),
            eddy_viscosity_m2ps: span(&Layout::eddy_viscosity),
        }
    }

    /// Checks a layout against the ranges.
    ///
    /// # Errors
    /// [`Error::Model`] naming the quantity, its value and the trained range.
    pub fn check(&self, layout: &Layout) -> Result<()> {
        let (length, across) = Frame::of(layout).canonical_sides();
        if (layout.cell() - self.cell_m).abs() > 1e-9 {
            return Err(Error::Model(format!(
                "the layout's cell_m = {} m differs from the {} m cells the model was trained on",
                layout.cell(),
                self.cell_m
            )));
        }
        let quantities = [
            ("room length along the wind (m)", length, self.length_m),
            ("room width across the wind (m)", across, self.across_m),
            ("wind speed (m/s)", layout.wind_speed(), self.speed_mps),
            (
                "diffusivity_m2ps",
                layout.diffusivity(),
                self.diffusivity_m2ps,
            ),
            (
                "eddy_viscosity_m2ps",
                layout.eddy_viscosity(),
                self.eddy_viscosity_m2ps,
            ),
        ];
        for (name, value, [lo, hi]) in quantities {
            let tol = 1e-9 * hi.abs().max(1.0);
            if value < lo - tol || value > hi + tol {
                return Err(Error::Model(format!(
                    "the layout's {name} is {value}, outside the trained range [{lo}, {hi}]"
                )));
            }
        }
        Ok(())
    }
}

/// A dataset held in memory for training and evaluation, every layout in its canonical frame
/// ([`crate::frame`]: turned so that the wind comes from the west, as the network sees it).
#[derive(Debug, Clone)]
pub struct TrainingData {
    /// The manifests of the datasets, in order.
    pub manifests: Vec<Manifest>,
    /// SHA-256 of `manifest.json` for one dataset; of the datasets' digests, one per line, for
    /// several. Recorded with a trained model.
    pub digest: String,
    /// The layout indices of each dataset.
    parts: Vec<std::ops::Range<usize>>,
    /// The layouts (real frame), checked.
    layouts: Vec<Layout>,
    rooms: Vec<RoomPlanes>,
    /// Layout index of each sample.
    pub source_layout: Vec<usize>,
    /// Source position of each sample (m, canonical frame).
    pub source_xy: Vec<[f64; 2]>,
    /// Target concentrations, canonical `[H, W]` per sample.
    concentration: Vec<Array2<f32>>,
}

impl TrainingData {
    /// Loads several complete dataset directories as one (for example random rooms and the
    /// paper's arena); each keeps its own validation layouts ([`TrainingData::split_by_layout`]).
    ///
    /// # Errors
    /// As [`TrainingData::load`]; [`Error::Dataset`] for no directory or datasets of different
    /// cell sizes.
    pub fn load_all(dirs: &[&Path]) -> Result<Self> {
        let mut all: Option<Self> = None;
        for dir in dirs {
            let next = Self::load(dir)?;
            all = Some(match all {
                None => next,
                Some(mut data) => {
                    let cell = |d: &Self| d.layouts.first().map(Layout::cell);
                    if cell(&data) != cell(&next) {
                        return Err(Error::Dataset(format!(
                            "{} has other cells ({:?} m) than the datasets before it ({:?} m)",
                            dir.display(),
                            cell(&next),
                            cell(&data)
                        )));
                    }
                    let offset = data.layouts.len();
                    data.parts.push(offset..offset + next.layouts.len());
                    data.digest = format!("{}\n{}", data.digest, next.digest);
                    data.manifests.extend(next.manifests);
                    data.layouts.extend(next.layouts);
                    data.rooms.extend(next.rooms);
                    data.source_layout
                        .extend(next.source_layout.iter().map(|l| l + offset));
                    data.source_xy.extend(next.source_xy);
                    data.concentration.extend(next.concentration);
                    data
                }
            });
        }
        let mut data = all.ok_or_else(|| Error::Dataset("no dataset given".into()))?;
        if dirs.len() > 1 {
            data.digest = sha256_hex(data.digest.as_bytes());
        }
        Ok(data)
    }

    /// Loads a complete dataset directory.
    ///
    /// # Errors
    /// Any error of [`Manifest::load`]; [`Error::Dataset`] for a shard, an invalid layout,
    /// inconsistent indices or non-finite values.
    pub fn load(dir: &Path) -> Result<Self> {
        let manifest = Manifest::load(dir)?;
        let bad = |m: String| Error::Dataset(format!("{}: {m}", dir.display()));
        if manifest.shard.is_some() {
            return Err(bad(
                "this is one shard; merge the shards first (plumenet merge)".into(),
            ));
        }
        let text = io::read_to_string(&dir.join("manifest.json"))?;
        let digest = sha256_hex(text.as_bytes());
        let flat = |name: &str| io::read_npy::<f32, IxDyn>(&dir.join(format!("{name}.npy")));
        let masks = flat("obstacle_mask")?;
        let sdf = flat("signed_distance")?;
        let wind = flat("wind")?;
        let concentration = flat("concentration")?;
        let owner = io::read_npy::<u32, Ix1>(&dir.join("source_layout.npy"))?;
        let xy = io::read_npy::<f32, Ix2>(&dir.join("source_xy.npy"))?;
        for (name, array) in [
            ("concentration", &concentration),
            ("wind", &wind),
            ("signed_distance", &sdf),
            ("obstacle_mask", &masks),
        ] {
            if array.iter().any(|c| !c.is_finite()) {
                return Err(bad(format!("{name}.npy holds NaN or infinity")));
            }
        }
        if xy.dim() != (owner.len(), 2) {
            return Err(bad(format!(
                "source_xy.npy has shape {:?}, not [{}, 2] (one row per source in \
                 source_layout.npy)",
                xy.shape(),
                owner.len()
            )));
        }
        let (masks, sdf, wind, concentration) = (
            masks.as_slice().unwrap_or_default(),
            sdf.as_slice().unwrap_or_default(),
            wind.as_slice().unwrap_or_default(),
            concentration.as_slice().unwrap_or_default(),
        );
        let mut layouts = Vec::with_capacity(manifest.layouts.len());
        let mut rooms = Vec::with_capacity(manifest.layouts.len());
        let mut offset = 0;
        for (k, spec) in manifest.layouts.iter().enumerate() {
            let layout =
                LayoutSpec::check(spec.clone()).map_err(|e| bad(format!("layout {k}: {e}")))?;
            let (h, w) = grid_of(spec);
            let frame = Frame::of(&layout);
            let planes = |v: &[f32]| Array2::from_shape_vec((h, w), v.to_vec());
            let cells = offset..offset + h * w;
            let (Ok(mask), Ok(dist)) = (planes(&masks[cells.clone()]), planes(&sdf[cells])) else {
                return Err(bad(format!("layout {k}: arrays too short")));
            };
            let speed = layout.wind_speed();
            let (Ok(u), Ok(v)) = (
                planes(&wind[2 * offset..2 * offset + h * w]),
                planes(&wind[2 * offset + h * w..2 * offset + 2 * h * w]),
            ) else {
                return Err(bad(format!("layout {k}: wind too short")));
            };
            let canonical = frame.layout_to_canonical(&layout)?;
            let turned = |a: &Array2<f32>| frame.cells_to_canonical(a.view());
            let mut uc = Array2::zeros(frame.canonical_shape());
            let mut vc = Array2::zeros(frame.canonical_shape());
            for ((j, i), &uv) in u.indexed_iter() {
                let (a, b) = frame.vector_to_canonical(f64::from(uv), f64::from(v[[j, i]]));
                let jc = frame.cell_to_canonical(j, i);
                uc[jc] = (a / speed) as f32;
                vc[jc] = (b / speed) as f32;
            }
            rooms.push(RoomPlanes::with_planes(
                &canonical,
                turned(&mask),
                turned(&dist),
                Some([uc, vc]),
            ));
            layouts.push(layout);
            offset += h * w;
        }
        let mut samples = Vec::with_capacity(owner.len());
        let mut fields = Vec::with_capacity(owner.len());
        let mut at = 0;
        for (s, &k) in owner.iter().enumerate() {
            let l = k as usize;
            if l >= layouts.len() {
                return Err(bad(format!(
                    "source {s} names layout {k}, which is not listed"
                )));
            }
            let layout = &layouts[l];
            layout
                .check_source(f64::from(xy[[s, 0]]), f64::from(xy[[s, 1]]))
                .map_err(|e| bad(format!("source {s}: {e}")))?;
            let frame = Frame::of(layout);
            let (h, w) = layout.shape();
            let field = concentration
                .get(at..at + h * w)
                .and_then(|v| Array2::from_shape_vec((h, w), v.to_vec()).ok())
                .ok_or_else(|| bad("concentration.npy is too short for its sources".into()))?;
            at += h * w;
            fields.push(frame.cells_to_canonical(field.view()));
            let (x, y) = frame.to_canonical(f64::from(xy[[s, 0]]), f64::from(xy[[s, 1]]));
            samples.push((l, [x, y]));
        }
        Ok(Self {
            manifests: vec![manifest],
            digest,
            parts: std::iter::once(0..layouts.len()).collect(),
            layouts,
            rooms,
            source_layout: samples.iter().map(|s| s.0).collect(),
            source_xy: samples.iter().map(|s| s.1).collect(),
            concentration: fields,
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

    /// The layouts (real frame).
    pub fn layouts(&self) -> &[Layout] {
        &self.layouts
    }

    /// The canonical planes of layout `l`.
    pub fn room(&self, l: usize) -> &RoomPlanes {
        &self.rooms[l]
    }

    /// Target concentration of sample `s` (canonical frame).
    pub fn concentration(&self, s: usize) -> ArrayView2<'_, f32> {
        self.concentration[s].view()
    }

    /// The ranges of room physics in this dataset.
    pub fn ranges(&self) -> TrainedRanges {
        TrainedRanges::of(&self.layouts)
    }

    /// Splits samples by layout: of each dataset, the last `ceil(fraction * L)` layouts (at
    /// least one when it has two or more) are for validation, so validation measures unseen
    /// layouts.
    pub fn split_by_layout(&self, fraction: f64) -> (Vec<usize>, Vec<usize>) {
        let held_out: Vec<std::ops::Range<usize>> = self
            .parts
            .iter()
            .map(|part| {
                let layouts = part.len();
                let held = if layouts < 2 {
                    0
                } else {
                    ((fraction * layouts as f64).ceil() as usize).clamp(1, layouts - 1)
                };
                part.end - held..part.end
            })
            .collect();
        (0..self.len()).partition(|&s| !held_out.iter().any(|r| r.contains(&self.source_layout[s])))
    }

    /// `samples` grouped by their padded canonical grid (padding to multiples of `pad_cells`),
    /// in grid order, each group in the order given.
    pub fn buckets(&self, samples: &[usize], pad_cells: usize) -> Vec<Vec<usize>> {
        let mut groups: BTreeMap<(usize, usize), Vec<usize>> = BTreeMap::new();
        for &s in samples {
            let shape = padded_shape(self.rooms[self.source_layout[s]].shape(), pad_cells);
            groups.entry(shape).or_default().push(s);
        }
        groups.into_values().collect()
    }

    /// Input, target and weight tensors `[B, C, H, W]` for the given samples, padded to the
    /// largest padded grid among them; the weight is 1 in free cells of the room, 0 elsewhere.
    /// With `mirror`, the samples whose entry is true are mirrored across the wind
    /// ([`RoomPlanes::mirrored`], source and target alike).
    ///
    /// # Errors
    /// As [`RoomPlanes::encode`].
    #[allow(clippy::too_many_arguments)]
    pub fn batch(
        &self,
        samples: &[usize],
        mirror: Option<&[bool]>,
        inputs: InputSet,
        encoding: SourceEncoding,
        norm: &Normalization,
        pad_cells: usize,
        device: &Device,
    ) -> Result<(Tensor<4>, Tensor<4>, Tensor<4>)> {
        let (h, w) = samples
            .iter()
            .map(|&s| padded_shape(self.rooms[self.source_layout[s]].shape(), pad_cells))
            .fold((0, 0), |(a, b), (c, d)| (a.max(c), b.max(d)));
        let plane = h * w;
        let b = samples.len();
        let channels = inputs.channels();
        let mut input = vec![0.0f32; b * channels * plane];
        let mut target = vec![0.0f32; b * plane];
        let mut free = vec![0.0f32; b * plane];
        for (n, &s) in samples.iter().enumerate() {
            let mut room = &self.rooms[self.source_layout[s]];
            let mut source = self.source_xy[s];
            let mut concentration = self.concentration[s].view();
            let mirrored;
            if mirror.is_some_and(|m| m[n]) {
                source = room.mirrored_point(source);
                concentration.invert_axis(ndarray::Axis(0));
                mirrored = room.mirrored();
                room = &mirrored;
            }
            room.encode(
                source,
                inputs,
                encoding,
                norm,
                (h, w),
                &mut input[n * channels * plane..(n + 1) * channels * plane],
            )?;
            for (((j, i), &c), &m) in concentration.indexed_iter().zip(room.mask.iter()) {
                let k = n * plane + j * w + i;
                target[k] = norm.forward(c, room.speed_mps);
                free[k] = 1.0 - m;
            }
        }
        let t = |v: Vec<f32>, c: usize| {
            Tensor::<4>::from_data(TensorData::new(v, [b, c, h, w]), device)
        };
        Ok((t(input, channels), t(target, 1), t(free, 1)))
    }
}
