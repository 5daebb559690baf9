//! The binary: outputs of the main commands, and one clear error line for bad input.

use ndarray::{Ix2, Ix3};
use plumenet::io::read_npy;

use crate::common::{
    assert_clean_failure, command, plumenet, plumenet_ok, read_json, spawn_server,
};

const TUNNEL: &str = "data/layouts/wind-tunnel.json";

#[test]
fn simulate_writes_field_wind_png_and_report() {
    let tmp = tempfile::tempdir().unwrap();
    let p = |n: &str| tmp.path().join(n).to_string_lossy().into_owned();
    plumenet_ok(&[
        "simulate",
        "--layout",
        TUNNEL,
        "--source",
        "3,2",
        "--out",
        &p("f.npy"),
        "--wind-out",
        &p("w.npy"),
        "--png",
        &p("f.png"),
        "--log",
        "--json",
        &p("r.json"),
    ]);
    let field = read_npy::<f32, Ix2>(&tmp.path().join("f.npy")).unwrap();
    assert_eq!(field.dim(), (32, 144));
    let wind = read_npy::<f32, Ix3>(&tmp.path().join("w.npy")).unwrap();
    assert_eq!(wind.dim(), (2, 32, 144));
    let png = image::open(tmp.path().join("f.png")).unwrap();
    assert!(png.width() > 144 && png.height() > 32);
    // The release leaves through the outlet or the inlet, to the fields' single precision.
    let report = read_json(tmp.path().join("r.json"));
    let flux = |k: &str| report[k].as_f64().unwrap();
    assert!((flux("outlet_flux") + flux("inlet_flux") - 1.0).abs() < 0.5 * f64::from(f32::EPSILON));
}

#[test]
fn bank_writes_every_candidate() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("bank.npy");
    plumenet_ok(&[
        "bank",
        "--solver",
        "--layout",
        TUNNEL,
        "--out",
        path.to_str().unwrap(),
    ]);
    let bank = read_npy::<f32, Ix3>(&path).unwrap();
    let cands = read_npy::<f32, Ix2>(&tmp.path().join("bank.candidates.npy")).unwrap();
    assert_eq!(bank.dim(), (1112, 32, 144));
    assert_eq!(cands.dim(), (1112, 2));
}

#[test]
fn bad_input_gives_one_clear_error_line_and_no_file() {
    let tmp = tempfile::tempdir().unwrap();
    let out_path = tmp.path().join("f.npy");
    let out = out_path.to_str().unwrap();
    let bad_layout = tmp.path().join("bad.json");
    std::fs::write(
        &bad_layout,
        r#"{"width_m": 18, "height_m": 4, "cell_m": 0.3, "wind": {"speed_mps": 1}}"#,
    )
    .unwrap();
    let blocker = tmp.path().join("a-file");
    std::fs::write(&blocker, "").unwrap();
    let unwritable = blocker.join("f.npy");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec![
                "simulate", "--layout", TUNNEL, "--source", "7,1.2", "--out", out,
            ],
            "inside obstacle",
        ),
        (
            vec![
                "simulate", "--layout", TUNNEL, "--source", "30,1", "--out", out,
            ],
            "outside the arena",
        ),
        (
            vec![
                "simulate", "--layout", TUNNEL, "--source", "NaN,1", "--out", out,
            ],
            "finite",
        ),
        (
            vec![
                "simulate",
                "--layout",
                "nope.json",
                "--source",
                "3,2",
                "--out",
                out,
            ],
            "cannot read",
        ),
        (
            vec![
                "simulate",
                "--layout",
                bad_layout.to_str().unwrap(),
                "--source",
                "3,2",
                "--out",
                out,
            ],
            "does not divide",
        ),
        (
            vec![
                "simulate",
                "--layout",
                TUNNEL,
                "--source",
                "3,2",
                "--out",
                unwritable.to_str().unwrap(),
            ],
            "cannot write",
        ),
        (
            vec![
                "simulate", "--layout", TUNNEL, "--source", "3;2", "--out", out,
            ],
            "expected X,Y",
        ),
        (
            vec!["merge", "--out", out, "/nonexistent/shard"],
            "cannot read",
        ),
        (
            vec![
                "generate",
                "--out",
                out,
                "--layouts",
                "2",
                "--sources",
                "1",
                "--shard",
                "3/2",
            ],
            "shard must be",
        ),
        (
            vec![
                "generate",
                "--out",
                out,
                "--layouts",
                "1",
                "--sources",
                "1",
                "--base",
                "/nonexistent/arena.json",
            ],
            "cannot read",
        ),
        (
            vec!["train", "--data", out, "--out", out, "--inputs", "bogus"],
            "invalid value 'bogus'",
        ),
        (
            vec!["experiment", "--solver", "--with-solver", "--out", out],
            "cannot be used with",
        ),
        (
            vec!["experiment", "--solver", "--start", "upwind", "--out", out],
            "invalid value 'upwind'",
        ),
    ];
    for (args, needle) in cases {
        let result = plumenet(&args);
        assert_clean_failure(&result, needle);
        let stderr = String::from_utf8_lossy(&result.stderr);
        if result.status.code() == Some(1) {
            // Our own errors (clap's usage errors exit with 2 and add a hint line).
            assert_eq!(stderr.trim_end().lines().count(), 1, "{args:?}: {stderr}");
        }
        assert!(!out_path.exists(), "{args:?} left an output file");
    }
}

/// A failing Python reference ends `bench` with one clear error, and the export folder it made
/// for the reference is gone (it lives in `TMPDIR`, pointed here at an empty folder).
#[test]
fn bench_cleans_up_when_the_reference_fails() {
    let tmp = tempfile::tempdir().unwrap();
    let out = command()
        .args(["bench", "--repeats", "1"])
        .env("TMPDIR", tmp.path())
        .env("PATH", tmp.path())
        .output()
        .expect("binary runs");
    assert_clean_failure(&out, "cannot run python3 for the SuperLU reference");
    let left: Vec<_> = std::fs::read_dir(tmp.path()).unwrap().collect();
    assert!(left.is_empty(), "left behind: {left:?}");
}

#[test]
fn every_command_has_help() {
    for cmd in [
        "simulate",
        "bank",
        "generate",
        "merge",
        "bench",
        "train",
        "predict",
        "eval",
        "localize",
        "replay",
        "survey",
        "serve",
        "robot-sim",
        "bench-serve",
        "experiment",
        "bench-ste",
        "bench-net",
    ] {
        let out = plumenet(&[cmd, "--help"]);
        assert!(out.status.success());
        assert!(String::from_utf8_lossy(&out.stdout).contains("Usage"));
    }
}

/// A reader that closes the pipe before the program prints (`plumenet ... | head -1`) ends
/// it quietly, by the pipe's signal, never with a panic.
#[cfg(unix)]
#[test]
fn a_closed_output_pipe_ends_the_program_without_a_panic() {
    use std::os::unix::process::ExitStatusExt;
    let tmp = tempfile::tempdir().unwrap();
    let field = tmp.path().join("p.npy");
    let mut child = command()
        .args(["predict", "--model", "models/default", "--layout", TUNNEL])
        .args(["--source", "3,2", "--out", field.to_str().unwrap()])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    drop(child.stdout.take());
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert_eq!(out.status.signal(), Some(libc::SIGPIPE), "{stderr}");
}

#[test]
fn shipped_model_predicts_and_banks_the_paper_arena() {
    let tmp = tempfile::tempdir().unwrap();
    let field = tmp.path().join("p.npy");
    plumenet_ok(&[
        "predict",
        "--model",
        "models/default",
        "--layout",
        TUNNEL,
        "--source",
        "3,2",
        "--out",
        field.to_str().unwrap(),
    ]);
    let f = read_npy::<f32, Ix2>(&field).unwrap();
    assert_eq!(f.dim(), (32, 144));
    assert!(f.iter().all(|v| *v >= 0.0 && v.is_finite()));
    // The plume is strongest just downwind of the source and absent far upwind.
    assert!(
        f[[16, 28]] > 10.0 * f[[16, 4]].max(1e-6),
        "{} vs {}",
        f[[16, 28]],
        f[[16, 4]]
    );

    let coarse = tmp.path().join("coarse.json");
    std::fs::write(
        &coarse,
        r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#,
    )
    .unwrap();
    let bank = |model: &str| {
        plumenet(&[
            "bank",
            "--model",
            model,
            "--layout",
            coarse.to_str().unwrap(),
            "--out",
            tmp.path().join("b.npy").to_str().unwrap(),
        ])
    };
    assert_clean_failure(&bank("models/default"), "cell");
    assert_clean_failure(
        &bank("models/arena-v1"),
        "is a one-room model (plumenet-model-v1) and knows only a [32, 144] grid",
    );
}

#[test]
fn bench_net_reports_throughput_and_flop_rate() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("bench.json");
    let out = plumenet_ok(&[
        "bench-net",
        "--spacing",
        "2",
        "--rounds",
        "1",
        "--batch",
        "2",
        "--steps",
        "1",
        "--no-reference",
        "--json",
        json.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("GFLOP/s"), "{stdout}");
    let report = read_json(&json);
    for key in [
        "ours_bank_images_per_s",
        "ours_train_images_per_s",
        "burn_conv_bank_images_per_s",
        "burn_conv_train_images_per_s",
    ] {
        let rates = report[key].as_array().unwrap();
        assert_eq!(rates.len(), 1);
        assert!(rates[0].as_f64().unwrap() > 0.0, "{key}: {rates:?}");
    }
    // Each part's ratio is named; without the reference only ours against Burn's.
    let ratios = report["ratios"].as_object().unwrap();
    for key in ["bank_ours_over_burn_conv", "training_ours_over_burn_conv"] {
        assert!(ratios[key].as_f64().unwrap() > 0.0, "{key}");
    }
    assert!(!ratios.contains_key("bank_ours_over_torch"));
    // The shipped network (five levels, seven inputs) on the paper's grid: 180 M
    // multiply-adds per image (the one-arena network of models/arena-v1 has 150 M).
    let macs = report["forward_macs"].as_f64().unwrap();
    assert!((1.7e8..1.9e8).contains(&macs), "{macs}");
}

#[test]
fn localize_writes_the_run_and_its_pictures() {
    let tmp = tempfile::tempdir().unwrap();
    let json_path = tmp.path().join("run.json");
    let pics = tmp.path().join("pics");
    let cache = tmp.path().join("cache");
    let args = [
        "localize",
        "--solver",
        "--source",
        "4.1,2.1",
        "--start",
        "12,1",
        "--feature",
        "rank",
        "--sensor",
        "sensor-ii",
        "--seed",
        "3",
        "--max-iterations",
        "4",
        "--json",
        json_path.to_str().unwrap(),
        "--png-dir",
        pics.to_str().unwrap(),
        "--cache-dir",
        cache.to_str().unwrap(),
    ];
    let out = plumenet_ok(&args);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let run = read_json(&json_path);
    // The estimate and the two baselines, one line each, with the errors the JSON holds.
    for (label, error) in [
        ("estimate", &run["error_m"]),
        (
            "highest reading",
            &run["baselines"]["highest_reading"]["error_m"],
        ),
        ("arena centre", &run["baselines"]["centre"]["error_m"]),
    ] {
        let expected = format!("error {:5.2} m", error.as_f64().unwrap());
        assert!(
            stdout
                .lines()
                .any(|l| l.trim_start().starts_with(label) && l.contains(&expected)),
            "{label} {expected}: {stdout}"
        );
    }
    for key in [
        "estimate",
        "error_m",
        "iterations",
        "converged",
        "trajectory",
        "samples",
        "sigmas",
        "baselines",
        "reality",
    ] {
        assert!(run.get(key).is_some(), "missing {key}");
    }
    // The highest-reading baseline is the position of the largest recorded value.
    let samples = run["samples"].as_array().unwrap();
    let best = samples
        .iter()
        .max_by(|a, b| {
            let v = |s: &serde_json::Value| s["value"].as_f64().unwrap();
            v(a).total_cmp(&v(b))
        })
        .unwrap();
    let highest = &run["baselines"]["highest_reading"];
    assert_eq!(highest["x"], best["x"]);
    let herr = (best["x"].as_f64().unwrap() - 4.1).hypot(best["y"].as_f64().unwrap() - 2.1);
    assert!((highest["error_m"].as_f64().unwrap() - herr).abs() < 1e-9);
    assert_eq!(run["reality"]["wind_scale"], 1.0);
    // The uncertainty beside the estimate is the final posterior's: each region is the
    // fewest most probable cells reaching its level, and covers the source's cell exactly
    // when the source's level is below it; the printed line states the 90% region's area.
    let u = &run["uncertainty"];
    let mut p: Vec<f64> = (run["posterior"].as_array().unwrap().iter())
        .map(|v| v.as_f64().unwrap())
        .collect();
    p.sort_by(|a, b| b.total_cmp(a));
    let level = u["source"]["level"].as_f64().unwrap();
    for region in u["regions"].as_array().unwrap() {
        let at = region["level"].as_f64().unwrap();
        let cells = region["cells"].as_array().unwrap().len();
        let mass: f64 = p[..cells].iter().sum();
        let short: f64 = p[..cells - 1].iter().sum();
        assert!(
            mass >= at - 1e-9 && short < at,
            "{at}: {cells} cells hold {mass}"
        );
        assert_eq!(region["covers_source"], level < at);
        assert!((region["mass"].as_f64().unwrap() - mass).abs() < 1e-9);
        assert!((region["area_m2"].as_f64().unwrap() - cells as f64 * 0.0625).abs() < 1e-9);
    }
    let area90 = u["regions"][1]["area_m2"].as_f64().unwrap();
    assert!(
        stdout.contains(&format!("90% region {area90:.2} m²")),
        "{stdout}"
    );
    let expected: f64 = (run["candidates"].as_array().unwrap().iter())
        .zip(run["posterior"].as_array().unwrap())
        .map(|(c, p)| {
            let [x, y] = [c[0].as_f64().unwrap(), c[1].as_f64().unwrap()];
            let e = &run["estimate"];
            p.as_f64().unwrap() * (x - e[0].as_f64().unwrap()).hypot(y - e[1].as_f64().unwrap())
        })
        .sum();
    assert!((u["expected_distance_m"].as_f64().unwrap() - expected).abs() < 1e-9);
    // The run names its sensor as the flag does.
    assert_eq!(run["config"]["sensor"], "sensor-ii");
    // The solver's bank is exact, but no steady model ranks the intermittent plume exactly:
    // the tempered likelihood knows its ranks within 1.5, independent readings exactly;
    // PlumeNet's are known within its own factor, unless the flag says otherwise.
    assert_eq!(run["config"]["ste"]["model_rank_factor"], 1.5);
    // The tempered likelihood checks every model's misfit against 50 (none with independent
    // readings), and the exact solver's fit per reading against 0.02 too.
    assert_eq!(run["config"]["ste"]["misfit_reference"], 50.0);
    assert_eq!(run["config"]["ste"]["fit_reference"], 0.02);
    // Rank marginalises a rising background by default (rises 0, 0.25 and 0.5 fully mixed).
    assert_eq!(run["config"]["ste"]["background_rise"], 0.5);
    assert_eq!(run["backgrounds"].as_array().unwrap().len(), 3);
    // Rank lags its estimates in the sensor's response, 1/1.58, with a 0.2 ppm floor, unless
    // said otherwise.
    let response = 1.0 / 1.58;
    assert_eq!(run["config"]["ste"]["sensor_lag_exponent"], response);
    assert_eq!(run["config"]["ste"]["detection_floor_ppm"], 0.2);
    let surrogate_json = tmp.path().join("plumenet.json");
    // One iteration of a coarse run with these flags, its record read back.
    let one_iteration = |flags: &[&str]| {
        let mut args = vec![
            "localize",
            "--no-cache",
            "--spacing",
            "2",
            "--source",
            "4.1,2.1",
            "--max-iterations",
            "1",
            "--json",
            surrogate_json.to_str().unwrap(),
        ];
        args.extend_from_slice(flags);
        plumenet_ok(&args);
        read_json(&surrogate_json)
    };
    // (flags, model rank factor, background rise, lag exponent, detection floor, fit reference,
    // misfit reference)
    let none = serde_json::Value::Null;
    for (flags, factor, rise, exponent, floor, fit, misfit) in [
        (&[][..], 3.0, 0.5, response, 0.2, none.clone(), 50.0.into()),
        (
            &["--model-rank-factor", "1.5", "--background-rise", "0"][..],
            1.5,
            0.0,
            response,
            0.2,
            none.clone(),
            50.0.into(),
        ),
        (
            &["--feature", "value"][..],
            3.0,
            0.0,
            1.0,
            1.0,
            none.clone(),
            none.clone(),
        ),
        (
            &["--solver", "--evidence-weight", "1"][..],
            1.0,
            0.5,
            response,
            0.2,
            none.clone(),
            none.clone(),
        ),
        (
            &["--solver", "--model-rank-factor", "1"][..],
            1.0,
            0.5,
            response,
            0.2,
            0.02.into(),
            50.0.into(),
        ),
        (
            &["--solver", "--no-fit-check", "--misfit-reference", "50"][..],
            1.5,
            0.5,
            response,
            0.2,
            none.clone(),
            50.0.into(),
        ),
        (
            &["--solver", "--no-fit-check"][..],
            1.5,
            0.5,
            response,
            0.2,
            none.clone(),
            none.clone(),
        ),
        (
            &["--fit-reference", "0.03"][..],
            3.0,
            0.5,
            response,
            0.2,
            0.03.into(),
            50.0.into(),
        ),
        (
            &["--evidence-weight", "1"][..],
            3.0,
            0.5,
            response,
            0.2,
            none.clone(),
            none.clone(),
        ),
        (
            &["--solver", "--no-fit-check", "--fit-reference", "0.02"][..],
            1.5,
            0.5,
            response,
            0.2,
            0.02.into(),
            none.clone(),
        ),
        (
            &["--solver", "--misfit-reference", "80"][..],
            1.5,
            0.5,
            response,
            0.2,
            0.02.into(),
            80.0.into(),
        ),
        (
            &["--paper-rank"][..],
            1.0,
            0.0,
            1.0,
            1.0,
            none.clone(),
            none.clone(),
        ),
        (
            &["--lag-exponent", "1", "--detection-floor", "1"][..],
            3.0,
            0.5,
            1.0,
            1.0,
            none.clone(),
            50.0.into(),
        ),
        (
            &["--paper-rank", "--lag-exponent", "0.5"][..],
            1.0,
            0.0,
            0.5,
            1.0,
            none.clone(),
            none.clone(),
        ),
    ] {
        let run = one_iteration(flags);
        assert_eq!(
            run["config"]["ste"]["model_rank_factor"], factor,
            "{flags:?}"
        );
        assert_eq!(run["config"]["ste"]["background_rise"], rise, "{flags:?}");
        assert_eq!(
            run["config"]["ste"]["sensor_lag_exponent"], exponent,
            "{flags:?}"
        );
        assert_eq!(
            run["config"]["ste"]["detection_floor_ppm"], floor,
            "{flags:?}"
        );
        assert_eq!(run["config"]["ste"]["fit_reference"], fit, "{flags:?}");
        assert_eq!(
            run["config"]["ste"]["misfit_reference"], misfit,
            "{flags:?}"
        );
    }

    // The planner discounts ground already sensed within 0.25 m with the exact solver and
    // the tempered likelihood, and counts every point in full with PlumeNet, with
    // independent readings, or as the flag says.
    for (flags, radius) in [
        (&["--solver"][..], 0.25),
        (&[][..], 0.0),
        (&["--solver", "--evidence-weight", "1"][..], 0.0),
        (&["--solver", "--paper-rank"][..], 0.0),
        (&["--solver", "--revisit-radius", "0"][..], 0.0),
        (&["--revisit-radius", "0.5"][..], 0.5),
    ] {
        let run = one_iteration(flags);
        assert_eq!(
            run["config"]["robot"]["revisit_radius_m"], radius,
            "{flags:?}"
        );
    }

    let iterations = run["iterations"].as_u64().unwrap() as usize;
    assert!((1..=4).contains(&iterations));
    let [ex, ey] = [0, 1].map(|k| run["estimate"][k].as_f64().unwrap());
    let err = (ex - 4.1).hypot(ey - 2.1);
    assert!((err - run["error_m"].as_f64().unwrap()).abs() < 1e-9);
    let pngs = std::fs::read_dir(&pics).unwrap().count();
    assert_eq!(pngs, iterations);
    let banks = std::fs::read_dir(&cache).unwrap().count();
    assert_eq!(banks, 1, "the bank is cached");
    // The second run reads the cached bank and repeats the first exactly.
    let again = plumenet(&args);
    assert!(String::from_utf8_lossy(&again.stdout).contains("bank from cache"));
    let run2 = read_json(&json_path);
    assert_eq!(run["samples"], run2["samples"]);
    assert_eq!(run["estimate"], run2["estimate"]);
}

#[test]
fn a_run_with_an_upwind_probe_returns_through_it_before_it_stops() {
    // An arena run whose source lies by the south wall: at evidence weight 0.3 its posterior
    // settles 2.1 m downwind of the source, where the robot never drove between them.
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let run_with = |probe: &str| {
        let json = tmp.path().join(format!("run-{probe}.json"));
        plumenet_ok(&[
            "localize",
            "--source",
            "10.496734550318372,0.5361144658323198",
            "--start",
            "15.46769769986209,2.7129367940066107",
            "--seed",
            "10420694705320995839",
            "--evidence-weight",
            "0.3",
            "--misfit-reference",
            "33.333333333333336",
            "--upwind-probe",
            probe,
            "--json",
            json.to_str().unwrap(),
            "--cache-dir",
            cache.to_str().unwrap(),
        ]);
        read_json(&json)
    };
    let estimate = |run: &serde_json::Value| [0, 1].map(|k| run["estimate"][k].as_f64().unwrap());
    let without = run_with("0");
    let with = run_with("1");
    assert_eq!(with["config"]["termination"]["upwind_probe_m"], 1.0);
    assert_eq!(without["converged"], true);
    assert_eq!(with["converged"], true);
    // The last leg went upwind of the estimate it was planned from and back to it...
    let history = with["history"].as_array().unwrap();
    let (before, last) = (&history[history.len() - 2], &history[history.len() - 1]);
    assert_eq!(last["goal"], before["estimate"]);
    let west = with["samples"].as_array().unwrap()[before["samples"].as_u64().unwrap() as usize..]
        .iter()
        .map(|s| s["x"].as_f64().unwrap())
        .fold(f64::INFINITY, f64::min);
    let planned_from = before["estimate"][0].as_f64().unwrap();
    assert!(west <= planned_from - 3.0, "{west} from {planned_from}");
    // ...and the run stopped having sensed 1 m upwind (west) of its last estimate, which the
    // readings on the way back moved upwind, towards the source.
    let [ex, ey] = estimate(&with);
    assert!(with["samples"].as_array().unwrap().iter().any(|s| {
        let [x, y] = [&s["x"], &s["y"]].map(|v| v.as_f64().unwrap());
        (x - (ex - 1.0)).hypot(y - ey) <= 0.375
    }));
    assert!(ex < estimate(&without)[0], "{ex}");
}

#[test]
fn replay_and_experiment_write_their_reports() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("log.csv");
    let mut csv = String::from("t,x,y,value\n");
    for k in 0..40 {
        let x = 2.0 + 0.3 * f64::from(k);
        csv.push_str(&format!(
            "{},{x},2.0,{}\n",
            f64::from(k) * 0.1,
            1.0 / (1.0 + (x - 6.0).abs())
        ));
    }
    std::fs::write(&log, csv).unwrap();
    let json_path = tmp.path().join("replay.json");
    plumenet_ok(&[
        "replay",
        "--solver",
        "--no-cache",
        "--log",
        log.to_str().unwrap(),
        "--json",
        json_path.to_str().unwrap(),
    ]);
    let rep = read_json(&json_path);
    let post = rep["posterior"].as_array().unwrap();
    assert_eq!(post.len(), 1112);
    let total: f64 = post.iter().map(|p| p["p"].as_f64().unwrap()).sum();
    assert!((total - 1.0).abs() < 1e-9);
    assert!(rep["estimate"].as_array().unwrap().len() == 2);
    // The report is the library's, and its uncertainty is the posterior's.
    let report: plumenet::ste::replay::ReplayReport = serde_json::from_value(rep.clone()).unwrap();
    let u = report.uncertainty.unwrap();
    let p: Vec<f64> = report.posterior.iter().map(|c| c.p).collect();
    let cells: Vec<[f64; 2]> = report.posterior.iter().map(|c| [c.x, c.y]).collect();
    assert_eq!(
        u,
        plumenet::ste::Uncertainty::of(&cells, &p, report.estimate, None)
    );

    let dir = tmp.path().join("study");
    plumenet_ok(&[
        "experiment",
        "--solver",
        "--no-cache",
        "--runs",
        "2",
        "--features",
        "value,rank",
        "--sensors",
        "sensor-ii",
        "--max-iterations",
        "3",
        "--out",
        dir.to_str().unwrap(),
    ]);
    let runs = std::fs::read_to_string(dir.join("runs.csv")).unwrap();
    assert_eq!(runs.lines().count(), 1 + 4);
    assert!(runs.starts_with("layout,model,reality,paths,feature,sensor,run,seed,source_x"));
    let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
    assert!(
        summary.contains("| wind-tunnel | solver | none | planner | rank | sensor-ii | 2 |"),
        "{summary}"
    );
    assert!(summary.contains("| highest reading (m) | centre (m) |"));
    assert!(summary.contains("| 50% region covers | 90% region covers | 90% region median (m²) |"));
    // Each run states its regions and whether they hold the source, consistently with the
    // source's level.
    let mut reader = csv::Reader::from_reader(runs.as_bytes());
    for row in reader.deserialize::<plumenet::study::experiment::RunRow>() {
        let row = row.unwrap();
        assert_eq!(row.covers_50, Some(row.source_level < 0.5));
        assert_eq!(row.covers_90, Some(row.source_level < 0.9));
        assert!(row.area_50_m2 > 0.0 && row.area_50_m2 <= row.area_90_m2);
        assert!(row.mass_50 >= 0.5 - 1e-9 && row.mass_90 >= 0.9 - 1e-9);
        assert!(row.mass_50 <= row.mass_90 && row.mass_90 <= 1.0);
        assert!(row.expected_distance_m >= 0.0 && row.log_p_source <= 0.0);
    }
    assert!(dir.join("boxplots.png").exists());
}

/// `experiment --rooms-of` runs in the layouts of a generated dataset (unseen rooms).
#[test]
fn experiment_runs_in_the_rooms_of_a_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("rooms");
    let d = data.to_str().unwrap();
    // Seed 12 draws a 7 m x 3 m room with the wind from the south.
    plumenet_ok(&[
        "generate",
        "--out",
        d,
        "--layouts",
        "1",
        "--sources",
        "1",
        "--seed",
        "12",
    ]);
    let out = tmp.path().join("study");
    let run = |rooms: &str| {
        plumenet(&[
            "experiment",
            "--solver",
            "--no-cache",
            "--rooms-of",
            d,
            "--rooms",
            rooms,
            "--runs",
            "1",
            "--features",
            "rank",
            "--sensors",
            "sensor-ii",
            "--max-iterations",
            "2",
            "--out",
            out.to_str().unwrap(),
        ])
    };
    assert!(run("1").status.success());
    let runs = std::fs::read_to_string(out.join("runs.csv")).unwrap();
    let row = runs.lines().nth(1).unwrap();
    assert!(
        row.starts_with("rooms-0,solver,none,planner,rank,sensor-ii,0,"),
        "{row}"
    );
    assert_eq!(
        runs.lines().count(),
        2,
        "only the dataset's room, not the default arena"
    );
    assert_clean_failure(&run("2"), "--rooms 2 is not between 1 and the 1 layouts");
}

#[test]
fn a_survey_log_replays_with_errors_and_the_mismatch_suite_runs() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("survey.csv");
    let out = plumenet_ok(&[
        "survey",
        "--source",
        "4.5,2.3",
        "--spacing",
        "1",
        "--reality-background",
        "0.5",
        "--seed",
        "2",
        "--out",
        log.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        stdout.contains("18 lanes") && stdout.contains("background 0.5"),
        "{stdout}"
    );
    let text = std::fs::read_to_string(&log).unwrap();
    assert!(text.starts_with("t,x,y,value\n"));
    let json_path = tmp.path().join("replay.json");
    plumenet_ok(&[
        "replay",
        "--solver",
        "--no-cache",
        "--log",
        log.to_str().unwrap(),
        "--source",
        "4.5,2.3",
        "--json",
        json_path.to_str().unwrap(),
    ]);
    let rep = read_json(&json_path);
    assert_eq!(
        rep["samples"].as_u64().unwrap() as usize,
        text.lines().count() - 1
    );
    let [ex, ey] = [0, 1].map(|k| rep["estimate"][k].as_f64().unwrap());
    assert!((rep["error_m"].as_f64().unwrap() - (ex - 4.5).hypot(ey - 2.3)).abs() < 1e-9);
    for guess in ["highest_reading", "centre"] {
        let g = &rep["baselines"][guess];
        let e = (g["x"].as_f64().unwrap() - 4.5).hypot(g["y"].as_f64().unwrap() - 2.3);
        assert!((g["error_m"].as_f64().unwrap() - e).abs() < 1e-9, "{guess}");
    }
    // Thinned: at most that many readings reach the STE; the baselines still see them all.
    let thinned_path = tmp.path().join("thinned.json");
    let out = plumenet_ok(&[
        "replay",
        "--solver",
        "--no-cache",
        "--log",
        log.to_str().unwrap(),
        "--source",
        "4.5,2.3",
        "--thin-to",
        "100",
        "--json",
        thinned_path.to_str().unwrap(),
    ]);
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("thinned to"), "{stdout}");
    let thinned = read_json(&thinned_path);
    let used = thinned["samples"].as_u64().unwrap();
    assert!((51..=100).contains(&used), "{used}");
    assert_eq!(thinned["log_readings"], rep["samples"]);
    assert_eq!(thinned["baselines"], rep["baselines"]);

    // The suite, and the suite with the walled wander in place of the whole-field wander.
    for walled in [false, true] {
        let dir = tmp.path().join(format!("suite-{walled}"));
        let mut args = vec![
            "experiment",
            "--solver",
            "--no-cache",
            "--mismatch",
            "--paths",
            "lawnmower",
            "--survey-spacing",
            "2",
            "--runs",
            "1",
            "--features",
            "rank",
            "--sensors",
            "sensor-ii",
            "--out",
            dir.to_str().unwrap(),
        ];
        if walled {
            args.push("--reality-meander-walled");
        }
        plumenet_ok(&args);
        let summary = std::fs::read_to_string(dir.join("summary.md")).unwrap();
        let meander = if walled {
            "meander 30° walled"
        } else {
            "meander 30°"
        };
        for reality in [
            "| none |".to_string(),
            "| wind x0.5 |".to_string(),
            "| diffusivity x3 |".to_string(),
            format!("| {meander} |"),
            "| background 1 |".to_string(),
            format!("| wind x0.5, diffusivity x3, {meander}, background 1 |"),
        ] {
            assert!(summary.contains(&reality), "{reality} missing in {summary}");
        }
        assert_eq!(summary.matches("| survey |").count(), 6);
    }
}

#[test]
fn bad_ste_input_fails_cleanly() {
    let tmp = tempfile::tempdir().unwrap();
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, "t,x,value\n0,1,2\n").unwrap();
    let out = plumenet(&[
        "replay",
        "--solver",
        "--no-cache",
        "--log",
        bad.to_str().unwrap(),
    ]);
    assert_clean_failure(&out, "missing column 'y'");
    let out = plumenet(&["replay", "--solver", "--thin-to", "0", "--log", "x.csv"]);
    assert_clean_failure(&out, "--thin-to");
    let out = plumenet(&["localize", "--solver", "--no-cache", "--source", "7,1"]);
    assert_clean_failure(&out, "inside obstacle");
    let out = plumenet(&[
        "localize",
        "--no-cache",
        "--model",
        "models/missing",
        "--source",
        "3,2",
    ]);
    assert_clean_failure(&out, "models/missing");
    let out = plumenet(&[
        "localize",
        "--solver",
        "--no-cache",
        "--source",
        "3,2",
        "--rank-tolerance",
        "0.5",
    ]);
    assert_clean_failure(&out, "rank tolerance must be a factor of at least 1");
    let log = tmp.path().join("log.csv");
    for (flags, needle) in [
        (
            &["--reality-wind-scale", "-1"][..],
            "--reality-wind-scale must be a positive number",
        ),
        (
            &["--reality-meander-deg", "120"][..],
            "between 0 and 90 degrees",
        ),
        (
            &["--reality-meander-walled"][..],
            "--reality-meander-walled needs a wander",
        ),
        (&["--spacing", "40"][..], "does not fit the arena"),
    ] {
        let mut args = vec!["survey", "--source", "3,2", "--out", log.to_str().unwrap()];
        args.extend_from_slice(flags);
        assert_clean_failure(&plumenet(&args), needle);
        assert!(!log.exists(), "no log after a failed survey");
    }
    let out = plumenet(&[
        "localize",
        "--solver",
        "--no-cache",
        "--source",
        "3,2",
        "--reality-background",
        "-2",
    ]);
    assert_clean_failure(&out, "--reality-background must be zero or positive");
    for (flag, value, needle) in [
        (
            "--background-rise",
            "-1",
            "background rise must be zero or positive",
        ),
        (
            "--background-time",
            "0",
            "background time constant must be a positive",
        ),
        ("--wind-spreads", "0,120", "between 0 and 90 degrees"),
        (
            "--model-rank-factor",
            "0.5",
            "rank factor must be at least 1",
        ),
        ("--lag-exponent", "0", "lag's exponent must lie in (0, 1]"),
        ("--lag-exponent", "1.5", "lag's exponent must lie in (0, 1]"),
        ("--detection-floor", "-1", "detection floor"),
        (
            "--wind-wander",
            "70",
            "wander must be between 0 and 60 degrees",
        ),
        (
            "--wind-wander",
            "-5",
            "wander must be between 0 and 60 degrees",
        ),
    ] {
        let args = [
            "localize",
            "--solver",
            "--no-cache",
            "--source",
            "3,2",
            flag,
            value,
        ];
        assert_clean_failure(&plumenet(&args), needle);
    }
    let out = plumenet(&[
        "experiment",
        "--solver",
        "--mismatch",
        "--reality-background",
        "1",
    ]);
    assert_clean_failure(&out, "cannot be used with");
    let out = plumenet(&[
        "localize",
        "--solver",
        "--source",
        "3,2",
        "--paper-rank",
        "--clean-air-model-ties",
    ]);
    assert_clean_failure(&out, "cannot be used with");
}

/// `serve` over TCP with a state file: killed with SIGKILL in the middle of a stream and
/// restarted, it ends with the posterior of an uninterrupted session.
#[test]
fn serve_survives_sigkill_with_its_state_file() {
    use std::io::{BufRead, BufReader, Write};
    let tmp = tempfile::tempdir().unwrap();
    let state = tmp.path().join("state.jsonl");
    let start = || spawn_server(&["--solver".as_ref(), "--state".as_ref(), state.as_os_str()]);
    let talk = |at: &str, lines: &[String]| -> Vec<serde_json::Value> {
        let stream = std::net::TcpStream::connect(at).unwrap();
        let mut reader = BufReader::new(stream.try_clone().unwrap());
        let mut writer = stream;
        lines
            .iter()
            .map(|l| {
                writeln!(writer, "{l}").unwrap();
                let mut reply = String::new();
                reader.read_line(&mut reply).unwrap();
                serde_json::from_str(&reply).unwrap()
            })
            .collect()
    };
    let batch = |id: usize, k: usize| {
        let readings: Vec<serde_json::Value> = (0..50)
            .map(|i| {
                let t = 0.1 * (k * 50 + i) as f64;
                let x = 16.0 - 0.02 * (k * 50 + i) as f64;
                serde_json::json!({"t": t, "x": x, "y": 2.0, "value": 1.0 + 0.1 * (-(x - 5.0f64).powi(2)).exp()})
            })
            .collect();
        serde_json::json!({"id": id, "op": "readings", "readings": readings}).to_string()
    };
    let belief = r#"{"id":99,"op":"belief"}"#.to_string();
    let update = r#"{"id":98,"op":"iterate"}"#.to_string();
    // Uninterrupted.
    std::fs::write(&state, "").unwrap();
    let (mut child, at) = start();
    let mut lines: Vec<String> = (0..10).map(|k| batch(k, k)).collect();
    lines.extend([update.clone(), belief.clone()]);
    let whole = talk(&at, &lines);
    child.kill().unwrap();
    child.wait().unwrap();
    // Killed after the fifth batch, restarted on the same file, the rest sent again from the
    // last acknowledged batch.
    std::fs::write(&state, "").unwrap();
    let (mut child, at) = start();
    let first = talk(&at, &lines[..5]);
    assert_eq!(first[4]["accepted"], 250);
    child.kill().unwrap();
    child.wait().unwrap();
    let (mut child, at) = start();
    let rest = talk(&at, &lines[5..]);
    child.kill().unwrap();
    child.wait().unwrap();
    assert_eq!(rest[4]["accepted"], 500);
    // The same posterior up to round-off (one update of 500 readings against updates of 250
    // and 250).
    let p = |r: &serde_json::Value| -> Vec<f64> {
        r["posterior"]
            .as_array()
            .unwrap()
            .iter()
            .map(|c| c["p"].as_f64().unwrap())
            .collect()
    };
    let (a, b) = (p(rest.last().unwrap()), p(whole.last().unwrap()));
    assert_eq!(a.len(), b.len());
    let worst = a
        .iter()
        .zip(&b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-12, "posteriors differ by up to {worst}");
    assert_eq!(
        rest.last().unwrap()["estimate"],
        whole.last().unwrap()["estimate"]
    );
}

#[test]
fn robot_sim_without_a_server_fails_cleanly() {
    // Port 9 (discard) on loopback: nothing listens there in a test sandbox.
    let out = plumenet(&[
        "robot-sim",
        "--connect",
        "127.0.0.1:9",
        "--source",
        "4.5,2.5",
    ]);
    assert_clean_failure(&out, "cannot connect to");
}

#[test]
fn bench_serve_loses_no_reading() {
    let tmp = tempfile::tempdir().unwrap();
    let json = tmp.path().join("serve.json");
    let out = plumenet_ok(&[
        "bench-serve",
        "--solver",
        "--sizes",
        "300",
        "--rate",
        "50",
        "--seconds",
        "20",
        "--iterate-every",
        "5",
        "--json",
        json.to_str().unwrap(),
    ]);
    assert!(String::from_utf8_lossy(&out.stdout).contains("counted by the server"));
    let report = read_json(&json);
    assert_eq!(report["load"]["sent"], 1000);
    assert_eq!(report["load"]["accepted"], 1000);
    assert_eq!(report["load"]["errors"], 0);
    assert_eq!(report["load"]["round_trips_s"].as_array().unwrap().len(), 4);
    assert!(report["iterations"][0]["iteration_ms"].as_f64().unwrap() > 0.0);
}

/// `-h` shows what an ordinary user sets; `--help` adds every tuning knob under its own
/// heading, each flag still accepted.
#[test]
fn short_help_is_for_users_and_long_help_holds_the_knobs() {
    let flags = |text: &str| {
        text.lines()
            .filter(|l| l.trim_start().starts_with("--") || l.trim_start().starts_with("-h"))
            .count()
    };
    for command in ["localize", "replay", "experiment", "serve"] {
        let short = plumenet_ok(&[command, "-h"]);
        let short = String::from_utf8_lossy(&short.stdout).to_string();
        assert!(flags(&short) <= 16, "{command} -h: {short}");
        assert!(short.contains("see more with '--help'"), "{short}");
        let long = plumenet_ok(&[command, "--help"]);
        let long = String::from_utf8_lossy(&long.stdout).to_string();
        for heading in ["Plume model and bank:", "Likelihood tuning:"] {
            assert!(long.contains(heading), "{command} --help lacks {heading}");
        }
        for knob in [
            "--rank-tolerance",
            "--background-rise",
            "--wind-wander",
            "--cache-dir",
        ] {
            assert!(!short.contains(knob), "{command} -h shows {knob}");
            assert!(long.contains(knob), "{command} --help lacks {knob}");
        }
    }
    let long = plumenet_ok(&["localize", "--help"]);
    let long = String::from_utf8_lossy(&long.stdout).to_string();
    for heading in [
        "Robot and stopping rule:",
        "Simulated reality (mismatch with the plume model):",
    ] {
        assert!(long.contains(heading), "localize --help lacks {heading}");
    }
}

/// A likelihood setting out of range is refused before the plume bank is computed: no bank
/// reaches the cache, and the message names the setting and its value.
#[test]
fn bad_likelihood_settings_fail_before_the_bank() {
    let tmp = tempfile::tempdir().unwrap();
    let cache = tmp.path().join("cache");
    let cache = cache.to_str().unwrap();
    let log = tmp.path().join("log.csv");
    std::fs::write(&log, "t,x,y,value\n0.1,15,1,1.0\n0.2,14.9,1,1.1\n").unwrap();
    let log = log.to_str().unwrap();
    let tolerance = "rank tolerance must be a factor of at least 1, got 0.5";
    let factor = "the model's rank factor must be at least 1, got 0.5";
    let weight = |w: &str| format!("the evidence weight must lie in (0, 1], got {w}");
    let (zero, above, nan) = (weight("0"), weight("1.5"), weight("NaN"));
    for (args, needle) in [
        (
            &["localize", "--source", "4.5,2.5", "--evidence-weight", "0"][..],
            zero.as_str(),
        ),
        (
            &["replay", "--log", log, "--evidence-weight", "1.5"][..],
            above.as_str(),
        ),
        (
            &["experiment", "--runs", "1", "--evidence-weight", "NaN"][..],
            nan.as_str(),
        ),
        (
            &["serve", "--fit-reference", "-1"][..],
            "the fit reference must be a positive number, got -1",
        ),
        (
            &["localize", "--source", "4.5,2.5", "--misfit-reference", "0"][..],
            "the misfit reference must be a positive number, got 0",
        ),
        (
            &["replay", "--log", log, "--misfit-reference", "NaN"][..],
            "the misfit reference must be a positive number, got NaN",
        ),
        (
            &[
                "localize",
                "--source",
                "4.5,2.5",
                "--evidence-saturation",
                "-1",
            ][..],
            "the evidence saturation must be a positive number of readings, got -1",
        ),
        (
            &["replay", "--log", log, "--evidence-saturation", "inf"][..],
            "the evidence saturation must be a positive number of readings, got inf",
        ),
        (
            &["localize", "--source", "4.5,2.5", "--background-odds", "0"][..],
            "the background odds must be a positive number, got 0",
        ),
        (
            &["localize", "--source", "4.5,2.5", "--leg-cost", "-1"][..],
            "the leg cost must be a finite number of metres, zero or more, got -1",
        ),
        (
            &["serve", "--leg-cost", "NaN"][..],
            "the leg cost must be a finite number of metres, zero or more, got NaN",
        ),
        (
            &[
                "localize",
                "--source",
                "4.5,2.5",
                "--revisit-radius",
                "-0.5",
            ][..],
            "the revisit radius must be a finite number of metres, zero or more, got -0.5",
        ),
        (
            &["serve", "--revisit-radius", "inf"][..],
            "the revisit radius must be a finite number of metres, zero or more, got inf",
        ),
        (
            &["localize", "--source", "4.5,2.5", "--upwind-probe", "-1"][..],
            "the upwind probe must be a finite number of metres, zero or more, got -1",
        ),
        (
            &["experiment", "--runs", "1", "--upwind-probe", "NaN"][..],
            "the upwind probe must be a finite number of metres, zero or more, got NaN",
        ),
        (
            &["calibration", "--quick", "--target-area", "0"][..],
            "the target area must be a positive number of square metres",
        ),
        (
            &["localize", "--source", "4.5,2.5", "--rank-tolerance", "0.5"][..],
            tolerance,
        ),
        (
            &["replay", "--log", log, "--model-rank-factor", "0.5"][..],
            factor,
        ),
        (
            &["experiment", "--runs", "1", "--rank-tolerance", "0.5"][..],
            tolerance,
        ),
        (&["serve", "--rank-tolerance", "0.5"][..], tolerance),
    ] {
        let mut all = args.to_vec();
        all.extend(["--cache-dir", cache]);
        let out = plumenet(&all);
        assert_clean_failure(&out, needle);
        assert!(
            !std::path::Path::new(cache).exists(),
            "{args:?} computed a bank"
        );
    }
    let out = plumenet(&[
        "localize",
        "--solver",
        "--source",
        "4.5,2.5",
        "--model-rank-factor",
        "0.5",
        "--cache-dir",
        cache,
    ]);
    assert_clean_failure(&out, factor);
    assert!(!std::path::Path::new(cache).exists());
}

/// A small empty room (6 m x 3 m, 0.25 m cells: 288 cells and candidates) for end-to-end runs.
const SMALL_ROOM: &str = r#"{"width_m":6,"height_m":3,"cell_m":0.25,"wind":{"speed_mps":0.5}}"#;

/// `SMALL_ROOM` written into `dir`, and its path.
fn small_room(dir: &std::path::Path) -> String {
    let path = dir.join("room.json");
    std::fs::write(&path, SMALL_ROOM).unwrap();
    path.to_str().unwrap().to_string()
}

/// generate (whole and in shards), merge, train (and continue), eval and predict, each run to
/// success on a tiny dataset.
#[test]
fn the_dataset_and_model_commands_run_end_to_end() {
    let tmp = tempfile::tempdir().unwrap();
    let room = small_room(tmp.path());
    let dir = |name: &str| tmp.path().join(name).to_str().unwrap().to_string();
    let generate = |out: &str, shard: Option<&str>| {
        let mut args = vec![
            "generate",
            "--base",
            &room,
            "--layouts",
            "2",
            "--sources",
            "3",
            "--seed",
            "5",
            "--out",
            out,
        ];
        args.extend(shard.iter().flat_map(|s| ["--shard", *s]));
        plumenet_ok(&args);
    };
    generate(&dir("whole"), None);
    generate(&dir("shard0"), Some("0/2"));
    generate(&dir("shard1"), Some("1/2"));
    plumenet_ok(&[
        "merge",
        "--out",
        &dir("merged"),
        &dir("shard0"),
        &dir("shard1"),
    ]);
    // The merged shards are the whole dataset, byte for byte, manifest included.
    let files = |d: &str| {
        let mut names: Vec<_> = std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        names.sort();
        names
    };
    assert_eq!(files(&dir("merged")), files(&dir("whole")));
    for name in files(&dir("whole")) {
        assert!(
            std::fs::read(tmp.path().join("merged").join(&name)).unwrap()
                == std::fs::read(tmp.path().join("whole").join(&name)).unwrap(),
            "{name:?} differs"
        );
    }

    let train = |epochs: &str| {
        plumenet_ok(&[
            "train",
            "--data",
            &dir("merged"),
            "--out",
            &dir("model"),
            "--epochs",
            epochs,
            "--filters",
            "4,8",
            "--batch-size",
            "2",
        ])
    };
    let first = String::from_utf8_lossy(&train("2").stdout).to_string();
    assert!(
        first.contains("epoch   2") && !first.contains("epoch   3"),
        "{first}"
    );
    // A finished training continued with more epochs resumes from its checkpoint.
    let more = String::from_utf8_lossy(&train("3").stdout).to_string();
    assert!(
        more.contains("resuming at epoch 3") && more.contains("epoch   3"),
        "{more}"
    );
    assert!(!more.contains("epoch   1 "), "{more}");

    // `eval` with `extra` flags: its JSON report, or its failure.
    let eval = |name: &str, extra: &[&str]| {
        let path = tmp.path().join(format!("{name}.json"));
        let (model, data) = (dir("model"), dir("whole"));
        let mut args = vec!["eval", "--model", &model, "--data", &data];
        args.extend(extra);
        args.extend(["--json", path.to_str().unwrap()]);
        let out = plumenet(&args);
        (out.status.success()).then(|| read_json(&path)).ok_or(out)
    };
    let scores = eval("eval", &[]).unwrap();
    assert_eq!(scores["summary"]["maps"], 6);
    assert_eq!(scores["maps"].as_array().unwrap().len(), 6);
    let l2 = scores["summary"]["median_relative_l2"].as_f64().unwrap();
    assert!(l2.is_finite() && l2 >= 0.0, "{l2}");
    // The coarse form's bound: at level 0 the best correction is the truth itself; at level 2
    // (0.5 m cells) it misses.
    let exact = eval("bound-0", &["--coarse-bound", "0"]).unwrap()["summary"].clone();
    assert!(
        exact["median_relative_l2"].as_f64().unwrap() < 1e-5,
        "{exact}"
    );
    assert!(exact["p10_spearman"].as_f64().unwrap() > 0.9999, "{exact}");
    let coarse =
        eval("bound-2", &["--coarse-bound", "2"]).unwrap()["summary"]["median_relative_l2"]
            .as_f64()
            .unwrap();
    assert!(coarse > 1e-3 && coarse.is_finite(), "{coarse}");
    // Shared by blocks of 2 x 2 cells, each source is predicted at level 0 by the map of its
    // block's centre (at most 0.09 m away) moved by the difference of the two priors: no
    // longer the truth, yet a map that overlaps it (maps that do not overlap score above 1).
    let shared = eval("shared", &["--coarse-bound", "0", "--coarse-share", "1"]).unwrap();
    let moved = shared["summary"]["median_relative_l2"].as_f64().unwrap();
    assert!(moved > 1e-4 && moved < 1.0, "{shared}");
    assert!(shared["summary"]["maps"].as_u64().unwrap() >= 1, "{shared}");
    assert_clean_failure(
        &eval("bound-5", &["--coarse-bound", "5"]).unwrap_err(),
        "--coarse-bound",
    );
    // A model without the analytic prior has no coarse bound.
    assert_clean_failure(
        &plumenet(&[
            "eval",
            "--model",
            "models/arena-v1",
            "--data",
            &dir("whole"),
            "--coarse-bound",
            "1",
        ]),
        "inputs hold no analytic prior",
    );

    let field = tmp.path().join("field.npy");
    plumenet_ok(&[
        "predict",
        "--model",
        &dir("model"),
        "--layout",
        &room,
        "--source",
        "1.5,1.5",
        "--out",
        field.to_str().unwrap(),
    ]);
    let f = read_npy::<f32, Ix2>(&field).unwrap();
    assert_eq!(f.dim(), (12, 24));
    assert!(f.iter().all(|v| v.is_finite() && *v >= 0.0));

    // The operator network trains, and `bench --model` times its bank beside the solver's.
    plumenet_ok(&[
        "train",
        "--data",
        &dir("merged"),
        "--out",
        &dir("operator"),
        "--epochs",
        "1",
        "--filters",
        "4,8",
        "--batch-size",
        "3",
        "--operator",
    ]);
    let bench = bench_json(tmp.path(), &room, &["--model", &dir("operator")]);
    let (model, solver) = (
        bench["model_bank_ms"].as_f64().unwrap(),
        bench["total_ms"].as_f64().unwrap(),
    );
    assert!(model > 0.0 && solver > 0.0, "{bench}");
    assert!(
        (bench["model_over_solver"].as_f64().unwrap() - model / solver).abs() < 1e-9,
        "{bench}"
    );

    // So does its coarse form (five levels: the room's U-Net decodes to level 2, where a
    // per-source network of two levels pools once); `--coarse` without `--operator` is
    // refused.
    let merged = dir("merged");
    let coarse = |out: &str, extra: &[&str]| {
        let mut args = vec![
            "train",
            "--data",
            &merged,
            "--out",
            out,
            "--epochs",
            "1",
            "--filters",
            "4,4,4,4,4",
            "--batch-size",
            "3",
            "--coarse",
        ];
        args.extend_from_slice(extra);
        plumenet(&args)
    };
    let coarse_dir = dir("coarse");
    assert_clean_failure(&coarse(&coarse_dir, &[]), "--operator");
    assert!(
        coarse(&coarse_dir, &["--operator", "--coarse-filters", "4,6"])
            .status
            .success()
    );
    let saved = read_json(tmp.path().join("coarse").join("config.json"));
    let per_source = &saved["architecture"]["operator"]["coarse"];
    assert_eq!(per_source["level"], 2);
    assert_eq!(per_source["filters"], serde_json::json!([4, 6]));
    let bench = bench_json(tmp.path(), &room, &["--model", &coarse_dir]);
    assert!(bench["model_bank_ms"].as_f64().unwrap() > 0.0, "{bench}");

    // Its per-candidate variant: `--coarse-level 1` puts the per-source network on 0.25 m
    // cells; a level the room's U-Net cannot give, or one without `--coarse`, is refused.
    let fine_dir = dir("fine");
    let fine = &["--operator", "--coarse-filters", "4,6", "--coarse-level"];
    for bad in ["0", "9", "x"] {
        let out = coarse(&fine_dir, &[fine.as_slice(), &[bad]].concat());
        assert_clean_failure(&out, "--coarse-level");
    }
    assert_clean_failure(
        &plumenet(&[
            "train",
            "--data",
            &merged,
            "--out",
            &fine_dir,
            "--operator",
            "--coarse-level",
            "1",
        ]),
        "--coarse",
    );
    assert!(
        coarse(&fine_dir, &[fine.as_slice(), &["1"]].concat())
            .status
            .success()
    );
    let saved = read_json(tmp.path().join("fine").join("config.json"));
    assert_eq!(saved["architecture"]["operator"]["coarse"]["level"], 1);
    let bench = bench_json(tmp.path(), &room, &["--model", &fine_dir]);
    assert!(bench["model_bank_ms"].as_f64().unwrap() > 0.0, "{bench}");
}

/// The figures `bench` writes for `room` (one repeat, no Python reference) with `extra`
/// arguments, through a JSON file in `dir`.
fn bench_json(dir: &std::path::Path, room: &str, extra: &[&str]) -> serde_json::Value {
    let json = dir.join("bench.json");
    let mut args = vec![
        "bench",
        "--layout",
        room,
        "--repeats",
        "1",
        "--no-reference",
        "--json",
        json.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    plumenet_ok(&args);
    read_json(&json)
}

/// bench (without its Python reference) and bench-ste run to success on a small room and write
/// their figures.
#[test]
fn the_benchmarks_run_on_a_small_room() {
    let tmp = tempfile::tempdir().unwrap();
    let room = small_room(tmp.path());
    let bench = bench_json(tmp.path(), &room, &[]);
    assert_eq!(bench["candidates"], 288);
    assert_eq!(bench["unknowns"], 288);
    assert!(bench["total_ms"].as_f64().unwrap() > 0.0);

    let json = tmp.path().join("bench-ste.json");
    plumenet_ok(&[
        "bench-ste",
        "--layout",
        &room,
        "--samples",
        "200",
        "--batch",
        "20",
        "--repeats",
        "1",
        "--source",
        "1.5,1.5",
        "--start",
        "5,1",
        "--json",
        json.to_str().unwrap(),
    ]);
    let ste = read_json(&json);
    let updates = ste["updates"].as_array().unwrap();
    assert!(updates.len() >= 2, "{ste}");
    assert!(
        updates
            .iter()
            .all(|u| u["candidates"] == 288 && u["update_ms"].as_f64().unwrap() > 0.0)
    );
    assert!(ste["run_iterations"].as_u64().unwrap() >= 1);
    // The arena's default start does not fit this room: one clear line, before any timing.
    let out = plumenet(&["bench-ste", "--layout", &room]);
    assert_clean_failure(
        &out,
        "invalid source position (15, 1): the robot cannot start here",
    );
    assert!(
        out.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&out.stdout)
    );
}

/// serve on its standard input answers every line, the bad ones with an error, and robot-sim
/// drives a served session to its end.
#[test]
fn serve_on_stdin_and_robot_sim_against_a_server_run_to_the_end() {
    use std::io::{BufRead, BufReader, Write};
    let tmp = tempfile::tempdir().unwrap();
    let room = small_room(tmp.path());
    let mut child = command()
        .args(["serve", "--solver", "--layout", &room])
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let lines = [
        r#"{"id":1,"op":"readings","readings":[{"t":0.0,"x":5.0,"y":1.5,"value":1.0},{"t":0.1,"x":4.9,"y":1.5,"value":1.2}]}"#,
        r#"{"id":2,"op":"iterate","position":[4.9,1.5]}"#,
        "[1,2]",
        r#"{"id":3,"op":"belief"}"#,
    ];
    {
        let mut stdin = child.stdin.take().unwrap();
        for line in lines {
            writeln!(stdin, "{line}").unwrap();
        }
    }
    let replies: Vec<serde_json::Value> = BufReader::new(child.stdout.take().unwrap())
        .lines()
        .map(|l| serde_json::from_str(&l.unwrap()).unwrap())
        .collect();
    assert!(
        child.wait().unwrap().success(),
        "serve ends when its input does"
    );
    assert_eq!(replies.len(), lines.len());
    assert_eq!(replies[0]["accepted"], 2);
    assert!(replies[1]["path"].is_array(), "{}", replies[1]);
    assert_eq!(replies[2]["ok"], false);
    assert_eq!(replies[3]["posterior"].as_array().unwrap().len(), 288);

    let (mut server, at) = spawn_server(&["--solver".as_ref(), "--layout".as_ref(), room.as_ref()]);
    let json = tmp.path().join("robot.json");
    let out = plumenet(&[
        "robot-sim",
        "--connect",
        &at,
        "--layout",
        &room,
        "--source",
        "1.5,1.5",
        "--start",
        "5,1",
        "--max-iterations",
        "5",
        "--json",
        json.to_str().unwrap(),
    ]);
    server.kill().unwrap();
    server.wait().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    // Five legs, the budget given, each ending in an iterate reply; the readings all counted.
    let run = read_json(&json);
    assert_eq!(run["legs"], 5, "{run}");
    assert_eq!(run["last"]["iteration"], 5, "{run}");
    assert_eq!(run["last"]["readings"], run["readings"], "{run}");
    assert!(run["error_m"].as_f64().unwrap().is_finite());
}

/// A state file written by a session of another room or another feature (or plume model: the
/// session's name holds all three) is refused with one line before anything is served, and left
/// untouched.
#[test]
fn serve_refuses_a_state_file_of_another_session() {
    let tmp = tempfile::tempdir().unwrap();
    let room = small_room(tmp.path());
    let state = tmp.path().join("state.jsonl");
    let state = state.to_str().unwrap();
    let serve = |args: &[&str]| {
        let mut child = command()
            .args(["serve", "--state", state])
            .args(args)
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        {
            use std::io::Write;
            // A server that refuses its state file exits without reading: ignore a broken pipe.
            let mut stdin = child.stdin.take().unwrap();
            let _ = writeln!(
                stdin,
                r#"{{"id":1,"op":"readings","readings":[{{"t":0.0,"x":5.0,"y":1.5,"value":1.0}}]}}"#
            );
        }
        child.wait_with_output().unwrap()
    };
    let first = serve(&["--solver", "--layout", &room]);
    assert!(
        first.status.success(),
        "{}",
        String::from_utf8_lossy(&first.stderr)
    );
    let written = std::fs::read(state).unwrap();
    // The same session again: restored.
    let again = serve(&["--solver", "--layout", &room]);
    assert!(String::from_utf8_lossy(&again.stderr).contains("1 readings in 1 batches restored"));
    let written = std::fs::read(state).unwrap().len().max(written.len());
    for other in [
        vec!["--solver"],
        vec!["--solver", "--layout", &room, "--feature", "value"],
    ] {
        let out = serve(&other);
        assert_clean_failure(&out, "holds the readings of another session (layout room");
        assert_eq!(
            String::from_utf8_lossy(&out.stderr)
                .lines()
                .filter(|l| l.starts_with("error"))
                .count(),
            1
        );
        assert!(out.stdout.is_empty());
        assert_eq!(std::fs::read(state).unwrap().len(), written);
    }
}

/// The calibration benchmark's quick form runs to success (one iteration per run, so that the
/// banks are most of its cost) and writes its table, rows and picture: every suite with both
/// plume models, each row's coverages between 0 and 1 and its run counts whole, and its
/// median distance driven that of the suite's runs.
#[test]
fn the_calibration_benchmark_runs_in_its_quick_form() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("calibration");
    plumenet_ok(&[
        "calibration",
        "--quick",
        "--max-iterations",
        "1",
        "--out",
        out.to_str().unwrap(),
    ]);
    let rows = read_json(out.join("calibration.json"));
    let rows = rows.as_array().unwrap();
    let mut cells: Vec<(String, String)> = rows
        .iter()
        .map(|r| {
            let text = |k: &str| r[k].as_str().unwrap().to_string();
            (text("suite"), text("model"))
        })
        .collect();
    cells.sort();
    let mut expected = Vec::new();
    for suite in ["arena", "mismatch", "surveys", "unseen rooms"] {
        for model in ["plumenet", "solver"] {
            expected.push((suite.to_string(), model.to_string()));
        }
    }
    assert_eq!(cells, expected);
    for r in rows {
        let runs = r["runs"].as_u64().unwrap();
        assert!(runs > 0, "{r}");
        for k in ["cover_50", "cover_90"] {
            let c = r[k].as_f64().unwrap();
            assert!((0.0..=1.0).contains(&c), "{r}");
            // A share of whole runs.
            assert!(
                (c * runs as f64 - (c * runs as f64).round()).abs() < 1e-9,
                "{r}"
            );
        }
        assert!(r["cover_50"].as_f64() <= r["cover_90"].as_f64(), "{r}");
        // What a calibrated posterior's regions would hold: their mean mass, at least the
        // level.
        let [m50, m90] = ["mass_50_mean", "mass_90_mean"].map(|k| r[k].as_f64().unwrap());
        assert!(
            0.5 <= m50 && m50 <= m90 && (0.9..=1.0).contains(&m90),
            "{r}"
        );
        // The median distance driven is the median of the suite's runs of that model.
        let suite = r["suite"].as_str().unwrap().replace(' ', "-");
        let runs_csv = std::fs::read_to_string(out.join(suite).join("runs.csv")).unwrap();
        let model_runs: Vec<plumenet::study::experiment::RunRow> =
            csv::Reader::from_reader(runs_csv.as_bytes())
                .deserialize::<plumenet::study::experiment::RunRow>()
                .map(|row| row.unwrap())
                .filter(|row| row.model == r["model"].as_str().unwrap())
                .collect();
        let mut distances: Vec<f64> = model_runs.iter().map(|row| row.distance_m).collect();
        assert_eq!(distances.len() as u64, runs, "{r}");
        // The PIT columns are the runs' mean PIT, from their level and log posterior.
        for (key, u) in [("pit_50_mean", 0.5), ("pit_90_mean", 0.9)] {
            let mean = model_runs
                .iter()
                .map(|row| plumenet::ste::credible::pit(row.source_level, row.log_p_source, u))
                .sum::<f64>()
                / runs as f64;
            assert!((r[key].as_f64().unwrap() - mean).abs() < 1e-9, "{r}: {key}");
        }
        distances.sort_by(f64::total_cmp);
        let n = distances.len();
        let median = 0.5 * (distances[(n - 1) / 2] + distances[n / 2]);
        assert!(median > 0.0, "{r}");
        assert!(
            (r["distance_median_m"].as_f64().unwrap() - median).abs() < 1e-9,
            "{r}: {median}"
        );
    }
    let csv = std::fs::read_to_string(out.join("calibration.csv")).unwrap();
    assert_eq!(csv.lines().count(), rows.len() + 1);
    assert!(
        std::fs::read_to_string(out.join("calibration.md"))
            .unwrap()
            .contains("| suite |")
    );
    let picture = image::open(out.join("reliability.png")).unwrap();
    assert!(picture.width() > 300 && picture.height() > 200);
}
