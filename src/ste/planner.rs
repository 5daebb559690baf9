//! Informative path planning: where the robot drives next.
//!
//! Both planners score goals by the **expected information gain** of what the robot would sense
//! on the way, computed the same way:
//!
//! 1. Hypotheses: `M` = 64 candidates drawn from the posterior (seeded; duplicates merged, so
//!    the weights are the draw counts / `M`). This works for a flat early posterior as well as
//!    a peaked late one.
//! 2. Predicted observations: at each point `q` of a path (every 0.5 m, at most 40 points), the
//!    plume bank gives every hypothesis's concentration; it is observed as
//!    `y = ln(1 + c / 0.01)` (the feature-agnostic log scale the surrogate is trained on) with
//!    Gaussian noise `sigma = 0.5`, each point's evidence weighed by the estimator's
//!    [`SteParams::evidence_weight`](crate::ste::params::SteParams::evidence_weight) `W` as
//!    the likelihood weighs each reading's. Counted in full under a tempered likelihood, a few
//!    metres near the estimate would seem to refute every other hypothesis that the posterior
//!    in fact keeps, and the robot would circle the estimate while far mass stays. With a
//!    revisit radius ([`RobotParams::revisit_radius_m`]) a point weighs `1 / (1 + n)` of that,
//!    where `n` passes' readings already lie within the radius.
//! 3. Gain: `H(w) - sum_k w_k H(w | y = y_k)`, where `w | y_k` is the hypothesis posterior had
//!    the source been hypothesis `k` (noise-free predictions), i.e. the mutual information
//!    between the source and the path's observations, approximated on the hypotheses.
//!
//! **Belief clustering** (the paper's planner, after Jin et al. 2024; no public description
//! exists, so this is what we built from the paper's words): the cells of the 90% credible set
//! are clustered by probability-weighted k-means (k = 4, k-means++ start, seeded; clusters whose
//! centroids are within 1 m are merged). Around every cluster centroid the goals are the
//! centroid itself, points 1 and 2 m upwind and downwind, 1 m to either side, and 1 m downwind
//! to either side, plus 8 random free points for exploration. (The upwind goals are ours: a
//! path upwind of a cluster crosses the clean air a true source leaves there, the cheapest way
//! to refute a cluster that formed far downwind of the real source.) Each goal gets an A*
//! path; its score is the expected gain of sensing along the **whole path** divided by the path
//! length plus a fixed cost of 2 m per iteration. The best goal wins; goals closer than 1 m to
//! the robot are skipped.
//!
//! **Baseline** (after the authors' released controller: a blend of information gain and a
//! marginal-distance goal): goals on a 1 m lattice of free points; score = gain of a single
//! observation **at the goal** (normalised by the best goal's) minus 0.5 x the distance from
//! the goal to the posterior's marginal mean `(E[x], E[y])` (normalised by the largest such
//! distance). The robot still senses along the A* path to it.

use std::collections::HashMap;

use rand::SeedableRng;
use rand::distr::{Distribution, weighted::WeightedIndex};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::ste::posterior::{Estimator, entropy, normalise};
use crate::ste::robot::{Occupancy, RobotParams, path_length, point_at};
use crate::ste::sampler::FieldSampler;

/// Which planner chooses the goals.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PlannerKind {
    /// Clusters of high belief, goal with the best expected gain per metre of path.
    BeliefClustering,
    /// Single-point gain blended with the distance to the marginal estimate.
    Baseline,
}

impl PlannerKind {
    /// The name used on the command line and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Self::BeliefClustering => "belief-clustering",
            Self::Baseline => "baseline",
        }
    }
}

const HYPOTHESES: usize = 64;
const OBS_SIGMA: f64 = 0.5;
const OBS_REF: f64 = 0.01;
const PATH_STEP_M: f64 = 0.5;
const MAX_PATH_POINTS: usize = 40;
const CLUSTERS: usize = 4;
const CREDIBLE_MASS: f64 = 0.9;
const MERGE_M: f64 = 1.0;
const EXPLORE_GOALS: usize = 8;
const MIN_GOAL_M: f64 = 1.0;
const LATTICE_M: f64 = 1.0;
const DISTANCE_WEIGHT: f64 = 0.5;
/// Goals around a centroid, `[downwind, across]` in metres (turned by the wind's direction).
const GOAL_OFFSETS: [[f64; 2]; 9] = [
    [0.0, 0.0],
    [-1.0, 0.0],
    [-2.0, 0.0],
    [1.0, 0.0],
    [2.0, 0.0],
    [0.0, 1.0],
    [0.0, -1.0],
    [1.0, 1.0],
    [1.0, -1.0],
];

/// The next goal and the path to it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// Goal position (m).
    pub goal: [f64; 2],
    /// Obstacle-free polyline from the robot to the goal.
    pub path: Vec<[f64; 2]>,
    /// The planner's score of the chosen goal.
    pub score: f64,
}

/// A seeded planner.
#[derive(Debug, Clone)]
pub struct Planner {
    kind: PlannerKind,
    leg_cost_m: f64,
    revisit: Revisit,
    rng: ChaCha8Rng,
}

/// How much less a predicted point tells where the robot has sensed before
/// ([`RobotParams::revisit_radius_m`]).
#[derive(Debug, Clone, Copy)]
struct Revisit {
    /// The radius within which past readings count (m); 0 counts none.
    radius_m: f64,
    /// The readings one pass leaves within the radius.
    pass_readings: f64,
}

impl Revisit {
    fn new(robot: &RobotParams) -> Self {
        Self {
            radius_m: robot.revisit_radius_m,
            pass_readings: 2.0 * robot.revisit_radius_m * robot.readings_per_m(),
        }
    }

    /// The grid cell, as wide as the radius, that holds `p`: every reading within the radius
    /// of a point lies in the point's cell or one of its eight neighbours.
    fn cell(&self, p: [f64; 2]) -> [i64; 2] {
        p.map(|x| (x / self.radius_m).floor() as i64)
    }
}

/// The readings already taken, binned on a grid whose cells are the revisit radius wide, so
/// that counting those near a point looks in the nine cells around it instead of at every
/// reading of the run.
struct Sensed {
    revisit: Revisit,
    cells: HashMap<[i64; 2], Vec<[f64; 2]>>,
}

impl Sensed {
    /// Bins the positions of the readings taken (`past`); none without a radius.
    fn new(revisit: Revisit, past: &[[f64; 2]]) -> Self {
        let mut cells: HashMap<[i64; 2], Vec<[f64; 2]>> = HashMap::new();
        if revisit.radius_m > 0.0 {
            for &p in past {
                cells.entry(revisit.cell(p)).or_default().push(p);
            }
        }
        Self { revisit, cells }
    }

    /// The readings taken within the radius of `q`.
    fn near(&self, q: [f64; 2]) -> usize {
        // The cells beside it, saturating where a radius too small for the room's extent in
        // cells puts the point in the grid's last cell.
        let around = |k: i64| k.saturating_sub(1)..=k.saturating_add(1);
        let [i, j] = self.revisit.cell(q);
        let r = self.revisit.radius_m;
        around(i)
            .flat_map(|a| around(j).map(move |b| [a, b]))
            .filter_map(|c| self.cells.get(&c))
            .flatten()
            .filter(|p| (p[0] - q[0]).hypot(p[1] - q[1]) < r)
            .count()
    }

    /// Each point's share of a fresh point's evidence: `1 / (1 + n / n1)`, with `n` the
    /// readings taken within the radius and `n1` one pass's; 1 everywhere without a radius.
    fn shares(&self, points: &[[f64; 2]]) -> Vec<f64> {
        if self.revisit.radius_m <= 0.0 {
            return vec![1.0; points.len()];
        }
        points
            .iter()
            .map(|&q| 1.0 / (1.0 + self.near(q) as f64 / self.revisit.pass_readings))
            .collect()
    }
}

/// Weighted source hypotheses drawn from the posterior.
struct Hypotheses {
    index: Vec<usize>,
    weight: Vec<f64>,
}

impl Planner {
    /// A planner for `robot`, which counts its [`RobotParams::leg_cost_m`] metres of driving
    /// for each leg and discounts points within its [`RobotParams::revisit_radius_m`] of
    /// readings already taken, and whose random choices come from `seed`.
    pub fn new(kind: PlannerKind, robot: &RobotParams, seed: u64) -> Self {
        Self {
            kind,
            leg_cost_m: robot.leg_cost_m,
            revisit: Revisit::new(robot),
            rng: ChaCha8Rng::seed_from_u64(seed),
        }
    }

    /// Chooses the next goal from the current belief.
    ///
    /// # Errors
    /// [`Error::Parameter`] when no goal is reachable from `position`.
    pub fn next(
        &mut self,
        est: &Estimator,
        occupancy: &Occupancy,
        position: [f64; 2],
    ) -> Result<Plan> {
        let hyp = self.hypotheses(est.posterior())?;
        match self.kind {
            PlannerKind::BeliefClustering => {
                let goals = self.cluster_goals(est, occupancy);
                let leg = Leg {
                    weight: est.params().evidence_weight,
                    cost_m: self.leg_cost_m,
                    sensed: Sensed::new(self.revisit, est.positions()),
                };
                best_by_path_gain(&hyp, est.sampler(), occupancy, position, &goals, &leg)
            }
            PlannerKind::Baseline => baseline(&hyp, est, occupancy, position),
        }
        .ok_or_else(|| {
            Error::Parameter(format!(
                "no reachable goal from ({:.2}, {:.2})",
                position[0], position[1]
            ))
        })
    }

    fn hypotheses(&mut self, posterior: &[f64]) -> Result<Hypotheses> {
        let dist = WeightedIndex::new(posterior)
            .map_err(|e| Error::Parameter(format!("posterior cannot be sampled: {e}")))?;
        let mut counts = std::collections::BTreeMap::new();
        for _ in 0..HYPOTHESES {
            *counts.entry(dist.sample(&mut self.rng)).or_insert(0usize) += 1;
        }
        Ok(Hypotheses {
            index: counts.keys().copied().collect(),
            weight: counts
                .values()
                .map(|&c| c as f64 / HYPOTHESES as f64)
                .collect(),
        })
    }

    /// Goals around the centroids of the clustered credible set, plus exploration goals.
    fn cluster_goals(&mut self, est: &Estimator, occupancy: &Occupancy) -> Vec<[f64; 2]> {
        let cells = est.credible_set(CREDIBLE_MASS);
        let pts: Vec<([f64; 2], f64)> = cells
            .iter()
            .map(|&k| (est.candidates()[k], est.posterior()[k]))
            .collect();
        let centroids = self.kmeans(&pts);
        let layout = est.sampler().layout();
        let [dx, dy] = layout.wind_from().downwind();
        let mut goals: Vec<[f64; 2]> = centroids
            .iter()
            .flat_map(|c| {
                GOAL_OFFSETS
                    .iter()
                    .map(move |[a, b]| [c[0] + a * dx - b * dy, c[1] + a * dy + b * dx])
            })
            .collect();
        for _ in 0..EXPLORE_GOALS {
            let x = rand::RngExt::random_range(&mut self.rng, 0.0..layout.width());
            let y = rand::RngExt::random_range(&mut self.rng, 0.0..layout.height());
            goals.push([x, y]);
        }
        goals
            .into_iter()
            .map(|p| occupancy.free_or_nearest(p))
            .collect()
    }

    /// Probability-weighted k-means with a seeded k-means++ start; merged centroids.
    fn kmeans(&mut self, pts: &[([f64; 2], f64)]) -> Vec<[f64; 2]> {
        let k = CLUSTERS.min(pts.len());
        let mut centres: Vec<[f64; 2]> = Vec::with_capacity(k);
        while centres.len() < k {
            let d2: Vec<f64> = pts
                .iter()
                .map(|(p, w)| {
                    w * centres
                        .iter()
                        .map(|c| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2))
                        .fold(1.0, f64::min)
                })
                .collect();
            let Ok(pick) = WeightedIndex::new(&d2) else {
                break;
            };
            centres.push(pts[pick.sample(&mut self.rng)].0);
        }
        let mut mass = vec![0.0; centres.len()];
        for _ in 0..20 {
            let mut sum = vec![[0.0, 0.0]; centres.len()];
            mass.fill(0.0);
            for (p, w) in pts {
                let c = nearest(&centres, *p);
                sum[c][0] += w * p[0];
                sum[c][1] += w * p[1];
                mass[c] += w;
            }
            for (c, (s, m)) in centres.iter_mut().zip(sum.iter().zip(&mass)) {
                if *m > 0.0 {
                    *c = [s[0] / m, s[1] / m];
                }
            }
        }
        let mut order: Vec<usize> = (0..centres.len()).collect();
        order.sort_by(|&a, &b| mass[b].total_cmp(&mass[a]));
        let mut kept: Vec<[f64; 2]> = Vec::new();
        for c in order.into_iter().map(|i| centres[i]) {
            if kept
                .iter()
                .all(|k| (k[0] - c[0]).hypot(k[1] - c[1]) > MERGE_M)
            {
                kept.push(c);
            }
        }
        kept
    }
}

fn nearest(centres: &[[f64; 2]], p: [f64; 2]) -> usize {
    let d = |c: &[f64; 2]| (p[0] - c[0]).powi(2) + (p[1] - c[1]).powi(2);
    (0..centres.len())
        .min_by(|&a, &b| d(&centres[a]).total_cmp(&d(&centres[b])))
        .unwrap_or(0)
}

/// Expected information gain of observing the hypotheses' log concentrations at `points`,
/// each observation's log-likelihood weighed by `weight` (the evidence weight) times its
/// share of a fresh point's evidence (`shares`, one per point).
fn expected_gain(
    hyp: &Hypotheses,
    sampler: &FieldSampler,
    points: &[[f64; 2]],
    shares: &[f64],
    weight: f64,
) -> f64 {
    let m = hyp.index.len();
    let mut row = vec![0.0f32; sampler.len()];
    let mut dist2 = vec![0.0f64; m * m];
    let mut y = vec![0.0f64; m];
    for (q, share) in points.iter().zip(shares) {
        sampler.gather(q[0], q[1], 1.0, &mut row);
        for (ya, &a) in y.iter_mut().zip(&hyp.index) {
            *ya = (f64::from(row[a]) / OBS_REF).ln_1p();
        }
        for a in 0..m {
            for b in 0..m {
                let d = y[a] - y[b];
                dist2[a * m + b] += share * d * d;
            }
        }
    }
    let prior_h = entropy(&hyp.weight);
    let scale = 0.5 * weight / (OBS_SIGMA * OBS_SIGMA);
    let expected_h: f64 = (0..m)
        .map(|k| {
            let log_w: Vec<f64> = (0..m)
                .map(|j| hyp.weight[j].ln() - scale * dist2[j * m + k])
                .collect();
            hyp.weight[k] * entropy(&normalise(&log_w))
        })
        .sum();
    (prior_h - expected_h).max(0.0)
}

/// Points every 0.5 m along a path (after its start), at most 40, the goal included.
fn path_points(path: &[[f64; 2]]) -> Vec<[f64; 2]> {
    let len = path_length(path);
    let n = ((len / PATH_STEP_M).ceil() as usize).clamp(1, MAX_PATH_POINTS);
    (1..=n)
        .map(|k| point_at(path, len * k as f64 / n as f64))
        .collect()
}

fn far_enough(position: [f64; 2], goal: [f64; 2]) -> bool {
    (goal[0] - position[0]).hypot(goal[1] - position[1]) >= MIN_GOAL_M
}

/// How a leg is scored: the evidence weight of its predicted points, what one more leg
/// costs, and the discount of points near the readings already taken.
struct Leg {
    weight: f64,
    cost_m: f64,
    sensed: Sensed,
}

/// The goal whose path gains the most expected information per metre, each leg counting
/// `leg.cost_m` metres more than its length.
fn best_by_path_gain(
    hyp: &Hypotheses,
    sampler: &FieldSampler,
    occupancy: &Occupancy,
    position: [f64; 2],
    goals: &[[f64; 2]],
    leg: &Leg,
) -> Option<Plan> {
    goals
        .iter()
        .filter(|&&g| far_enough(position, g))
        .filter_map(|&goal| {
            let path = occupancy.plan(position, goal)?;
            let points = path_points(&path);
            let shares = leg.sensed.shares(&points);
            let gain = expected_gain(hyp, sampler, &points, &shares, leg.weight);
            let score = gain / (path_length(&path) + leg.cost_m);
            Some(Plan { goal, path, score })
        })
        .fold(None, |best: Option<Plan>, p| match best {
            Some(b) if b.score >= p.score => Some(b),
            _ => Some(p),
        })
}

/// The baseline: single-point gain at lattice goals blended with the marginal distance.
fn baseline(
    hyp: &Hypotheses,
    est: &Estimator,
    occupancy: &Occupancy,
    position: [f64; 2],
) -> Option<Plan> {
    let layout = est.sampler().layout();
    let (mx, my) = est
        .candidates()
        .iter()
        .zip(est.posterior())
        .fold((0.0, 0.0), |(sx, sy), (c, p)| {
            (sx + p * c[0], sy + p * c[1])
        });
    let nx = (layout.width() / LATTICE_M).round() as usize;
    let ny = (layout.height() / LATTICE_M).round() as usize;
    let goals: Vec<[f64; 2]> = (0..ny)
        .flat_map(|j| {
            (0..nx).map(move |i| [(i as f64 + 0.5) * LATTICE_M, (j as f64 + 0.5) * LATTICE_M])
        })
        .map(|p| occupancy.free_or_nearest(p))
        .filter(|&g| far_enough(position, g))
        .collect();
    let gains: Vec<f64> = goals
        .iter()
        .map(|&g| {
            expected_gain(
                hyp,
                est.sampler(),
                &[g],
                &[1.0],
                est.params().evidence_weight,
            )
        })
        .collect();
    let dists: Vec<f64> = goals.iter().map(|g| (g[0] - mx).hypot(g[1] - my)).collect();
    let top_gain = gains.iter().copied().fold(0.0, f64::max).max(1e-12);
    let top_dist = dists.iter().copied().fold(0.0, f64::max).max(1e-12);
    let mut order: Vec<(f64, [f64; 2])> = goals
        .iter()
        .zip(gains.iter().zip(&dists))
        .map(|(&g, (gain, d))| (gain / top_gain - DISTANCE_WEIGHT * d / top_dist, g))
        .collect();
    order.sort_by(|a, b| b.0.total_cmp(&a.0));
    order.into_iter().find_map(|(score, goal)| {
        occupancy
            .plan(position, goal)
            .map(|path| Plan { goal, path, score })
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::layout::Layout;
    use crate::plume::{PhysicsSolver, PlumeModel};
    use rand::RngExt;

    /// A 4 m wide room `height_m` deep with the wind from the west, three sources at
    /// `x = 0.5` m and `ys`, and hypotheses of them weighing `weights`.
    fn three_sources(
        height_m: f64,
        ys: [f64; 3],
        weights: [f64; 3],
    ) -> (Layout, FieldSampler, Hypotheses) {
        let layout = Layout::from_json(&format!(
            r#"{{"width_m":4,"height_m":{height_m},"cell_m":0.125,"wind":{{"speed_mps":0.75}}}}"#
        ))
        .unwrap();
        let candidates = ys.map(|y| [0.5, y]);
        let bank = PhysicsSolver.bank(&layout, &candidates).unwrap();
        let sampler = FieldSampler::new(&layout, &bank).unwrap();
        let hyp = Hypotheses {
            index: vec![0, 1, 2],
            weight: weights.to_vec(),
        };
        (layout, sampler, hyp)
    }

    /// Every point a fresh point's share of the evidence.
    fn fresh(points: &[[f64; 2]]) -> Vec<f64> {
        vec![1.0; points.len()]
    }

    /// A point where the robot has sensed before tells less: where one pass's readings lie
    /// within the revisit radius it weighs half a fresh point, where three passes' a quarter,
    /// and readings beyond the radius, or no radius, leave it whole. Its share is what a
    /// fresh point at that fraction of the weight gains, and the path's gain falls with it.
    #[test]
    fn ground_already_sensed_tells_less() {
        let (_, sampler, hyp) = three_sources(2.0, [0.5, 1.0, 1.5], [0.5, 0.25, 0.25]);
        let robot = RobotParams {
            revisit_radius_m: 0.5,
            ..RobotParams::default()
        };
        let revisit = Revisit::new(&robot);
        // One pass along x at full speed leaves a reading every 0.027 m.
        let step = robot.max_speed_mps * robot.tick_s;
        let pass = |y: f64, times: usize| -> Vec<[f64; 2]> {
            (0..times)
                .flat_map(|_| (0..=150).map(move |k| [k as f64 * step, y]))
                .collect()
        };
        let point = [[2.0, 0.5]];
        let share = |past: &[[f64; 2]]| Sensed::new(revisit, past).shares(&point)[0];
        // The readings within 0.5 m of the point: 37 of one pass, one pass's worth.
        assert!(
            (share(&pass(0.5, 1)) - 0.5).abs() < 0.02,
            "{}",
            share(&pass(0.5, 1))
        );
        assert!((share(&pass(0.5, 3)) - 0.25).abs() < 0.01);
        assert_eq!(share(&pass(1.5, 3)), 1.0);
        assert_eq!(share(&[]), 1.0);
        let none = Revisit::new(&RobotParams::default());
        assert_eq!(Sensed::new(none, &pass(0.5, 3)).shares(&point), vec![1.0]);
        let weight = 0.2;
        let s = share(&pass(0.5, 1));
        let discounted = expected_gain(&hyp, &sampler, &point, &[s], weight);
        let at_fraction = expected_gain(&hyp, &sampler, &point, &[1.0], weight * s);
        assert!((discounted - at_fraction).abs() <= 1e-12 * at_fraction);
        let whole = expected_gain(&hyp, &sampler, &point, &[1.0], weight);
        assert!(
            discounted > 0.0 && discounted < whole * (1.0 - 1e-6),
            "{discounted} {whole}"
        );
    }

    /// The binned readings count, around every point, exactly the readings a look at each
    /// reading finds within the radius: points and readings on both sides of zero, on cell
    /// edges and at the radius's distance.
    #[test]
    fn binned_readings_count_what_a_look_at_each_finds() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        for radius_m in [0.25, 0.5, 1.3] {
            let revisit = Revisit::new(&RobotParams {
                revisit_radius_m: radius_m,
                ..RobotParams::default()
            });
            let mut past: Vec<[f64; 2]> = (0..400)
                .map(|_| [rng.random_range(-3.0..5.0), rng.random_range(-2.0..4.0)])
                .collect();
            past.extend((-8..8).map(|k| [k as f64 * radius_m, radius_m]));
            let mut points: Vec<[f64; 2]> = (0..300)
                .map(|_| [rng.random_range(-4.0..6.0), rng.random_range(-3.0..5.0)])
                .collect();
            points.extend((-8..8).map(|k| [k as f64 * radius_m, 0.0]));
            let sensed = Sensed::new(revisit, &past);
            let mut some = 0;
            for &q in &points {
                let brute = past
                    .iter()
                    .filter(|p| (p[0] - q[0]).hypot(p[1] - q[1]) < radius_m)
                    .count();
                assert_eq!(sensed.near(q), brute, "radius {radius_m}, point {q:?}");
                some += usize::from(brute > 0);
            }
            assert!(some > points.len() / 4, "radius {radius_m}: {some}");
        }
        // A radius so small that the room spans more cells than an i64 counts: every point
        // lies in the grid's last cell, and the readings at a point's own position still count.
        let tiny = Revisit::new(&RobotParams {
            revisit_radius_m: 1e-300,
            ..RobotParams::default()
        });
        let sensed = Sensed::new(tiny, &[[1.0, 2.0], [1.0, 2.0], [3.0, 4.0]]);
        assert_eq!(sensed.near([1.0, 2.0]), 2);
        assert_eq!(sensed.near([3.0, 4.0]), 1);
        assert_eq!(sensed.near([2.0, 2.0]), 0);
    }

    /// Each observation's evidence weighs `weight`: a path sensed once at a weight gains what
    /// the same path sensed twice at half of it gains (the log-likelihoods add), and without
    /// the weight the twice-sensed path would gain more. Three sources side by side in a small
    /// room, and two points downwind of them where their plumes overlap (so that no weight
    /// tells the three apart for sure).
    #[test]
    fn each_observation_weighs_the_evidence_weight() {
        let (_, sampler, hyp) = three_sources(2.0, [0.5, 1.0, 1.5], [0.5, 0.25, 0.25]);
        let path = [[2.0, 0.5], [3.0, 0.5]];
        let twice: Vec<[f64; 2]> = path.iter().flat_map(|&p| [p, p]).collect();
        for weight in [1.0, 0.2, 0.01] {
            let once = expected_gain(&hyp, &sampler, &path, &fresh(&path), weight);
            let halves = expected_gain(&hyp, &sampler, &twice, &fresh(&twice), weight / 2.0);
            assert!(
                once > 1e-4 && once < 0.9 * entropy(&hyp.weight),
                "{weight}: {once}"
            );
            assert!(
                (once - halves).abs() < 1e-9 * once,
                "{weight}: {once} {halves}"
            );
            assert!(
                expected_gain(&hyp, &sampler, &twice, &fresh(&twice), weight) > once * (1.0 + 1e-6)
            );
        }
        // A weaker weight gains less from the same path here, and nothing from none.
        let gain = |w: f64| expected_gain(&hyp, &sampler, &path, &fresh(&path), w);
        assert!(gain(0.01) < gain(0.2) && gain(0.2) < gain(1.0));
        assert_eq!(gain(0.0), 0.0);
    }

    /// Each leg counts its length plus the leg cost: without a cost the planner takes the
    /// goal of most gain per metre, with a large one the goal of most gain, and its score is
    /// the gain over the length plus the cost (both found here by trying every goal). Three
    /// sources side by side in a small room, the robot downwind of them.
    #[test]
    fn a_leg_costs_its_length_plus_the_leg_cost() {
        let (layout, sampler, hyp) = three_sources(4.0, [1.5, 2.0, 2.5], [0.4, 0.3, 0.3]);
        let occupancy = Occupancy::new(&layout, 0.12).unwrap();
        let position = [1.3, 1.0];
        let goals = [[1.3, 3.0], [1.3, 3.8], [2.5, 3.0], [3.5, 2.0]];
        let weight = 0.2;
        let legs: Vec<(f64, f64)> = goals
            .iter()
            .map(|&g| {
                let path = occupancy.plan(position, g).unwrap();
                let points = path_points(&path);
                let gain = expected_gain(&hyp, &sampler, &points, &fresh(&points), weight);
                (gain, path_length(&path))
            })
            .collect();
        let best = |cost: f64| {
            (0..goals.len())
                .max_by(|&a, &b| {
                    let s = |k: usize| legs[k].0 / (legs[k].1 + cost);
                    s(a).total_cmp(&s(b))
                })
                .unwrap()
        };
        // The fixture tells the two rules apart.
        assert_ne!(best(0.0), best(1000.0), "{legs:?}");
        for cost in [0.0, 2.0, 1000.0] {
            let leg = Leg {
                weight,
                cost_m: cost,
                sensed: Sensed::new(Revisit::new(&RobotParams::default()), &[]),
            };
            let plan =
                best_by_path_gain(&hyp, &sampler, &occupancy, position, &goals, &leg).unwrap();
            let k = best(cost);
            assert_eq!(plan.goal, goals[k], "cost {cost}: {legs:?}");
            let expected = legs[k].0 / (legs[k].1 + cost);
            assert!(
                (plan.score - expected).abs() <= 1e-12 * expected,
                "cost {cost}"
            );
        }
    }
}
