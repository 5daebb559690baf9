//! `localize` (one simulated run) and `replay` (the estimator over a logged run).

use std::path::PathBuf;

use anyhow::Result;
use clap::Args;

use plumenet::io;
use plumenet::layout::Layout;

use plumenet::report::belief::{BeliefPlot, belief_panel, write_episode_pictures};
use plumenet::report::{Panel, save_figure};
use plumenet::sim::episode::RunReport;
use plumenet::sim::{World, run_episode};
use plumenet::ste::baseline::Guess;
use plumenet::ste::replay::{self, ReplayReport, read_log, replay_in_steps, thin};
use plumenet::ste::{Baselines, Feature};
use plumenet::viewer::RunView;

use super::args::*;
use super::parse_point;

#[derive(Debug, Args)]
pub struct LocalizeArgs {
    #[command(flatten)]
    trial: TrialArgs,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    /// Sensor.
    #[arg(long, value_enum, default_value_t = SensorArg::SensorII)]
    sensor: SensorArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    #[command(flatten)]
    run: RunArgs,
    #[command(flatten)]
    reality: RealityArgs,
    /// Seed of the plume, the sensor noise, the planner and the default start.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Write the run (estimate, error, trajectory, samples, sigmas, history) as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Write one picture per iteration into this directory.
    #[arg(long)]
    png_dir: Option<PathBuf>,
    /// Write the run viewer: one self-contained HTML page with a slider over the iterations.
    #[arg(long)]
    html: Option<PathBuf>,
}

pub fn localize(a: LocalizeArgs) -> Result<()> {
    let (layout, source) = a.trial.layout_and_source()?;
    let mismatch = a.reality.mismatch()?;
    let feature = Feature::from(a.feature);
    a.run.check(&layout)?;
    let (room, params, model) = a.plume.room(layout, &a.features, feature, false)?;
    let model_name = model.name();
    let world = World::new(room)?.with_mismatch(mismatch)?;
    let config = a.run.config(params, a.sensor.into(), model.rank_factor());
    let start = a.trial.start(&world.room.layout, &config.robot, a.seed)?;
    let keep_posteriors = a.png_dir.is_some() || a.html.is_some();
    let episode = run_episode(&world, &config, source, start, a.seed, keep_posteriors)?;
    println!(
        "{} / {} / {}, source ({:.2}, {:.2}), start ({:.2}, {:.2}): {} after {} iterations, {} readings, {:.1} s",
        feature.name(),
        config.sensor.name(),
        model_name,
        source[0],
        source[1],
        start[0],
        start[1],
        outcome(
            episode.converged,
            plumenet::ste::posterior::plume_signal(
                &episode.samples.iter().map(|s| s.value).collect::<Vec<_>>()
            ),
            episode.plume_reached,
        ),
        episode.iterations,
        episode.samples.len(),
        episode.wall_time_s
    );
    let estimate = Guess {
        x: episode.estimate[0],
        y: episode.estimate[1],
        error_m: Some(episode.error_m),
    };
    print_guesses(Some(estimate), &episode.baselines);
    if let Some(u) = &episode.uncertainty {
        print_uncertainty(u);
    }
    println!(
        "  (one run is one draw: `experiment` compares the estimate with both baselines over many runs)"
    );
    if !mismatch.is_none() {
        println!("reality departed from the model: {mismatch}");
    }
    if let Some(dir) = &a.png_dir {
        let paths = write_episode_pictures(
            &world.room.layout,
            world.room.sampler.candidates(),
            a.plume.spacing(),
            &episode,
            dir,
        )?;
        println!("wrote {} pictures into {}", paths.len(), dir.display());
    }
    if let Some(path) = &a.html {
        let title = format!(
            "localize: {} / {} / {}, seed {}: error {:.2} m after {} iterations",
            feature.name(),
            config.sensor.name(),
            model_name,
            a.seed,
            episode.error_m,
            episode.iterations
        );
        RunView::from_episode(
            title,
            &world.room.layout,
            world.room.sampler.candidates(),
            a.plume.spacing(),
            &episode,
        )?
        .write(path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.json {
        let report = RunReport {
            sigmas: config.ste.sigmas,
            candidates: world.room.sampler.candidates().to_vec(),
            model: model_name,
            episode,
        };
        io::write_json(path, &report)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}

#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// Layout JSON file.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Readings log, CSV with the columns t,x,y,value.
    #[arg(long)]
    log: PathBuf,
    /// The true source "X,Y" (m), when known: errors are reported for the estimate and the
    /// baselines.
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: Option<(f64, f64)>,
    /// Gas feature.
    #[arg(long, value_enum, default_value_t = FeatureArg::Rank)]
    feature: FeatureArg,
    #[command(flatten)]
    plume: PlumeArgs,
    #[command(flatten)]
    features: FeatureArgs,
    /// Robot radius (m): the prior excludes obstacles inflated by it.
    #[arg(long, default_value_t = 0.07)]
    robot_radius: f64,
    /// Write estimate and posterior as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Draw the posterior with the samples (PNG, or SVG when the name ends in .svg).
    #[arg(long)]
    png: Option<PathBuf>,
    /// Write the run viewer: one self-contained HTML page with a slider over the replay taken
    /// in --html-steps chunks of readings.
    #[arg(long)]
    html: Option<PathBuf>,
    /// Chunks of readings the viewer's replay takes them in (its iterations).
    #[arg(long, default_value_t = 20, value_parser = clap::value_parser!(u64).range(1..=1000))]
    html_steps: u64,
    /// Use every k-th reading, k the smallest that leaves at most N (a long log, thinned evenly
    /// in time so that the replay fits in memory; the baselines still see every reading).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    thin_to: Option<u64>,
}

pub fn replay_log(a: ReplayArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let samples = read_log(&a.log)?;
    let source = a.source.map(|(x, y)| [x, y]);
    if let Some([x, y]) = source {
        layout.check_source(x, y)?;
    }
    let feature = Feature::from(a.feature);
    let (room, params, model) = a.plume.room(layout, &a.features, feature, false)?;
    let model_name = model.name();
    let steps = if a.html.is_some() {
        a.html_steps as usize
    } else {
        1
    };
    let used = match a.thin_to {
        Some(n) => thin(&samples, n as usize)?,
        None => samples.clone(),
    };
    replay::check_memory(&room, &params, used.len(), io::available_memory_bytes())?;
    if used.len() < samples.len() {
        println!("thinned to {} of {} readings", used.len(), samples.len());
    }
    let (est, trace) = replay_in_steps(room.samplers(), params, a.robot_radius, &used, steps)?;
    let estimate = est.estimate();
    let error_m = source.map(|s| (estimate[0] - s[0]).hypot(estimate[1] - s[1]));
    let baselines = Baselines::new(&room.layout, &samples, source)?;
    println!(
        "{} readings, {}: entropy {:.2} nats, fit {:.3}",
        used.len(),
        feature.name(),
        est.entropy(),
        est.fit().unwrap_or(f64::NAN)
    );
    let guess = Guess {
        x: estimate[0],
        y: estimate[1],
        error_m,
    };
    print_guesses(Some(guess), &baselines);
    print_uncertainty(&est.uncertainty(source));
    if let Some(path) = &a.png {
        let title = format!(
            "replay  {}  estimate ({:.2}, {:.2})",
            feature.name(),
            estimate[0],
            estimate[1]
        );
        let panel = belief_panel(
            &room.layout,
            BeliefPlot {
                title: &title,
                candidates: est.candidates(),
                spacing_m: a.plume.spacing(),
                posterior: est.posterior(),
                trajectory: &[],
                samples: est.positions(),
                edf: est.measured_edf(),
                source,
                estimate,
            },
        )?;
        save_figure(&[Panel::Field(panel)], path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.html {
        let view = RunView::from_replay(
            &room.layout,
            est.candidates(),
            a.plume.spacing(),
            &params,
            &used,
            &trace,
        );
        let title = format!(
            "replay of {}: {} / {}, {} readings in {} steps",
            a.log.display(),
            feature.name(),
            model_name,
            used.len(),
            trace.len()
        );
        RunView {
            title,
            source,
            ..view
        }
        .write(path)?;
        println!("wrote {}", path.display());
    }
    if let Some(path) = &a.json {
        let report = ReplayReport::new(&est, &room, &model_name, samples.len(), baselines, source);
        io::write_json(path, &report)?;
        println!("wrote {}", path.display());
    }
    Ok(())
}
