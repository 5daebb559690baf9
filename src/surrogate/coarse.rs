//! The coarse form of an operator network ([`super::model::CoarseConfig`]) on the CPU: the
//! anchors of sources and their planes pooled to the network's level (for training from planes
//! encoded cell by cell, for banks straight from the sources' tables), and for banks the
//! network's correction upsampled and added to each source's prior, so that no source's
//! full-resolution planes are ever stored (training's Burn pass,
//! [`super::model::CoarseNet::fields`], builds them; the tests hold the two together).

use ndarray::{Array2, ArrayView2};

use super::data::RoomPlanes;
use super::head::SourceTables;
use super::model::{COARSE_OFFSET_CELLS, COARSE_SOURCE_PLANES};

/// One output row's or column's bilinear taps: the two input indices and the second's weight.
pub type Tap = (usize, usize, f32);

/// The taps of upsampling `n_in` values to `n_out` with half-pixel centres and the edges
/// clamped, as Burn's bilinear `interpolate` without aligned corners computes them.
pub fn upsampling_taps(n_in: usize, n_out: usize) -> Vec<Tap> {
    let ratio = n_in as f64 / n_out as f64;
    (0..n_out)
        .map(|o| {
            let at = (o as f64 + 0.5) * ratio - 0.5;
            let low = at.max(0.0).floor() as usize;
            (
                low,
                (low + 1).min(n_in - 1),
                (at - low as f64).max(0.0) as f32,
            )
        })
        .collect()
}

/// The anchor of canonical `source` (m) for a network pooling by `k`: the centre of the
/// `k x k` block of cells that holds it. Every source of one block shares its correction.
pub fn anchor(source: [f64; 2], cell_m: f64, k: usize) -> [f64; 2] {
    let (row, column) = block(source, cell_m, k);
    [column, row].map(|n| (n as f64 + 0.5) * k as f64 * cell_m)
}

/// The block of cells ([`anchor`]) that holds canonical `source`, `(row, column)`.
pub fn block(source: [f64; 2], cell_m: f64, k: usize) -> (i64, i64) {
    let block = k as f64 * cell_m;
    let [x, y] = source.map(|v| (v / block).floor() as i64);
    (y, x)
}

/// Writes the per-source planes of an anchor in `room` ([`anchor`]), pooled by `k` on the
/// padded grid `(H', W')`, into `out`, a zeroed buffer of [`COARSE_SOURCE_PLANES`] planes of
/// `(H' / k, W' / k)`: the means over each `k x k` block of the prior (zero in obstacles),
/// `tanh(dx / 2 m)` and `tanh(dy / 2 m)` (zero outside the room), the prior's maximum, and the
/// offsets of the block centres from the anchor along and across the wind in
/// [`COARSE_OFFSET_CELLS`]. `rows(j)` gives the anchor's planes along room row `j` as
/// [`SourceTables::row`] does (the prior need not be masked).
pub fn pooled_planes<'a>(
    rows: impl Fn(usize) -> (&'a [f32], &'a [f32], f32),
    room: &RoomPlanes,
    anchor: [f64; 2],
    ((hp, wp), k): ((usize, usize), usize),
    out: &mut [f32],
) {
    let h = room.shape().0;
    let (hs, ws) = (hp / k, wp / k);
    let plane = hs * ws;
    assert_eq!(
        out.len(),
        COARSE_SOURCE_PLANES * plane,
        "pooled planes of this grid"
    );
    let (means, rest) = out.split_at_mut(3 * plane);
    let (peaks, offsets) = rest.split_at_mut(plane);
    for j in 0..h {
        let (prior, dx, dy) = rows(j);
        let base = (j / k) * ws;
        for (i, ((&p, &d), &m)) in prior.iter().zip(dx).zip(room.mask.row(j)).enumerate() {
            let b = base + i / k;
            let p = if m == 0.0 { p } else { 0.0 };
            means[b] += p;
            means[plane + b] += d;
            means[2 * plane + b] += dy;
            peaks[b] = peaks[b].max(p);
        }
    }
    let area = (k * k) as f32;
    means.iter_mut().for_each(|v| *v /= area);
    let [sx, sy] = anchor.map(|v| (v / room.cell_m) as f32);
    let centre = |n: usize| (n * k) as f32 + k as f32 / 2.0;
    let (along, across) = offsets.split_at_mut(plane);
    for (jc, (row_along, row_across)) in along
        .chunks_exact_mut(ws)
        .zip(across.chunks_exact_mut(ws))
        .enumerate()
    {
        let dy = (centre(jc) - sy) / COARSE_OFFSET_CELLS;
        for (ic, (a, c)) in row_along.iter_mut().zip(row_across.iter_mut()).enumerate() {
            *a = (centre(ic) - sx) / COARSE_OFFSET_CELLS;
            *c = dy;
        }
    }
}

/// Writes the transformed concentration of canonical `source` in `room` on the room's cells of
/// `field`, a plane of the padded grid `W'` columns wide: the prior (zero in obstacles) plus
/// `correction` (`[H' / k, W' / k]`) upsampled with the row and column taps
/// ([`upsampling_taps`]), first between two rows, then along the row (the same bilinear
/// weights as Burn's, in another order of the operations).
pub fn fine_field(
    tables: &SourceTables,
    room: &RoomPlanes,
    source: [f64; 2],
    (correction, ws): (&[f32], usize),
    (rows, cols): (&[Tap], &[Tap]),
    field: &mut [f32],
) {
    let (h, w) = tables.shape();
    let wp = field.len() / rows.len();
    // Each row interpolates between two rows of the correction, then along the row.
    let mut between = vec![0.0f32; ws];
    for (j, &(r0, r1, fy)) in rows.iter().enumerate().take(h) {
        let (prior, _, _) = tables.row(source, j);
        let (low, high) = (&correction[r0 * ws..], &correction[r1 * ws..]);
        for ((slot, &a), &b) in between.iter_mut().zip(low).zip(high) {
            *slot = a + (b - a) * fy;
        }
        let out = &mut field[j * wp..j * wp + w];
        for (((slot, &p), &m), &(c0, c1, fx)) in
            out.iter_mut().zip(prior).zip(room.mask.row(j)).zip(cols)
        {
            let (a, b) = (between[c0], between[c1]);
            *slot = if m == 0.0 { p } else { 0.0 } + a + (b - a) * fx;
        }
    }
}

/// `coarse` (`[h, w]` values, row-major) upsampled bilinearly ([`upsampling_taps`]) to the
/// `rows x cols` taps' grid.
fn upsample(coarse: &[f64], w: usize, (rows, cols): (&[Tap], &[Tap])) -> Vec<f64> {
    let mut fine = Vec::with_capacity(rows.len() * cols.len());
    for &(r0, r1, fy) in rows {
        let fy = f64::from(fy);
        for &(c0, c1, fx) in cols {
            let fx = f64::from(fx);
            let at = |r: usize, c: usize| coarse[r * w + c];
            let low = at(r0, c0) + (at(r0, c1) - at(r0, c0)) * fx;
            let high = at(r1, c0) + (at(r1, c1) - at(r1, c0)) * fx;
            fine.push(low + (high - low) * fy);
        }
    }
    fine
}

/// The transpose of [`upsample`]: each fine value spread back onto its four coarse taps.
fn upsample_transposed(
    fine: &[f64],
    (h, w): (usize, usize),
    (rows, cols): (&[Tap], &[Tap]),
) -> Vec<f64> {
    let mut coarse = vec![0.0; h * w];
    for (&(r0, r1, fy), row) in rows.iter().zip(fine.chunks_exact(cols.len())) {
        let fy = f64::from(fy);
        for (&(c0, c1, fx), &v) in cols.iter().zip(row) {
            let fx = f64::from(fx);
            coarse[r0 * w + c0] += (1.0 - fy) * (1.0 - fx) * v;
            coarse[r0 * w + c1] += (1.0 - fy) * fx * v;
            coarse[r1 * w + c0] += fy * (1.0 - fx) * v;
            coarse[r1 * w + c1] += fy * fx * v;
        }
    }
    coarse
}

/// The best correction a coarse form pooling by `k` can give: the field on
/// `(⌈H / k⌉, ⌈W / k⌉)` coarse cells whose bilinear upsampling ([`upsampling_taps`], as the
/// coarse form's) fits `target` (`[H, W]`) with the least squared error over the cells where
/// `free` holds, returned upsampled to `[H, W]`. Solved by conjugate gradients on the normal
/// equations, to a residual of `1e-9` of the right-hand side's norm. A correction a trained
/// network could give is no closer, so this bounds the coarse form's accuracy.
pub fn best_correction(target: ArrayView2<f32>, free: ArrayView2<bool>, k: usize) -> Array2<f32> {
    let (h, w) = target.dim();
    let (hc, wc) = (h.div_ceil(k), w.div_ceil(k));
    let (rows, cols) = (
        upsampling_taps(hc, hc * k)[..h].to_vec(),
        upsampling_taps(wc, wc * k)[..w].to_vec(),
    );
    let taps = (rows.as_slice(), cols.as_slice());
    let mask: Vec<f64> = free.iter().map(|&f| f64::from(u8::from(f))).collect();
    // The normal operator A^T M A of the upsampling A restricted to the free cells M.
    let normal = |g: &[f64]| {
        let masked: Vec<f64> = upsample(g, wc, taps)
            .iter()
            .zip(&mask)
            .map(|(v, m)| v * m)
            .collect();
        upsample_transposed(&masked, (hc, wc), taps)
    };
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let masked_target: Vec<f64> = target
        .iter()
        .zip(&mask)
        .map(|(&t, m)| f64::from(t) * m)
        .collect();
    let rhs = upsample_transposed(&masked_target, (hc, wc), taps);
    let mut g = vec![0.0; hc * wc];
    let mut r = rhs.clone();
    let mut p = r.clone();
    let mut rr = dot(&r, &r);
    let stop = 1e-18 * rr;
    for _ in 0..hc * wc {
        if rr <= stop {
            break;
        }
        let q = normal(&p);
        let alpha = rr / dot(&p, &q);
        g.iter_mut().zip(&p).for_each(|(g, p)| *g += alpha * p);
        r.iter_mut().zip(&q).for_each(|(r, q)| *r -= alpha * q);
        let next = dot(&r, &r);
        let beta = next / rr;
        p.iter_mut().zip(&r).for_each(|(p, r)| *p = r + beta * *p);
        rr = next;
    }
    Array2::from_shape_vec(
        (h, w),
        upsample(&g, wc, taps).iter().map(|&v| v as f32).collect(),
    )
    .expect("the upsampled grid is the target's")
}
