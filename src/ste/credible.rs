//! Credible regions of the posterior over the candidate cells, the posterior's expected
//! distance from its estimate, and, when the source is known, where the posterior placed it:
//! what every report states beside the estimate.
//!
//! A region at level `L` holds the most probable cells, in order, until their mass reaches
//! `L` (ties in the order of the candidates). The source's level is the mass of the cells
//! ranked before the source's own cell, so the region at `L` covers the source exactly when
//! that level is below `L`: over many runs of a calibrated posterior the levels are uniform on
//! `[0, 1)` when no cell holds much of the mass. A region holds at least its level, more by
//! its last cell's share ([`CredibleRegion::mass`]); over many runs of a calibrated posterior,
//! that mass, not the level, is the share of runs whose region holds the source, and the
//! source's level spread over its cell's mass (the nonrandomised probability integral
//! transform, [`SourceScore::pit`]) is uniform however sharp the posterior.

use serde::{Deserialize, Serialize};

/// The levels every report states: the 50% and 90% credible regions.
pub const REPORTED_LEVELS: [f64; 2] = [0.5, 0.9];

/// The smallest set of candidate cells holding at least `level` of the posterior.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CredibleRegion {
    /// The posterior mass asked for, in `(0, 1]`.
    pub level: f64,
    /// The cells' candidates (m), most probable first.
    pub cells: Vec<[f64; 2]>,
    /// The region's area (m^2): its cells times the candidates' cell area.
    pub area_m2: f64,
    /// The posterior mass the region holds: at least its level, more by its last cell's
    /// share. A calibrated posterior's regions hold the source in this share of runs, on
    /// average. `None` in a record without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// Whether the region holds the true source's cell, when the source is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covers_source: Option<bool>,
}

/// Where the posterior placed a known source.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct SourceScore {
    /// The source's cell: the candidate nearest the source (m), the most probable of them
    /// when the source lies on the border of several.
    pub cell: [f64; 2],
    /// The smallest credible level whose region holds that cell: the mass of the cells ranked
    /// before it (over runs of a calibrated posterior uniform on `[0, 1)` when no cell holds
    /// much of the mass; [`SourceScore::pit`] is uniform however sharp the posterior).
    pub level: f64,
    /// The natural logarithm of the posterior of that cell (negative infinity, written as
    /// `null`, for a cell the prior excluded).
    pub log_posterior: f64,
}

impl SourceScore {
    /// The nonrandomised probability integral transform at `u` in `[0, 1]` (Czado, Gneiting
    /// and Held 2009): the share of the source's cell that lies within the credible level
    /// `u`, its mass spread over the levels from [`SourceScore::level`] to the level plus
    /// the cell's posterior. Averaged over the runs of a calibrated posterior it is `u`,
    /// however much of the mass one cell holds.
    pub fn pit(&self, u: f64) -> f64 {
        pit(self.level, self.log_posterior, u)
    }
}

/// [`SourceScore::pit`] of a source whose cell has the level `level` and the log posterior
/// `log_posterior`: what a run record keeps of its score.
pub fn pit(level: f64, log_posterior: f64, u: f64) -> f64 {
    let mass = log_posterior.exp();
    match mass > 0.0 {
        true => ((u - level) / mass).clamp(0.0, 1.0),
        false => f64::from(u > level),
    }
}

/// The uncertainty of a posterior over candidate cells, as reports state it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Uncertainty {
    /// The credible regions at [`REPORTED_LEVELS`].
    pub regions: Vec<CredibleRegion>,
    /// The posterior's expected distance (m) from the estimate: how far off the estimate is
    /// by the posterior's own account.
    pub expected_distance_m: f64,
    /// Where the posterior placed the source, when it is known.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<SourceScore>,
}

impl Uncertainty {
    /// The uncertainty of `posterior` over `candidates` (a regular grid) with its estimate,
    /// scored against `source` when it is known.
    ///
    /// # Panics
    /// If `posterior` and `candidates` differ in length.
    pub fn of(
        candidates: &[[f64; 2]],
        posterior: &[f64],
        estimate: [f64; 2],
        source: Option<[f64; 2]>,
    ) -> Self {
        assert_eq!(
            candidates.len(),
            posterior.len(),
            "one probability a candidate"
        );
        let order = ranked(posterior);
        let cell_area = cell_area_m2(candidates);
        let score = source.and_then(|s| {
            let rank = source_rank(candidates, &order, s)?;
            let cell = order[rank];
            Some(SourceScore {
                cell: candidates[cell],
                level: order[..rank]
                    .iter()
                    .map(|&k| posterior[k])
                    .sum::<f64>()
                    .min(1.0),
                log_posterior: posterior[cell].ln(),
            })
        });
        let regions = REPORTED_LEVELS
            .iter()
            .map(|&level| {
                let (cells, mass) = region(&order, posterior, level);
                CredibleRegion {
                    level,
                    area_m2: cells.len() as f64 * cell_area,
                    mass: Some(mass.min(1.0)),
                    covers_source: score.map(|s| s.level < level),
                    cells: cells.iter().map(|&k| candidates[k]).collect(),
                }
            })
            .collect();
        let expected_distance_m = candidates
            .iter()
            .zip(posterior)
            .map(|(c, p)| p * (c[0] - estimate[0]).hypot(c[1] - estimate[1]))
            .sum();
        Self {
            regions,
            expected_distance_m,
            source: score,
        }
    }

    /// The region at `level`, if it is one of [`REPORTED_LEVELS`].
    pub fn region(&self, level: f64) -> Option<&CredibleRegion> {
        self.regions.iter().find(|r| r.level == level)
    }
}

/// Candidate indices, most probable first (ties in candidate order).
fn ranked(posterior: &[f64]) -> Vec<usize> {
    let mut order: Vec<usize> = (0..posterior.len()).collect();
    order.sort_by(|&a, &b| posterior[b].total_cmp(&posterior[a]));
    order
}

/// The first cells of `order` whose mass reaches `level`, with the mass they hold.
fn region(order: &[usize], posterior: &[f64], level: f64) -> (Vec<usize>, f64) {
    let mut total = 0.0;
    let mut out = Vec::new();
    for &k in order {
        if total >= level {
            break;
        }
        total += posterior[k];
        out.push(k);
    }
    (out, total)
}

/// Indices of the smallest set of candidates holding at least `level` of `posterior`, most
/// probable first.
pub fn credible_set(posterior: &[f64], level: f64) -> Vec<usize> {
    region(&ranked(posterior), posterior, level).0
}

/// The candidates (m) of the credible region at `level` of `posterior`, most probable first.
pub fn region_cells(candidates: &[[f64; 2]], posterior: &[f64], level: f64) -> Vec<[f64; 2]> {
    credible_set(posterior, level)
        .into_iter()
        .map(|k| candidates[k])
        .collect()
}

/// The rank in `order` of the source's cell: the candidate nearest `point`, or, when the
/// point lies on the border of several cells (equally near, within a micrometre), the most
/// probable of them. `None` without candidates.
fn source_rank(candidates: &[[f64; 2]], order: &[usize], point: [f64; 2]) -> Option<usize> {
    let d = |k: usize| (candidates[k][0] - point[0]).hypot(candidates[k][1] - point[1]);
    let nearest = (0..candidates.len()).map(d).min_by(f64::total_cmp)?;
    order.iter().position(|&k| d(k) <= nearest + 1e-6)
}

/// The area (m^2) of one cell of the candidates' grid: the smallest gaps between distinct x
/// and between distinct y coordinates multiplied (a single row or column takes its one gap
/// for both; a single candidate has no area).
pub fn cell_area_m2(candidates: &[[f64; 2]]) -> f64 {
    let gap = |axis: usize| {
        let mut v: Vec<f64> = candidates.iter().map(|c| c[axis]).collect();
        v.sort_by(f64::total_cmp);
        v.windows(2)
            .map(|w| w[1] - w[0])
            .filter(|&d| d > 1e-9)
            .min_by(f64::total_cmp)
    };
    match (gap(0), gap(1)) {
        (Some(dx), Some(dy)) => dx * dy,
        (Some(d), None) | (None, Some(d)) => d * d,
        (None, None) => 0.0,
    }
}

/// The outline of a region of grid cells of side `spacing_m` centred on `cells`: the cell
/// sides that no other cell of the region shares, as segments `[from, to]` (m).
pub fn outline(cells: &[[f64; 2]], spacing_m: f64) -> Vec<[[f64; 2]; 2]> {
    let Some(&[x0, y0]) = cells.first() else {
        return Vec::new();
    };
    let key = |[x, y]: [f64; 2]| {
        (
            ((x - x0) / spacing_m).round() as i64,
            ((y - y0) / spacing_m).round() as i64,
        )
    };
    let inside: std::collections::HashSet<(i64, i64)> = cells.iter().map(|&c| key(c)).collect();
    let h = 0.5 * spacing_m;
    let mut out = Vec::new();
    for &[x, y] in cells {
        let (i, j) = key([x, y]);
        let sides = [
            ((i - 1, j), [[x - h, y - h], [x - h, y + h]]),
            ((i + 1, j), [[x + h, y - h], [x + h, y + h]]),
            ((i, j - 1), [[x - h, y - h], [x + h, y - h]]),
            ((i, j + 1), [[x - h, y + h], [x + h, y + h]]),
        ];
        for (neighbour, side) in sides {
            if !inside.contains(&neighbour) {
                out.push(side);
            }
        }
    }
    out
}
