//! Mismatched realities, the baselines and raster surveys: each knob does what it says and
//! nothing else, against closed forms (the fully mixed concentration, the Ornstein-Uhlenbeck
//! process's moments) and brute force.

use plumenet::physics::filament::{FilamentConfig, FilamentPlume};
use plumenet::physics::wind::WindField;
use plumenet::sim::survey::{fly, lawnmower};
use plumenet::sim::{EpisodeConfig, Mismatch, Reality};
use plumenet::ste::params::RankParams;
use plumenet::ste::posterior::Sample;
use plumenet::ste::robot::Occupancy;
use plumenet::ste::{Baselines, Feature, SensorPreset, SteParams};

use crate::common::{assert_err, empty_tunnel, wind_tunnel};

const SOURCE: (f64, f64) = (3.0, 2.0);

#[test]
fn the_background_adds_exactly_its_level_and_leaves_the_plume_alone() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let with = FilamentConfig {
        background: 1.0,
        ..FilamentConfig::default()
    };
    let mut plain = FilamentPlume::new(&l, &w, SOURCE, FilamentConfig::default(), 5).unwrap();
    let mut mixed = FilamentPlume::new(&l, &w, SOURCE, with, 5).unwrap();
    // q / (U H) with q = 1, U = 0.75 m/s, H = 4 m, risen for one time constant.
    let full = 1.0 / (0.75 * 4.0);
    for step in 1..=600 {
        plain.step();
        mixed.step();
        let t = 0.1 * f64::from(step);
        let level = full * (1.0 - (-t / 60.0).exp());
        assert!((mixed.background_level() - level).abs() < 1e-12 * full);
        if step % 100 == 0 {
            for (x, y) in [(1.0, 2.0), (6.0, 2.0), (10.0, 0.5), (16.0, 3.5)] {
                let extra = mixed.concentration_at(x, y) - plain.concentration_at(x, y);
                assert!(
                    (extra - level).abs() < 1e-9,
                    "({x}, {y}): {extra} vs {level}"
                );
            }
            assert_eq!(
                mixed.concentration_at(7.0, 1.2),
                0.0,
                "none inside obstacles"
            );
        }
    }
    assert_eq!(plain.len(), mixed.len(), "the same filaments");
}

#[test]
fn the_meander_is_an_ornstein_uhlenbeck_angle_and_off_by_default() {
    let l = empty_tunnel();
    let w = WindField::solve(&l).unwrap();
    let config = FilamentConfig {
        meander_deg: 30.0,
        ..FilamentConfig::default()
    };
    let mut plume = FilamentPlume::new(&l, &w, SOURCE, config, 11).unwrap();
    // 16 000 s = 800 correlation times, sampled every 2 s.
    let angles: Vec<f64> = (0..8000)
        .map(|_| {
            plume.advance(2.0);
            plume.meander_deg()
        })
        .collect();
    // The bounds are about four standard errors of the estimates for an AR(1) series of 8000
    // samples with lag-one correlation r = exp(-0.1): the mean's 30 / sqrt(8000 (1 - r) /
    // (1 + r)) = 1.5 degrees (bound 6); the standard deviation's 30 / sqrt(2 * 8000 (1 - r^2)
    // / (1 + r^2)) = 0.75 (bound 3); the lag-20 s correlation's 0.027 by Bartlett's formula
    // (bound 0.1).
    let n = angles.len() as f64;
    let mean = angles.iter().sum::<f64>() / n;
    let var = angles.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / n;
    assert!(
        (var.sqrt() - 30.0).abs() < 3.0,
        "standard deviation {}",
        var.sqrt()
    );
    assert!(mean.abs() < 6.0, "mean {mean}");
    // Autocorrelation at a lag of 20 s (10 samples) is exp(-1).
    let lag = 10;
    let cov = angles
        .windows(lag + 1)
        .map(|w| (w[0] - mean) * (w[lag] - mean))
        .sum::<f64>()
        / (n - lag as f64);
    let rho = cov / var;
    assert!(
        (rho - (-1.0f64).exp()).abs() < 0.1,
        "lag-20 s correlation {rho}"
    );
    let steady = FilamentPlume::new(&l, &w, SOURCE, FilamentConfig::default(), 11).unwrap();
    assert_eq!(steady.meander_deg(), 0.0);
}

#[test]
fn reality_scales_wind_and_diffusivity_and_keeps_mass_flux() {
    let l = empty_tunnel();
    let w = WindField::solve(&l).unwrap();
    // Far downwind in an empty arena the crosswind mean of the time average is q / (U H): the
    // whole release crosses every section, carried by the reality's wind, not the layout's.
    let section_mean = |mismatch: Mismatch| {
        let reality = Reality::new(&l, &w, mismatch).unwrap();
        let mut plume = reality.plume([SOURCE.0, SOURCE.1], 0.1, 3).unwrap();
        plume.advance(80.0);
        let ys: Vec<f64> = (0..16).map(|k| 0.125 + 0.25 * f64::from(k)).collect();
        let steps = 4000;
        let mut sum = 0.0;
        for _ in 0..steps {
            plume.step();
            sum += ys
                .iter()
                .map(|&y| plume.concentration_at(12.0, y))
                .sum::<f64>();
        }
        sum / (steps * ys.len()) as f64
    };
    for (scale, d) in [(1.0, 1.0), (0.5, 3.0)] {
        let m = Mismatch {
            wind_scale: scale,
            diffusivity_scale: d,
            ..Mismatch::NONE
        };
        let reality = Reality::new(&l, &w, m).unwrap();
        assert_eq!(reality.layout().wind_speed(), 0.75 * scale);
        assert!((reality.layout().diffusivity() - 0.05 * d).abs() < 1e-15);
        let expected = 1.0 / (0.75 * scale * 4.0);
        let got = section_mean(m);
        assert!(
            (got / expected - 1.0).abs() < 0.12,
            "wind x{scale}: section mean {got}, expected {expected}"
        );
    }
}

#[test]
fn bad_knobs_are_named() {
    let l = empty_tunnel();
    let w = WindField::solve(&l).unwrap();
    for (m, needle) in [
        (
            Mismatch {
                wind_scale: -1.0,
                ..Mismatch::NONE
            },
            "--reality-wind-scale",
        ),
        (
            Mismatch {
                diffusivity_scale: f64::NAN,
                ..Mismatch::NONE
            },
            "--reality-diffusivity-scale",
        ),
        (
            Mismatch {
                meander_deg: 91.0,
                ..Mismatch::NONE
            },
            "between 0 and 90",
        ),
        (
            Mismatch {
                background: -0.1,
                ..Mismatch::NONE
            },
            "--reality-background",
        ),
    ] {
        let err = Reality::new(&l, &w, m).unwrap_err().to_string();
        assert!(err.contains(needle), "{err}");
    }
    let suite = Mismatch::suite();
    assert_eq!(suite.len(), 6);
    assert!(suite[0].is_none() && suite[1..].iter().all(|m| !m.is_none()));
    assert_eq!(suite[0].to_string(), "none");
    assert_eq!(
        suite[5].to_string(),
        "wind x0.5, diffusivity x3, meander 30°, background 1"
    );
}

#[test]
fn baselines_are_the_highest_reading_and_the_centre() {
    let l = wind_tunnel();
    let samples: Vec<Sample> = (0..50)
        .map(|k| {
            let x = 1.0 + 0.3 * f64::from(k);
            Sample {
                t: 0.1 * f64::from(k),
                x,
                y: 2.0,
                value: (-(x - 6.1).powi(2)).exp(),
            }
        })
        .collect();
    let best = samples
        .iter()
        .max_by(|a, b| a.value.total_cmp(&b.value))
        .unwrap();
    let b = Baselines::new(&l, &samples, Some([5.0, 1.0])).unwrap();
    assert_eq!([b.highest_reading.x, b.highest_reading.y], [best.x, best.y]);
    let err = (best.x - 5.0).hypot(best.y - 1.0);
    assert!((b.highest_reading.error_m.unwrap() - err).abs() < 1e-12);
    assert_eq!([b.centre.x, b.centre.y], [9.0, 2.0]);
    assert!((b.centre.error_m.unwrap() - 4.0f64.hypot(1.0)).abs() < 1e-12);
    let unknown = Baselines::new(&l, &samples, None).unwrap();
    assert!(unknown.highest_reading.error_m.is_none());
    assert_err(
        Baselines::new(&l, &[], None),
        "no readings: no highest reading",
    );
}

#[test]
fn lawnmower_lanes_cross_the_wind_in_free_space_and_bad_spacings_fail() {
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let robot = config.robot;
    for from in ["west", "north"] {
        let text =
            std::fs::read_to_string(crate::common::repo_path("data/layouts/wind-tunnel.json"))
                .unwrap();
        let mut spec: serde_json::Value = serde_json::from_str(&text).unwrap();
        spec["wind"]["from"] = serde_json::json!(from);
        let l = plumenet::layout::Layout::from_json(&spec.to_string()).unwrap();
        let survey = lawnmower(&l, &robot, 0.5).unwrap();
        let occupancy = Occupancy::new(&l, robot.radius_m + robot.clearance_m).unwrap();
        for pair in survey.path.windows(2) {
            assert!(occupancy.segment_free(pair[0], pair[1]), "{from}: {pair:?}");
        }
        // Crosswind lanes every 0.5 m along the wind: 36 along the 18 m of a west wind, 8
        // across the 4 m the wind blows along from the north.
        assert_eq!(survey.lanes, if from == "west" { 36 } else { 8 }, "{from}");
        assert_eq!(survey.skipped, 0);
        // The first lane is half a spacing before the outlet.
        let first = survey.path[0];
        match from {
            "west" => assert!((first[0] - 17.75).abs() < 1e-9),
            _ => assert!((first[1] - 0.25).abs() < 1e-9),
        }
    }
    let l = wind_tunnel();
    for bad in [0.0, -1.0, 0.1, 19.0, f64::NAN] {
        let err = lawnmower(&l, &robot, bad).unwrap_err().to_string();
        assert!(err.contains("does not fit the arena"), "{err}");
    }
}

#[test]
fn a_survey_reads_every_tick_along_its_path() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&l, &config.robot, 1.0).unwrap();
    let flight = config.flight();
    let reality = Reality::new(&l, &w, Mismatch::NONE).unwrap();
    let samples = fly(&reality, &survey.path, [4.5, 2.3], &flight, 2).unwrap();
    let length = plumenet::ste::robot::path_length(&survey.path);
    let step = config.robot.max_speed_mps * config.robot.tick_s;
    assert_eq!(samples.len(), (length / step).ceil() as usize);
    assert!(samples.windows(2).all(|p| p[1].t > p[0].t));
    assert_eq!(
        samples,
        fly(&reality, &survey.path, [4.5, 2.3], &flight, 2).unwrap()
    );
    // The plume is there: readings downwind of the source beat those upwind of it.
    let mean = |keep: &dyn Fn(&Sample) -> bool| {
        let v: Vec<f64> = samples
            .iter()
            .filter(|s| keep(s))
            .map(|s| s.value)
            .collect();
        v.iter().sum::<f64>() / v.len() as f64
    };
    assert!(mean(&|s| s.x > 5.0 && s.x < 9.0) > mean(&|s| s.x < 3.5));
    assert_err(
        fly(&reality, &survey.path, [7.0, 1.2], &flight, 2),
        "invalid source position (7, 1.2): inside obstacle 0",
    );
}

/// A survey study runs the same sources as the planner's (paired), its rows are the survey
/// flown and replayed by hand, and every row's baselines agree with its readings.
#[test]
fn survey_studies_replay_the_flown_survey_and_carry_the_baselines() {
    use plumenet::sim::episode::StartRule;
    use plumenet::ste::replay::replay;
    use plumenet::study::experiment::{Paths, StudySite, plan_runs, run_study, summarize};
    let world = crate::ste::world();
    let meander = world
        .with_mismatch(Mismatch {
            meander_deg: 20.0,
            ..Mismatch::NONE
        })
        .unwrap();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&world.room.layout, &config.robot, 1.0).unwrap();
    let plan = plan_runs(&[Feature::Rank], &[SensorPreset::SensorII], 2);
    let study = |w, paths| {
        let site = StudySite {
            world: w,
            layout: "wind-tunnel",
            model: "solver",
            paths,
        };
        run_study(site, &plan, 4, EpisodeConfig::new, || ()).unwrap()
    };
    let flown = study(&meander, Paths::Survey(&survey.path));
    let planned = study(world, Paths::Planner(StartRule::Anywhere));
    for (s, p) in flown.iter().zip(&planned) {
        assert_eq!((s.source_x, s.source_y), (p.source_x, p.source_y));
        assert_eq!((s.paths.as_str(), p.paths.as_str()), ("survey", "planner"));
        assert_eq!(
            (s.reality.as_str(), p.reality.as_str()),
            ("meander 20°", "none")
        );
        assert_eq!(s.iterations, 0);
        let source = [s.source_x, s.source_y];
        let flight = config.flight();
        let samples = fly(&meander.reality, &survey.path, source, &flight, s.seed).unwrap();
        let est = replay(
            meander.room.samplers(),
            config.ste,
            config.robot.radius_m,
            &samples,
        )
        .unwrap();
        assert_eq!([s.estimate_x, s.estimate_y], est.estimate());
        let b = Baselines::new(&world.room.layout, &samples, Some(source)).unwrap();
        assert_eq!(
            [s.highest_x, s.highest_y],
            [b.highest_reading.x, b.highest_reading.y]
        );
        for r in [s, p] {
            let e = (r.highest_x - r.source_x).hypot(r.highest_y - r.source_y);
            assert!((r.highest_error_m - e).abs() < 1e-12);
            let c = (9.0 - r.source_x).hypot(2.0 - r.source_y);
            assert!((r.centre_error_m - c).abs() < 1e-12);
        }
    }
    let rows: Vec<_> = flown.iter().chain(&planned).cloned().collect();
    let summary = summarize(&rows);
    assert_eq!(summary.len(), 2);
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    let highest: Vec<f64> = flown.iter().map(|r| r.highest_error_m).collect();
    assert!((summary[0].highest_error_mean_m - mean(&highest)).abs() < 1e-12);
}

/// Marginalising over banks: with identical banks nothing changes and each bank holds half the
/// mass; with different banks the candidate posterior is the mixture of the single-bank
/// posteriors weighted by the bank posterior (the law of total probability, brute force).
#[test]
fn the_bank_marginal_is_the_mixture_of_single_bank_posteriors() {
    use plumenet::plume::PhysicsSolver;
    use plumenet::ste::posterior::{Estimator, prior_support};
    use plumenet::ste::replay::replay;
    let world = crate::ste::world();
    let slow = world
        .with_wind_scales(&PhysicsSolver, &[0.5, 1.0], None)
        .unwrap();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&world.room.layout, &config.robot, 1.5).unwrap();
    let samples = fly(
        &world.reality,
        &survey.path,
        [4.5, 2.3],
        &config.flight(),
        1,
    )
    .unwrap();
    let r = config.robot.radius_m;
    let single = replay(vec![world.room.sampler.clone()], config.ste, r, &samples).unwrap();
    let twice = replay(
        vec![world.room.sampler.clone(), world.room.sampler.clone()],
        config.ste,
        r,
        &samples,
    )
    .unwrap();
    for (a, b) in single.posterior().iter().zip(twice.posterior()) {
        assert!((a - b).abs() < 1e-12);
    }
    assert!(
        twice
            .bank_posterior()
            .iter()
            .all(|p| (p - 0.5).abs() < 1e-12)
    );
    let both = replay(slow.room.samplers(), config.ste, r, &samples).unwrap();
    let parts: Vec<Estimator> = slow
        .room
        .samplers()
        .into_iter()
        .map(|s| replay(vec![s], config.ste, r, &samples).unwrap())
        .collect();
    let w = both.bank_posterior();
    assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    for (j, p) in both.posterior().iter().enumerate() {
        let mixture: f64 = parts
            .iter()
            .zip(w)
            .map(|(e, wk)| wk * e.posterior()[j])
            .sum();
        assert!(
            (p - mixture).abs() < 1e-9,
            "candidate {j}: {p} vs {mixture}"
        );
    }
    // Banks over other candidates, or none at all, are refused.
    let support =
        prior_support(&world.room.layout, world.room.sampler.candidates(), r, 0.25).unwrap();
    assert_err(
        Estimator::with_banks(vec![], &support, config.ste),
        "no plume bank",
    );
    assert_err(
        world.with_wind_scales(&PhysicsSolver, &[0.0, 1.0], None),
        "model wind scales must be positive numbers, got [0.0, 1.0]",
    );
}

/// The wind speed is identifiable from the readings' ranks: replaying surveys over banks at
/// half, once and twice the layout's speed gives reality's speed the largest mean share over
/// eight surveys, with the lag in the concentration (the other features' form) and in the
/// sensor's response (rank's default), each alone and beside the background nuisance (single
/// surveys scatter: a slow wind's higher concentrations partly resemble a rising background).
/// The source sits on a candidate: with a coarse candidate grid a wider plume can make up for
/// a source between candidates, and the speed is not told apart from the position.
#[test]
fn the_wind_speed_posterior_finds_realitys_speed() {
    use plumenet::plume::PhysicsSolver;
    use plumenet::ste::replay::replay;
    let scales = [0.5, 1.0, 2.0];
    let world = crate::ste::world()
        .with_wind_scales(&PhysicsSolver, &scales, None)
        .unwrap();
    let source = [4.625, 2.375];
    assert!(world.room.sampler.candidates().contains(&source));
    // Readings taken as independent evidence, with the solver's exact ranks that go with
    // them: the nuisance's posterior is asked to pick the speed from one survey, which the
    // tempered default weighs five times less.
    let mut config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    config.ste.evidence_weight = 1.0;
    config.ste.rank.model_rank_factor = config.ste.rank_factor_for(1.0);
    config.ste.fit_reference = config.ste.fit_reference_for(1.0);
    config.ste.misfit_reference = config.ste.misfit_reference_for();
    assert_eq!(config.ste.rank.model_rank_factor, 1.0);
    assert_eq!(
        (config.ste.fit_reference, config.ste.misfit_reference),
        (None, None)
    );
    assert_eq!(config.ste.background_rise, 0.5);
    let lag_in_c = config.ste.lag_in_concentration();
    assert_eq!(
        (lag_in_c.sensor_lag_exponent, lag_in_c.detection_floor_ppm),
        (1.0, 1.0)
    );
    let alone = |ste: SteParams| SteParams {
        background_rise: 0.0,
        ..ste
    };
    let forms = [alone(lag_in_c), lag_in_c, alone(config.ste), config.ste];
    let survey = lawnmower(&world.room.layout, &config.robot, 1.0).unwrap();
    let seeds = 1..=8u64;
    for (k, &scale) in scales.iter().enumerate() {
        let reality = world
            .with_mismatch(Mismatch {
                wind_scale: scale,
                ..Mismatch::NONE
            })
            .unwrap();
        // The mean posterior over the surveys, alone and beside the background nuisance.
        let mut mean = [[0.0; 3]; 4];
        for seed in seeds.clone() {
            let samples = fly(
                &reality.reality,
                &survey.path,
                source,
                &config.flight(),
                seed,
            )
            .unwrap();
            for (m, ste) in mean.iter_mut().zip(forms) {
                let est =
                    replay(world.room.samplers(), ste, config.robot.radius_m, &samples).unwrap();
                let w = est.bank_posterior();
                for (m, w) in m.iter_mut().zip(w) {
                    *m += w / seeds.clone().count() as f64;
                }
            }
        }
        // Every form puts its largest mean share on reality's speed.
        for m in &mean {
            assert!(
                m.iter().all(|&w| w <= m[k]),
                "reality at x{scale}: mean bank posterior {m:?}"
            );
        }
    }
}

/// The background nuisance: readings with a background rising through the run put most of the
/// mass on a rising background, readings without one on none; rank's default marginalises
/// rises of up to half the fully mixed concentration, and with the option off there is one
/// background, none. The fully mixed concentration is across the wind, whichever wall it
/// enters through.
#[test]
fn the_background_posterior_tells_a_rising_background_from_none() {
    use plumenet::ste::replay::replay;
    let world = crate::ste::world();
    assert!((world.room.layout.fully_mixed(1.0) - 1.0 / (0.75 * 4.0)).abs() < 1e-15);
    let mut spec = world.room.layout.spec().clone();
    spec.wind.from = plumenet::layout::WindFrom::South;
    let south = spec.check().unwrap();
    assert!((south.fully_mixed(3.0) - 3.0 / (0.75 * 18.0)).abs() < 1e-15);

    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&world.room.layout, &config.robot, 1.0).unwrap();
    let source = [4.625, 2.375];
    let mut ste = SteParams {
        background_rise: 0.0,
        ..config.ste
    };
    let r = config.robot.radius_m;
    let samples = fly(&world.reality, &survey.path, source, &config.flight(), 3).unwrap();
    let plain = replay(world.room.samplers(), ste, r, &samples).unwrap();
    assert!(matches!(plain.backgrounds()[..], [[a, p]] if a == 0.0 && (p - 1.0).abs() < 1e-12));
    let default = replay(world.room.samplers(), config.ste, r, &samples).unwrap();
    let levels: Vec<f64> = default.backgrounds().iter().map(|b| b[0]).collect();
    assert_eq!(levels, [0.0, 0.25, 0.5]);
    ste.background_rise = 1.0;
    let clean = replay(world.room.samplers(), ste, r, &samples).unwrap();
    let levels: Vec<f64> = clean.backgrounds().iter().map(|b| b[0]).collect();
    assert_eq!(levels, [0.0, 0.5, 1.0]);
    let w: Vec<f64> = clean.backgrounds().iter().map(|b| b[1]).collect();
    assert!((w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    assert!(w[0] > 0.5, "no background in reality: {w:?}");
    let recirculating = world
        .with_mismatch(Mismatch {
            background: 2.0,
            ..Mismatch::NONE
        })
        .unwrap();
    let samples = fly(
        &recirculating.reality,
        &survey.path,
        source,
        &config.flight(),
        3,
    )
    .unwrap();
    let est = replay(world.room.samplers(), ste, r, &samples).unwrap();
    let w: Vec<f64> = est.backgrounds().iter().map(|b| b[1]).collect();
    assert!(w[0] < 0.5, "a rising background in reality: {w:?}");
    ste.background_time_s = 0.0;
    assert_err(
        replay(world.room.samplers(), ste, r, &samples),
        "the background time constant must be a positive number of seconds, got 0",
    );
}

/// The background odds are a prior: the posterior odds of each rise against none are the
/// likelihood ratio times the prior odds, so changing them from `o` to `o'` scales the
/// posterior odds by exactly `o' / o`; before any reading the background posterior is the
/// prior itself; independent readings weigh every rise as likely as none (odds 1, the
/// paper-form default), the calibrated default 0.01. Odds of 0, below 0, infinite or NaN are
/// refused.
#[test]
fn the_background_odds_scale_the_posterior_odds_of_a_rise() {
    use plumenet::ste::posterior::{Estimator, prior_support};
    use plumenet::ste::replay::replay;
    let world = crate::ste::world();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&world.room.layout, &config.robot, 1.0).unwrap();
    let samples = fly(
        &world.reality,
        &survey.path,
        [4.625, 2.375],
        &config.flight(),
        5,
    )
    .unwrap();
    let r = config.robot.radius_m;
    let odds = |prior: f64| {
        let ste = SteParams {
            background_odds: Some(prior),
            ..config.ste
        };
        let est = replay(world.room.samplers(), ste, r, &samples).unwrap();
        let w: Vec<f64> = est.backgrounds().iter().map(|b| b[1]).collect();
        assert_eq!(w.len(), 3);
        [w[1] / w[0], w[2] / w[0]]
    };
    let (p, q) = (0.01, 0.7);
    let [a, b] = odds(p);
    let [c, d] = odds(q);
    assert!((c / a / (q / p) - 1.0).abs() < 1e-9, "{a} {c}");
    assert!((d / b / (q / p) - 1.0).abs() < 1e-9, "{b} {d}");

    let sampler = world.room.samplers()[0].clone();
    let support = prior_support(&world.room.layout, sampler.candidates(), r, 0.0).unwrap();
    let prior = |ste: SteParams| -> Vec<f64> {
        let fresh = Estimator::new(sampler.clone(), &support, ste).unwrap();
        fresh.backgrounds().iter().map(|b| b[1]).collect()
    };
    let w = prior(SteParams {
        background_odds: Some(0.25),
        ..config.ste
    });
    let close = |a: &[f64], b: &[f64]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-12);
    assert!(close(&w, &[2.0 / 3.0, 1.0 / 6.0, 1.0 / 6.0]), "{w:?}");
    assert!(close(
        &prior(config.ste),
        &[1.0 / 1.02, 0.01 / 1.02, 0.01 / 1.02]
    ));
    let independent = SteParams {
        evidence_weight: 1.0,
        ..config.ste
    };
    assert_eq!(prior(independent), [1.0 / 3.0; 3]);
    for bad in [0.0, -1.0, f64::INFINITY, f64::NAN] {
        let ste = SteParams {
            background_odds: Some(bad),
            ..config.ste
        };
        assert_err(
            Estimator::new(sampler.clone(), &support, ste),
            "the background odds must be a positive number",
        );
    }
}

/// Clean-air model ties: on a lawnmower survey (0.5 m lanes, from the outlet upwind) of a
/// source near the outlet with a rising background, most readings are the background alone,
/// and its first minutes lie within the readings' clean-air band. With the nuisance's ranks
/// below that band tied as the readings are (`clean_air_model_ties`, an option), or with the
/// clean-air rank floor, the background nuisance explains them and the estimate lands on the
/// source rather than upwind, where a plume would rise along the survey as the background
/// does. The ties need a rise to be as likely a priori as none (background odds of 1): under
/// the default odds the source at (16.5, 1.25) ends 2.4 m off with them; the floor finds all
/// three under the default odds.
#[test]
fn clean_air_model_ties_keep_a_rising_background_from_reading_as_a_plume_upwind() {
    use plumenet::ste::replay::replay;
    let world = crate::ste::world();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    assert!(!config.ste.rank.clean_air_model_ties);
    let with = SteParams {
        rank: RankParams {
            clean_air_model_ties: true,
            ..config.ste.rank
        },
        background_odds: Some(1.0),
        ..config.ste
    };
    assert!(!with.papers_rank().rank.clean_air_model_ties);
    // The clean-air rank floor ties every estimate of a background slot below the readings'
    // clean-air group, the background's alone among them.
    assert!(!config.ste.rank.clean_air_rank_floor);
    let floor = SteParams {
        rank: RankParams {
            clean_air_rank_floor: true,
            ..config.ste.rank
        },
        ..config.ste
    };
    assert!(!floor.papers_rank().rank.clean_air_rank_floor);
    let survey = lawnmower(&world.room.layout, &config.robot, 0.5).unwrap();
    let recirculating = world
        .with_mismatch(Mismatch {
            background: 1.0,
            ..Mismatch::NONE
        })
        .unwrap();
    let r = config.robot.radius_m;
    for source in [[17.25, 3.5], [17.25, 2.0], [16.5, 1.25]] {
        let flight = config.flight();
        let samples = fly(&recirculating.reality, &survey.path, source, &flight, 2).unwrap();
        let error = |ste: SteParams| {
            let est = replay(world.room.samplers(), ste, r, &samples).unwrap();
            let [x, y] = est.estimate();
            (x - source[0]).hypot(y - source[1])
        };
        // Both options find the source: within 1.5 m, the distance beyond which the
        // calibration benchmark counts an estimate as wrong.
        let (tied, floored) = (error(with), error(floor));
        assert!(
            tied < 1.5 && floored < 1.5,
            "source {source:?}: {tied} m off with the ties, {floored} m with the floor"
        );
        // Without the nuisance's slots the floor leaves the posterior exactly as it is.
        let plain = |floor: bool| {
            let ste = SteParams {
                background_rise: 0.0,
                rank: RankParams {
                    clean_air_rank_floor: floor,
                    ..config.ste.rank
                },
                ..config.ste
            };
            replay(world.room.samplers(), ste, r, &samples)
                .unwrap()
                .posterior()
                .to_vec()
        };
        assert_eq!(plain(true), plain(false));
    }
}

/// The spread bank is closer to the meandering reality's time average: across the wind, 1.5 and
/// 3 m downwind of the source, the filament plume under a 30 degree meander (averaged over
/// 40 correlation times) is nearer the solver's plume spread by 30 degrees than the solver's
/// own. A spread of 0 is the bank itself, and spreads outside 0..=90 degrees are refused.
#[test]
fn the_spread_bank_is_nearer_the_meandering_plumes_average() {
    use plumenet::plume::{PhysicsSolver, PlumeBank, PlumeModel};
    let l = empty_tunnel();
    let source = [3.0, 2.0];
    let bank = PhysicsSolver.bank(&l, &[source]).unwrap();
    assert_eq!(bank.spread_over_directions(&l, 0.0).unwrap(), bank);
    for bad in [-1.0, 91.0, f64::NAN] {
        assert_err(
            bank.spread_over_directions(&l, bad),
            "a wind-direction spread must be between 0 and 90 degrees",
        );
    }
    let spread = bank.spread_over_directions(&l, 30.0).unwrap();
    let w = WindField::solve(&l).unwrap();
    let meander = Mismatch {
        meander_deg: 30.0,
        ..Mismatch::NONE
    };
    let reality = Reality::new(&l, &w, meander).unwrap();
    for x in [4.5, 6.0] {
        let mut plume = reality.plume(source, 0.1, 7).unwrap();
        plume.advance(60.0);
        let (_, i) = l.cell_of(x, 0.0);
        let ys: Vec<f64> = (0..l.ny()).map(|j| l.cell_centre(j, i).1).collect();
        let steps = 8000;
        let mut mean = vec![0.0; ys.len()];
        for _ in 0..steps {
            plume.step();
            for (m, &y) in mean.iter_mut().zip(&ys) {
                *m += plume.concentration_at(x, y) / f64::from(steps);
            }
        }
        // Relative L2 distance of a bank's cross-wind profile from the time average.
        let distance = |b: &PlumeBank| {
            let num: f64 = (0..ys.len())
                .map(|j| (f64::from(b.fields[[0, j, i]]) - mean[j]).powi(2))
                .sum();
            (num / mean.iter().map(|r| r * r).sum::<f64>()).sqrt()
        };
        let (plain, spread) = (distance(&bank), distance(&spread));
        assert!(
            spread < plain,
            "{x} m: the spread plume is {spread} off the meander's average, the plain {plain}"
        );
    }
}

/// The spread's posterior: replaying surveys over banks spread by 0 and 30 degrees puts most of
/// the mass on no spread when the wind holds its direction (every source and seed here), and on
/// the spread when it wanders (for a source mid-arena, on average and in most surveys; a source
/// near a wall or an obstacle can hide the wander); episodes report the spread's posterior.
#[test]
fn the_spread_posterior_tells_a_wandering_wind_from_a_steady_one() {
    use plumenet::ste::replay::replay;
    let world = crate::ste::world().with_wind_spreads(&[0.0, 30.0]).unwrap();
    assert_eq!(world.room.banks.len(), 2);
    assert_err(
        crate::ste::world().with_wind_spreads(&[]),
        "give at least one wind-direction spread",
    );
    assert_err(
        crate::ste::world().with_wind_spreads(&[0.0, 95.0]),
        "a wind-direction spread must be between 0 and 90 degrees, got 95",
    );
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let survey = lawnmower(&world.room.layout, &config.robot, 1.0).unwrap();
    let wandering = world
        .with_mismatch(Mismatch {
            meander_deg: 30.0,
            ..Mismatch::NONE
        })
        .unwrap();
    let spread_mass = |reality: &plumenet::sim::World, source, seed| {
        let samples = fly(
            &reality.reality,
            &survey.path,
            source,
            &config.flight(),
            seed,
        )
        .unwrap();
        let est = replay(
            world.room.samplers(),
            config.ste,
            config.robot.radius_m,
            &samples,
        )
        .unwrap();
        let w = world.room.marginal(est.bank_posterior(), |b| b.spread_deg);
        assert_eq!(w.len(), 2);
        assert!((w[0][1] + w[1][1] - 1.0).abs() < 1e-12);
        w[1][1]
    };
    for seed in 1..=3 {
        for source in [[4.625, 2.375], [3.125, 1.125], [8.125, 3.125]] {
            let p = spread_mass(&world, source, seed);
            assert!(p < 0.5, "steady wind, {source:?}, seed {seed}: spread {p}");
        }
    }
    // A wandering wind's surveys scatter more (a 20 s wander over a 10-minute survey): on
    // average over seeds the spread takes more than half the mass (the binary choice's
    // decision threshold).
    let wander: Vec<f64> = (1..=10)
        .map(|seed| spread_mass(&wandering, [4.625, 2.375], seed))
        .collect();
    let mean = wander.iter().sum::<f64>() / wander.len() as f64;
    assert!(mean > 0.5, "wandering wind: spread {wander:.2?}");
    let ep =
        plumenet::sim::run_episode(&world, &config, [5.1, 2.1], [15.0, 1.0], 0, false).unwrap();
    assert_eq!(ep.wind_spreads.len(), 2);
    assert_eq!((ep.wind_spreads[0][0], ep.wind_spreads[1][0]), (0.0, 30.0));
    assert_eq!(ep.wind_scales.len(), 1);
    assert!((ep.wind_scales[0][1] - 1.0).abs() < 1e-12);
}

/// The walled wander (`--reality-meander-walled`) turns only what the walls let through: in an
/// empty corridor that is nothing between the side walls, so 3 m downwind of the source its
/// time average stays the steady plume's, while the whole field's wander piles gas up against
/// a side wall (the mean at the walls several times that in the middle).
#[test]
fn a_walled_wander_leaves_a_corridors_plume_in_place() {
    use plumenet::plume::{PhysicsSolver, PlumeModel};
    let l = empty_tunnel();
    let source = [3.0, 2.0];
    let bank = PhysicsSolver.bank(&l, &[source]).unwrap();
    let w = WindField::solve(&l).unwrap();
    let x = 6.0;
    let (_, i) = l.cell_of(x, 0.0);
    let ys: Vec<f64> = (0..l.ny()).map(|j| l.cell_centre(j, i).1).collect();
    let steady: Vec<f64> = (0..ys.len())
        .map(|j| f64::from(bank.fields[[0, j, i]]))
        .collect();
    let mut averages = Vec::new();
    for walled in [false, true] {
        let m = Mismatch {
            meander_deg: 30.0,
            meander_walled: walled,
            ..Mismatch::NONE
        };
        assert_eq!(
            m.to_string(),
            if walled {
                "meander 30° walled"
            } else {
                "meander 30°"
            }
        );
        let mut plume = Reality::new(&l, &w, m)
            .unwrap()
            .plume(source, 0.1, 7)
            .unwrap();
        plume.advance(60.0);
        let steps = 8000;
        let mut mean = vec![0.0; ys.len()];
        for _ in 0..steps {
            plume.step();
            for (m, &y) in mean.iter_mut().zip(&ys) {
                *m += plume.concentration_at(x, y) / f64::from(steps);
            }
        }
        let num: f64 = mean.iter().zip(&steady).map(|(a, b)| (a - b).powi(2)).sum();
        let distance = (num / steady.iter().map(|b| b * b).sum::<f64>()).sqrt();
        let (edge, middle) = ((mean[0] + mean[ys.len() - 1]) / 2.0, mean[ys.len() / 2]);
        averages.push((distance, edge / middle));
    }
    let [(turned, piled), (walled, level)] = [averages[0], averages[1]];
    assert!(
        walled < 0.35,
        "the walled wander's average is {walled} off the steady plume"
    );
    assert!(
        turned > 2.0 * walled,
        "the whole field's wander: {turned} against {walled}"
    );
    assert!(
        piled > 2.0 && level < 1.0,
        "walls / middle: turned {piled}, walled {level}"
    );
    let bad = Mismatch {
        meander_walled: true,
        ..Mismatch::NONE
    };
    let err = bad.check().unwrap_err().to_string();
    assert!(err.contains("--reality-meander-deg"), "{err}");
}

/// A turned bank is the plume under a turned wind: in the empty corridor, 2 m downwind of a
/// source mid-height, the plume turned by 20 degrees (counter-clockwise) peaks about 2 tan 20
/// = 0.73 m north of the steady plume's peak, and by -20 degrees as far south. An angle of 0 is
/// the bank itself; angles beyond 90 degrees either way, and NaN, are refused.
#[test]
fn a_turned_bank_is_the_plume_under_a_turned_wind() {
    use plumenet::plume::{PhysicsSolver, PlumeModel};
    let l = empty_tunnel();
    let source = [3.0, 2.0];
    let bank = PhysicsSolver.bank(&l, &[source]).unwrap();
    assert_eq!(bank.turned(&l, 0.0).unwrap(), bank);
    for bad in [-91.0, 91.0, f64::NAN] {
        assert_err(
            bank.turned(&l, bad),
            "a wind turn must be within 90 degrees either way",
        );
    }
    let (_, i) = l.cell_of(source[0] + 2.0, 0.0);
    let peak_y = |b: &plumenet::plume::PlumeBank| {
        let j = (0..l.ny())
            .max_by(|&a, &b2| b.fields[[0, a, i]].total_cmp(&b.fields[[0, b2, i]]))
            .unwrap();
        l.cell_centre(j, i).1
    };
    let steady = peak_y(&bank);
    assert!(
        (steady - source[1]).abs() <= l.cell(),
        "steady peak at {steady}"
    );
    let shift = 2.0 * 20f64.to_radians().tan();
    for (angle, sign) in [(20.0, 1.0), (-20.0, -1.0)] {
        let y = peak_y(&bank.turned(&l, angle).unwrap());
        assert!(
            (y - steady - sign * shift).abs() <= 1.5 * l.cell(),
            "{angle} degrees: peak at {y}, steady at {steady}"
        );
    }
}

/// The wander's posterior: on the planner's own runs, the estimator that weighs a wandering
/// wind against a steady one gives, on average over seeds, the steady wind more than half the
/// mass when the wind holds its direction and less than half when the reality's wind wanders by
/// 30 degrees (the binary choice's decision threshold); runs report it, and runs that do not
/// weigh a wander report none.
#[test]
fn the_wander_posterior_tells_a_wandering_wind_from_a_steady_one() {
    let world = crate::ste::world();
    let wandering = world
        .with_mismatch(Mismatch {
            meander_deg: 30.0,
            ..Mismatch::NONE
        })
        .unwrap();
    // Readings taken as independent evidence, with the stopping rule that goes with them.
    let mut config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    config.ste.evidence_weight = 1.0;
    config.termination = plumenet::ste::Termination::for_params(&config.ste);
    let plain = plumenet::sim::run_episode(world, &config, [5.1, 2.1], [15.0, 1.0], 0, false);
    assert_eq!(plain.unwrap().steady_wind, None);
    config.ste.wander_deg = 30.0;
    let steady_mass = |w: &plumenet::sim::World, seed| {
        let ep = plumenet::sim::run_episode(w, &config, [5.1, 2.1], [15.0, 1.0], seed, false);
        ep.unwrap().steady_wind.expect("a wander was weighed")
    };
    let steady: Vec<f64> = (0..3).map(|seed| steady_mass(world, seed)).collect();
    let wander: Vec<f64> = (0..3).map(|seed| steady_mass(&wandering, seed)).collect();
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&steady) > 0.5 && mean(&wander) < 0.5,
        "steady reality {steady:?}, wandering {wander:?}"
    );
}
