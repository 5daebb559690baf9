//! When a run stops: the belief concentrated (its entropy and credible set, or the credible
//! region's area) and stable, or the iteration budget spent.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::ste::credible;
use crate::ste::params::SteParams;
use crate::ste::posterior::Estimator;
use crate::ste::robot::check_metres;

/// The free floor (m^2) up to which [`Termination::max_iterations`] holds as it is: the paper
/// arena's whole floor.
const BUDGET_AREA_M2: f64 = 72.0;

/// When a run stops.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Termination {
    /// Posterior entropy (nats) below which the belief counts as concentrated.
    pub entropy_nats: f64,
    /// Mass of the credible set that must be confined.
    pub mass: f64,
    /// Every cell of that credible set lies within this distance of the MAP cell (m).
    pub radius_m: f64,
    /// Hard limit on iterations (the paper's 30 in simulation), in a room of at most
    /// `BUDGET_AREA_M2` of free floor when it grows with the room.
    pub max_iterations: usize,
    /// The limit grows with the square root of the room's free floor beyond
    /// `BUDGET_AREA_M2` ([`Termination::budget`]): a larger room needs more legs to explore.
    /// A record without this field reads as `false`, the fixed limit.
    #[serde(default)]
    pub grow_with_room: bool,
    /// The belief must have been concentrated, with the MAP cell within `radius_m` of the
    /// current one, for this many consecutive iterations (1 = the paper's rule alone).
    pub stable_iterations: usize,
    /// When set, the belief counts as concentrated when the credible region of `mass` covers
    /// at most this area (m^2), instead of the entropy and radius rule. `None` (what a record
    /// without this field reads as) keeps the entropy and radius rule.
    #[serde(default)]
    pub target_area_m2: Option<f64>,
    /// With a target area, the credible region must also lie within this distance (m) of the
    /// MAP cell: two small, distant modes can fit within the area together, and a run that
    /// stopped on them would be right only when the right mode wins. `None` (what a record
    /// without this field reads as) checks the area alone.
    #[serde(default)]
    pub region_radius_m: Option<f64>,
    /// When set, the belief counts as concentrated only once the readings hold a plume that
    /// the estimate explains: their highest stands at least [`PLUME_SIGNAL_NOISES`] noise
    /// levels above their median ([`Estimator::plume_signal`]), and the estimate's plume
    /// reaches at least one reading that high ([`Estimator::reaches_plume`]). Readings of
    /// clean air alone say where the source is not, never where it is, so a run that has met
    /// no gas keeps exploring, and so does one whose estimate could not have made the gas it
    /// met. `false` (what a record without this field reads as) stops without it.
    #[serde(default)]
    pub require_plume: bool,
    /// When set, a run whose belief meets the rest of the rule stops only once the robot has
    /// sensed this far (m) upwind of the estimate ([`crate::ste::probe`]); until then its next
    /// leg goes there. `None` (what a record without this field reads as) stops without it.
    #[serde(default)]
    pub upwind_probe_m: Option<f64>,
}

/// Noise levels above the readings' median that the highest reading must reach before a run
/// with [`Termination::require_plume`] may stop. The simulated sensors' noise alone stays
/// within a few levels in thousands of readings (tested); a plume the robot met stands tens of
/// levels above.
pub const PLUME_SIGNAL_NOISES: f64 = 8.0;

impl Default for Termination {
    fn default() -> Self {
        Self {
            entropy_nats: 1.5,
            mass: 0.9,
            radius_m: 0.75,
            max_iterations: 30,
            grow_with_room: true,
            stable_iterations: 2,
            target_area_m2: None,
            region_radius_m: None,
            require_plume: false,
            upwind_probe_m: None,
        }
    }
}

/// The default target area of the 90% credible region (m^2) for a tempered likelihood.
pub const TARGET_AREA_M2: f64 = 1.0;

/// The default [`Termination::region_radius_m`] for a tempered likelihood (m): where the
/// calibration benchmark counts a converged run as wrong, so that a run stopped on a region
/// within it is that far off only when the source lies outside its region altogether.
pub const REGION_RADIUS_M: f64 = 1.5;

impl Termination {
    /// The rule that goes with the estimator's settings: a tempered likelihood
    /// ([`SteParams::evidence_weight`] below 1), whose credible regions are calibrated, stops
    /// when its 90% region covers at most [`TARGET_AREA_M2`] and the readings hold a plume
    /// that the estimate's reaches; readings taken as independent (whose regions are
    /// over-confident) stop on the entropy rule alone, as the paper's.
    pub fn for_params(params: &SteParams) -> Self {
        let tempered = params.tempered();
        Self {
            target_area_m2: tempered.then_some(TARGET_AREA_M2),
            region_radius_m: tempered.then_some(REGION_RADIUS_M),
            require_plume: tempered,
            ..Self::default()
        }
    }

    /// Whether the belief is concentrated: the credible region within the target area when
    /// one is set, and all of it within `region_radius_m` of the MAP cell when that is set;
    /// else entropy below the threshold and the credible set confined within `radius_m` of
    /// the MAP cell; never before the readings hold a plume that the estimate's plume reaches
    /// when that is required.
    pub fn concentrated(&self, est: &Estimator) -> bool {
        // A reading that the estimate's plume reaches, that high, is a plume signal that high.
        if est.is_empty() || self.require_plume && !est.reaches_plume(PLUME_SIGNAL_NOISES) {
            return false;
        }
        if let Some(target) = self.target_area_m2 {
            let cells = est.credible_set(self.mass);
            let area = cells.len() as f64 * credible::cell_area_m2(est.candidates());
            return area <= target && self.region_radius_m.is_none_or(|r| within(est, &cells, r));
        }
        est.entropy() < self.entropy_nats
            && within(est, &est.credible_set(self.mass), self.radius_m)
    }

    /// The iteration limit in a room with `free_area_m2` of free floor:
    /// [`Termination::max_iterations`], times `sqrt(free_area_m2 / BUDGET_AREA_M2)` in a larger
    /// room when the limit grows with the room.
    pub fn budget(&self, free_area_m2: f64) -> usize {
        let scale = (free_area_m2 / BUDGET_AREA_M2).sqrt();
        if self.grow_with_room && scale > 1.0 {
            (self.max_iterations as f64 * scale).ceil() as usize
        } else {
            self.max_iterations
        }
    }

    /// Checks the rule for a room of `area_m2` square metres.
    ///
    /// # Errors
    /// [`Error::Parameter`] for a target area that is not positive or larger than the room,
    /// a region radius that is not positive, or an upwind probe distance that is negative.
    pub fn check(&self, area_m2: f64) -> Result<()> {
        if let Some(d) = self.upwind_probe_m {
            check_upwind_probe(d)?;
        }
        if let Some(r) = self
            .region_radius_m
            .filter(|r| !(r.is_finite() && *r > 0.0))
        {
            return Err(Error::Parameter(format!(
                "the region radius must be a positive number of metres, got {r}"
            )));
        }
        match self.target_area_m2 {
            Some(a) if !(a.is_finite() && a > 0.0 && a <= area_m2) => {
                Err(Error::Parameter(format!(
                    "the target area must be a positive number of square metres no larger than the room's {area_m2:.1}, got {a}"
                )))
            }
            _ => Ok(()),
        }
    }

    /// Whether to stop: the belief is concentrated and `recent` (whether it was concentrated,
    /// and the MAP estimate, at each earlier iteration, oldest first) shows it concentrated
    /// around the same place for the last `stable_iterations` iterations, this one included.
    pub fn converged(&self, est: &Estimator, recent: &[(bool, [f64; 2])]) -> bool {
        if !self.concentrated(est) {
            return false;
        }
        let need = self.stable_iterations.saturating_sub(1);
        let [mx, my] = est.estimate();
        recent.len() >= need
            && recent[recent.len() - need..]
                .iter()
                .all(|&(c, [x, y])| c && (x - mx).hypot(y - my) <= self.radius_m)
    }
}

/// Checks an upwind probe distance ([`Termination::upwind_probe_m`]): a finite number of metres,
/// zero (no probe) or more.
///
/// # Errors
/// [`Error::Parameter`] naming the value otherwise.
pub fn check_upwind_probe(m: f64) -> Result<()> {
    check_metres("upwind probe", m)
}

/// Whether every candidate of `cells` lies within `radius_m` of the MAP cell.
fn within(est: &Estimator, cells: &[usize], radius_m: f64) -> bool {
    let [mx, my] = est.estimate();
    cells.iter().all(|&k| {
        let [x, y] = est.candidates()[k];
        (x - mx).hypot(y - my) <= radius_m
    })
}
