//! Surrogate accuracy on a dataset: per-map relative L2 error and Spearman rank correlation at
//! sampled free-space points (the rank feature of the STE only needs the ordering right).

use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::data::TrainingData;
use super::inference::Surrogate;
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::{Layout, LayoutSpec};

/// Accuracy of one map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapScore {
    /// Sample index in the dataset.
    pub sample: usize,
    /// `||c_pred - c_true|| / ||c_true||` over free cells.
    pub relative_l2: f64,
    /// Spearman rho between predicted and true values at the sampled points.
    pub spearman: f64,
}

/// Medians and quartiles of the scores.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// Maps evaluated.
    pub maps: usize,
    /// Median relative L2 error.
    pub median_relative_l2: f64,
    /// 90th percentile relative L2 error.
    pub p90_relative_l2: f64,
    /// Median Spearman rho.
    pub median_spearman: f64,
    /// 10th percentile Spearman rho.
    pub p10_spearman: f64,
}

/// Ranks with ties sharing their average rank.
fn ranks(values: &[f64]) -> Vec<f64> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    order.sort_by(|&a, &b| values[a].total_cmp(&values[b]));
    let mut r = vec![0.0; values.len()];
    let mut start = 0;
    while start < order.len() {
        let mut end = start + 1;
        while end < order.len() && values[order[end]] == values[order[start]] {
            end += 1;
        }
        let avg = (start + end - 1) as f64 / 2.0 + 1.0;
        for &k in &order[start..end] {
            r[k] = avg;
        }
        start = end;
    }
    r
}

/// Spearman's rank correlation (Pearson correlation of the tie-averaged ranks).
pub fn spearman(a: &[f64], b: &[f64]) -> f64 {
    let (ra, rb) = (ranks(a), ranks(b));
    let n = ra.len() as f64;
    let (ma, mb) = (ra.iter().sum::<f64>() / n, rb.iter().sum::<f64>() / n);
    let cov: f64 = ra.iter().zip(&rb).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = ra.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = rb.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

fn quantile(mut v: Vec<f64>, q: f64) -> f64 {
    v.sort_by(f64::total_cmp);
    v[((v.len() - 1) as f64 * q).round() as usize]
}

/// Scores every map of `data` (`points` sampled free cells per map for Spearman, seeded).
///
/// # Errors
/// [`Error::Model`] when the model's grid differs from the dataset's.
pub fn evaluate(
    model: &Surrogate,
    data: &TrainingData,
    points: usize,
    seed: u64,
) -> Result<(Vec<MapScore>, Summary)> {
    let layouts: Vec<Layout> = data
        .manifest
        .layouts
        .iter()
        .map(|s: &LayoutSpec| {
            // The dataset is held in the canonical frame (see `TrainingData`).
            let real = s.clone().check()?;
            Frame::of(&real).layout_to_canonical(&real)
        })
        .collect::<Result<_>>()?;
    let mut scores = Vec::with_capacity(data.len());
    for (l, layout) in layouts.iter().enumerate() {
        let samples: Vec<usize> = (0..data.len())
            .filter(|&s| data.source_layout[s] == l)
            .collect();
        if samples.is_empty() {
            continue;
        }
        let sources: Vec<[f64; 2]> = samples.iter().map(|&s| data.source_xy[s]).collect();
        let predicted = model.predict_many(layout, &sources)?;
        let free: Vec<(usize, usize)> = layout
            .solid()
            .indexed_iter()
            .filter(|(_, s)| !**s)
            .map(|(ji, _)| ji)
            .collect();
        for (n, &s) in samples.iter().enumerate() {
            let truth = data.concentration.index_axis(ndarray::Axis(0), s);
            let pred = predicted.index_axis(ndarray::Axis(0), n);
            let (mut num, mut den) = (0.0, 0.0);
            for &(j, i) in &free {
                num += f64::from(pred[[j, i]] - truth[[j, i]]).powi(2);
                den += f64::from(truth[[j, i]]).powi(2);
            }
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(s as u64);
            let picks = sample(&mut rng, free.len(), points.min(free.len()));
            let (a, b): (Vec<f64>, Vec<f64>) = picks
                .iter()
                .map(|k| {
                    let (j, i) = free[k];
                    (f64::from(pred[[j, i]]), f64::from(truth[[j, i]]))
                })
                .unzip();
            scores.push(MapScore {
                sample: s,
                relative_l2: (num / den).sqrt(),
                spearman: spearman(&a, &b),
            });
        }
    }
    if scores.is_empty() {
        return Err(Error::Dataset("no map to evaluate".into()));
    }
    let l2: Vec<f64> = scores.iter().map(|s| s.relative_l2).collect();
    let rho: Vec<f64> = scores.iter().map(|s| s.spearman).collect();
    let summary = Summary {
        maps: scores.len(),
        median_relative_l2: quantile(l2.clone(), 0.5),
        p90_relative_l2: quantile(l2, 0.9),
        median_spearman: quantile(rho.clone(), 0.5),
        p10_spearman: quantile(rho, 0.1),
    };
    Ok((scores, summary))
}
