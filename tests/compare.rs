//! Paired comparison of two studies: the statistics against brute force, the pairing, and the
//! command's output and errors.

use plumenet::Error;
use plumenet::stats::{paired_difference, sign_test};
use plumenet::study::compare::{compare, compare_table, load_runs};
use plumenet::study::experiment::RunRow;

use crate::common::{assert_clean_failure, plumenet, plumenet_ok};

/// The exact sign test is the chance of a split at least as uneven, counted over every one of
/// the `2^n` equally likely outcomes.
#[test]
fn sign_test_matches_enumerating_every_outcome() {
    for n in 0..=12usize {
        for k in 0..=n {
            let extreme = |heads: usize| heads.abs_diff(n - heads) >= k.abs_diff(n - k);
            let count = (0u32..1 << n)
                .filter(|bits| extreme(bits.count_ones() as usize))
                .count();
            let brute = count as f64 / f64::from(1u32 << n);
            let ours = sign_test(k, n);
            assert!(
                (ours - brute).abs() < 1e-12,
                "n {n}, k {k}: {ours} vs {brute}"
            );
        }
    }
    // Large n stays finite and symmetric: 60 of 200 is far out, 100 of 200 is an even split.
    assert!(sign_test(60, 200) < 1e-7 && sign_test(60, 200) > 0.0);
    assert_eq!(sign_test(60, 200), sign_test(140, 200));
    assert_eq!(sign_test(100, 200), 1.0);
}

#[test]
fn paired_difference_is_the_mean_and_standard_error_of_the_differences() {
    // Differences 1, 0, 2, 0: mean 0.75, sample variance 2.75 / 3.
    let (mean, se) = paired_difference(&[1.0, 2.0, 3.0, 4.0], &[2.0, 2.0, 5.0, 4.0]);
    assert!((mean - 0.75).abs() < 1e-12);
    assert!((se - (2.75f64 / 3.0).sqrt() / 2.0).abs() < 1e-12);
}

/// A run of a study at `error_m` metres off.
fn run(layout: &str, reality: &str, run: usize, error_m: f64, iterations: usize) -> RunRow {
    RunRow {
        layout: layout.into(),
        model: "solver".into(),
        reality: reality.into(),
        paths: "planner".into(),
        feature: "rank".into(),
        sensor: "sensor-ii".into(),
        run,
        seed: 1000 + run as u64,
        source_x: 1.0,
        source_y: 2.0,
        start_x: 15.0,
        start_y: 1.0,
        estimate_x: 1.0 + error_m,
        estimate_y: 2.0,
        error_m,
        highest_x: 2.0,
        highest_y: 2.0,
        highest_error_m: 1.0,
        centre_error_m: 4.0,
        iterations,
        converged: true,
        samples: 100,
        distance_m: 10.0,
        wall_time_s: 0.1,
        fit: 0.01,
        area_50_m2: 0.5,
        area_90_m2: 1.0,
        mass_50: 0.6,
        mass_90: 0.92,
        covers_50: Some(error_m < 0.5),
        covers_90: Some(error_m < 1.0),
        source_level: 0.5,
        log_p_source: -2.0,
        expected_distance_m: 0.4,
    }
}

#[test]
fn runs_pair_by_layout_run_and_seed_whatever_their_order() {
    let errors_a = [0.2, 0.3, 5.0, 0.4, 2.0, 0.1];
    let errors_b = [0.1, 0.3, 0.2, 3.0, 0.5, 0.1];
    let mut base = Vec::new();
    let mut other = Vec::new();
    for (k, (&a, &b)) in errors_a.iter().zip(&errors_b).enumerate() {
        let layout = if k % 2 == 0 { "hall" } else { "lab" };
        base.push(run(layout, "none", k, a, 10));
        other.push(run(layout, "none", k, b, 14));
        // The same runs under another reality form their own row.
        base.push(run(layout, "background 1", k, a + 1.0, 10));
        other.push(run(layout, "background 1", k, a + 1.0, 10));
    }
    // A run without a twin, and the other study in reverse order.
    base.push(run("hall", "none", 99, 50.0, 30));
    other.reverse();
    let (rows, [base_alone, other_alone]) = compare(&base, &other).unwrap();
    assert_eq!((base_alone, other_alone), (1, 0));
    assert_eq!(rows.len(), 2);
    let none = &rows[0];
    assert_eq!((none.reality.as_str(), none.pairs), ("none", 6));
    let (mean, se) = paired_difference(&errors_a, &errors_b);
    assert!((none.difference_mean_m - mean).abs() < 1e-12);
    assert!((none.difference_se_m - se).abs() < 1e-12);
    assert!((none.base_error_mean_m - 8.0 / 6.0).abs() < 1e-12);
    // Closer: base in run 3, other in runs 0, 2 and 4; runs 1 and 5 are ties.
    assert_eq!((none.base_closer, none.other_closer), (1, 3));
    assert_eq!(none.closer_p, sign_test(1, 4));
    // Far off (over 1.5 m): base runs 2 and 4, other run 3; all three discordant.
    assert_eq!((none.base_far, none.other_far), (2, 1));
    assert_eq!(none.far_p, sign_test(1, 3));
    assert_eq!(
        (none.base_iterations_mean, none.other_iterations_mean),
        (10.0, 14.0)
    );
    let same = &rows[1];
    assert_eq!(same.reality, "background 1");
    assert_eq!((same.difference_mean_m, same.difference_se_m), (0.0, 0.0));
    assert_eq!(
        (same.base_closer, same.other_closer, same.closer_p),
        (0, 0, 1.0)
    );
    let table = compare_table(&rows);
    assert!(
        table.contains("| none | planner | rank | sensor-ii | 6 | 1.333 | 0.700 | -0.633 ±"),
        "{table}"
    );
}

#[test]
fn studies_that_do_not_pair_are_errors() {
    let base = vec![run("hall", "none", 0, 0.2, 10)];
    let mut twice = vec![
        run("hall", "none", 0, 0.2, 10),
        run("hall", "none", 0, 0.3, 10),
    ];
    twice[1].model = "plumenet".into();
    let err = compare(&base, &twice).unwrap_err();
    assert!(
        matches!(&err, Error::Parameter(m) if m.contains("--other-model")),
        "{err}"
    );
    let mut shifted = base.clone();
    shifted[0].seed += 1;
    let err = compare(&base, &shifted).unwrap_err();
    assert!(
        matches!(&err, Error::Parameter(m) if m.contains("same --seed")),
        "{err}"
    );
}

#[test]
fn compare_command_prints_the_table_and_refuses_bad_files() {
    let tmp = tempfile::tempdir().unwrap();
    let path = |n: &str| tmp.path().join(n);
    let base: Vec<RunRow> = (0..4).map(|k| run("hall", "none", k, 0.5, 10)).collect();
    let mut other = base.clone();
    other.iter_mut().for_each(|r| r.error_m = 0.25);
    plumenet::io::write_csv(&path("a.csv"), &base).unwrap();
    plumenet::io::write_csv(&path("b.csv"), &other).unwrap();
    let s = |n: &str| path(n).to_string_lossy().into_owned();
    let out = plumenet_ok(&["compare", &s("a.csv"), &s("b.csv"), "--csv", &s("c.csv")]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("| 4 | 0.500 | 0.250 | -0.250 ± 0.000 | 0 / 4 (0.12) | 0 / 0 (1.00) |"),
        "{stdout}"
    );
    let csv = std::fs::read_to_string(path("c.csv")).unwrap();
    assert!(
        csv.starts_with("reality,paths,feature,sensor,pairs,"),
        "{csv}"
    );
    assert_eq!(load_runs(&path("a.csv")).unwrap(), base);

    // A truncated file, a NaN error, an empty file, a missing file, a model none of the runs has.
    let text = std::fs::read_to_string(path("a.csv")).unwrap();
    std::fs::write(path("cut.csv"), &text[..text.len() - 30]).unwrap();
    std::fs::write(path("nan.csv"), text.replacen(",0.5,", ",NaN,", 1)).unwrap();
    std::fs::write(path("empty.csv"), text.lines().next().unwrap()).unwrap();
    for (file, needle) in [
        ("cut.csv", "bad study runs"),
        ("nan.csv", "error_m is NaN"),
        ("empty.csv", "no runs"),
        ("missing.csv", "cannot read"),
    ] {
        let out = plumenet(&["compare", &s("a.csv"), &s(file)]);
        assert_clean_failure(&out, needle);
    }
    let out = plumenet(&[
        "compare",
        &s("a.csv"),
        &s("b.csv"),
        "--other-model",
        "plumenet",
    ]);
    assert_clean_failure(&out, "no run of plume model plumenet");
}
