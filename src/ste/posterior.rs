//! The Bayesian estimator: likelihood, posterior over candidate cells, entropy and MAP (the
//! stopping rule is [`crate::ste::termination`]).
//!
//! For every candidate `theta_j` the estimated concentrations `c_i(theta_j)` at the sample
//! positions come from the plume bank ([`FieldSampler`]) in ppm. Features `m_i` (readings) and
//! `e_i(theta_j)` (estimates) come from [`FeatureTrack`]s, and the log-likelihood is
//!
//! ```text
//! ln p(D | theta_j) = -W/2 * sum_i n/(n+1) * (e_i - m_i)^2 / (sigma_E^2 + sigma_M^2 + w_i^2)
//! ```
//!
//! over all `n` readings so far, each weighing `W` ([`SteParams::reading_weight`]), recomputed from a uniform prior at every update (ranks change
//! with every reading). The prior is zero inside the inflated obstacles and the boundary band.
//! Before the features are taken, each estimated series passes through the sensor's response
//! and recovery ([`SteParams::sensor_lag_s`], acting on the estimates raised to
//! [`SteParams::sensor_lag_exponent`]) and values below [`SteParams::detection_floor_ppm`]
//! become zero. For rank, `w_i` is the rank tolerance ([`crate::ste::params::RankParams::rank_tolerance`]), `e_i`
//! the expected rank under the model's own uncertainty ([`crate::ste::params::RankParams::model_rank_factor`]),
//! readings near clean air tie ([`clean_air_ties`]), and a rising background is marginalised
//! ([`SteParams::background_rise`]); the paper's form is [`SteParams::papers_rank`].
//! `docs/method.md` explains each term and the ablation behind it.

use std::sync::Arc;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::ste::credible::{self, Uncertainty};
use crate::ste::features::{Feature, FeatureTrack};
use crate::ste::params::WANDER_NODES;
pub use crate::ste::params::{Sigmas, SteParams, ValidSteParams};
use crate::ste::sampler::FieldSampler;

/// One reading at a position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Time (s).
    pub t: f64,
    /// Position x (m).
    pub x: f64,
    /// Position y (m).
    pub y: f64,
    /// Reading (volts, or ppm above clean air for a calibrated sensor).
    pub value: f64,
}

/// Which candidates the prior allows: outside obstacles inflated by `inflate_m` and at least
/// `band_m` from the arena's four edges.
///
/// # Errors
/// [`Error::Parameter`] when no candidate is left.
pub fn prior_support(
    layout: &Layout,
    candidates: &[[f64; 2]],
    inflate_m: f64,
    band_m: f64,
) -> Result<Vec<bool>> {
    let support: Vec<bool> = candidates
        .iter()
        .map(|&[x, y]| {
            layout.edge_distance(x, y) >= band_m && layout.obstacle_distance(x, y) >= inflate_m
        })
        .collect();
    if !support.iter().any(|&s| s) {
        return Err(Error::Parameter(
            "the prior excludes every candidate (band or inflation too large)".into(),
        ));
    }
    Ok(support)
}

/// The background rises an estimator marginalises, in fully mixed concentrations: none
/// without the nuisance, else 0, half and the whole of [`SteParams::background_rise`].
fn background_levels(params: &SteParams) -> Vec<f64> {
    match params.background_rise {
        0.0 => vec![0.0],
        a => vec![0.0, 0.5 * a, a],
    }
}

/// The log prior weight of each of [`background_levels`], relative to no rise: none without
/// the nuisance, else 0 for no rise and `ln o` for each rise, `o` the odds of
/// [`SteParams::background_odds()`] (all 0, exactly, when every rise is as likely as none).
fn background_log_prior(params: &SteParams) -> Vec<f64> {
    match params.background_rise {
        0.0 => vec![0.0],
        _ => {
            let o = params.background_odds().ln();
            vec![0.0, o, o]
        }
    }
}

/// The grid Bayesian filter over candidate source cells.
#[derive(Debug, Clone)]
pub struct Estimator {
    params: ValidSteParams,
    /// The banks: the model's at the layout's wind speed first, then at the other nuisance
    /// values (see [`Estimator::with_banks`]), each followed by its turned copies when the
    /// wind may wander (`turns` per bank, the unturned first).
    samplers: Vec<Arc<FieldSampler>>,
    /// Samplers per bank: the wind turns weighed ([`SteParams::wander_turns`]).
    turns: usize,
    /// The log prior weight of each turn under the wander hypothesis (normalised).
    turn_log_prior: Vec<f64>,
    /// The posterior probability of a steady wind, when the wind may wander.
    steady_posterior: Option<f64>,
    /// Posterior of each bank (its nuisance value), summed over candidates and backgrounds.
    bank_posterior: Vec<f64>,
    /// The background rises marginalised per bank, in fully mixed concentrations, 0 first
    /// (see [`SteParams::background_rise`]).
    backgrounds: Vec<f64>,
    /// The fully mixed concentration in ppm under each bank's wind.
    mixed_ppm: Vec<f64>,
    /// Posterior of each background rise, summed over banks and candidates.
    background_posterior: Vec<f64>,
    /// The log prior weight of each background rise ([`SteParams::background_odds()`]).
    background_log_prior: Vec<f64>,
    log_prior: Vec<f64>,
    measured: FeatureTrack<f64>,
    edf: FeatureTrack<f64>,
    estimated: Vec<FeatureTrack<f32>>,
    /// The readings so far, in time order.
    readings: Vec<f64>,
    positions: Vec<[f64; 2]>,
    times: Vec<f64>,
    posterior: Vec<f64>,
    /// Goodness of fit of the most probable (bank, candidate); see [`Estimator::fit`].
    fit: Option<f64>,
    lag_state: Vec<f32>,
    last_time: Option<f64>,
}

/// One candidate of a reported posterior.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CellProbability {
    /// The candidate's x (m).
    pub x: f64,
    /// The candidate's y (m).
    pub y: f64,
    /// Its posterior probability.
    pub p: f64,
}

impl Estimator {
    /// A fresh estimator with the uniform prior over `support`.
    ///
    /// # Errors
    /// [`Error::Parameter`] for bad settings (unless already checked, [`ValidSteParams`]) or
    /// a support of the wrong length or empty.
    pub fn new<P>(sampler: Arc<FieldSampler>, support: &[bool], params: P) -> Result<Self>
    where
        P: TryInto<ValidSteParams>,
        Error: From<P::Error>,
    {
        Self::with_banks(vec![sampler], support, params)
    }

    /// A fresh estimator over several banks of the same candidates: the plume model under
    /// different values of a nuisance parameter (the wind speed), each equally likely a priori.
    /// The posterior is over (bank, candidate) jointly; [`Estimator::posterior`] is its
    /// marginal over candidates and [`Estimator::bank_posterior`] over banks.
    ///
    /// # Errors
    /// [`Error::Parameter`] for bad settings (unless already checked), no bank, banks over different candidates, or a
    /// support of the wrong length or empty.
    pub fn with_banks<P>(
        samplers: Vec<Arc<FieldSampler>>,
        support: &[bool],
        params: P,
    ) -> Result<Self>
    where
        P: TryInto<ValidSteParams>,
        Error: From<P::Error>,
    {
        let params = params.try_into()?;
        let Some(first) = samplers.first() else {
            return Err(Error::Parameter("no plume bank".into()));
        };
        if samplers
            .iter()
            .any(|s| s.candidates() != first.candidates())
        {
            return Err(Error::Parameter(
                "the plume banks cover different candidates".into(),
            ));
        }
        let n = first.len();
        if support.len() != n || !support.iter().any(|&s| s) {
            return Err(Error::Parameter(format!(
                "prior support has {} entries ({} allowed) for {} candidates",
                support.len(),
                support.iter().filter(|&&s| s).count(),
                n
            )));
        }
        let log_prior: Vec<f64> = support
            .iter()
            .map(|&s| if s { 0.0 } else { f64::NEG_INFINITY })
            .collect();
        let posterior = normalise(&log_prior);
        let banks = samplers.len();
        let angles = params.wander_turns();
        let samplers = samplers
            .iter()
            .flat_map(|s| angles.iter().map(|&a| s.turned(a)))
            .collect::<Result<Vec<_>>>()?;
        // Gaussian in the turn's standard deviations; the steady direction alone without it.
        let weights: Vec<f64> = WANDER_NODES[..angles.len()]
            .iter()
            .map(|u| -0.5 * u * u)
            .collect();
        let backgrounds = background_levels(&params);
        let rise_log_prior = background_log_prior(&params);
        let slots = samplers.len() * backgrounds.len() * n;
        let track = FeatureTrack::new(params.feature, params.features);
        Ok(Self {
            estimated: vec![track; slots],
            measured: FeatureTrack::new(params.feature, params.features),
            edf: FeatureTrack::new(Feature::Rank, params.features),
            params,
            bank_posterior: vec![1.0 / banks as f64; banks],
            background_posterior: normalise(&rise_log_prior),
            background_log_prior: rise_log_prior,
            backgrounds,
            mixed_ppm: samplers
                .iter()
                .map(|s| s.layout().fully_mixed(1.0) * params.ppm_per_unit)
                .collect(),
            samplers,
            turns: angles.len(),
            turn_log_prior: log_normalise(&weights),
            steady_posterior: None,
            log_prior,
            readings: Vec::new(),
            positions: Vec::new(),
            times: Vec::new(),
            posterior,
            fit: None,
            lag_state: vec![0.0; slots],
            last_time: None,
        })
    }

    /// About how many bytes an estimator over `banks` banks of `candidates` candidates holds
    /// after `readings` readings, most of it in one update that takes them all at once (a
    /// replay): every (bank, wind turn, background, candidate) slot keeps each reading's
    /// estimate, feature and rank (12 bytes), and an update gathers its readings' estimates
    /// first (4 more).
    pub fn memory_bytes(
        banks: usize,
        candidates: usize,
        params: &SteParams,
        readings: usize,
    ) -> u64 {
        let turns = params.wander_turns().len();
        let slots = banks * turns * background_levels(params).len() * candidates;
        16 * slots as u64 * readings as u64
    }

    /// The background rises marginalised (in fully mixed concentrations: 0, then half and the
    /// whole of [`SteParams::background_rise`]) with their posterior; `[[0, 1]]` without the
    /// nuisance.
    pub fn backgrounds(&self) -> Vec<[f64; 2]> {
        let pairs = self.backgrounds.iter().zip(&self.background_posterior);
        pairs.map(|(&a, &p)| [a, p]).collect()
    }

    /// The settings.
    pub fn params(&self) -> &SteParams {
        &self.params
    }

    /// The bank the planner predicts with: the most probable one, unturned.
    pub fn sampler(&self) -> &FieldSampler {
        &self.samplers[argmax(&self.bank_posterior) * self.turns]
    }

    /// The posterior probability that the wind is steady rather than wandering (see
    /// [`SteParams::wander_deg`]); `None` when the estimator takes it as steady, or before the
    /// first reading.
    pub fn steady_posterior(&self) -> Option<f64> {
        self.steady_posterior
    }

    /// The posterior of each bank (summed over candidates), in the order given.
    pub fn bank_posterior(&self) -> &[f64] {
        &self.bank_posterior
    }

    /// Candidate positions (m).
    pub fn candidates(&self) -> &[[f64; 2]] {
        self.samplers[0].candidates()
    }

    /// Number of readings so far.
    pub fn len(&self) -> usize {
        self.measured.len()
    }

    /// Whether no reading has arrived.
    pub fn is_empty(&self) -> bool {
        self.measured.is_empty()
    }

    /// The readings' own features `m_i`, in time order.
    pub fn measured_features(&self) -> &[f32] {
        self.measured.features()
    }

    /// The readings' EDF values (their normalised ranks), whatever the feature: used to colour
    /// samples in pictures.
    pub fn measured_edf(&self) -> &[f32] {
        self.edf.features()
    }

    /// Sample positions so far.
    pub fn positions(&self) -> &[[f64; 2]] {
        &self.positions
    }

    /// The posterior probability of every candidate (sums to 1).
    pub fn posterior(&self) -> &[f64] {
        &self.posterior
    }

    /// Adds new readings (in time order) and recomputes the posterior.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a non-finite reading, time or position, or a position outside
    /// the arena; nothing is changed then.
    pub fn update(&mut self, samples: &[Sample]) -> Result<()> {
        let layout = self.samplers[0].layout();
        for (k, s) in samples.iter().enumerate() {
            let finite = [s.t, s.x, s.y, s.value].iter().all(|v| v.is_finite());
            let inside =
                s.x >= 0.0 && s.x <= layout.width() && s.y >= 0.0 && s.y <= layout.height();
            if !finite || !inside {
                return Err(Error::Parameter(format!(
                    "sample {k} (t {}, x {}, y {}, value {}) is not finite or lies outside the arena",
                    s.t, s.x, s.y, s.value
                )));
            }
        }
        if samples.is_empty() {
            return Ok(());
        }
        let positions = self.samplers[0].len();
        let n_cand = self.estimated.len();
        let scale = self.params.ppm_per_unit as f32;
        let per_bank = self.backgrounds.len() * positions;
        let t0 = self.times.first().copied().unwrap_or(samples[0].t);
        let tau = self.params.background_time_s;
        let rise = |t: f64| 1.0 - (-(t - t0).max(0.0) / tau).exp();
        let mut gathered = vec![0.0f32; samples.len() * n_cand];
        for (s, row) in samples.iter().zip(gathered.chunks_mut(n_cand)) {
            let rise = rise(s.t);
            let banks = self.samplers.iter().zip(&self.mixed_ppm);
            for ((sampler, mixed), part) in banks.zip(row.chunks_mut(per_bank)) {
                let (plume, rest) = part.split_at_mut(positions);
                sampler.gather(s.x, s.y, scale, plume);
                for (a, slot) in self.backgrounds[1..].iter().zip(rest.chunks_mut(positions)) {
                    let b = (a * mixed * rise) as f32;
                    slot.iter_mut().zip(&*plume).for_each(|(c, p)| *c = p + b);
                }
            }
        }
        if let Some(taus) = self.params.sensor_lag_s {
            self.apply_lag(samples, &mut gathered, taus);
        }
        let floor_ppm = self.params.detection_floor_ppm;
        let floor = floor_ppm as f32;
        for c in gathered.iter_mut().filter(|c| **c < floor) {
            *c = 0.0;
        }
        let values: Vec<f64> = samples.iter().map(|s| s.value).collect();
        self.edf.extend(&values);
        self.readings.extend_from_slice(&values);
        self.times.extend(samples.iter().map(|s| s.t));
        if self.params.rank.clean_air_ties && self.params.feature == Feature::Rank {
            let mut all = self.readings.clone();
            match self.params.rank.clean_air_window_s {
                None => clean_air_ties(&mut all),
                Some(w) => drifting_clean_air_ties(&mut all, &self.times, w),
            }
            self.measured = FeatureTrack::new(self.params.feature, self.params.features);
            self.measured.extend(&all);
        } else {
            self.measured.extend(&values);
        }
        self.positions.extend(samples.iter().map(|s| [s.x, s.y]));

        let n = self.measured.len() as f64;
        let factor = -0.5 * n / (n + 1.0) * self.params.reading_weight(self.measured.len());
        let variance = self.params.sigmas.variance();
        let (r, r_model) = (
            self.params.rank.rank_tolerance,
            self.params.rank.model_rank_factor,
        );
        let within = self.params.feature == Feature::Rank && (r > 1.0 || r_model > 1.0);
        let m = self.measured.features();
        // Clean-air model ties: in a background slot, an estimate that is the background alone
        // (its plume below the floor) and ranked below the readings' clean-air tie group joins
        // that group (its rank raised to the group's, the readings' lowest).
        let tied = self.params.feature == Feature::Rank
            && self.params.rank.clean_air_ties
            && self.params.rank.clean_air_model_ties;
        // The clean-air rank floor: in a background slot, every estimate ranked below that
        // group joins it.
        let floored = self.params.feature == Feature::Rank
            && self.params.rank.clean_air_ties
            && self.params.rank.clean_air_rank_floor;
        let q = m.iter().copied().fold(f32::INFINITY, f32::min);
        let rises: Vec<f64> = match tied {
            true => self.times.iter().map(|&t| rise(t)).collect(),
            false => Vec::new(),
        };
        let levels = self.backgrounds.len();
        let p = samples.len();
        // Each reading's wander segment, when the wind may wander.
        let segment: Vec<usize> = match self.turns {
            1 => Vec::new(),
            _ => self
                .times
                .iter()
                .map(|t| ((t - self.times[0]) / WANDER_SEGMENT_S).floor() as usize)
                .collect(),
        };
        let segments = segment.iter().max().map_or(0, |s| s + 1);
        let slot_lik: Vec<(f64, Vec<f64>)> = self
            .estimated
            .par_iter_mut()
            .enumerate()
            .map(|(k, track)| {
                let fresh: Vec<f32> = (0..p).map(|i| gathered[i * n_cand + k]).collect();
                track.extend(&fresh);
                let slot = k / positions;
                // The slot's background (ppm) at a whole rise.
                let full = self.backgrounds[slot % levels] * self.mixed_ppm[slot / levels];
                let joins = tied && full > 0.0;
                let floors = floored && full > 0.0;
                // The log-likelihood of each wander segment, when the wind may wander.
                let mut parts = vec![0.0; segments];
                let sum = if within || joins || floors {
                    let mut sum = 0.0;
                    track.for_each_within(r, r_model, |i, v, w, e| {
                        // The background alone, with a little room for the f32 rounding.
                        let alone = joins && v <= full * rises[i] * (1.0 + 1e-6) + floor_ppm;
                        let e = if alone || floors { e.max(q) } else { e };
                        let w = if within { w } else { 0.0 };
                        let d = f64::from(e - m[i]).powi(2) / (variance + f64::from(w * w));
                        sum += d;
                        if let Some(&s) = segment.get(i) {
                            parts[s] += factor * d;
                        }
                    });
                    sum
                } else {
                    let e = track.features();
                    for (i, (&e, &m)) in e.iter().zip(m).enumerate().take(segment.len()) {
                        parts[segment[i]] += factor * f64::from(e - m).powi(2) / variance;
                    }
                    e.iter()
                        .zip(m)
                        .map(|(&e, &m)| f64::from(e - m).powi(2))
                        .sum::<f64>()
                        / variance
                };
                (factor * sum, parts)
            })
            .collect();
        // The readings' noise level taken from the best fit: a model that explains them less
        // well than a reference (per reading, or over all of them) weighs each reading less.
        let (fit_ref, misfit_ref) = (self.params.fit_reference, self.params.misfit_reference);
        let scale = match fit_ref.is_some() || misfit_ref.is_some() {
            false => 1.0,
            true => {
                let misfit = slot_lik
                    .iter()
                    .enumerate()
                    .filter(|(k, _)| self.log_prior[k % positions].is_finite())
                    .map(|(_, l)| l.0 / factor)
                    .fold(f64::INFINITY, f64::min);
                let weigh = |reference: Option<f64>, value: f64| {
                    reference.map_or(1.0, |r| r / value.max(r))
                };
                weigh(fit_ref, misfit / n) * weigh(misfit_ref, misfit)
            }
        };
        let slot_lik: Vec<(f64, Vec<f64>)> = match scale {
            1.0 => slot_lik,
            c => slot_lik
                .into_iter()
                .map(|(total, parts)| (c * total, parts.into_iter().map(|p| c * p).collect()))
                .collect(),
        };
        let (log_lik, steady_share) = self.wander_marginal(&slot_lik, positions);
        let levels = self.backgrounds.len();
        let log_post: Vec<f64> = log_lik
            .chunks(positions)
            .enumerate()
            .flat_map(|(slot, bank)| {
                let rise = self.background_log_prior[slot % levels];
                self.log_prior
                    .iter()
                    .zip(bank)
                    .map(move |(a, b)| a + b + rise)
            })
            .collect();
        let best = argmax(&log_post);
        self.fit = Some(log_lik[best] / (factor * scale) / n);
        let joint = normalise(&log_post);
        self.posterior = (0..positions)
            .map(|j| joint.iter().skip(j).step_by(positions).sum())
            .collect();
        let slot_mass: Vec<f64> = joint.chunks(positions).map(|b| b.iter().sum()).collect();
        self.bank_posterior = slot_mass.chunks(levels).map(|b| b.iter().sum()).collect();
        self.steady_posterior =
            steady_share.map(|share| share.iter().zip(&joint).map(|(s, p)| s * p).sum());
        self.background_posterior = (0..levels)
            .map(|l| slot_mass.iter().skip(l).step_by(levels).sum())
            .collect();
        Ok(())
    }

    /// The log-likelihood of every (bank, background, candidate) from its samplers' `slot_lik`
    /// (whole-run log-likelihood, per-segment log-likelihoods), marginalised over the wind's
    /// wander (see [`SteParams::wander_deg`]): `p0 L_steady + (1 - p0) prod_s sum_t w_t L_(s,t)`
    /// in logs, `p0` the steady wind's prior, `w_t` the turns' and `L_(s,t)` segment `s`'s
    /// likelihood under turn `t`; beside it, each one's share `p0 L_steady / L` of the steady
    /// wind. With a steady wind, the slots' own log-likelihoods and no share.
    fn wander_marginal(
        &self,
        slot_lik: &[(f64, Vec<f64>)],
        positions: usize,
    ) -> (Vec<f64>, Option<Vec<f64>>) {
        if self.turns == 1 {
            return (slot_lik.iter().map(|l| l.0).collect(), None);
        }
        let levels = self.backgrounds.len();
        let per_turn = levels * positions;
        let combined = self.samplers.len() / self.turns * per_turn;
        let (log_lik, share): (Vec<f64>, Vec<f64>) = (0..combined)
            .into_par_iter()
            .map(|c| {
                let (bank, rest) = (c / per_turn, c % per_turn);
                let slot = |t: usize| &slot_lik[(bank * self.turns + t) * per_turn + rest];
                let segments = slot(0).1.len();
                let wandering: f64 = (0..segments)
                    .map(|s| {
                        let terms = (0..self.turns).map(|t| self.turn_log_prior[t] + slot(t).1[s]);
                        log_sum_exp(terms)
                    })
                    .sum();
                let steady = WANDER_STEADY.ln() + slot(0).0;
                let both = log_sum_exp([steady, (1.0 - WANDER_STEADY).ln() + wandering]);
                (both, (steady - both).exp())
            })
            .unzip();
        (log_lik, Some(share))
    }

    /// Passes every candidate's estimated series through the sensor's first-order dynamics
    /// (rise with `tau_res`, fall with `tau_rec`), continuing from the previous update. The
    /// first sample of a run starts the filter at its own value (the sensor in equilibrium).
    fn apply_lag(&mut self, samples: &[Sample], gathered: &mut [f32], [res, rec]: [f64; 2]) {
        let n = self.estimated.len();
        // The lag acts on the sensor's response `c^a`, not on the concentration.
        let a = self.params.sensor_lag_exponent as f32;
        if a != 1.0 {
            gathered.iter_mut().for_each(|c| *c = c.max(0.0).powf(a));
        }
        for (s, row) in samples.iter().zip(gathered.chunks_mut(n)) {
            match self.last_time {
                None => self.lag_state.copy_from_slice(row),
                Some(t0) => {
                    let dt = (s.t - t0).max(0.0);
                    let (a_res, a_rec) = (
                        (1.0 - (-dt / res).exp()) as f32,
                        (1.0 - (-dt / rec).exp()) as f32,
                    );
                    for (y, c) in self.lag_state.iter_mut().zip(row.iter_mut()) {
                        let a = if *c > *y { a_res } else { a_rec };
                        *y += a * (*c - *y);
                        *c = *y;
                    }
                }
            }
            self.last_time = Some(s.t);
        }
        if a != 1.0 {
            gathered.iter_mut().for_each(|c| *c = c.powf(1.0 / a));
        }
    }

    /// Goodness of fit: the mean squared standardised residual per reading,
    /// `sum_i (e_i - m_i)^2 / sigma_i^2 / n`, of the most probable (bank, candidate). About 1
    /// or below when that candidate's predicted features explain the measured ones within the
    /// sigmas; well above 1 when no candidate does. `None` before the first reading.
    pub fn fit(&self) -> Option<f64> {
        self.fit
    }

    /// How far the highest reading so far stands above the readings' median, in noise levels
    /// ([`plume_signal`]): whether the readings hold a plume at all.
    pub fn plume_signal(&self) -> f64 {
        plume_signal(&self.readings)
    }

    /// Whether the estimate's plume reaches the plume the readings hold: the most probable
    /// candidate's concentration under the most probable bank ([`Estimator::sampler`]) is at
    /// least [`SteParams::detection_floor_ppm`] where at least one reading was taken that
    /// stands `noises` noise levels above the readings' median (as [`plume_signal`] measures).
    /// A candidate whose plume misses every such reading cannot have made them, however well
    /// the readings' order fits it: a source whose plume the wind sweeps out of the room at
    /// once leaves every reading's rank to the clean air. `false` without such a reading.
    pub fn reaches_plume(&self, noises: f64) -> bool {
        let Some((median, noise)) = median_and_noise(&self.readings) else {
            return false;
        };
        let level = median + noises * noise;
        let (k, sampler) = (self.map_index(), self.sampler());
        let floor = self.params.detection_floor_ppm / self.params.ppm_per_unit;
        self.readings
            .iter()
            .zip(&self.positions)
            .filter(|&(&v, _)| v > median && v >= level)
            .any(|(_, &[x, y])| f64::from(sampler.value(k, x, y)) >= floor)
    }

    /// Shannon entropy of the posterior (nats).
    pub fn entropy(&self) -> f64 {
        entropy(&self.posterior)
    }

    /// Index of the most probable candidate.
    pub fn map_index(&self) -> usize {
        argmax(&self.posterior)
    }

    /// The most probable candidate's position (m).
    pub fn estimate(&self) -> [f64; 2] {
        self.candidates()[self.map_index()]
    }

    /// Indices of the smallest set of candidates holding at least `mass` of the posterior,
    /// most probable first.
    pub fn credible_set(&self, mass: f64) -> Vec<usize> {
        credible::credible_set(&self.posterior, mass)
    }

    /// The posterior as reports write it: each candidate with its probability.
    pub fn posterior_cells(&self) -> Vec<CellProbability> {
        let cells = self.candidates().iter().zip(&self.posterior);
        cells
            .map(|(c, &p)| CellProbability {
                x: c[0],
                y: c[1],
                p,
            })
            .collect()
    }

    /// The posterior's credible regions and expected distance from the estimate, scored
    /// against `source` when it is known ([`Uncertainty::of`]).
    pub fn uncertainty(&self, source: Option<[f64; 2]>) -> Uncertainty {
        Uncertainty::of(self.candidates(), &self.posterior, self.estimate(), source)
    }
}

/// The length (s) of the wander's segments, within each of which its direction is taken as
/// fixed: the correlation time of the simulated reality's wander. On 50 wandering runs 10 s
/// and 60 s segments did worse (`docs/ablations.md`).
const WANDER_SEGMENT_S: f64 = 20.0;

/// The prior probability that the wind is steady rather than wandering: halves, so that a
/// steady reality keeps the steady bank's posterior.
const WANDER_STEADY: f64 = 0.5;

/// Noise levels above the clean-air baseline below which readings tie.
const CLEAN_AIR_NOISES: f64 = 3.0;

/// Sets every reading within `CLEAN_AIR_NOISES` noise levels of the clean-air baseline to the baseline, so
/// that readings of clean air form one tie group, as the plume model's values below the
/// detection floor do. Calibration-free: the baseline is the 5th percentile of the readings,
/// and the noise level is estimated from successive differences,
/// `1.4826 median |d_i - d_(i-1)| / sqrt 2` (white noise dominates them at 10 Hz, the plume and
/// the sensor being slower).
pub fn clean_air_ties(values: &mut [f64]) {
    if values.len() < 3 {
        return;
    }
    let noise = reading_noise(values);
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let baseline = sorted[(0.05 * (sorted.len() - 1) as f64).round() as usize];
    for v in values.iter_mut() {
        if *v <= baseline + CLEAN_AIR_NOISES * noise {
            *v = baseline;
        }
    }
}

/// [`clean_air_ties`] with a baseline that drifts: reading `i`'s baseline is the 5th
/// percentile of the readings within `window_s / 2` of it in time. Readings within
/// `CLEAN_AIR_NOISES` noise levels of their baseline become 0 (one tie group), the others
/// their excess over it.
pub fn drifting_clean_air_ties(values: &mut [f64], times: &[f64], window_s: f64) {
    if values.len() < 3 {
        return;
    }
    let noise = reading_noise(values);
    let original = values.to_vec();
    let (mut lo, mut hi) = (0, 0);
    let mut window = Vec::new();
    for (i, v) in values.iter_mut().enumerate() {
        while times[lo] < times[i] - 0.5 * window_s {
            lo += 1;
        }
        while hi < original.len() && times[hi] <= times[i] + 0.5 * window_s {
            hi += 1;
        }
        window.clear();
        window.extend_from_slice(&original[lo..hi]);
        let k = (0.05 * (window.len() - 1) as f64).round() as usize;
        let baseline = *window.select_nth_unstable_by(k, f64::total_cmp).1;
        *v = if *v <= baseline + CLEAN_AIR_NOISES * noise {
            0.0
        } else {
            *v - baseline
        };
    }
}

/// The readings' noise level, calibration-free: `1.4826 median |d_i - d_(i-1)| / sqrt 2` over
/// successive readings (white noise dominates their differences at 10 Hz, the plume and the
/// sensor being slower). At least two readings.
fn reading_noise(values: &[f64]) -> f64 {
    let diffs: Vec<f64> = values.windows(2).map(|w| (w[1] - w[0]).abs()).collect();
    1.4826 * crate::stats::median(&diffs) / std::f64::consts::SQRT_2
}

/// How far the highest reading stands above the readings' median, in noise levels (estimated
/// from successive readings' differences, as for [`clean_air_ties`]): calibration-free (unchanged by the sensor's gain and offset), 0 for
/// fewer than three readings, infinite for noise-free readings that rise at all. Noise alone
/// stays within a few levels; a plume the sensor met stands tens of them above.
pub fn plume_signal(values: &[f64]) -> f64 {
    let Some((median, noise)) = median_and_noise(values) else {
        return 0.0;
    };
    let rise = values.iter().copied().fold(f64::NEG_INFINITY, f64::max) - median;
    if rise <= 0.0 {
        0.0
    } else if noise > 0.0 {
        rise / noise
    } else {
        f64::INFINITY
    }
}

/// The readings' median and noise level ([`reading_noise`]), what [`plume_signal`] and
/// [`Estimator::reaches_plume`] measure a plume against; `None` for fewer than three readings.
fn median_and_noise(values: &[f64]) -> Option<(f64, f64)> {
    (values.len() >= 3).then(|| (crate::stats::median(values), reading_noise(values)))
}

/// Shifts log weights so that their exponentials sum to 1.
fn log_normalise(log_w: &[f64]) -> Vec<f64> {
    let z = log_sum_exp(log_w.iter().copied());
    log_w.iter().map(|w| w - z).collect()
}

/// `ln sum_i exp(x_i)`, without overflow; minus infinity for no terms or all of them minus
/// infinity.
fn log_sum_exp(x: impl IntoIterator<Item = f64> + Clone) -> f64 {
    let top = x.clone().into_iter().fold(f64::NEG_INFINITY, f64::max);
    if top == f64::NEG_INFINITY {
        return top;
    }
    top + x.into_iter().map(|v| (v - top).exp()).sum::<f64>().ln()
}

/// Probabilities from log-weights (`-inf` allowed), max-shifted for stability.
pub fn normalise(log_w: &[f64]) -> Vec<f64> {
    let top = log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let w: Vec<f64> = log_w.iter().map(|&l| (l - top).exp()).collect();
    let total: f64 = w.iter().sum();
    w.into_iter().map(|v| v / total).collect()
}

/// Shannon entropy (nats) of a probability vector.
pub fn entropy(p: &[f64]) -> f64 {
    -p.iter()
        .filter(|&&v| v > 0.0)
        .map(|&v| v * v.ln())
        .sum::<f64>()
}

/// Index of the largest value (the first one on ties).
pub fn argmax(v: &[f64]) -> usize {
    v.iter()
        .enumerate()
        .fold((0, f64::NEG_INFINITY), |best, (k, &x)| {
            if x > best.1 { (k, x) } else { best }
        })
        .0
}
