//! The simulated MOX gas sensor (MiCS-5521 on a voltage divider) and its three presets.
//!
//! Signal chain, one call of [`MoxSensor::sample`] per 0.1 s tick:
//!
//! 1. Gas seen by the sensor: `g = g_bg + ppm_per_unit * c` (ppm), where `c` is the plume's
//!    concentration (units/m^2 for a 1 unit/s source, the unit of the plume models) and `g_bg`
//!    a small clean-air background that keeps the sensor resistance finite.
//! 2. Nominal response (datasheet, ethanol): `log10(g) = k log10(Rs/R0) + b`, k = -1.58,
//!    b = 0.17, so `Rs = R0 (g / 10^b)^(1/k)`.
//! 3. Voltage divider: the output is the voltage across the load, `v = V_T R_L / (R_L + Rs)`,
//!    with `V_T` = 5 V and `R_L` = 100 kOhm (a common breakout-board choice; with these values
//!    Sensor I is strongly saturating and Sensor II nearly a power law, the two ends of the
//!    datasheet's R0 spread).
//! 4. First-order dynamics on the output voltage: it approaches the nominal voltage with time
//!    constant `tau_res` = 2.04 s while rising and `tau_rec` = 4.57 s while falling (exact
//!    exponential update over the tick).
//! 5. Additive Gaussian noise with standard deviation `sigma_b + sigma_k |v|` (0.01 V and 2%).
//! 6. Reading: raw volts for the uncalibrated presets; for `calibrated`, the voltage converted
//!    back with the same `[k, b, R0]` (eq. 2 of the paper) minus the known clean-air background,
//!    i.e. ppm above clean air, the unit in which the estimator compares model values.

use rand::Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// Which sensor the robot carries and how its output is read.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SensorPreset {
    /// Sensor II hardware (R0 = 1500 kOhm) whose voltage is converted back to ppm with the true
    /// `[k, b, R0]`.
    Calibrated,
    /// R0 = 100 kOhm, raw volts (the datasheet's low end: strong saturation).
    SensorI,
    /// R0 = 1500 kOhm, raw volts (the datasheet's high end).
    #[serde(rename = "sensor-ii", alias = "sensor-i-i")]
    SensorII,
}

impl SensorPreset {
    /// All presets, in the order of the paper's figure.
    pub const ALL: [SensorPreset; 3] = [Self::Calibrated, Self::SensorI, Self::SensorII];

    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::Calibrated => "calibrated",
            Self::SensorI => "sensor-i",
            Self::SensorII => "sensor-ii",
        }
    }
}

/// Parameters of the MOX sensor model (defaults: the crate's documented values).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MoxParams {
    /// Slope of the log-log response.
    pub k: f64,
    /// Intercept of the log-log response.
    pub b: f64,
    /// Clean-air reference resistance (Ohm).
    pub r0_ohm: f64,
    /// Load resistor of the divider (Ohm).
    pub r_load_ohm: f64,
    /// Supply voltage of the divider (V).
    pub supply_v: f64,
    /// ppm of gas per plume-model unit (units/m^2 of a 1 unit/s source).
    pub ppm_per_unit: f64,
    /// Clean-air background the sensor always sees (ppm).
    pub background_ppm: f64,
    /// Background noise (V).
    pub sigma_b: f64,
    /// Proportional noise (share of the output voltage).
    pub sigma_k: f64,
    /// Response (rising) time constant (s).
    pub tau_res_s: f64,
    /// Recovery (falling) time constant (s).
    pub tau_rec_s: f64,
}

impl MoxParams {
    /// The preset's hardware with the default electronics, noise and dynamics.
    pub fn for_preset(preset: SensorPreset) -> Self {
        let r0_ohm = match preset {
            SensorPreset::SensorI => 100e3,
            SensorPreset::Calibrated | SensorPreset::SensorII => 1500e3,
        };
        Self {
            k: -1.58,
            b: 0.17,
            r0_ohm,
            r_load_ohm: 100e3,
            supply_v: 5.0,
            ppm_per_unit: 100.0,
            background_ppm: 0.1,
            sigma_b: 0.01,
            sigma_k: 0.02,
            tau_res_s: 2.04,
            tau_rec_s: 4.57,
        }
    }

    /// The same sensor without noise.
    pub fn noise_free(self) -> Self {
        Self {
            sigma_b: 0.0,
            sigma_k: 0.0,
            ..self
        }
    }

    fn check(&self) -> Result<()> {
        let positive = [
            self.r0_ohm,
            self.r_load_ohm,
            self.supply_v,
            self.ppm_per_unit,
            self.background_ppm,
            self.tau_res_s,
            self.tau_rec_s,
        ];
        let ok = positive.iter().all(|v| v.is_finite() && *v > 0.0)
            && self.k.is_finite()
            && self.k != 0.0
            && self.b.is_finite()
            && [self.sigma_b, self.sigma_k]
                .iter()
                .all(|v| v.is_finite() && *v >= 0.0);
        if ok {
            Ok(())
        } else {
            Err(Error::Parameter(format!(
                "bad MOX sensor parameters {self:?}"
            )))
        }
    }

    /// The power of the gas that the sensor's conductance follows, `1/|k|` (with a load
    /// resistor small against the sensor's resistance, so does the divider's voltage): the
    /// exponent of [`crate::ste::SteParams::sensor_lag_exponent`] that lags the estimates in
    /// the sensor's response.
    pub fn response_exponent(&self) -> f64 {
        1.0 / self.k.abs()
    }

    /// Steady-state (nominal) output voltage for a plume concentration `c` (model units).
    pub fn steady_voltage(&self, c: f64) -> f64 {
        let g = self.background_ppm + self.ppm_per_unit * c.max(0.0);
        let rs = self.r0_ohm * (g / 10f64.powf(self.b)).powf(1.0 / self.k);
        self.supply_v * self.r_load_ohm / (self.r_load_ohm + rs)
    }

    /// Eq. 2 of the paper: gas concentration (ppm) from an output voltage with `[k, b, R0]`.
    /// The voltage is clamped into the divider's open range so noise cannot make it undefined.
    pub fn ppm_from_voltage(&self, v: f64) -> f64 {
        let eps = 1e-6 * self.supply_v;
        let v = v.clamp(eps, self.supply_v - eps);
        let ratio = self.r_load_ohm * (self.supply_v - v) / (self.r0_ohm * v);
        10f64.powf(self.b) * ratio.powf(self.k)
    }
}

/// A MOX sensor with its dynamic state and its read-out mode.
#[derive(Debug, Clone)]
pub struct MoxSensor {
    params: MoxParams,
    calibrated: bool,
    noise: Option<Normal<f64>>,
    voltage: f64,
}

impl MoxSensor {
    /// A sensor in clean-air equilibrium.
    ///
    /// # Errors
    /// [`Error::Parameter`] for non-finite or non-positive parameters.
    pub fn new(params: MoxParams, calibrated: bool) -> Result<Self> {
        params.check()?;
        let noise = (params.sigma_b > 0.0 || params.sigma_k > 0.0)
            .then(|| Normal::new(0.0, 1.0).expect("unit normal"));
        Ok(Self {
            voltage: params.steady_voltage(0.0),
            params,
            calibrated,
            noise,
        })
    }

    /// The preset's sensor, optionally without noise.
    ///
    /// # Errors
    /// As [`MoxSensor::new`].
    pub fn preset(preset: SensorPreset, noise: bool) -> Result<Self> {
        let params = MoxParams::for_preset(preset);
        let params = if noise { params } else { params.noise_free() };
        Self::new(params, preset == SensorPreset::Calibrated)
    }

    /// The model parameters.
    pub fn params(&self) -> &MoxParams {
        &self.params
    }

    /// Whether readings are converted to ppm.
    pub fn is_calibrated(&self) -> bool {
        self.calibrated
    }

    /// The noise-free output voltage (the dynamic state).
    pub fn voltage(&self) -> f64 {
        self.voltage
    }

    /// Exposes the sensor to concentration `c` (model units) for `dt` seconds and returns the
    /// reading at the end: volts, or ppm above clean air when calibrated.
    pub fn sample<R: Rng + ?Sized>(&mut self, c: f64, dt: f64, rng: &mut R) -> f64 {
        let target = self.params.steady_voltage(c);
        let tau = if target > self.voltage {
            self.params.tau_res_s
        } else {
            self.params.tau_rec_s
        };
        self.voltage += (target - self.voltage) * (1.0 - (-dt / tau).exp());
        let noisy = match &self.noise {
            Some(unit) => {
                let sigma = self.params.sigma_b + self.params.sigma_k * self.voltage.abs();
                self.voltage + sigma * unit.sample(rng)
            }
            None => self.voltage,
        };
        self.read(noisy)
    }

    /// Converts an output voltage into this sensor's reading.
    pub fn read(&self, v: f64) -> f64 {
        if self.calibrated {
            self.params.ppm_from_voltage(v) - self.params.background_ppm
        } else {
            v
        }
    }
}
