//! The estimator's benchmarks: `bench-ste` and `bench-serve`.

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;
use serde_json::json;

use plumenet::io;
use plumenet::layout::Layout;
use plumenet::plume::PhysicsSolver;
use plumenet::sim::{EpisodeConfig, World, run_episode};
use plumenet::ste::params::RankParams;
use plumenet::ste::{Feature, RoomBanks, SensorPreset, SteParams};

use super::live::SessionArgs;
use super::parse_point;

#[derive(Debug, Args)]
pub struct BenchSteArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Readings after the last timed update.
    #[arg(long, default_value_t = 3000)]
    samples: usize,
    /// Readings arriving in the timed update (one iteration's worth).
    #[arg(long, default_value_t = 100)]
    batch: usize,
    /// Successive timed updates (medians are reported).
    #[arg(long, default_value_t = 7)]
    repeats: usize,
    /// Also time rank over one bank per model wind-speed factor (e.g. 0.5,1,2) against one
    /// bank, side by side: the cost of marginalising the wind speed.
    #[arg(long, value_delimiter = ',')]
    wind_scales: Vec<f64>,
    /// Also time rank over one bank per spread of the wind's direction (degrees, e.g. 0,30)
    /// against one bank, side by side: the cost of marginalising the direction's spread.
    #[arg(long, value_delimiter = ',')]
    wind_spreads: Vec<f64>,
    /// Also time rank with the background nuisance at this rise (three rises) against rank
    /// without it, side by side (0: not timed).
    #[arg(long, default_value_t = 0.0)]
    background_rise: f64,
    /// Also time rank weighing a wandering wind of this standard deviation (degrees; seven
    /// turned banks) against rank over one bank, side by side (0: not timed).
    #[arg(long, default_value_t = 0.0)]
    wind_wander: f64,
    /// Source of the timed whole run "X,Y" (m); the default suits the paper's arena.
    #[arg(long, value_parser = parse_point, default_value = "5.1,2.1")]
    source: (f64, f64),
    /// Robot start of the timed whole run "X,Y" (m); the default suits the paper's arena.
    #[arg(long, value_parser = parse_point, default_value = "15,1")]
    start: (f64, f64),
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn bench_ste(a: BenchSteArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    // The timed run's positions are checked before anything is timed.
    layout.check_source(a.source.0, a.source.1)?;
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    plumenet::sim::episode::check_start(&layout, &config.robot, [a.start.0, a.start.1])?;
    let (world, _) = World::build(layout, &PhysicsSolver, 0.25, None)?;
    println!(
        "one STE update on one core: {} new readings, the last of {} successive updates ending at {} readings ({} candidates), medians",
        a.batch,
        a.repeats,
        a.samples,
        world.room.sampler.len()
    );
    let mut report = Vec::new();
    let rank = SteParams::for_feature(Feature::Rank);
    let variants = Feature::ALL
        .map(|f| (f.name(), SteParams::for_feature(f)))
        .into_iter()
        .chain([
            (
                "rank-exact",
                SteParams {
                    rank: RankParams {
                        model_rank_factor: 1.0,
                        ..rank.rank
                    },
                    ..rank
                },
            ),
            (
                "rank-ties",
                SteParams {
                    rank: RankParams {
                        clean_air_model_ties: true,
                        ..rank.rank
                    },
                    ..rank
                },
            ),
            ("rank-lag-c", rank.lag_in_concentration()),
            ("rank-paper", rank.papers_rank()),
        ]);
    for (name, params) in variants {
        let t = super::timing::time_ste_update(&world.room, params, a.samples, a.batch, a.repeats)?;
        println!(
            "  {:13} update {:7.2} ms   floor (read N x n once) {:6.2} ms   ratio {:5.1}x",
            name,
            t.update_s * 1e3,
            t.floor_s * 1e3,
            t.update_s / t.floor_s
        );
        report.push(json!({
            "feature": name, "update_ms": t.update_s * 1e3, "floor_ms": t.floor_s * 1e3,
            "candidates": t.candidates, "samples": t.samples,
        }));
    }
    // Each nuisance against rank over one bank without any (not even rank's default background
    // nuisance), side by side: (what, world, settings, values).
    let bare = SteParams {
        background_rise: 0.0,
        ..rank
    };
    let mut nuisances = Vec::new();
    if a.wind_scales.len() > 1 {
        let banks = world
            .room
            .with_wind_scales(&PhysicsSolver, &a.wind_scales, None)?;
        nuisances.push(("wind-speed banks", banks, bare, a.wind_scales.len()));
    }
    if a.wind_spreads.len() > 1 {
        let banks = world.room.with_wind_spreads(&a.wind_spreads)?;
        nuisances.push(("wind-spread banks", banks, bare, a.wind_spreads.len()));
    }
    if a.background_rise > 0.0 {
        let with = SteParams {
            background_rise: a.background_rise,
            ..bare
        };
        nuisances.push(("background rises", world.room.clone(), with, 3));
    }
    if a.wind_wander > 0.0 {
        let with = SteParams {
            wander_deg: a.wind_wander,
            ..bare
        };
        nuisances.push((
            "wind turns",
            world.room.clone(),
            with,
            with.wander_turns().len(),
        ));
    }
    let time =
        |w: &RoomBanks, p| super::timing::time_ste_update(w, p, a.samples, a.batch, a.repeats);
    let mut nuisance = Vec::new();
    if !nuisances.is_empty() {
        let one = time(&world.room, bare)?;
        for (what, w, params, k) in &nuisances {
            let all = time(w, *params)?;
            let per_added = (all.update_s - one.update_s) / (k - 1) as f64 / one.update_s;
            println!(
                "  rank over {k} {what}: update {:7.2} ms against {:.2} ms over one; each added value costs {per_added:.2}x one bank's update",
                all.update_s * 1e3,
                one.update_s * 1e3
            );
            nuisance.push(json!({"nuisance": what, "values": k, "update_ms": all.update_s * 1e3, "one_bank_ms": one.update_s * 1e3, "per_added_value": per_added}));
        }
    }
    let ep = run_episode(
        &world,
        &config,
        [a.source.0, a.source.1],
        [a.start.0, a.start.1],
        0,
        false,
    )?;
    println!(
        "  whole run (rank, sensor-ii, solver bank ready, all cores): {:.2} s, {} iterations, {} readings",
        ep.wall_time_s,
        ep.iterations,
        ep.samples.len()
    );
    if let Some(path) = &a.json {
        let value = json!({"updates": report, "run_s": ep.wall_time_s, "run_iterations": ep.iterations, "nuisances": nuisance});
        io::write_json(path, &value)?;
    }
    Ok(())
}

#[derive(Debug, Args)]
pub struct BenchServeArgs {
    #[command(flatten)]
    session: SessionArgs,
    /// Readings at which one iteration (100 new readings, then planning) is timed.
    #[arg(long, value_delimiter = ',', default_values_t = [1000, 3000, 10000])]
    sizes: Vec<usize>,
    /// Readings per simulated second in the load test.
    #[arg(long, default_value_t = 100)]
    rate: usize,
    /// Simulated seconds streamed in the load test.
    #[arg(long, default_value_t = 600)]
    seconds: usize,
    /// An iteration every this many simulated seconds.
    #[arg(long, default_value_t = 10)]
    iterate_every: usize,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

pub fn bench_serve(a: BenchServeArgs) -> Result<()> {
    let (room, config, model) = a.session.room()?;
    println!(
        "one session iteration (100 new readings, then planning; all cores), {} candidates, {}:",
        room.sampler.len(),
        model.name()
    );
    let mut sizes = Vec::new();
    for &n in &a.sizes {
        let s = super::timing::time_session_iteration(&room, config, n, 100)?;
        println!("  at {n:6} readings: {:8.1} ms", s * 1e3);
        sizes.push(json!({"readings": n, "iteration_ms": s * 1e3}));
    }
    let load = super::timing::serve_load(&room, config, a.rate, a.seconds, a.iterate_every)?;
    let rt = &load.round_trips_s;
    let ms = |k: usize| rt.get(k).map_or(f64::NAN, |s| s * 1e3);
    println!(
        "load over TCP on loopback: {} readings sent ({} a simulated second for {} s), {} counted by the server, {} errors, {:.1} s wall",
        load.sent, a.rate, a.seconds, load.accepted, load.errors, load.wall_s
    );
    println!(
        "  readings + iterate round trip: {:.1} ms at the first iteration, {:.1} ms at the last ({} iterations)",
        ms(0),
        ms(rt.len().saturating_sub(1)),
        rt.len()
    );
    if let (Some(first), Some(last)) = (load.resident_bytes.first(), load.resident_bytes.last()) {
        let per = (*last as f64 - *first as f64)
            / (load.sent as f64 * (1.0 - 1.0 / rt.len().max(1) as f64)).max(1.0);
        println!(
            "  resident memory {:.0} MB after the first iteration, {:.0} MB after the last: {per:.0} bytes a reading",
            *first as f64 / 1e6,
            *last as f64 / 1e6
        );
    }
    if let Some(path) = &a.json {
        io::write_json(path, &json!({"iterations": sizes, "load": load}))?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
