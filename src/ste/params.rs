//! The estimator's settings: the likelihood's standard deviations, every option of the
//! features and the likelihood ([`SteParams`], with each feature's defaults), and the same
//! settings checked against their ranges ([`ValidSteParams`], what the estimator runs on).
//!
//! As in linfa's parameter guards, [`SteParams`] is the open builder and [`ValidSteParams`]
//! the checked value: [`SteParams::validate`] checks once, and the estimator takes either (an
//! unchecked value is checked when the estimator is built).

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::ste::features::{Feature, FeatureParams};
use crate::ste::sensor::{MoxParams, SensorPreset};

/// Standard deviations of the model and measurement errors of one feature, in the feature's
/// unit; only `sigma_E^2 + sigma_M^2` enters the likelihood.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Sigmas {
    /// `sigma_E`, model (plume-bank) error.
    pub model: f64,
    /// `sigma_M`, measurement error.
    pub measurement: f64,
}

impl Sigmas {
    /// The defaults of a feature. They were tuned on training seeds only
    /// (`docs/method.md`): value in ppm, the others on their `[0, 1]` scale.
    pub fn default_for(feature: Feature) -> Self {
        let (model, measurement) = match feature {
            Feature::Value => (40.0, 40.0),
            Feature::FixedHit => (0.5, 0.5),
            Feature::AdaptiveHit => (0.7, 0.7),
            Feature::Rank => (0.5, 0.5),
        };
        Self { model, measurement }
    }

    pub(crate) fn variance(&self) -> f64 {
        self.model * self.model + self.measurement * self.measurement
    }
}

/// Everything the estimator needs besides the bank.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SteParams {
    /// The gas feature.
    pub feature: Feature,
    /// Feature settings (fixed threshold, lambda).
    pub features: FeatureParams,
    /// Error standard deviations.
    pub sigmas: Sigmas,
    /// ppm per plume-model unit (the known source strength).
    pub ppm_per_unit: f64,
    /// Sensor response and recovery time constants `[tau_res, tau_rec]` (s) applied to the
    /// estimated concentration series (see [`crate::ste::posterior::Estimator`]); `None` compares the plume model's
    /// values directly, as the paper writes it.
    pub sensor_lag_s: Option<[f64; 2]>,
    /// The exponent `a` of the sensor's response in which that lag acts: the estimated
    /// concentrations `c` are raised to `a`, lagged, and taken back (`c^a` lagged, then to the
    /// power `1/a`). A MOX sensor's dynamics act on its output, and its conductance follows the
    /// gas as the power `1/|k|` of its type's datasheet slope `k` (with a load resistor small
    /// against the sensor's resistance, so does the divider's voltage): `1/1.58` for the
    /// MiCS-5521, a property of the sensor type like the time constants, not a calibration.
    /// Rank's default is that exponent, with [`SteParams::detection_floor_ppm`] lowered to
    /// where the readings' clean-air band ends; the other features' is 1, which lags the
    /// concentration itself (and what a record without this field reads as).
    #[serde(default = "concentration_lag")]
    pub sensor_lag_exponent: f64,
    /// Estimated concentrations below this (ppm) are set to zero: a sensor cannot tell them
    /// apart, and without the floor the rank feature would order samples by the plume model's
    /// exponentially small upwind tails (values like 1e-20), which carry no physical meaning.
    /// 1 ppm by default; rank's is 0.2 ppm, where Sensor II's clean-air tie band ends (three
    /// noise levels above clean air), to go with the lag in the sensor's response.
    pub detection_floor_ppm: f64,
    /// The rank feature's own settings (unused by the other features), in the same JSON
    /// object as the rest.
    #[serde(flatten)]
    pub rank: RankParams,
    /// A background of recirculated gas rising during the run, as a nuisance: the model's
    /// concentrations plus `a * (1 - exp(-t / background_time_s))` (t from the first reading),
    /// with the rise `a` unknown among 0, half and the whole of this many fully mixed
    /// concentrations ([`crate::layout::Layout::fully_mixed`]), each rise
    /// [`SteParams::background_odds()`] times as likely a priori as none, and marginalised in
    /// the posterior. 0 turns it off; rank's default is 0.5, the other features' 0 (and 0 is
    /// what a record without this field reads as).
    #[serde(default)]
    pub background_rise: f64,
    /// The prior odds of each background rise (the half and the whole) against none; `None`
    /// takes the default that goes with the evidence weight (see
    /// [`SteParams::background_odds()`]; what a record without this field reads as).
    #[serde(default)]
    pub background_odds: Option<f64>,
    /// The background's time constant (s), the room's air-exchange time.
    #[serde(default = "default_background_time_s")]
    pub background_time_s: f64,
    /// The wind's direction as a hidden state that may wander during the run: the prior
    /// standard deviation (degrees) of its turn. Two hypotheses, equally likely a priori
    /// (`WANDER_STEADY`): the wind is steady (the bank as it is, the paper's form), or it
    /// wanders, its direction fixed within each `WANDER_SEGMENT_S` of readings and unknown
    /// among turns of 0, ±0.5, ±1 and ±1.5 standard deviations (`WANDER_NODES`, Gaussian
    /// prior weights; [`crate::plume::PlumeBank::turned`] banks), marginalised per segment and the segments
    /// multiplied. 0 (the default, and what a record without this field reads as)
    /// takes the wind as steady. Each turn costs about one bank's update.
    #[serde(default)]
    pub wander_deg: f64,
    /// The weight of each reading's evidence: the log-likelihood is multiplied by it (a
    /// tempered likelihood). Readings taken at 10 Hz by a sensor whose response lasts seconds,
    /// through a plume model that is not exact, carry less than independent ones would; 1
    /// treats them as independent (the paper's form, the other features' default, and what a
    /// record without this field reads as); rank's default is 0.2, set by calibration.
    /// The rank factor's default goes with it ([`SteParams::rank_factor_for`]): set once the
    /// weight is, so a changed weight leaves [`RankParams::model_rank_factor`] as it was.
    #[serde(default = "independent_readings")]
    pub evidence_weight: f64,
    /// When set, `S` readings: the evidence saturates, as it does when the readings share a
    /// plume model's error that no number of them averages out. Each of the `n` readings so
    /// far then weighs `W 2S / (S + n)` ([`SteParams::reading_weight`], `W` the
    /// [`SteParams::evidence_weight`]): `W` once `S` readings are in, more before, less in a
    /// long run or a whole survey, and all of them together never more than `2S` readings of
    /// weight `W`. The planner weighs its predicted readings by `W`. `None` (the default, and
    /// what a record without this field reads as): every reading weighs `W`.
    #[serde(default)]
    pub evidence_saturation: Option<f64>,
    /// When set, the readings' noise level is taken from the data: with the best candidate's
    /// fit ([`crate::ste::posterior::Estimator::fit`]) above this reference, every reading's
    /// evidence is weighed down by their ratio, so that a plume model that explains the
    /// readings less well than it usually does (a reality it does not know) leaves a wider
    /// posterior. `None` (what a record without this field reads as) weighs by
    /// [`SteParams::evidence_weight`] alone. The default is [`SteParams::fit_reference_for`]
    /// the plume model: with a tempered likelihood [`TEMPERED_FIT_REFERENCE`] for the solver,
    /// none for PlumeNet.
    #[serde(default)]
    pub fit_reference: Option<f64>,
    /// When set, the readings' noise level is taken from the data by the best candidate's
    /// misfit, the sum over all readings of their squared standardised residuals
    /// ([`crate::ste::posterior::Estimator::fit`] times their number): above this reference,
    /// every reading's evidence is weighed down by their ratio. Readings along a path share
    /// their errors, so a plume model that explains them as well as it usually does misfits
    /// them by about as much over a short run as over a long survey, while the mean per
    /// reading ([`SteParams::fit_reference`]) falls with every stretch of clean air. Set
    /// with the fit reference too, both factors apply. `None` (what a record without this
    /// field reads as) leaves the weight as it is; the default is
    /// [`SteParams::misfit_reference_for`] these settings (`docs/calibration.md`).
    #[serde(default)]
    pub misfit_reference: Option<f64>,
}

/// The rank feature's own settings: how readings near clean air tie, how far the plume model's
/// concentrations are trusted when ranked, and how the background nuisance's faintest
/// estimates are ranked.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct RankParams {
    /// Treat readings within three noise levels of the clean-air baseline as one
    /// tie group (see [`crate::ste::posterior::clean_air_ties`]). On by default; the rank posterior is then invariant
    /// under gain and offset of the readings, no longer under every increasing transform.
    pub clean_air_ties: bool,
    /// With `clean_air_ties` and the background nuisance: an estimate that is the
    /// background alone (its plume below the detection floor) and ranked within the readings'
    /// clean-air tie group (below the group's rank `q`, its share of the readings) joins that
    /// group, its rank raised to `q`: the sensor cannot order those readings, so neither is
    /// the background's order among them compared. Off by default (and for records from
    /// without this field): it fixes a rising background on surveys but costs elsewhere
    /// (`docs/ablations.md`).
    #[serde(default)]
    pub clean_air_model_ties: bool,
    /// With `clean_air_ties` and the background nuisance: in a background slot,
    /// every estimate ranked within the readings' clean-air tie group (below the group's rank
    /// `q`, its share of the readings) joins that group, whatever its value (the model ties'
    /// estimates of the background alone among them): the sensor cannot order the lowest `q`
    /// of the readings, so the slot's lowest `q` of the estimates are not compared by their
    /// order either. The slot without a background is left as it is (flooring it too broke
    /// the planner's paths). Off by default (and for a record without this field): it
    /// helps surveys in unseen rooms and costs in the paper arena
    /// (`docs/ablations.md`).
    #[serde(default)]
    pub clean_air_rank_floor: bool,
    /// With `clean_air_ties`: the length (s) of a centred window in which the
    /// clean-air baseline is taken, so that it follows a drifting baseline (sensor drift, gas
    /// accumulating in the room); readings above it count by their excess over it. `None`
    /// takes one baseline over the whole run.
    pub clean_air_window_s: Option<f64>,
    /// the factor `r >= 1` within which the plume model's concentrations are
    /// trusted; the share of estimates within that factor of each estimate is added to its
    /// model error (see the module doc). 1 turns it off (the paper's constant sigmas).
    pub rank_tolerance: f64,
    /// the factor `r_e >= 1` within which the plume model's concentrations are
    /// known when they are ranked; each candidate's *expected* ranks under that uncertainty
    /// are compared with the readings' (see the module doc). 1 (what a record without this
    /// field reads as) compares its exact ranks. The default is
    /// [`SteParams::rank_factor_for`] the plume model's own factor
    /// ([`crate::plume::PlumeModel::rank_factor`]: 1 for the solver, 3 for PlumeNet): with
    /// the tempered likelihood 1.5 for the solver and 3 for PlumeNet.
    #[serde(default = "exact_model_ranks")]
    pub model_rank_factor: f64,
}

/// The lag in the concentration itself: what a record without
/// [`SteParams::sensor_lag_exponent`] reads as.
fn concentration_lag() -> f64 {
    1.0
}

/// Exact model ranks: the default [`RankParams::model_rank_factor`].
fn exact_model_ranks() -> f64 {
    1.0
}

/// Independent readings: the [`SteParams::evidence_weight`] of a record without it.
fn independent_readings() -> f64 {
    1.0
}

/// The default time constant of the background's rise (s).
fn default_background_time_s() -> f64 {
    60.0
}

impl SteParams {
    /// The defaults for a feature with a plume model whose concentrations are exact (the
    /// solver's; [`SteParams::for_model`] takes another model's rank factor).
    pub fn for_feature(feature: Feature) -> Self {
        Self::for_model(feature, exact_model_ranks())
    }

    /// The defaults for a feature with a plume model whose concentrations are known within
    /// `rank_factor` when ranked ([`crate::plume::PlumeModel::rank_factor`]).
    pub fn for_model(feature: Feature, rank_factor: f64) -> Self {
        // The source strength and the time constants are the sensor type's, not a calibration.
        let sensor = MoxParams::for_preset(SensorPreset::SensorII);
        let mut params = Self {
            feature,
            features: FeatureParams::default(),
            sigmas: Sigmas::default_for(feature),
            ppm_per_unit: sensor.ppm_per_unit,
            sensor_lag_s: Some([sensor.tau_res_s, sensor.tau_rec_s]),
            sensor_lag_exponent: match feature {
                Feature::Rank => sensor.response_exponent(),
                _ => concentration_lag(),
            },
            detection_floor_ppm: match feature {
                Feature::Rank => RANK_DETECTION_FLOOR_PPM,
                _ => DETECTION_FLOOR_PPM,
            },
            rank: RankParams {
                clean_air_ties: true,
                clean_air_model_ties: false,
                clean_air_rank_floor: false,
                clean_air_window_s: None,
                rank_tolerance: RANK_TOLERANCE,
                model_rank_factor: rank_factor,
            },
            background_rise: match feature {
                Feature::Rank => BACKGROUND_RISE,
                _ => 0.0,
            },
            background_time_s: default_background_time_s(),
            background_odds: None,
            wander_deg: 0.0,
            evidence_weight: match feature {
                Feature::Rank => RANK_EVIDENCE_WEIGHT,
                _ => independent_readings(),
            },
            evidence_saturation: None,
            fit_reference: None,
            misfit_reference: None,
        };
        // The model's factor and both fit checks go with the weight (the floor of a
        // tempered likelihood applies to exact models too).
        params.rank.model_rank_factor = params.rank_factor_for(rank_factor);
        params.fit_reference = params.fit_reference_for(rank_factor);
        params.misfit_reference = params.misfit_reference_for();
        params
    }

    /// The weight of each reading's evidence once `n` readings are in:
    /// [`SteParams::evidence_weight`] `W`, or `W 2S / (S + n)` when the evidence saturates at
    /// `S` readings ([`SteParams::evidence_saturation`]).
    pub fn reading_weight(&self, n: usize) -> f64 {
        let n = n as f64;
        self.evidence_weight * self.evidence_saturation.map_or(1.0, |s| 2.0 * s / (s + n))
    }

    /// Whether the likelihood is tempered: each reading's evidence weighs less than one
    /// independent reading's ([`SteParams::evidence_weight`] below 1). The tempered likelihood
    /// is the calibrated one; its companions (the background odds, the rank factor's floor,
    /// the stopping rule) go with it.
    pub fn tempered(&self) -> bool {
        self.evidence_weight < 1.0
    }

    /// The [`RankParams::model_rank_factor`] these settings give a plume model whose own
    /// factor is `model_factor` ([`crate::plume::PlumeModel::rank_factor`]): with a tempered
    /// likelihood at least [`TEMPERED_RANK_FACTOR`], the model's own with independent readings.
    /// No steady model, the exact solver included, ranks the intermittent plume it is compared
    /// with exactly, and the tempered likelihood is the one whose regions are calibrated
    /// (`docs/calibration.md`).
    pub fn rank_factor_for(&self, model_factor: f64) -> f64 {
        match self.tempered() {
            true => model_factor.max(TEMPERED_RANK_FACTOR),
            false => model_factor,
        }
    }

    /// The [`SteParams::fit_reference`] these settings give a plume model whose own rank
    /// factor is `model_factor` ([`crate::plume::PlumeModel::rank_factor`]): with a tempered
    /// likelihood [`TEMPERED_FIT_REFERENCE`] for a model whose concentrations are exact (the
    /// solver), whose posterior nothing else widens when reality departs from it; none for a
    /// model known only within a wider factor (PlumeNet), whose own error already widens its
    /// posterior and which the check per reading makes no safer; none with independent
    /// readings (`docs/calibration.md`).
    pub fn fit_reference_for(&self, model_factor: f64) -> Option<f64> {
        (self.tempered() && model_factor <= exact_model_ranks()).then_some(TEMPERED_FIT_REFERENCE)
    }

    /// The [`crate::ste::robot::RobotParams::revisit_radius_m`] these settings give a plume
    /// model whose own rank factor is `model_factor` ([`crate::plume::PlumeModel::rank_factor`]):
    /// with a tempered likelihood [`TEMPERED_REVISIT_RADIUS_M`] for a model whose
    /// concentrations are exact (the solver), whose runs it ends sooner at the same errors and
    /// coverage; 0, every predicted point counted in full, for a model known only within a
    /// wider factor (PlumeNet), whose quicker runs some converge far off, and with independent
    /// readings (`docs/calibration.md`).
    pub fn revisit_radius_for(&self, model_factor: f64) -> f64 {
        match self.tempered() && model_factor <= exact_model_ranks() {
            true => TEMPERED_REVISIT_RADIUS_M,
            false => 0.0,
        }
    }

    /// The [`SteParams::misfit_reference`] these settings give, for every plume model: with a
    /// tempered likelihood [`TEMPERED_MISFIT_REFERENCE`], where a misfit worse than usual
    /// says that reality departs from the model; none with independent readings, the paper's
    /// form (`docs/calibration.md`).
    pub fn misfit_reference_for(&self) -> Option<f64> {
        self.tempered().then_some(TEMPERED_MISFIT_REFERENCE)
    }

    /// The prior odds of each background rise against none ([`SteParams::background_rise`]):
    /// the odds set, else [`TEMPERED_BACKGROUND_ODDS`] for a tempered likelihood
    /// ([`SteParams::evidence_weight`] below 1) and 1, every rise as likely as none, for
    /// independent readings. Every candidate whose plume the robot never met explains rising
    /// readings as the background alone; independent readings refute those hundreds of
    /// candidates by tens of nats, but a tempered likelihood only by a few, so with all rises
    /// equally likely they would keep a large share of the posterior spread over the room
    /// (`docs/calibration.md`).
    pub fn background_odds(&self) -> f64 {
        let default = if self.tempered() {
            TEMPERED_BACKGROUND_ODDS
        } else {
            1.0
        };
        self.background_odds.unwrap_or(default)
    }

    /// The wind turns (degrees) the estimator weighs: `[0]` with a steady wind, else
    /// [`SteParams::wander_deg`] times each of `WANDER_NODES`, 0 first.
    pub fn wander_turns(&self) -> Vec<f64> {
        match self.wander_deg {
            0.0 => vec![0.0],
            s => WANDER_NODES.iter().map(|u| u * s).collect(),
        }
    }

    /// The same settings with the sensor's lag in the concentration itself and the 1 ppm
    /// detection floor: the other features' defaults.
    pub fn lag_in_concentration(self) -> Self {
        Self {
            sensor_lag_exponent: concentration_lag(),
            detection_floor_ppm: DETECTION_FLOOR_PPM,
            ..self
        }
    }

    /// The same settings with the paper's rank likelihood: no clean-air ties (of the readings
    /// or of the model), no rank tolerance, exact model ranks, no background nuisance,
    /// independent readings, and the
    /// other features' lag in the concentration and detection floor
    /// ([`SteParams::lag_in_concentration`]; other features are unaffected).
    pub fn papers_rank(self) -> Self {
        Self {
            rank: RankParams {
                clean_air_ties: false,
                clean_air_model_ties: false,
                clean_air_rank_floor: false,
                rank_tolerance: 1.0,
                model_rank_factor: 1.0,
                ..self.rank
            },
            background_rise: 0.0,
            wander_deg: 0.0,
            evidence_weight: independent_readings(),
            evidence_saturation: None,
            fit_reference: None,
            misfit_reference: None,
            ..self.lag_in_concentration()
        }
    }

    /// These settings checked against their ranges, as the estimator takes them.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the first setting out of range and its value.
    pub fn validate(self) -> Result<ValidSteParams> {
        self.check()?;
        Ok(ValidSteParams(self))
    }

    /// Checks every setting against its range.
    ///
    /// # Errors
    /// [`Error::Parameter`] naming the first setting out of range and its value.
    pub fn check(&self) -> Result<()> {
        self.features.check()?;
        let s = [self.sigmas.model, self.sigmas.measurement];
        if s.iter().any(|v| !v.is_finite() || *v < 0.0) || self.sigmas.variance() <= 0.0 {
            return Err(Error::Parameter(format!(
                "sigmas must be finite, non-negative and not both zero: {:?}",
                self.sigmas
            )));
        }
        if let Some([rise, fall]) = self
            .sensor_lag_s
            .filter(|t| t.iter().any(|v| !(v.is_finite() && *v > 0.0)))
        {
            return Err(Error::Parameter(format!(
                "sensor time constants must be positive numbers of seconds, got {rise} and {fall}"
            )));
        }
        if !(self.detection_floor_ppm.is_finite() && self.detection_floor_ppm >= 0.0) {
            return Err(Error::Parameter(format!(
                "detection floor must be finite and non-negative, got {}",
                self.detection_floor_ppm
            )));
        }
        check_positive(
            self.rank.clean_air_window_s,
            "the clean-air window must be a positive number of seconds",
        )?;
        if !(self.sensor_lag_exponent.is_finite()
            && self.sensor_lag_exponent > 0.0
            && self.sensor_lag_exponent <= 1.0)
        {
            return Err(Error::Parameter(format!(
                "the sensor lag's exponent must lie in (0, 1], got {}",
                self.sensor_lag_exponent
            )));
        }
        if !(self.rank.rank_tolerance.is_finite() && self.rank.rank_tolerance >= 1.0) {
            return Err(Error::Parameter(format!(
                "rank tolerance must be a factor of at least 1, got {}",
                self.rank.rank_tolerance
            )));
        }
        if !(self.rank.model_rank_factor.is_finite() && self.rank.model_rank_factor >= 1.0) {
            return Err(Error::Parameter(format!(
                "the model's rank factor must be at least 1, got {}",
                self.rank.model_rank_factor
            )));
        }
        if !(self.background_rise.is_finite() && self.background_rise >= 0.0) {
            return Err(Error::Parameter(format!(
                "the background rise must be zero or positive, got {}",
                self.background_rise
            )));
        }
        check_positive(
            self.background_odds,
            "the background odds must be a positive number",
        )?;
        if !(self.background_time_s.is_finite() && self.background_time_s > 0.0) {
            return Err(Error::Parameter(format!(
                "the background time constant must be a positive number of seconds, got {}",
                self.background_time_s
            )));
        }
        if !(self.wander_deg.is_finite() && (0.0..=MAX_WANDER_DEG).contains(&self.wander_deg)) {
            return Err(Error::Parameter(format!(
                "the wind's wander must be between 0 and {MAX_WANDER_DEG} degrees, got {}",
                self.wander_deg
            )));
        }
        if !(self.evidence_weight.is_finite()
            && self.evidence_weight > 0.0
            && self.evidence_weight <= 1.0)
        {
            return Err(Error::Parameter(format!(
                "the evidence weight must lie in (0, 1], got {}",
                self.evidence_weight
            )));
        }
        check_positive(
            self.evidence_saturation,
            "the evidence saturation must be a positive number of readings",
        )?;
        check_positive(
            self.fit_reference,
            "the fit reference must be a positive number",
        )?;
        check_positive(
            self.misfit_reference,
            "the misfit reference must be a positive number",
        )?;
        if !(self.ppm_per_unit.is_finite() && self.ppm_per_unit > 0.0) {
            return Err(Error::Parameter(format!(
                "ppm per unit must be positive, got {}",
                self.ppm_per_unit
            )));
        }
        Ok(())
    }
}

/// Checks an optional setting that, when set, must be a finite positive number.
///
/// # Errors
/// [`Error::Parameter`] with `what`, followed by the value, otherwise.
fn check_positive(value: Option<f64>, what: &str) -> Result<()> {
    match value.filter(|v| !(v.is_finite() && *v > 0.0)) {
        Some(v) => Err(Error::Parameter(format!("{what}, got {v}"))),
        None => Ok(()),
    }
}

/// [`SteParams`] checked against their ranges ([`SteParams::validate`]): what
/// [`crate::ste::posterior::Estimator`] runs on. Reads as the settings it holds; serialised as
/// them.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(transparent)]
pub struct ValidSteParams(SteParams);

impl ValidSteParams {
    /// The settings, to change and check again.
    pub fn into_inner(self) -> SteParams {
        self.0
    }
}

impl std::ops::Deref for ValidSteParams {
    type Target = SteParams;

    fn deref(&self) -> &SteParams {
        &self.0
    }
}

impl TryFrom<SteParams> for ValidSteParams {
    type Error = Error;

    fn try_from(params: SteParams) -> Result<Self> {
        params.validate()
    }
}

/// Rank's evidence weight: each reading counts a fifth, the weight whose 90% credible regions
/// held the source in 88-95% of the tuning runs (the paper arena and generated rooms of seeds
/// no benchmark uses, PlumeNet and the solver; `docs/calibration.md`).
const RANK_EVIDENCE_WEIGHT: f64 = 0.2;

/// The default rank tolerance: model concentrations are trusted within a factor of 3.
const RANK_TOLERANCE: f64 = 3.0;

/// The default detection floor (ppm).
const DETECTION_FLOOR_PPM: f64 = 1.0;

/// Rank's detection floor (ppm): where Sensor II's clean-air tie band ends, about 0.1 ppm above
/// clean air (three noise levels), rounded up.
const RANK_DETECTION_FLOOR_PPM: f64 = 0.2;

/// Rank's default background nuisance: a rise of up to half the fully mixed concentration
/// (chosen on the mismatch suite: the smallest rise measured that fixes a rising background
/// in the paper arena and in unseen rooms; without a background it costs nothing measurable
/// with Sensor II and about 0.1 m with the calibrated sensor and Sensor I).
const BACKGROUND_RISE: f64 = 0.5;

/// The default prior odds of each background rise against none for a tempered likelihood
/// ([`SteParams::background_odds()`]): a rise of either size 1% as likely as none.
pub const TEMPERED_BACKGROUND_ODDS: f64 = 0.01;

/// The least rank factor of a tempered likelihood ([`SteParams::rank_factor_for`]): the
/// factor whose expected ranks lowered the solver's mean error under mismatch on the tuning
/// suites at the least cost in iterations (1.5 and 2 measured; `docs/calibration.md`).
/// PlumeNet's own factor, 3, lies above it.
pub const TEMPERED_RANK_FACTOR: f64 = 1.5;

/// The default fit reference of a tempered likelihood with an exact plume model
/// ([`SteParams::fit_reference_for`]): about the median fit of planned runs under mismatch
/// and the 90th percentile of surveys without it, so that surveys which fit as a known
/// reality does keep their regions (0.01 to 0.03 measured on the tuning seed's surveys and
/// planned suites; `docs/calibration.md`).
pub const TEMPERED_FIT_REFERENCE: f64 = 0.02;

/// The default revisit radius (m) of a tempered likelihood with an exact plume model
/// ([`SteParams::revisit_radius_for`]): on the tuning suites it ended the solver's runs in
/// 13 / 15 / 22 median iterations (arena / rooms / mismatch) against 16.5 / 18.5 / 26 with
/// none, at the same coverage and errors, with no run converged far off; 0.5 m ended them
/// sooner still but one rooms run 4.5 m off (`docs/calibration.md`).
pub const TEMPERED_REVISIT_RADIUS_M: f64 = 0.25;

/// The default misfit reference of a tempered likelihood ([`SteParams::misfit_reference_for`]):
/// on the tuning seed's suites, above the misfit of nine in ten planned arena runs that ended
/// within 1 m of the source (20 median, 34 at the 90th percentile) and about the median of
/// arena surveys without mismatch (40-48), below the median surveys under all departures at
/// once (150-211) and under a wandering wind (174-242) (`docs/calibration.md`).
pub const TEMPERED_MISFIT_REFERENCE: f64 = 50.0;

/// The wander hypothesis's turns of the wind, in prior standard deviations (see
/// [`SteParams::wander_deg`]), the steady direction first: a Gaussian truncated at 1.5 of them.
pub(crate) const WANDER_NODES: [f64; 7] = [0.0, -1.5, -1.0, -0.5, 0.5, 1.0, 1.5];

/// The largest wander's standard deviation (degrees): its widest turn, 1.5 of them, stays
/// within 90 degrees, beyond which the wind would blow back to the inlet.
pub const MAX_WANDER_DEG: f64 = 60.0;
