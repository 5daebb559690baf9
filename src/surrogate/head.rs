//! An operator network's per-source head ([`super::model::OperatorConfig`]) fused for
//! inference on the CPU.
//!
//! Training runs the head as Burn tensors ([`super::model::PlumeNet::source_fields`]); a bank
//! runs it here, where nothing of size "sources x cells x channels" is ever stored. For each
//! source and each tile of `TILE` cells of a row, the `J` bilinear planes `z_j`, the hidden
//! units and the output stay in registers: `J G` multiply-adds for `z`, `H (J + 3)` for the
//! hidden layer (the room planes' share of it, `W_r R + b`, is the same for every source and
//! computed once per room) and `H` for the output, about 450 per cell with the default sizes.
//! The per-source planes come from tables: the analytic prior depends only on the offset from
//! the source (uniform wind), so it is tabulated once per sub-cell position of the sources
//! (every candidate of a bank shares one) and each source reads a window of the table.
//!
//! Work is split over sources, each task writing its own outputs, so results do not depend on
//! the thread count; the instruction set is chosen at run time as for the convolutions.

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;

use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::conv::kernel::{Isa, load, store};
use super::data::{Normalization, RoomPlanes};
use super::model::{OFFSET_SCALE_M, PlumeNet};
use crate::error::{Error, Result};

/// The padded grid's width is a multiple of this (the widest vector: 16 lanes of AVX-512), so
/// that every row is whole vectors.
pub const TILE: usize = 16;

/// Hidden units computed together (each `z_j` is loaded once per block).
pub const UNITS: usize = 4;

/// Sources computed together in the fused head (they share every load of the room's terms and
/// the weights).
const PAIR: usize = 2;

/// Sources per parallel task (they share the rows of the trunk planes in cache).
const SOURCES_PER_TASK: usize = 8;

/// The head's weights, read from the network ([`super::model::SourceHead`]).
#[derive(Debug, Clone)]
pub struct HeadWeights {
    /// Groups `J`.
    pub groups: usize,
    /// Terms per group `G`.
    pub group_size: usize,
    /// Hidden units `H`, padded with units of zero weights to whole blocks of [`UNITS`].
    pub hidden: usize,
    /// `[J, H]` weights of the bilinear planes.
    pub w_z: Vec<f32>,
    /// `[H, 3]` weights of the per-source planes (prior, `tanh(dx / 2 m)`, `tanh(dy / 2 m)`).
    pub w_s: Vec<f32>,
    /// `[H]` output weights.
    pub w_out: Vec<f32>,
    /// Output bias.
    pub b_out: f32,
}

/// What a room gives every source, on the padded grid the network ran on widened to whole
/// tiles, `[H', W']` (`W'` a multiple of [`TILE`]): the normalised trunk planes (`K`) and the
/// hidden layer's room share `W_r R + b` (`H` planes), each packed tile by tile as
/// `[H', W' / TILE, planes, TILE]`, so that a tile's values of every plane lie together (planes
/// a power of two apart would all fall into one cache set).
#[derive(Debug, Clone)]
pub struct RoomTerms {
    /// Trunk planes, packed.
    pub trunk: Vec<f32>,
    /// Room share of the hidden layer, packed.
    pub room: Vec<f32>,
    /// The grid `[H', W']`.
    pub grid: [usize; 2],
}

impl RoomTerms {
    /// Cells of one plane.
    fn plane(&self) -> usize {
        self.grid[0] * self.grid[1]
    }
}

/// The per-source planes of sources at one sub-cell position, for a room of `h` rows and a
/// padded grid `W'` columns wide: for row offsets `dj = j - js` in `[-(h - 1), h - 1]` and
/// column offsets `di = i - is` in `[-(W' - 1), W' - 1]`, the transformed analytic prior
/// (row-major, `2 W' - 1` wide), `tanh(dx / 2 m)` by `di` and `tanh(dy / 2 m)` by `dj`.
#[derive(Debug, Clone)]
struct SourceTable {
    prior: Vec<f32>,
    dx: Vec<f32>,
    dy: Vec<f32>,
}

/// One source as the kernel reads it: its bilinear coefficients `a(s)` (`[K]`), its cell
/// `(js, is)` and its table.
struct Source<'a> {
    coefficients: &'a [f32],
    cell: (usize, usize),
    table: &'a SourceTable,
}

/// The per-source tables of a room's sources (one per sub-cell position,
/// keyed by the position's exact bits).
#[derive(Debug, Clone)]
pub struct SourceTables {
    tables: BTreeMap<(u64, u64), SourceTable>,
    /// Room cells `(h, w)`.
    shape: (usize, usize),
    cell_m: f64,
}

impl SourceTables {
    /// The tables of canonical `sources` in `room`, on the grid of `terms`.
    pub fn new(
        room: &RoomPlanes,
        terms: &RoomTerms,
        sources: &[[f64; 2]],
        norm: &Normalization,
    ) -> Self {
        Self::with_width(room, terms.grid[1], sources, norm)
    }

    /// The tables of canonical `sources` in `room`, for a padded grid `width` columns wide.
    pub fn with_width(
        room: &RoomPlanes,
        width: usize,
        sources: &[[f64; 2]],
        norm: &Normalization,
    ) -> Self {
        let mut out = Self {
            tables: BTreeMap::new(),
            shape: room.shape(),
            cell_m: room.cell_m,
        };
        let size = (out.shape.0, width);
        for &source in sources {
            let (_, key, fraction) = out.place(source);
            if let Entry::Vacant(slot) = out.tables.entry(key) {
                slot.insert(table(room, size, fraction, norm));
            }
        }
        out
    }

    /// The per-source planes of canonical `source` (one of the tables' sources) along room row
    /// `j`, as [`RoomPlanes::encode_source`] gives them (the same values up to round-off of the
    /// offsets) for the room's `w` columns: the transformed prior (not yet masked by
    /// obstacles), `tanh(dx / 2 m)` and the row's `tanh(dy / 2 m)`.
    ///
    /// # Panics
    /// When `source` has no table or `j` is not a room row.
    pub fn row(&self, source: [f64; 2], j: usize) -> (&[f32], &[f32], f32) {
        let (h, w) = self.shape;
        assert!(j < h, "a room row");
        let ((js, is), key, _) = self.place(source);
        let table = &self.tables[&key];
        let tw = table.dx.len();
        let first = tw.div_ceil(2) - 1 - is;
        let r = j + h - 1 - js;
        (
            &table.prior[r * tw + first..r * tw + first + w],
            &table.dx[first..first + w],
            table.dy[r],
        )
    }

    /// Room cells `(h, w)`.
    pub fn shape(&self) -> (usize, usize) {
        self.shape
    }

    /// A canonical source's cell `(js, is)`, the key of its sub-cell position and the position
    /// `(fx, fy)` in fractions of a cell.
    fn place(&self, [sx, sy]: [f64; 2]) -> ((usize, usize), (u64, u64), (f64, f64)) {
        let (h, w) = self.shape;
        let (u, v) = (sx / self.cell_m, sy / self.cell_m);
        let (is, js) = (
            u.floor().clamp(0.0, (w - 1) as f64),
            v.floor().clamp(0.0, (h - 1) as f64),
        );
        let (fx, fy) = (u - is, v - js);
        (
            (js as usize, is as usize),
            (fx.to_bits(), fy.to_bits()),
            (fx, fy),
        )
    }
}

/// The transformed concentration `[n, H', W']` of `n` canonical `sources` on the grid of
/// `terms` (computed in the room's `h` rows, every column; the cells past the room's are to
/// be ignored), given the room's terms and tables, each source's coefficients `a(s)`
/// (`[n, K]`) and the head's weights.
///
/// # Panics
/// When `terms.grid[1]` is not a multiple of [`TILE`], `coefficients` is not `[n, K]` or a
/// source has no table.
pub fn source_fields(
    terms: &RoomTerms,
    tables: &SourceTables,
    sources: &[[f64; 2]],
    coefficients: &[f32],
    weights: &HeadWeights,
) -> Vec<f32> {
    let (h, w) = tables.shape;
    let [hp, wp] = terms.grid;
    assert!(
        wp % TILE == 0 && wp >= w && hp >= h,
        "a padded grid of whole tiles"
    );
    let k = weights.groups * weights.group_size;
    assert_eq!(
        coefficients.len(),
        sources.len() * k,
        "K coefficients per source"
    );
    assert!(
        terms.trunk.len() == k * terms.plane()
            && terms.room.len() == weights.hidden * terms.plane(),
        "room terms of this head"
    );
    let plane = terms.plane();
    let mut out = vec![0.0f32; sources.len() * plane];
    out.par_chunks_mut(SOURCES_PER_TASK * plane)
        .enumerate()
        .for_each(|(t, block)| {
            let first = t * SOURCES_PER_TASK;
            let batch: Vec<Source> = (first..first + block.len() / plane)
                .map(|n| {
                    let (cell, key, _) = tables.place(sources[n]);
                    Source {
                        coefficients: &coefficients[n * k..(n + 1) * k],
                        cell,
                        table: &tables.tables[&key],
                    }
                })
                .collect();
            Isa::best().run(Task {
                rows: h,
                terms,
                weights,
                sources: &batch,
                out: block,
            });
        });
    out
}

/// The table of sources at sub-cell position `(fx, fy)` (fractions of a cell) in `room`, for
/// `h` rows and `w` columns of the padded grid.
fn table(
    room: &RoomPlanes,
    (h, w): (usize, usize),
    (fx, fy): (f64, f64),
    norm: &Normalization,
) -> SourceTable {
    let cell = room.cell_m;
    let offset = |d: isize, f: f64| (d as f64 + 0.5 - f) * cell;
    let (tw, th) = (2 * w - 1, 2 * h - 1);
    let mut prior = vec![0.0f32; tw * th];
    prior.par_chunks_mut(tw).enumerate().for_each(|(r, row)| {
        let dy = offset(r as isize - (h as isize - 1), fy);
        for (c, slot) in row.iter_mut().enumerate() {
            let dx = offset(c as isize - (w as isize - 1), fx);
            *slot = norm.forward(room.unbounded_prior(dx, dy) as f32, room.speed_mps);
        }
    });
    let tanh = |d: f64| (d / OFFSET_SCALE_M).tanh() as f32;
    SourceTable {
        prior,
        dx: (0..tw)
            .map(|c| tanh(offset(c as isize - (w as isize - 1), fx)))
            .collect(),
        dy: (0..th)
            .map(|r| tanh(offset(r as isize - (h as isize - 1), fy)))
            .collect(),
    }
}

/// The `S::F32_LANES` values of `v` from `at` on, as a vector (a function, not a closure, so
/// that it is inlined into the instruction set's code).
///
/// # Panics
/// When they are not all in `v`.
#[inline(always)]
fn vector_at<S: Simd>(v: &[f32], at: usize) -> S::f32s {
    let part = &v[at..at + S::F32_LANES];
    // SAFETY: `part` holds `S::F32_LANES` readable values.
    unsafe { load::<S>(part.as_ptr()) }
}

/// A block of sources: every row, every tile.
struct Task<'a> {
    rows: usize,
    terms: &'a RoomTerms,
    weights: &'a HeadWeights,
    sources: &'a [Source<'a>],
    out: &'a mut [f32],
}

impl WithSimd for Task<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        // The default sizes compiled with their loop bounds known, others as they come.
        match (self.weights.groups, self.weights.group_size) {
            (16, 8) => self.run(simd, Fixed::<16, 8>),
            (j, g) => self.run(simd, Sizes(j, g)),
        }
    }
}

/// The bilinear form's sizes `(J, G)`, known at compile time or not.
trait Dims: Copy {
    /// Groups `J`.
    fn groups(self) -> usize;
    /// Terms per group `G`.
    fn group_size(self) -> usize;
}

/// Sizes known at compile time.
#[derive(Clone, Copy)]
struct Fixed<const J: usize, const G: usize>;

impl<const J: usize, const G: usize> Dims for Fixed<J, G> {
    #[inline(always)]
    fn groups(self) -> usize {
        J
    }
    #[inline(always)]
    fn group_size(self) -> usize {
        G
    }
}

/// Sizes known at run time.
#[derive(Clone, Copy)]
struct Sizes(usize, usize);

impl Dims for Sizes {
    #[inline(always)]
    fn groups(self) -> usize {
        self.0
    }
    #[inline(always)]
    fn group_size(self) -> usize {
        self.1
    }
}

impl Task<'_> {
    #[inline(always)]
    fn run<S: Simd, D: Dims>(self, simd: S, dims: D) {
        let Task {
            rows,
            terms,
            weights,
            sources,
            out,
        } = self;
        let [_, w] = terms.grid;
        let plane = terms.plane();
        let lanes = S::F32_LANES;
        let (j_groups, g_size, hidden) = (dims.groups(), dims.group_size(), weights.hidden);
        let tw = 2 * w - 1;
        // A vector of `lanes` values of `v` from `at` on.
        let zero = simd.splat_f32s(0.0);
        let mut z = vec![zero; j_groups * PAIR];
        let k = j_groups * g_size;
        let tiles = w / TILE;
        for row in 0..rows {
            for (t, sub) in (0..tiles).flat_map(|t| (0..TILE / lanes).map(move |v| (t, v))) {
                let col = t * TILE + sub * lanes;
                let at = row * w + col;
                let block = row * tiles + t;
                let trunk = (block * k) * TILE + sub * lanes;
                let room = (block * hidden) * TILE + sub * lanes;
                // Sources in pairs: each trunk vector and weight is loaded once for both (an
                // odd last source is computed twice and stored once).
                for (p, pair) in sources.chunks(PAIR).enumerate() {
                    let both = |k: usize| &pair[k.min(pair.len() - 1)];
                    let mut prior = [zero; PAIR];
                    let mut dx = [zero; PAIR];
                    let mut dy = [zero; PAIR];
                    for q in 0..PAIR {
                        let source = both(q);
                        let (js, is) = source.cell;
                        let table = source.table;
                        let trow = row + rows - 1 - js;
                        let first = col + w - 1 - is;
                        prior[q] = vector_at::<S>(&table.prior, trow * tw + first);
                        dx[q] = vector_at::<S>(&table.dx, first);
                        dy[q] = simd.splat_f32s(table.dy[trow]);
                    }
                    // z_j = sum_g a_jg T_jg over the tile.
                    for j in 0..j_groups {
                        let mut acc = [zero; PAIR];
                        for g in 0..g_size {
                            let kk = j * g_size + g;
                            let t = vector_at::<S>(&terms.trunk, trunk + kk * TILE);
                            for (q, a) in acc.iter_mut().enumerate() {
                                let c = both(q).coefficients[kk];
                                *a = simd.mul_add_f32s(simd.splat_f32s(c), t, *a);
                            }
                        }
                        for (q, a) in acc.into_iter().enumerate() {
                            z[j * PAIR + q] = a;
                        }
                    }
                    // Hidden units in blocks of UNITS, so that each z_j is read once a block.
                    let mut y = [simd.splat_f32s(weights.b_out); PAIR];
                    for u0 in (0..hidden).step_by(UNITS) {
                        // acc[d][q]: hidden unit u0 + d of source q.
                        let mut acc = [[zero; PAIR]; UNITS];
                        for (d, unit) in acc.iter_mut().enumerate() {
                            let u = u0 + d;
                            let ws = &weights.w_s[3 * u..3 * u + 3];
                            let base = vector_at::<S>(&terms.room, room + u * TILE);
                            let (w0, w1, w2) = (
                                simd.splat_f32s(ws[0]),
                                simd.splat_f32s(ws[1]),
                                simd.splat_f32s(ws[2]),
                            );
                            for (q, a) in unit.iter_mut().enumerate() {
                                *a = simd.mul_add_f32s(w0, prior[q], base);
                                *a = simd.mul_add_f32s(w1, dx[q], *a);
                                *a = simd.mul_add_f32s(w2, dy[q], *a);
                            }
                        }
                        for j in 0..j_groups {
                            let wz = &weights.w_z[j * hidden + u0..j * hidden + u0 + UNITS];
                            let zj = &z[j * PAIR..(j + 1) * PAIR];
                            for (unit, &wgt) in acc.iter_mut().zip(wz) {
                                let wgt = simd.splat_f32s(wgt);
                                for (a, &zq) in unit.iter_mut().zip(zj) {
                                    *a = simd.mul_add_f32s(wgt, zq, *a);
                                }
                            }
                        }
                        for (unit, &wo) in acc.iter().zip(&weights.w_out[u0..u0 + UNITS]) {
                            let wo = simd.splat_f32s(wo);
                            for (yq, &a) in y.iter_mut().zip(unit) {
                                *yq = simd.mul_add_f32s(wo, simd.max_f32s(a, zero), *yq);
                            }
                        }
                    }
                    for q in 0..pair.len() {
                        let n = p * PAIR + q;
                        let dst = &mut out[n * plane + at..n * plane + at + lanes];
                        // SAFETY: `dst` holds `lanes` writable values.
                        unsafe { store::<S>(dst.as_mut_ptr(), simd.add_f32s(y[q], prior[q])) };
                    }
                }
            }
        }
    }
}

/// An operator network's head read out of its Burn module for [`source_fields`], with the
/// weights that make the room terms.
#[derive(Debug, Clone)]
pub struct FusedHead {
    /// The per-source weights.
    pub weights: HeadWeights,
    /// `[H, E]` weights of the room planes.
    w_room: Vec<f32>,
    /// `[H]` hidden biases.
    b_hidden: Vec<f32>,
}

/// A parameter's values.
fn values<const D: usize>(tensor: burn::prelude::Tensor<D>) -> Result<Vec<f32>> {
    tensor
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| Error::Model(format!("cannot read a weight tensor: {e:?}")))
}

impl FusedHead {
    /// The head of `net`.
    ///
    /// # Errors
    /// [`Error::Model`] when `net` is not an operator network or a weight cannot be read.
    pub fn of(net: &PlumeNet) -> Result<Self> {
        let op = net
            .operator
            .as_ref()
            .ok_or_else(|| Error::Model("not an operator network".into()))?;
        let [hidden, inputs, _, _] = op.mix.weight.dims();
        let (groups, group_size) = (op.groups, op.group_size);
        let room_planes = inputs - groups - super::model::SOURCE_PLANES;
        let mix = values(op.mix.weight.val())?;
        let column = |u: usize, c: std::ops::Range<usize>| mix[u * inputs..][c].to_vec();
        let bias = |conv: &burn::nn::conv::Conv2d, n: usize| -> Result<Vec<f32>> {
            match &conv.bias {
                Some(b) => values(b.val()),
                None => Ok(vec![0.0; n]),
            }
        };
        // Hidden units padded to whole blocks with units of zero weights (they add nothing).
        let padded = hidden.div_ceil(UNITS) * UNITS;
        let unit = |u: usize, c: std::ops::Range<usize>| {
            if u < hidden {
                column(u, c)
            } else {
                vec![0.0; c.len()]
            }
        };
        let pad = |mut v: Vec<f32>| {
            v.resize(padded, 0.0);
            v
        };
        Ok(Self {
            weights: HeadWeights {
                groups,
                group_size,
                hidden: padded,
                w_z: (0..groups)
                    .flat_map(|j| (0..padded).map(move |u| (u, j)))
                    .map(|(u, j)| if u < hidden { mix[u * inputs + j] } else { 0.0 })
                    .collect(),
                w_s: (0..padded)
                    .flat_map(|u| unit(u, groups + room_planes..inputs))
                    .collect(),
                w_out: pad(values(op.out.weight.val())?),
                b_out: bias(&op.out, 1)?[0],
            },
            w_room: (0..padded)
                .flat_map(|u| unit(u, groups..groups + room_planes))
                .collect(),
            b_hidden: pad(bias(&op.mix, hidden)?),
        })
    }

    /// Bilinear terms `K`.
    fn terms(&self) -> usize {
        self.weights.groups * self.weights.group_size
    }

    /// The room terms of one room's planes `[2 K + E, H', W']` ([`PlumeNet::room_planes`]),
    /// on the grid widened with zeros to whole tiles ([`TILE`]), packed tile by tile.
    pub fn room_terms(&self, planes: &[f32], [hp, wp]: [usize; 2]) -> RoomTerms {
        let ws = wp.div_ceil(TILE) * TILE;
        let tiles = ws / TILE;
        let plane = hp * wp;
        let k = self.terms();
        let hidden = self.weights.hidden;
        let e = self.w_room.len() / hidden;
        // Plane `c` of `planes` at `(row, col)`, zero past the padded grid.
        let value = |c: usize, row: usize, col: usize| {
            if col < wp {
                planes[c * plane + row * wp + col]
            } else {
                0.0
            }
        };
        let pack = |channels: usize, f: &(dyn Fn(usize, usize, usize) -> f32 + Sync)| {
            let mut out = vec![0.0f32; hp * tiles * channels * TILE];
            out.par_chunks_mut(channels * TILE)
                .enumerate()
                .for_each(|(block, values)| {
                    let (row, first) = (block / tiles, (block % tiles) * TILE);
                    for (c, lane_values) in values.chunks_mut(TILE).enumerate() {
                        for (l, v) in lane_values.iter_mut().enumerate() {
                            *v = f(c, row, first + l);
                        }
                    }
                });
            out
        };
        RoomTerms {
            trunk: pack(k, &|c, row, col| value(c, row, col)),
            room: pack(hidden, &|u, row, col| {
                (0..e).fold(self.b_hidden[u], |acc, c| {
                    acc + self.w_room[u * e + c] * value(2 * k + c, row, col)
                })
            }),
            grid: [hp, ws],
        }
    }

    /// The coefficients `a(s)` (`[n, K]`) of canonical `sources` in `room`: its branch planes
    /// in `planes` read bilinearly at each source ([`RoomPlanes::taps`]).
    pub fn coefficients(
        &self,
        room: &RoomPlanes,
        planes: &[f32],
        grid: [usize; 2],
        sources: &[[f64; 2]],
    ) -> Vec<f32> {
        let plane = grid[0] * grid[1];
        let k = self.terms();
        let branch = &planes[k * plane..2 * k * plane];
        sources
            .iter()
            .flat_map(|&source| {
                let taps = room.taps(source, 0, (grid[0], grid[1]));
                (0..k).map(move |kk| {
                    taps.iter()
                        .map(|&(cell, weight)| weight * branch[kk * plane + cell as usize])
                        .sum::<f32>()
                })
            })
            .collect()
    }
}
