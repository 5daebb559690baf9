//! Paired comparison of two studies run on the same seeds (`plumenet compare`).
//!
//! Run `r` of a study with seed `S` has the same source, start, plume and sensor noise whatever
//! the estimator's settings ([`crate::study::experiment`]), so two studies that differ only in
//! those settings compare run by run. The errors of the planner's runs scatter by 2-3 m (a few
//! runs end 10 m off), so two means of 50 or 200 runs can differ by tenths of a metre from
//! noise alone; the paired difference and its standard error say how much of a difference
//! the runs support. Beside it, two exact sign tests that the few far-off runs cannot sway:
//! which estimate ended closer (runs ending equally close left out), and which runs ended
//! more than [`FAR_M`] off in one study but not in the other.

use std::collections::HashMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::report::markdown_table;
use crate::stats::{mean_std, paired_difference, sign_test};
use crate::study::experiment::RunRow;

/// A run ending further off than this (m) counts as far off.
pub const FAR_M: f64 = 1.5;

/// Two runs' errors closer than this (m) count as equally close.
const SAME_M: f64 = 1e-6;

/// The paired comparison of one reality, path kind, feature and sensor (over all layouts).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompareRow {
    /// How reality departed from the model.
    pub reality: String,
    /// Whose paths.
    pub paths: String,
    /// Gas feature.
    pub feature: String,
    /// Sensor preset.
    pub sensor: String,
    /// Pairs of runs (same layout, run and seed in both studies).
    pub pairs: usize,
    /// Mean error of the base study's runs (m).
    pub base_error_mean_m: f64,
    /// Mean error of the other study's runs (m).
    pub other_error_mean_m: f64,
    /// Mean of the paired differences, other minus base (m): negative when the other study
    /// ends closer.
    pub difference_mean_m: f64,
    /// Standard error of that mean (m).
    pub difference_se_m: f64,
    /// Pairs in which the base study's estimate ended closer.
    pub base_closer: usize,
    /// Pairs in which the other study's estimate ended closer.
    pub other_closer: usize,
    /// Two-sided exact sign test of those two counts.
    pub closer_p: f64,
    /// Base runs ending more than [`FAR_M`] off.
    pub base_far: usize,
    /// Other runs ending more than [`FAR_M`] off.
    pub other_far: usize,
    /// Two-sided exact sign test (McNemar's) of the pairs far off in one study only.
    pub far_p: f64,
    /// Mean iterations of the base study's runs.
    pub base_iterations_mean: f64,
    /// Mean iterations of the other study's runs.
    pub other_iterations_mean: f64,
}

/// Reads a study's `runs.csv`.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read, [`Error::Study`] when a row is malformed or an
/// error is not a finite non-negative number.
pub fn load_runs(path: &Path) -> Result<Vec<RunRow>> {
    let bad = |reason: String| Error::Study {
        path: path.to_path_buf(),
        reason,
    };
    let mut reader = csv::Reader::from_path(path).map_err(|e| match e.into_kind() {
        csv::ErrorKind::Io(source) => Error::Io {
            action: "cannot read",
            path: path.to_path_buf(),
            source,
        },
        other => bad(format!("{other:?}")),
    })?;
    let mut rows = Vec::new();
    for (k, row) in reader.deserialize::<RunRow>().enumerate() {
        let row = row.map_err(|e| bad(format!("row {}: {e}", k + 1)))?;
        if !(row.error_m.is_finite() && row.error_m >= 0.0) {
            return Err(bad(format!("row {}: error_m is {}", k + 1, row.error_m)));
        }
        rows.push(row);
    }
    if rows.is_empty() {
        return Err(bad("no runs".into()));
    }
    Ok(rows)
}

/// What pairs a run with its twin: the layout, reality, paths, feature, sensor, run index and
/// seed (not the plume model, so that banks compare too).
type PairKey = (String, String, String, String, String, usize, u64);

/// The row's pairing key.
fn key(r: &RunRow) -> PairKey {
    (
        r.layout.clone(),
        r.reality.clone(),
        r.paths.clone(),
        r.feature.clone(),
        r.sensor.clone(),
        r.run,
        r.seed,
    )
}

/// Indexes one study's runs by their pairing key.
fn index<'a>(runs: &'a [RunRow], name: &str) -> Result<HashMap<PairKey, &'a RunRow>> {
    let mut map = HashMap::with_capacity(runs.len());
    for r in runs {
        if map.insert(key(r), r).is_some() {
            return Err(Error::Parameter(format!(
                "the {name} study holds two runs of layout {}, reality {}, {} {} {}, run {} \
                 (one per plume model?): compare studies of one plume model each, or select one \
                 with --{name}-model",
                r.layout, r.reality, r.paths, r.feature, r.sensor, r.run
            )));
        }
    }
    Ok(map)
}

/// Pairs the runs of two studies and compares them per reality, paths, feature and sensor, in
/// the base study's order. Runs without a twin in the other study are left out; the second
/// value counts them (base, other).
///
/// # Errors
/// [`Error::Parameter`] when a study holds two runs with the same pairing key (two plume
/// models in one file), or when no run pairs at all (studies of other seeds or layouts).
pub fn compare(base: &[RunRow], other: &[RunRow]) -> Result<(Vec<CompareRow>, [usize; 2])> {
    let others = index(other, "other")?;
    index(base, "base")?;
    // One group per reality, paths, feature and sensor, in the base study's order, with the
    // paired runs of each study.
    type Group<'a> = (
        (String, String, String, String),
        Vec<&'a RunRow>,
        Vec<&'a RunRow>,
    );
    let mut groups: Vec<Group<'_>> = Vec::new();
    let mut paired = 0;
    for b in base {
        let Some(o) = others.get(&key(b)) else {
            continue;
        };
        paired += 1;
        let g = (
            b.reality.clone(),
            b.paths.clone(),
            b.feature.clone(),
            b.sensor.clone(),
        );
        let slot = match groups.iter().position(|(x, _, _)| *x == g) {
            Some(i) => i,
            None => {
                groups.push((g, Vec::new(), Vec::new()));
                groups.len() - 1
            }
        };
        groups[slot].1.push(b);
        groups[slot].2.push(o);
    }
    if paired == 0 {
        return Err(Error::Parameter(
            "no run of the one study pairs with a run of the other (same layout, reality, paths, \
             feature, sensor, run and seed): compare studies run with the same --seed"
                .into(),
        ));
    }
    let rows = groups
        .into_iter()
        .map(|((reality, paths, feature, sensor), b, o)| {
            let eb: Vec<f64> = b.iter().map(|r| r.error_m).collect();
            let eo: Vec<f64> = o.iter().map(|r| r.error_m).collect();
            let (difference_mean_m, difference_se_m) = paired_difference(&eb, &eo);
            let closer =
                |a: &[f64], z: &[f64]| a.iter().zip(z).filter(|(x, y)| **x < **y - SAME_M).count();
            let (base_closer, other_closer) = (closer(&eb, &eo), closer(&eo, &eb));
            let far_only = |a: &[f64], z: &[f64]| {
                a.iter()
                    .zip(z)
                    .filter(|(x, y)| **x > FAR_M && **y <= FAR_M)
                    .count()
            };
            let (base_only, other_only) = (far_only(&eb, &eo), far_only(&eo, &eb));
            let mean = |v: &[f64]| mean_std(v).0;
            let iterations =
                |v: &[&RunRow]| mean(&v.iter().map(|r| r.iterations as f64).collect::<Vec<_>>());
            CompareRow {
                reality,
                paths,
                feature,
                sensor,
                pairs: eb.len(),
                base_error_mean_m: mean(&eb),
                other_error_mean_m: mean(&eo),
                difference_mean_m,
                difference_se_m,
                base_closer,
                other_closer,
                closer_p: sign_test(base_closer, base_closer + other_closer),
                base_far: eb.iter().filter(|&&e| e > FAR_M).count(),
                other_far: eo.iter().filter(|&&e| e > FAR_M).count(),
                far_p: sign_test(base_only, base_only + other_only),
                base_iterations_mean: iterations(&b),
                other_iterations_mean: iterations(&o),
            }
        })
        .collect();
    Ok((rows, [base.len() - paired, other.len() - paired]))
}

/// The comparison as a Markdown table.
pub fn compare_table(rows: &[CompareRow]) -> String {
    let header = [
        "reality",
        "paths",
        "feature",
        "sensor",
        "pairs",
        "base error mean (m)",
        "other",
        "difference ± SE (m)",
        "closer: base / other (sign test p)",
        "over 1.5 m: base / other (p)",
        "iterations: base / other",
    ];
    markdown_table(
        &header,
        rows.iter().map(|r| {
            vec![
                r.reality.clone(),
                r.paths.clone(),
                r.feature.clone(),
                r.sensor.clone(),
                r.pairs.to_string(),
                format!("{:.3}", r.base_error_mean_m),
                format!("{:.3}", r.other_error_mean_m),
                format!("{:+.3} ± {:.3}", r.difference_mean_m, r.difference_se_m),
                format!("{} / {} ({:.2})", r.base_closer, r.other_closer, r.closer_p),
                format!("{} / {} ({:.2})", r.base_far, r.other_far, r.far_p),
                format!(
                    "{:.1} / {:.1}",
                    r.base_iterations_mean, r.other_iterations_mean
                ),
            ]
        }),
    )
}
