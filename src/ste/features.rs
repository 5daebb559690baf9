//! The four gas features of the paper, extracted incrementally from a time-ordered sequence.
//!
//! A [`FeatureTrack`] takes one sequence (the measured readings `d_1..d_n`, or one candidate's
//! estimated concentrations `c_1..c_n` at the same sample positions) and keeps its feature
//! values (and, for rank, the values themselves as a sorted list):
//!
//! - **value**: `m_i = d_i`;
//! - **fixed hit**: `m_i = 1` if `d_i > threshold`, else 0 (one documented threshold, in the
//!   reading's unit, for both sides; see [`FeatureParams::fixed_threshold`]);
//! - **adaptive hit**: the moving-window threshold `t_1 = d_1`,
//!   `t_i = lambda t_(i-1) + (1 - lambda) d_i`; a hit is a rising edge of the smoothed signal,
//!   `t_i > t_(i-1)`, which is the same as `d_i > t_(i-1)`; `m_1 = 0`;
//! - **rank**: the empirical distribution function `m_i = (1/n) #{j : d_j <= d_i}` (ties share
//!   the highest rank of their group, as the formula says). The values are kept as a sorted
//!   list; an update sorts the `P` new values and merges them in, then one sweep assigns every
//!   rank: `O(L + P log P)` for `L` old values. Unlike the other features, every rank changes
//!   when new readings arrive.

use std::cmp::Ordering;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Which gas feature the estimator compares.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Feature {
    /// The reading itself.
    Value,
    /// Binary hit against a fixed threshold.
    FixedHit,
    /// Binary hit on rising edges of a moving-window threshold.
    AdaptiveHit,
    /// Empirical distribution function (normalised rank) within all readings so far.
    Rank,
}

impl Feature {
    /// All features, in the order of the paper's figure.
    pub const ALL: [Feature; 4] = [Self::Value, Self::FixedHit, Self::AdaptiveHit, Self::Rank];

    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Value => "value",
            Self::FixedHit => "fixed-hit",
            Self::AdaptiveHit => "adaptive-hit",
            Self::Rank => "rank",
        }
    }
}

/// Settings of the feature extraction.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct FeatureParams {
    /// Threshold of the fixed hit, applied to readings and to estimates alike. The default,
    /// 5, is 5 ppm above clean air: chosen for a calibrated sensor (it sits at the plume's
    /// edge, about 0.05 model units); on raw volts it is simply the same number, as a fixed,
    /// hand-picked threshold would be.
    pub fixed_threshold: f64,
    /// Smoothing factor of the adaptive hit, in `[0, 1)`; the paper's 0.7.
    pub lambda: f64,
}

impl Default for FeatureParams {
    fn default() -> Self {
        Self {
            fixed_threshold: 5.0,
            lambda: 0.7,
        }
    }
}

impl FeatureParams {
    /// Checks the ranges.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a non-finite threshold or lambda outside `[0, 1)`.
    pub fn check(&self) -> Result<()> {
        if !self.fixed_threshold.is_finite() || !(0.0..1.0).contains(&self.lambda) {
            return Err(Error::Parameter(format!("bad feature settings {self:?}")));
        }
        Ok(())
    }
}

/// A reading type the tracks accept (f64 readings, f32 model estimates).
pub trait Reading: Copy + PartialOrd + Into<f64> + Send + Sync {}
impl Reading for f32 {}
impl Reading for f64 {}

/// The positions `lo..=hi` of a sorted list within a factor of one of its positive values;
/// moved forward as that value moves up the list.
struct Window {
    ratio: f64,
    lo: usize,
    hi: usize,
}

impl Window {
    /// A window for a factor `ratio >= 1`.
    fn new(ratio: f64) -> Self {
        Self {
            ratio,
            lo: 0,
            hi: 0,
        }
    }

    /// The values within `[v / ratio, v * ratio]` of the positive value `v` at position `p`,
    /// which must not lie below the previous call's.
    fn around<T: Reading>(&mut self, sorted: &[(T, u32)], p: usize) -> (usize, usize) {
        let v: f64 = sorted[p].0.into();
        let (low, high) = (v / self.ratio, v * self.ratio);
        while sorted[self.lo].0.into() < low {
            self.lo += 1;
        }
        self.hi = self.hi.max(p);
        while self.hi + 1 < sorted.len() && sorted[self.hi + 1].0.into() <= high {
            self.hi += 1;
        }
        (self.lo, self.hi)
    }
}

fn order<T: Reading>(a: &T, b: &T) -> Ordering {
    a.partial_cmp(b).unwrap_or(Ordering::Equal)
}

/// One time-ordered sequence and its feature values, updated incrementally.
#[derive(Debug, Clone)]
pub struct FeatureTrack<T: Reading> {
    feature: Feature,
    params: FeatureParams,
    features: Vec<f32>,
    threshold: f64,
    sorted: Vec<(T, u32)>,
}

impl<T: Reading> FeatureTrack<T> {
    /// An empty track.
    pub fn new(feature: Feature, params: FeatureParams) -> Self {
        Self {
            feature,
            params,
            features: Vec::new(),
            threshold: 0.0,
            sorted: Vec::new(),
        }
    }

    /// Number of values so far.
    pub fn len(&self) -> usize {
        self.features.len()
    }

    /// Whether the track is empty.
    pub fn is_empty(&self) -> bool {
        self.features.is_empty()
    }

    /// The feature of every value so far, in time order.
    pub fn features(&self) -> &[f32] {
        &self.features
    }

    /// Appends new values (in time order) and updates the features. Values must not be NaN
    /// (the estimator checks readings before they get here).
    pub fn extend(&mut self, new: &[T]) {
        let start = self.len();
        match self.feature {
            Feature::Value => self.features.extend(new.iter().map(|&v| v.into() as f32)),
            Feature::FixedHit => {
                let thr = self.params.fixed_threshold;
                self.features
                    .extend(new.iter().map(|&v| f32::from(v.into() > thr)));
            }
            Feature::AdaptiveHit => {
                let lambda = self.params.lambda;
                for (k, &v) in new.iter().enumerate() {
                    let v = v.into();
                    if start + k == 0 {
                        self.threshold = v;
                        self.features.push(0.0);
                    } else {
                        self.features.push(f32::from(v > self.threshold));
                        self.threshold = lambda * self.threshold + (1.0 - lambda) * v;
                    }
                }
            }
            Feature::Rank => self.update_ranks(start, new),
        }
    }

    /// How every value's rank stands when the values are known only within factors: calls
    /// `f(i, value, share, expected)` with the value's time index `i`, in the order of the
    /// sorted list. The estimator uses all three (see [`crate::ste::posterior`]).
    ///
    /// - `share`: the share of all values within a factor `share_ratio >= 1` of it (in
    ///   `[v / share_ratio, v * share_ratio]`, itself included; 0 for values `<= 0`), how far
    ///   its rank can move.
    /// - `expected`: its expected rank when every value is known only within a factor
    ///   `rank_ratio = e^h >= 1`: `(1/n) (#{j : v_j < v e^-h} + 1 + sum_j k_j)`, the sum over the
    ///   other values within the factor, with `k_j = (ln v - ln v_j + h) / (2 h)` the chance
    ///   that `v_j` lies below `v` when their log-ratio is known only within `± h`. It is the
    ///   exact rank for a value with no other value within the factor, and about 1/2 for values
    ///   that all lie within it. Values `<= 0` keep their exact rank (the top of their tie
    ///   group), and so does every value when `rank_ratio` is 1.
    ///
    /// One sweep, `O(n)` plus a logarithm per value. Rank tracks only: the other features keep
    /// no sorted list and call `f` for nothing.
    pub fn for_each_within(
        &self,
        share_ratio: f64,
        rank_ratio: f64,
        mut f: impl FnMut(usize, f64, f32, f32),
    ) {
        debug_assert!(self.feature == Feature::Rank || self.sorted.is_empty());
        let sorted = &self.sorted;
        let n = sorted.len();
        let inv_n = 1.0 / n as f64;
        let share_unit = 1.0 / n as f32;
        // For expected ranks, the logarithms of the values (0 for values <= 0, which sort first
        // and never enter a window) and their prefix sums.
        let h = rank_ratio.ln();
        let logs: Vec<f64> = match h > 0.0 {
            true => sorted
                .iter()
                .map(|&(v, _)| {
                    let v: f64 = v.into();
                    if v > 0.0 { v.ln() } else { 0.0 }
                })
                .collect(),
            false => Vec::new(),
        };
        let prefix: Vec<f64> = std::iter::once(0.0)
            .chain(logs.iter().scan(0.0, |sum, &l| {
                *sum += l;
                Some(*sum)
            }))
            .collect();
        let mut shares = Window::new(share_ratio);
        let mut ranks = Window::new(rank_ratio);
        for (p, &(v, idx)) in sorted.iter().enumerate() {
            let i = idx as usize;
            let value: f64 = v.into();
            if value <= 0.0 {
                f(i, value, 0.0, self.features[i]);
                continue;
            }
            let (lo, hi) = shares.around(sorted, p);
            let share = (hi + 1 - lo) as f32 * share_unit;
            let expected = if h > 0.0 {
                let (lo, hi) = ranks.around(sorted, p);
                let (l, others) = (logs[p], (hi - lo) as f64);
                let sum_others = prefix[hi + 1] - prefix[lo] - l;
                let inside = (others * (l + h) - sum_others) / (2.0 * h);
                ((lo as f64 + 1.0 + inside) * inv_n) as f32
            } else {
                self.features[i]
            };
            f(i, value, share, expected);
        }
    }

    /// Sort the new values, merge them into the sorted list in place (from the back, so no
    /// second buffer is kept), then assign the ranks in one pass: when a group of equal values
    /// ends at sorted position `k`, each member gets `k / n`.
    fn update_ranks(&mut self, start: usize, new: &[T]) {
        let mut fresh: Vec<(T, u32)> = new
            .iter()
            .enumerate()
            .map(|(k, &v)| (v, (start + k) as u32))
            .collect();
        fresh.sort_unstable_by(|a, b| order(&a.0, &b.0));
        let sorted = &mut self.sorted;
        let (mut i, mut j) = (sorted.len(), fresh.len());
        let n = i + j;
        sorted.reserve_exact(j);
        sorted.extend_from_slice(&fresh);
        let mut k = n;
        while j > 0 {
            k -= 1;
            // Old values first among equals (the new one goes after them); ties get the same
            // rank either way.
            if i == 0 || order(&fresh[j - 1].0, &sorted[i - 1].0) != Ordering::Less {
                j -= 1;
                sorted[k] = fresh[j];
            } else {
                i -= 1;
                sorted[k] = sorted[i];
            }
        }
        self.features.resize(n, 0.0);
        let inv = 1.0 / n as f64;
        let mut group = 0;
        for k in 1..n {
            if sorted[k - 1].0 != sorted[k].0 {
                let rank = (k as f64 * inv) as f32;
                for &(_, idx) in &sorted[group..k] {
                    self.features[idx as usize] = rank;
                }
                group = k;
            }
        }
        for &(_, idx) in &sorted[group..] {
            self.features[idx as usize] = 1.0;
        }
    }
}
