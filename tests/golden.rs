//! Reference values on disk for behaviour that must not drift between releases without
//! notice: the paper arena's wind, the solver's bank and PlumeNet's bank at probe points. A
//! change fails with a table of what moved; after a deliberate change the files are written
//! anew with
//!
//! ```sh
//! PLUMENET_BLESS=1 cargo test --release --locked --test tests golden
//! ```
//!
//! and the diff of `tests/golden/` goes into the commit that changes the behaviour.

use std::collections::BTreeMap;

use plumenet::Surrogate;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;
use plumenet::plume::PlumeModel;

use crate::common::{repo_path, wind_tunnel};

/// Compares `values` with `tests/golden/{name}.json`, each within `relative` of the larger
/// magnitude or `absolute`, whichever is larger; or writes the file when `PLUMENET_BLESS` is
/// set.
fn check_golden(name: &str, values: &BTreeMap<String, f64>, relative: f64, absolute: f64) {
    let path = repo_path(&format!("tests/golden/{name}.json"));
    if std::env::var_os("PLUMENET_BLESS").is_some() {
        let text = serde_json::to_string_pretty(values).unwrap();
        std::fs::write(&path, text + "\n").unwrap();
        return;
    }
    let stored: BTreeMap<String, f64> =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap_or_else(|e| {
            panic!("{}: {e} (write it with PLUMENET_BLESS=1)", path.display())
        }))
        .unwrap();
    let mut moved = Vec::new();
    for label in stored.keys().chain(values.keys()) {
        match (stored.get(label), values.get(label)) {
            (Some(&was), Some(&now)) => {
                if (now - was).abs() > (relative * was.abs().max(now.abs())).max(absolute) {
                    moved.push(format!(
                        "  {label}: {was:.9e} -> {now:.9e} (relative {:.1e})",
                        (now - was).abs() / was.abs().max(f64::MIN_POSITIVE)
                    ));
                }
            }
            (Some(_), None) => moved.push(format!("  {label}: no longer computed")),
            (None, Some(_)) => moved.push(format!("  {label}: new")),
            (None, None) => unreachable!(),
        }
    }
    moved.dedup();
    assert!(
        moved.is_empty(),
        "{name}: {} of {} values moved beyond {relative:e} (relative) and {absolute:e}:\n{}\n\
         If the change is meant, \
         rewrite the file: PLUMENET_BLESS=1 cargo test --release --locked --test tests golden",
        moved.len(),
        stored.len(),
        moved.join("\n")
    );
}

/// Probe points in the paper arena: around the obstacles, in their wakes and in open flow.
const PROBES: [(f64, f64); 8] = [
    (1.0, 2.0),
    (5.0, 0.3),
    (7.0, 2.5),
    (8.0, 1.1),
    (10.0, 1.8),
    (11.0, 3.8),
    (13.0, 3.0),
    (17.5, 0.6),
];

/// Candidates probed in the banks (indices into the arena's 1112 candidates at 0.25 m).
const CANDIDATES: [usize; 5] = [0, 77, 400, 801, 1111];

/// Adds the values of `bank` (the fields of the probed candidates, in order) at the probe
/// points, labelled with `model`, the source and the point.
fn probe_bank(
    values: &mut BTreeMap<String, f64>,
    model: &str,
    l: &plumenet::layout::Layout,
    bank: &ndarray::Array3<f32>,
    candidates: &[[f64; 2]],
) {
    for (n, k) in CANDIDATES.iter().enumerate() {
        let [sx, sy] = candidates[*k];
        for (x, y) in PROBES {
            let (j, i) = l.cell_of(x, y);
            values.insert(
                format!("{model}, source ({sx}, {sy}), cell at ({x}, {y})"),
                f64::from(bank[[n, j, i]]),
            );
        }
    }
}

#[test]
fn the_arena_wind_and_solver_bank_match_their_reference_values() {
    let l = wind_tunnel();
    let wind = WindField::solve(&l).unwrap();
    let candidates = l.candidates(0.25).unwrap();
    let bank = Transport::new(&l, &wind)
        .unwrap()
        .bank(&CANDIDATES.map(|k| candidates[k]))
        .unwrap();
    let mut values = BTreeMap::new();
    for (x, y) in PROBES {
        let (u, v) = wind.velocity_at(x, y);
        values.insert(format!("wind u at ({x}, {y})"), u);
        values.insert(format!("wind v at ({x}, {y})"), v);
    }
    probe_bank(&mut values, "solver", &l, &bank, &candidates);
    // Both come from direct solves (the wind's iteration converged to its tolerance) and the
    // bank is stored in single precision: 1e-5 relative, and 1e-9 for the far upwind tails.
    check_golden("arena-wind-and-solver-bank", &values, 1e-5, 1e-9);
}

#[test]
fn the_shipped_models_arena_bank_matches_its_reference_values() {
    let l = wind_tunnel();
    let model = Surrogate::load(&repo_path("models/default")).unwrap();
    let candidates = l.candidates(0.25).unwrap();
    let bank = model.bank(&l, &CANDIDATES.map(|k| candidates[k])).unwrap();
    let mut values = BTreeMap::new();
    probe_bank(&mut values, "plumenet", &l, &bank.fields, &candidates);
    // Single-precision network: each instruction set's kernels round differently (tests/conv.rs
    // compares them), so 1e-4 relative, and 1e-6 (of fields that peak near 1) in clean air.
    check_golden("default-model-arena-bank", &values, 1e-4, 1e-6);
}
