//! Reading a plume bank at arbitrary points: the estimated concentration of every candidate at
//! a sample position.
//!
//! The bank `[N, ny, nx]` is transposed once into `[ny * nx, N]`, so the `N` values of one cell
//! are contiguous and a sample position costs four contiguous rows (bilinear interpolation
//! between the four nearest cell centres; solid cells are left out and the weights of the others
//! renormalised, so values next to an obstacle are not dragged towards its zero).

use std::sync::{Arc, Mutex};

use ndarray::{Array3, Axis};

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::plume::PlumeBank;

/// A plume bank laid out for gathering by position.
#[derive(Debug, Clone)]
pub struct FieldSampler {
    layout: Layout,
    candidates: Vec<[f64; 2]>,
    by_cell: Vec<f32>,
    /// The turned copies made so far (angle in degrees, copy), shared by clones: see
    /// [`FieldSampler::turned`].
    turned: Arc<Mutex<Vec<Turned>>>,
}

/// A turned copy of a sampler: the angle (degrees) and the copy.
type Turned = (f64, Arc<FieldSampler>);

impl FieldSampler {
    /// Transposes a bank made for `layout`.
    ///
    /// # Errors
    /// [`Error::Parameter`] when the bank's grid is not the layout's, it is empty, or it holds
    /// a non-finite or negative value.
    pub fn new(layout: &Layout, bank: &PlumeBank) -> Result<Self> {
        let (n, ny, nx) = bank.fields.dim();
        if (ny, nx) != layout.shape() || n == 0 || n != bank.candidates.len() {
            return Err(Error::Parameter(format!(
                "bank of shape {:?} with {} candidates does not fit the layout grid {:?}",
                bank.fields.dim(),
                bank.candidates.len(),
                layout.shape()
            )));
        }
        if bank.fields.iter().any(|v| !v.is_finite() || *v < 0.0) {
            return Err(Error::Parameter(
                "bank holds a non-finite or negative concentration".into(),
            ));
        }
        let mut by_cell = vec![0.0f32; n * ny * nx];
        for (k, field) in bank.fields.axis_iter(Axis(0)).enumerate() {
            for (cell, &v) in field.iter().enumerate() {
                by_cell[cell * n + k] = v;
            }
        }
        Ok(Self {
            layout: layout.clone(),
            candidates: bank.candidates.clone(),
            by_cell,
            turned: Arc::default(),
        })
    }

    /// This bank under a wind turned by `angle_deg` ([`PlumeBank::turned`]), made once per
    /// angle and kept, so that every estimator over this sampler shares it; 0 is the sampler
    /// itself.
    ///
    /// # Errors
    /// [`Error::Parameter`] for an angle that is not within 90 degrees either way.
    pub fn turned(self: &Arc<Self>, angle_deg: f64) -> Result<Arc<Self>> {
        if angle_deg == 0.0 {
            return Ok(Arc::clone(self));
        }
        // Held while a copy is made, so that concurrent callers make it once.
        let mut made = self.turned.lock().unwrap_or_else(|e| e.into_inner());
        if let Some((_, copy)) = made.iter().find(|(a, _)| *a == angle_deg) {
            return Ok(Arc::clone(copy));
        }
        let copy = Arc::new(Self::new(
            &self.layout,
            &self.bank().turned(&self.layout, angle_deg)?,
        )?);
        made.push((angle_deg, Arc::clone(&copy)));
        Ok(copy)
    }

    /// The layout.
    pub fn layout(&self) -> &Layout {
        &self.layout
    }

    /// Candidate source positions (m).
    pub fn candidates(&self) -> &[[f64; 2]] {
        &self.candidates
    }

    /// Number of candidates.
    pub fn len(&self) -> usize {
        self.candidates.len()
    }

    /// Whether there is no candidate (never true for a constructed sampler).
    pub fn is_empty(&self) -> bool {
        self.candidates.is_empty()
    }

    /// The bank this sampler was made from.
    pub fn bank(&self) -> PlumeBank {
        let (ny, nx) = self.layout.shape();
        let n = self.len();
        let fields =
            Array3::from_shape_fn((n, ny, nx), |(k, j, i)| self.by_cell[(j * nx + i) * n + k]);
        PlumeBank {
            candidates: self.candidates.clone(),
            fields,
        }
    }

    /// Interpolation stencil of a point: up to four (cell, weight) pairs, weights summing to 1.
    fn stencil(&self, x: f64, y: f64) -> Vec<(usize, f32)> {
        let (ny, nx) = self.layout.shape();
        let h = self.layout.cell();
        let fx = (x / h - 0.5).clamp(0.0, (nx - 1) as f64);
        let fy = (y / h - 0.5).clamp(0.0, (ny - 1) as f64);
        let (i0, j0) = (fx.floor() as usize, fy.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(nx - 1), (j0 + 1).min(ny - 1));
        let (tx, ty) = (fx - i0 as f64, fy - j0 as f64);
        let corners = [
            (j0, i0, (1.0 - tx) * (1.0 - ty)),
            (j0, i1, tx * (1.0 - ty)),
            (j1, i0, (1.0 - tx) * ty),
            (j1, i1, tx * ty),
        ];
        let free: Vec<(usize, f64)> = corners
            .iter()
            .filter(|(j, i, w)| *w > 0.0 && !self.layout.is_solid(*j, *i))
            .map(|&(j, i, w)| (j * nx + i, w))
            .collect();
        let total: f64 = free.iter().map(|p| p.1).sum();
        if total <= 0.0 {
            // Inside an obstacle: concentration zero (any free cell's row times zero weight).
            return Vec::new();
        }
        free.into_iter()
            .map(|(c, w)| (c, (w / total) as f32))
            .collect()
    }

    /// Every candidate's concentration at `(x, y)`, scaled by `scale`, written into `out`
    /// (length `N`).
    pub fn gather(&self, x: f64, y: f64, scale: f32, out: &mut [f32]) {
        let n = self.len();
        out.fill(0.0);
        for (cell, w) in self.stencil(x, y) {
            let row = &self.by_cell[cell * n..(cell + 1) * n];
            let w = w * scale;
            for (o, &v) in out.iter_mut().zip(row) {
                *o += w * v;
            }
        }
    }

    /// The concentration of candidate `k` at `(x, y)`.
    pub fn value(&self, k: usize, x: f64, y: f64) -> f32 {
        let n = self.len();
        self.stencil(x, y)
            .into_iter()
            .map(|(cell, w)| w * self.by_cell[cell * n + k])
            .sum()
    }
}
