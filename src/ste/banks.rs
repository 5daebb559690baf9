//! What the estimator weighs in one room: the layout, the plume model's banks of every
//! candidate source, and the nuisance values each bank was made for.

use std::path::Path;
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::plume::{PlumeBank, PlumeModel, cached_bank};
use crate::ste::features::Feature;
use crate::ste::posterior::SteParams;
use crate::ste::sampler::FieldSampler;

/// Width of the boundary band the prior excludes (m): one candidate spacing.
pub const PRIOR_BAND_M: f64 = 0.25;

/// One plume bank the estimator weighs, with the nuisance values it was made for.
#[derive(Debug, Clone)]
pub struct Bank {
    /// The model's wind speed, as a factor of the layout's.
    pub wind_scale: f64,
    /// The spread of the wind's direction (degrees, see
    /// [`PlumeBank::spread_over_directions`]).
    pub spread_deg: f64,
    /// The fields, ready for sampling.
    pub sampler: Arc<FieldSampler>,
}

impl Bank {
    /// The layout's own bank: its wind speed, no spread.
    fn plain(sampler: Arc<FieldSampler>) -> Self {
        Self {
            wind_scale: 1.0,
            spread_deg: 0.0,
            sampler,
        }
    }
}

/// A room as the estimator sees it: the layout and the plume model's banks of its candidate
/// sources. No simulated truth: a live session, a replay and a simulated run all start here.
#[derive(Debug, Clone)]
pub struct RoomBanks {
    /// The room.
    pub layout: Layout,
    /// The plume model's bank at the layout's wind speed, ready for sampling.
    pub sampler: Arc<FieldSampler>,
    /// The banks the estimator marginalises over: the layout's alone unless
    /// [`RoomBanks::with_wind_scales`] or [`RoomBanks::with_wind_spreads`] was used.
    pub banks: Vec<Bank>,
    /// The plume model's [`PlumeModel::rank_factor`], the default of
    /// [`crate::ste::params::RankParams::model_rank_factor`] for this room.
    pub model_rank_factor: f64,
}

impl RoomBanks {
    /// Gets the model's bank over the candidate grid of spacing `spacing_m`, from the cache
    /// directory when given (see [`cached_bank`]). Also returns whether the bank came from
    /// the cache.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a bad spacing or a layout without candidates, the model's
    /// errors, and cache write failures.
    pub fn build(
        layout: Layout,
        model: &dyn PlumeModel,
        spacing_m: f64,
        cache: Option<&Path>,
    ) -> Result<(Self, bool)> {
        let candidates = layout.candidates(spacing_m)?;
        if candidates.is_empty() {
            return Err(Error::Parameter(format!(
                "the layout has no free candidate cell at spacing {spacing_m} m"
            )));
        }
        let (sampler, hit) = sampler_of(model, &layout, &candidates, cache)?;
        Ok((
            Self {
                layout,
                banks: vec![Bank::plain(Arc::clone(&sampler))],
                sampler,
                model_rank_factor: model.rank_factor(),
            },
            hit,
        ))
    }
    /// The estimator's default settings for `feature` over this room's banks: the feature's
    /// defaults ([`SteParams::for_feature`]) with the plume model's own rank factor.
    pub fn ste_params(&self, feature: Feature) -> SteParams {
        SteParams::for_model(feature, self.model_rank_factor)
    }

    /// The same room with the estimator marginalising over the model's wind speed: one bank
    /// of `model` for each factor in `scales` (the layout's speed times the factor; 1 reuses
    /// the layout's own bank), each equally likely a priori. These banks replace the room's
    /// (spread them after, with [`RoomBanks::with_wind_spreads`]).
    ///
    /// # Errors
    /// [`Error::Parameter`] for no factor, or a factor that is not positive and finite; the
    /// model's errors (a speed outside a PlumeNet model's trained range among them).
    pub fn with_wind_scales(
        &self,
        model: &dyn PlumeModel,
        scales: &[f64],
        cache: Option<&Path>,
    ) -> Result<Self> {
        if scales.is_empty() || scales.iter().any(|s| !(s.is_finite() && *s > 0.0)) {
            return Err(Error::Parameter(format!(
                "model wind scales must be positive numbers, got {scales:?}"
            )));
        }
        let candidates = self.sampler.candidates();
        let banks = scales
            .iter()
            .map(|&scale| {
                let sampler = if scale == 1.0 {
                    Arc::clone(&self.sampler)
                } else {
                    let mut spec = self.layout.spec().clone();
                    spec.wind.speed_mps *= scale;
                    let layout = spec.check()?;
                    sampler_of(model, &layout, candidates, cache)?.0
                };
                Ok(Bank {
                    wind_scale: scale,
                    ..Bank::plain(sampler)
                })
            })
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            banks,
            ..self.clone()
        })
    }

    /// The same room with the estimator marginalising over the spread of the wind's
    /// direction: each of its banks once per spread in `spreads` (degrees; each bank's
    /// fields averaged over turned winds, see [`PlumeBank::spread_over_directions`]; 0 keeps
    /// the bank as it is), each equally likely a priori.
    ///
    /// # Errors
    /// [`Error::Parameter`] for no spread, or a spread outside `0..=90` degrees.
    pub fn with_wind_spreads(&self, spreads: &[f64]) -> Result<Self> {
        if spreads.is_empty() {
            return Err(Error::Parameter(
                "give at least one wind-direction spread".into(),
            ));
        }
        for &spread_deg in spreads {
            PlumeBank::check_spread(spread_deg)?;
        }
        let mut banks = Vec::with_capacity(self.banks.len() * spreads.len());
        for bank in &self.banks {
            let fields = spreads
                .iter()
                .any(|&s| s != 0.0)
                .then(|| bank.sampler.bank());
            for &spread_deg in spreads {
                let sampler = match &fields {
                    Some(fields) if spread_deg != 0.0 => {
                        let spread = fields.spread_over_directions(&self.layout, spread_deg)?;
                        Arc::new(FieldSampler::new(&self.layout, &spread)?)
                    }
                    _ => Arc::clone(&bank.sampler),
                };
                banks.push(Bank {
                    spread_deg,
                    sampler,
                    ..*bank
                });
            }
        }
        Ok(Self {
            banks,
            ..self.clone()
        })
    }

    /// The banks' samplers, in the order of [`RoomBanks::banks`].
    pub fn samplers(&self) -> Vec<Arc<FieldSampler>> {
        self.banks.iter().map(|b| Arc::clone(&b.sampler)).collect()
    }

    /// The posterior of one nuisance, `value` of each bank (its wind scale or spread), summed
    /// over the others: `[value, probability]` in the order the values first appear in
    /// [`RoomBanks::banks`], from the estimator's bank posterior (in that order too).
    pub fn marginal(&self, bank_posterior: &[f64], value: fn(&Bank) -> f64) -> Vec<[f64; 2]> {
        let mut marginal: Vec<[f64; 2]> = Vec::new();
        for (bank, &p) in self.banks.iter().zip(bank_posterior) {
            let v = value(bank);
            match marginal.iter_mut().find(|m| m[0] == v) {
                Some(m) => m[1] += p,
                None => marginal.push([v, p]),
            }
        }
        marginal
    }
}

/// The model's bank of `candidates` in `layout`, through the cache when given, ready for
/// sampling; also whether it came from the cache.
fn sampler_of(
    model: &dyn PlumeModel,
    layout: &Layout,
    candidates: &[[f64; 2]],
    cache: Option<&Path>,
) -> Result<(Arc<FieldSampler>, bool)> {
    let (bank, hit) = match cache {
        Some(dir) => cached_bank(model, layout, candidates, dir)?,
        None => (model.bank(layout, candidates)?, false),
    };
    Ok((Arc::new(FieldSampler::new(layout, &bank)?), hit))
}
