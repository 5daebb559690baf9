//! Surrogate accuracy on a dataset: per-map relative L2 error and Spearman rank correlation at
//! sampled free-space points (the rank feature of the STE only needs the ordering right).

use ndarray::{Array2, ArrayView2, Axis, Zip};
use rand::SeedableRng;
use rand::seq::index::sample;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::coarse::{anchor, best_correction};
use super::data::{SIZE_CLASSES, TrainingData, size_class};
use super::inference::Surrogate;
use crate::error::{Error, Result};
use crate::frame::Frame;
use crate::layout::Layout;
use crate::physics::transport::Transport;
use crate::physics::wind::WindField;

/// Accuracy of one map.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MapScore {
    /// Sample index in the dataset.
    pub sample: usize,
    /// Layout index in the dataset.
    pub layout: usize,
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

/// The summary of one class of maps (a room size class or a wind speed third).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClassSummary {
    /// The class.
    pub class: String,
    /// Its scores; `None` when no map falls in it.
    pub summary: Option<Summary>,
}

/// Everything [`evaluate`] reports.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Evaluation {
    /// Every map's scores.
    pub maps: Vec<MapScore>,
    /// All maps together.
    pub summary: Summary,
    /// Per room size class ([`SIZE_CLASSES`]).
    pub by_size: Vec<ClassSummary>,
    /// Per third of the wind speed range [`SPEED_THIRDS`].
    pub by_speed: Vec<ClassSummary>,
}

/// Bounds (m/s) of the wind speed thirds of the room generator's range.
pub const SPEED_THIRDS: [f64; 4] = [0.25, 0.25 + 1.25 / 3.0, 0.25 + 2.5 / 3.0, 1.5];

/// Index of the speed third of `speed` (the first or last for speeds outside the range).
pub fn speed_third(speed: f64) -> usize {
    SPEED_THIRDS[1..3]
        .iter()
        .position(|&b| speed < b)
        .unwrap_or(2)
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

fn summarize(scores: &[&MapScore]) -> Option<Summary> {
    if scores.is_empty() {
        return None;
    }
    let l2: Vec<f64> = scores.iter().map(|s| s.relative_l2).collect();
    let rho: Vec<f64> = scores.iter().map(|s| s.spearman).collect();
    Some(Summary {
        maps: scores.len(),
        median_relative_l2: quantile(l2.clone(), 0.5),
        p90_relative_l2: quantile(l2, 0.9),
        median_spearman: quantile(rho.clone(), 0.5),
        p10_spearman: quantile(rho, 0.1),
    })
}

/// How maps are scored.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EvalSettings {
    /// Sampled free cells per map for Spearman rho.
    pub points: usize,
    /// Seed of the point sampling.
    pub seed: u64,
    /// Before ranking, both fields are raised to this fraction of the true peak, so that cells
    /// below it (clean air to any sensor; far upwind the solver's values fall to 1e-30 and
    /// below) tie instead of being ordered by round-off. 0 ranks every value.
    pub floor: f64,
}

impl Default for EvalSettings {
    fn default() -> Self {
        Self {
            points: 500,
            seed: 0,
            floor: 0.0,
        }
    }
}

/// Scores every map of `data` (Spearman rho at sampled free cells, seeded), with tables per
/// room size class and per wind speed third.
///
/// # Errors
/// [`Error::Model`] when the model does not cover a layout of the dataset, [`Error::Dataset`]
/// for an empty dataset.
pub fn evaluate(
    model: &Surrogate,
    data: &TrainingData,
    settings: &EvalSettings,
) -> Result<Evaluation> {
    evaluate_with(data, settings, |layout, samples| {
        let sources: Vec<[f64; 2]> = samples.iter().map(|&s| data.source_xy[s]).collect();
        let maps = model.predict_many(layout, &sources)?;
        Ok(maps.outer_iter().map(|m| Some(m.to_owned())).collect())
    })
}

/// Which correction [`coarse_bound`] fits to a source's map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoundSharing {
    /// Each source its own correction, fitted to its own map.
    Own,
    /// Sources share the correction of the anchor of their block of `2^level` cells a side
    /// ([`super::coarse::anchor`]), fitted to the anchor's map (solved with the physics model),
    /// as the coarse form shares corrections at its level. A map whose anchor lies in an
    /// obstacle has no such correction and is left out.
    Anchor(u32),
}

/// The accuracy bound of a coarse form ([`super::model::CoarseConfig`]) whose correction lies on
/// cells `2^level` times the grid's: every map of `data` scored as [`evaluate`] does for the
/// best prediction such a form can make, `model`'s transformed analytic prior of the source
/// plus the correction on coarse cells that fits the transformed truth best
/// ([`best_correction`]), the source's own or its block anchor's (`sharing`). No trained
/// network of that form predicts closer (in the transformed space the networks are trained
/// in). Level 0 with each source's own correction returns the truth.
///
/// # Errors
/// As [`evaluate`]; [`Error::Model`] when `model` has no analytic prior; the wind or transport
/// solver's errors for anchors.
pub fn coarse_bound(
    model: &Surrogate,
    data: &TrainingData,
    (level, sharing): (u32, BoundSharing),
    settings: &EvalSettings,
) -> Result<Evaluation> {
    let saved = model.saved();
    let inputs = saved.training.inputs;
    if !inputs.has_prior() {
        return Err(Error::Model(
            "this model's inputs hold no analytic prior, to which a coarse form adds its correction"
                .into(),
        ));
    }
    let norm = saved.normalization;
    let k = 1usize << level;
    let channels = inputs.channels();
    evaluate_with(data, settings, |layout, samples| {
        let room = data.room(data.source_layout[samples[0]]);
        let (h, w) = room.shape();
        let speed = room.speed_mps;
        let free = room.mask.mapv(|m| m == 0.0);
        let mut planes = vec![0.0f32; channels * h * w];
        let mut prior_of = |source: [f64; 2]| -> Result<Array2<f32>> {
            planes.fill(0.0);
            room.encode(source, inputs, saved.encoding, &norm, (h, w), &mut planes)?;
            Ok(
                ArrayView2::from_shape((h, w), &planes[(channels - 1) * h * w..])
                    .expect("the prior plane is the room's grid")
                    .to_owned(),
            )
        };
        // Each map's correction is fitted to the map of its source or of its block's anchor.
        let fitted: Vec<Option<[f64; 2]>> = samples
            .iter()
            .map(|&s| match sharing {
                BoundSharing::Own => Some(data.source_xy[s]),
                BoundSharing::Anchor(share) => {
                    let a = anchor(data.source_xy[s], room.cell_m, 1 << share);
                    layout.check_source(a[0], a[1]).is_ok().then_some(a)
                }
            })
            .collect();
        let anchors: Vec<[f64; 2]> = fitted.iter().flatten().copied().collect();
        let anchor_maps = match sharing {
            BoundSharing::Anchor(_) if !anchors.is_empty() => {
                Some(Transport::new(layout, &WindField::solve(layout)?)?.bank(&anchors)?)
            }
            _ => None,
        };
        let mut next_anchor = 0;
        let mut maps = Vec::with_capacity(samples.len());
        for (&s, at) in samples.iter().zip(&fitted) {
            let Some(at) = *at else {
                maps.push(None);
                continue;
            };
            let truth = match &anchor_maps {
                Some(fields) => fields.index_axis(Axis(0), next_anchor),
                None => data.concentration(s),
            };
            next_anchor += 1;
            let mut map = prior_of(data.source_xy[s])?;
            let fitted_prior = match sharing {
                BoundSharing::Own => map.clone(),
                BoundSharing::Anchor(_) => prior_of(at)?,
            };
            let residual = Zip::from(truth)
                .and(&fitted_prior)
                .map_collect(|&c, &p| norm.forward(c, speed) - p);
            let correction = best_correction(residual.view(), free.view(), k);
            Zip::from(&mut map)
                .and(&correction)
                .and(&free)
                .for_each(|m, &c, &f| *m = if f { norm.inverse(*m + c, speed) } else { 0.0 });
            maps.push(Some(map));
        }
        Ok(maps)
    })
}

/// Scores every map of `data` as [`evaluate`] does, the maps of each layout predicted by
/// `predict(canonical layout, samples)`, one `[H, W]` map per sample or `None` for a map left
/// out.
fn evaluate_with(
    data: &TrainingData,
    settings: &EvalSettings,
    mut predict: impl FnMut(&Layout, &[usize]) -> Result<Vec<Option<Array2<f32>>>>,
) -> Result<Evaluation> {
    let mut scores = Vec::with_capacity(data.len());
    for (l, real) in data.layouts().iter().enumerate() {
        // The dataset is held in the canonical frame (see `TrainingData`).
        let layout = Frame::of(real).layout_to_canonical(real)?;
        let samples: Vec<usize> = (0..data.len())
            .filter(|&s| data.source_layout[s] == l)
            .collect();
        if samples.is_empty() {
            continue;
        }
        let predicted = predict(&layout, &samples)?;
        let free: Vec<(usize, usize)> = layout
            .solid()
            .indexed_iter()
            .filter(|(_, s)| !**s)
            .map(|(ji, _)| ji)
            .collect();
        for (&s, pred) in samples.iter().zip(&predicted) {
            let Some(pred) = pred else { continue };
            let truth = data.concentration(s);
            let (mut num, mut den) = (0.0, 0.0);
            for &(j, i) in &free {
                num += f64::from(pred[[j, i]] - truth[[j, i]]).powi(2);
                den += f64::from(truth[[j, i]]).powi(2);
            }
            let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
            rng.set_stream(s as u64);
            let picks = sample(&mut rng, free.len(), settings.points.min(free.len()));
            let peak = truth.iter().fold(0.0f32, |m, v| m.max(*v));
            let floor = settings.floor * f64::from(peak);
            let (a, b): (Vec<f64>, Vec<f64>) = picks
                .iter()
                .map(|k| {
                    let (j, i) = free[k];
                    let raise = |v: f32| f64::from(v).max(floor);
                    (raise(pred[[j, i]]), raise(truth[[j, i]]))
                })
                .unzip();
            scores.push(MapScore {
                sample: s,
                layout: l,
                relative_l2: (num / den).sqrt(),
                spearman: spearman(&a, &b),
            });
        }
    }
    let all: Vec<&MapScore> = scores.iter().collect();
    let summary = summarize(&all).ok_or_else(|| Error::Dataset("no map to evaluate".into()))?;
    let class_of = |f: &dyn Fn(&Layout) -> usize, names: Vec<String>| -> Vec<ClassSummary> {
        names
            .into_iter()
            .enumerate()
            .map(|(c, class)| {
                let members: Vec<&MapScore> = scores
                    .iter()
                    .filter(|m| f(&data.layouts()[m.layout]) == c)
                    .collect();
                ClassSummary {
                    class,
                    summary: summarize(&members),
                }
            })
            .collect()
    };
    let by_size = class_of(
        &size_class,
        SIZE_CLASSES.iter().map(|(n, _)| n.to_string()).collect(),
    );
    let by_speed = class_of(
        &|l: &Layout| speed_third(l.wind_speed()),
        SPEED_THIRDS
            .windows(2)
            .map(|w| format!("{:.2} to {:.2} m/s", w[0], w[1]))
            .collect(),
    );
    Ok(Evaluation {
        summary,
        by_size,
        by_speed,
        maps: scores,
    })
}
