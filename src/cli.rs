//! The command line: clap definitions and the thin glue from flags to library calls.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ndarray::{Array2, Axis};
use serde_json::json;

use plumenet::dataset::{self, Distribution, GenerateConfig, GenerateParams, RoomParams, Shard};
use plumenet::frame::Frame;
use plumenet::io;
use plumenet::layout::Layout;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::report::{FieldPanel, FieldPlot, Panel, save_figure};
use plumenet::surrogate::config::{Selection, WarmStart};
use plumenet::surrogate::data::{InputSet, SourceEncoding};
use plumenet::surrogate::eval::{BoundSharing, EvalSettings, Summary, coarse_bound, evaluate};
use plumenet::surrogate::model::{CoarseConfig, OperatorConfig, ROOM_CHANNELS};
use plumenet::surrogate::{PlumeNetConfig, Surrogate, TrainEvent, TrainingConfig, TrainingData};

mod args;
mod bench_net;
mod bench_ste;
mod live;
mod net_timing;
mod run;
mod study;
mod timing;

/// Calibration-free gas source localisation: dispersion simulator, datasets and plume banks.
#[derive(Debug, Parser)]
#[command(name = "plumenet", version, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Solve the wind and the mean concentration of one source (physics model).
    Simulate(SimulateArgs),
    /// Mean fields of every candidate source cell of a layout, shape [N, H, W].
    Bank(BankArgs),
    /// Generate a training dataset of random layouts and sources (or one shard of it).
    Generate(GenerateArgs),
    /// Merge the shard directories of one dataset into a complete dataset.
    Merge(MergeArgs),
    /// Time wind, factorisation, one source and the whole bank against scipy's SuperLU.
    Bench(BenchArgs),
    /// Train PlumeNet on a dataset (resumes an interrupted run in the same --out).
    Train(TrainArgs),
    /// Predict one field with a trained PlumeNet.
    Predict(PredictArgs),
    /// Accuracy of a trained PlumeNet on a dataset (relative L2, Spearman rho).
    Eval(EvalArgs),
    /// One simulated localisation run: robot, MOX sensor, filament plume and the STE.
    Localize(run::LocalizeArgs),
    /// The STE over a logged run (CSV t,x,y,value), for a real robot's readings.
    Replay(run::ReplayArgs),
    /// Fly a raster survey through the simulated reality and write its readings log.
    Survey(study::SurveyArgs),
    /// Serve a live STE session to a robot: JSON lines on stdin/stdout or TCP.
    Serve(live::ServeArgs),
    /// Play the robot (filament plume, MOX sensor, motion) against a running `serve`.
    RobotSim(live::RobotSimArgs),
    /// Time session iterations and stream a load over TCP to an in-process `serve`.
    BenchServe(bench_ste::BenchServeArgs),
    /// Run the live STE as a ROS 2 node (built with --features ros2).
    #[cfg(feature = "ros2")]
    Ros2Node(live::Ros2NodeArgs),
    /// The paper's study: features x sensors x runs, CSV + summary + box plots.
    Experiment(study::ExperimentArgs),
    /// The calibration benchmark: whether the credible regions hold the source as often as
    /// they claim, PlumeNet and the solver side by side, on the arena, unseen rooms, the
    /// mismatch suite and surveys.
    Calibration(study::CalibrationArgs),
    /// Two studies run on the same seeds, run by run: the paired difference of their errors
    /// with its standard error, and sign tests.
    Compare(study::CompareArgs),
    /// Time one STE update per feature (one core) and a whole simulated run.
    BenchSte(bench_ste::BenchSteArgs),
    /// PlumeNet's bank and training throughput, side by side with the same network in PyTorch.
    BenchNet(bench_net::BenchNetArgs),
}

#[derive(Debug, Args)]
struct TrainArgs {
    /// Dataset directories (from `plumenet generate`, merged if sharded), comma-separated: the
    /// datasets are trained on together, each holding out its own validation layouts.
    #[arg(long, value_delimiter = ',', required = true)]
    data: Vec<PathBuf>,
    /// Output model directory (weights.bpk + config.json), e.g. models/NAME.
    #[arg(long)]
    out: PathBuf,
    /// Maximum epochs.
    #[arg(long, default_value_t = 30)]
    epochs: usize,
    /// Samples per batch.
    #[arg(long, default_value_t = 16)]
    batch_size: usize,
    /// Seed of initialisation and shuffling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Source encoding of the inputs.
    #[arg(long, value_enum, default_value_t = EncodingArg::Gaussian)]
    encoding: EncodingArg,
    /// Stop after this many epochs without validation improvement.
    #[arg(long, default_value_t = 6)]
    patience: usize,
    /// Input channels: geometry (mask, distance, source), physics (+ cell Peclet number), wind
    /// (+ the solved wind), analytic (+ the analytic plume in uniform wind; the default) or
    /// walled (+ the analytic plume between the room's side walls). With --init-from, the
    /// start's inputs unless given (they must have as many channels as the start's).
    #[arg(long, value_enum)]
    inputs: Option<InputsArg>,
    /// Channels per U-Net level, shallow to deep, comma-separated (default 8,16,32,32,32).
    /// With --init-from, the start's unless given; more channels than the start's at some
    /// levels widen it, the new channels starting so that the network's output is unchanged.
    #[arg(long, value_delimiter = ',')]
    filters: Option<Vec<usize>>,
    /// Hand the analytic prior straight to the output layer (the network learns a correction
    /// to it); needs inputs with that prior (analytic or walled).
    #[arg(long)]
    prior_skip: bool,
    /// Train the source-late operator network: the U-Net sees the room alone, once, and each
    /// source enters in a light per-source head (analytic inputs; docs/plumenet.md). With
    /// --init-from a U-Net, its body starts from the U-Net's weights.
    #[arg(long, conflicts_with = "prior_skip")]
    operator: bool,
    /// With --operator, its coarse form: each source runs a small U-Net at 0.5 m cells that
    /// corrects the analytic prior, reading the room's planes there (docs/plumenet.md).
    #[arg(long, requires = "operator")]
    coarse: bool,
    /// Channels per level of the coarse per-source network, shallow to deep, comma-separated
    /// (default 8,16,32: three levels, at 0.5, 1 and 2 m cells).
    #[arg(long, value_delimiter = ',', requires = "coarse")]
    coarse_filters: Option<Vec<usize>>,
    /// Pooling level of the coarse per-source network's cells: 1 for 0.25 m (each of the
    /// STE's candidates its own network run), 2 for 0.5 m (the default: four candidates share
    /// a run).
    #[arg(long, requires = "coarse", value_parser = clap::value_parser!(u8).range(1..=4))]
    coarse_level: Option<u8>,
    /// Start from this trained model's weights (its architecture and inputs too) instead of
    /// random ones, e.g. to continue a model on more or other data.
    #[arg(long)]
    init_from: Option<PathBuf>,
    /// Peak AdamW learning rate (cosine decay to 2% of it over the epochs).
    #[arg(long, default_value_t = 3e-4)]
    learning_rate: f64,
    /// Weight of the maps' squared relative L2 error (in concentration) added to the loss (0:
    /// the transformed target's squared error alone).
    #[arg(long, default_value_t = 0.0, value_parser = parse_weight)]
    rel_l2_weight: f32,
    /// Mirror each training map across the wind (north-south) with probability 1/2, drawn
    /// anew every epoch (an exact symmetry of the physics: twice the rooms for free).
    #[arg(long)]
    mirror: bool,
    /// Which validation score keeps the best epoch and drives early stopping: the loss, or
    /// the held-out maps' median relative L2 error (the evaluation's measure).
    #[arg(long, value_enum, default_value_t = SelectArg::Loss)]
    select_by: SelectArg,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum SelectArg {
    Loss,
    RelativeL2,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum InputsArg {
    Geometry,
    Physics,
    Wind,
    Analytic,
    Walled,
}

#[derive(Debug, Clone, Copy, clap::ValueEnum)]
enum EncodingArg {
    Gaussian,
    Distance,
}

#[derive(Debug, Args)]
struct PredictArgs {
    /// Model directory.
    #[arg(long)]
    model: PathBuf,
    /// Layout JSON file.
    #[arg(long)]
    layout: PathBuf,
    /// Source position in metres, "X,Y".
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: (f64, f64),
    /// Output field (.npy, f32, [H, W]).
    #[arg(long)]
    out: PathBuf,
    /// Also draw the field as a PNG.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Logarithmic colour scale in the PNG.
    #[arg(long)]
    log: bool,
}

#[derive(Debug, Args)]
struct EvalArgs {
    /// Model directory.
    #[arg(long)]
    model: PathBuf,
    /// Dataset directory (use layouts the model never saw: another --seed).
    #[arg(long)]
    data: PathBuf,
    /// Write per-map scores and the summary as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Sampled free cells per map for Spearman rho.
    #[arg(long, default_value_t = 500)]
    points: usize,
    /// Seed of the point sampling.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Rank both fields after raising them to this fraction of the true peak (sub-floor cells
    /// tie as clean air); 0 ranks every value.
    #[arg(long, default_value_t = 0.0)]
    floor: f64,
    /// PNG comparing prediction, physics and error for the first maps.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Score instead the best prediction a coarse form of this pooling level can make (cells
    /// 2^LEVEL times the grid's): the model's analytic prior plus the coarse correction that
    /// fits the truth best, the bound of any trained network of that level (0 to 4).
    #[arg(long, value_name = "LEVEL", conflicts_with = "png", value_parser = clap::value_parser!(u32).range(0..=4))]
    coarse_bound: Option<u32>,
    /// With --coarse-bound, sources share the correction of the centre of their block of
    /// 2^LEVEL cells a side, fitted to that point's map (solved with the physics model), as the
    /// coarse form shares corrections; maps whose block centre lies in an obstacle are left out.
    #[arg(long, value_name = "LEVEL", requires = "coarse_bound", value_parser = clap::value_parser!(u32).range(1..=4))]
    coarse_share: Option<u32>,
}

#[derive(Debug, Args)]
struct SimulateArgs {
    /// Layout JSON file.
    #[arg(long)]
    layout: PathBuf,
    /// Source position in metres, "X,Y".
    #[arg(long, value_parser = parse_point, allow_hyphen_values = true)]
    source: (f64, f64),
    /// Output field (.npy, f32, shape [H, W] = [rows in y, columns in x], units/m^2 for 1 unit/s).
    #[arg(long)]
    out: PathBuf,
    /// Also write the wind at cell centres (.npy, f32, shape [2, H, W], u then v, m/s).
    #[arg(long)]
    wind_out: Option<PathBuf>,
    /// Also draw the field as a PNG.
    #[arg(long)]
    png: Option<PathBuf>,
    /// Logarithmic colour scale in the PNG.
    #[arg(long)]
    log: bool,
    /// Write a JSON report (wind iterations, residual, mass balance).
    #[arg(long)]
    json: Option<PathBuf>,
}

#[derive(Debug, Args)]
#[command(group(clap::ArgGroup::new("plume").required(true).args(["solver", "model"])))]
struct BankArgs {
    /// Use the physics solver as plume model.
    #[arg(long)]
    solver: bool,
    /// Use a trained PlumeNet (model directory) as plume model.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Layout JSON file.
    #[arg(long)]
    layout: PathBuf,
    /// Output bank (.npy, f32, [N, H, W]); candidates go to <stem>.candidates.npy ([N, 2], m).
    #[arg(long)]
    out: PathBuf,
    /// Candidate grid spacing in metres (a multiple of the cell size).
    #[arg(long, default_value_t = 0.25)]
    spacing: f64,
}

#[derive(Debug, Args)]
struct GenerateArgs {
    /// Output directory (created).
    #[arg(long)]
    out: PathBuf,
    /// Number of random layouts in the whole dataset.
    #[arg(long)]
    layouts: usize,
    /// Random sources per layout.
    #[arg(long)]
    sources: usize,
    /// Master seed: identical seeds give identical bytes.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Generate only shard K of N ("K/N", K from 0); merge shards with `plumenet merge`.
    #[arg(long)]
    shard: Option<Shard>,
    /// Random obstacles in this one arena (grid, wind and coefficients; its own obstacles are
    /// ignored), e.g. data/layouts/wind-tunnel.json, the paper's arena; without it every layout
    /// is a random room (6-30 m x 3-12 m, wind 0.25-1.5 m/s from any wall).
    #[arg(long)]
    base: Option<PathBuf>,
}

#[derive(Debug, Args)]
struct MergeArgs {
    /// Output directory of the merged dataset.
    #[arg(long)]
    out: PathBuf,
    /// Shard directories, in any order.
    #[arg(required = true)]
    shards: Vec<PathBuf>,
}

#[derive(Debug, Args)]
struct BenchArgs {
    /// Layout to time.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Repeats per measurement (medians are reported).
    #[arg(long, default_value_t = 5)]
    repeats: usize,
    /// Candidate grid spacing in metres.
    #[arg(long, default_value_t = 0.25)]
    spacing: f64,
    /// Skip the scipy SuperLU reference.
    #[arg(long)]
    no_reference: bool,
    /// Also time this trained PlumeNet's bank of the same candidates (wind solve, input
    /// encoding and inverse transform included) against the solver's.
    #[arg(long)]
    model: Option<PathBuf>,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

fn parse_point(s: &str) -> Result<(f64, f64), String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("expected X,Y, got {s:?}"))?;
    let num = |t: &str| {
        t.trim()
            .parse::<f64>()
            .map_err(|_| format!("{t:?} is not a number"))
    };
    Ok((num(x)?, num(y)?))
}

/// A loss weight: finite and not negative.
fn parse_weight(s: &str) -> Result<f32, String> {
    match s.trim().parse::<f32>() {
        Ok(w) if w.is_finite() && w >= 0.0 => Ok(w),
        _ => Err(format!("{s:?} is not a finite weight of at least 0")),
    }
}

fn progress_bar(len: usize, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len as u64);
    if let Ok(style) =
        ProgressStyle::with_template("{msg} [{bar:40}] {pos}/{len} {elapsed_precise} eta {eta}")
    {
        bar.set_style(style.progress_chars("=> "));
    }
    bar.set_message(what.to_string());
    bar
}

/// Prints a line above the progress bar, or plainly when the bar is hidden (output to a file).
fn say(bar: &ProgressBar, line: String) {
    if bar.is_hidden() {
        println!("{line}")
    } else {
        bar.println(line)
    }
}

impl Cli {
    /// Runs the chosen command.
    pub fn run(self) -> Result<()> {
        match self.command {
            Command::Simulate(a) => simulate(a),
            Command::Bank(a) => bank(a),
            Command::Generate(a) => generate(a),
            Command::Merge(a) => merge(a),
            Command::Bench(a) => run_bench(a),
            Command::Train(a) => train(a),
            Command::Predict(a) => predict(a),
            Command::Eval(a) => eval(a),
            Command::Localize(a) => run::localize(a),
            Command::Replay(a) => run::replay_log(a),
            Command::Survey(a) => study::survey(a),
            Command::Serve(a) => live::serve(a),
            Command::RobotSim(a) => live::robot_sim(a),
            Command::BenchServe(a) => bench_ste::bench_serve(a),
            #[cfg(feature = "ros2")]
            Command::Ros2Node(a) => live::ros2_node(a),
            Command::Experiment(a) => study::experiment(a),
            Command::Calibration(a) => study::calibration(a),
            Command::Compare(a) => study::compare(a),
            Command::BenchSte(a) => bench_ste::bench_ste(a),
            Command::BenchNet(a) => bench_net::bench_net(a),
        }
    }
}

/// Writes a field as `.npy` (f32) and, when asked, as a PNG.
fn write_field(
    field: &Array2<f64>,
    layout: &Layout,
    out: &Path,
    png: Option<&Path>,
    log: bool,
    title: String,
) -> Result<()> {
    io::write_npy(out, &field.mapv(|v| v as f32))?;
    if let Some(path) = png {
        let plot = FieldPlot {
            title,
            log,
            unit: "concentration (units/m²)".into(),
        };
        save_figure(
            &[Panel::Field(FieldPanel::new(field.clone(), layout, plot)?)],
            path,
        )?;
    }
    Ok(())
}

fn simulate(a: SimulateArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    layout.check_source(a.source.0, a.source.1)?;
    let wind = WindField::solve(&layout)?;
    let transport = Transport::new(&layout, &wind)?;
    let field = transport.solve(a.source.0, a.source.1)?;
    let title = format!(
        "mean concentration, source ({}, {}) m",
        a.source.0, a.source.1
    );
    write_field(&field, &layout, &a.out, a.png.as_deref(), a.log, title)?;
    if let Some(path) = &a.wind_out {
        io::write_npy(path, &wind.centred().mapv(|v| v as f32))?;
    }
    let (outlet, inlet) = (transport.outlet_flux(&field), transport.inlet_flux(&field));
    let peak = field.iter().copied().fold(0.0, f64::max);
    println!(
        "wind: {} iterations, residual {:.1e}; of the 1 unit/s released, {:.4} leave through the outlet and {:.4} upwind through the inlet; peak {:.4} units/m2",
        wind.steps, wind.residual, outlet, inlet, peak
    );
    println!("wrote {}", a.out.display());
    if let Some(path) = &a.json {
        let report = json!({
            "layout": a.layout, "source": [a.source.0, a.source.1], "out": a.out,
            "wind_iterations": wind.steps, "wind_residual": wind.residual,
            "outlet_flux": outlet, "inlet_flux": inlet, "peak": peak,
            "grid": [layout.ny(), layout.nx()],
        });
        io::write_json(path, &report)?;
    }
    Ok(())
}

fn bank(a: BankArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let candidates = layout.candidates(a.spacing)?;
    if candidates.is_empty() {
        bail!(
            "the layout has no free candidate cell at spacing {} m",
            a.spacing
        );
    }
    let model: Box<dyn PlumeModel> = match &a.model {
        Some(dir) => Box::new(Surrogate::load(dir)?),
        None => Box::new(PhysicsSolver),
    };
    let bank = model.bank(&layout, &candidates)?.fields;
    let cand = Array2::from_shape_fn((candidates.len(), 2), |(k, d)| candidates[k][d] as f32);
    let cand_path = a.out.with_extension("candidates.npy");
    io::write_npy(&a.out, &bank)?;
    io::write_npy(&cand_path, &cand)?;
    println!(
        "wrote {} ({} candidates x {} x {}) and {}",
        a.out.display(),
        bank.len_of(Axis(0)),
        layout.ny(),
        layout.nx(),
        cand_path.display()
    );
    Ok(())
}

fn generate(a: GenerateArgs) -> Result<()> {
    let distribution = match &a.base {
        Some(path) => Distribution::Base {
            base: Layout::load(path)?.spec().clone(),
            params: GenerateParams::default(),
        },
        None => Distribution::Rooms {
            params: RoomParams::default(),
        },
    };
    let config = GenerateConfig {
        distribution,
        layouts: a.layouts,
        sources_per_layout: a.sources,
        seed: a.seed,
        shard: a.shard,
    };
    let total = config.layout_range().len();
    let bar = progress_bar(total, "layouts");
    // Output to a file (a nohup run) gets a line every 5% instead of the bar.
    let step = total.div_ceil(20).max(1) as u64;
    let manifest = dataset::generate(&config, &a.out, &|| {
        bar.inc(1);
        let done = bar.position();
        if bar.is_hidden() && (done % step == 0 || done == total as u64) {
            say(&bar, format!("{done}/{total} layouts"));
        }
    })?;
    bar.finish();
    println!(
        "wrote {} layouts x {} sources to {}",
        manifest.layouts.len(),
        manifest.sources_per_layout,
        a.out.display()
    );
    Ok(())
}

fn merge(a: MergeArgs) -> Result<()> {
    let shards: Vec<&Path> = a.shards.iter().map(PathBuf::as_path).collect();
    let manifest = dataset::merge(&shards, &a.out)?;
    println!(
        "merged {} shards ({} layouts) into {}",
        shards.len(),
        manifest.layouts.len(),
        a.out.display()
    );
    Ok(())
}

fn run_bench(a: BenchArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let (t, transport, candidates) = timing::time_bank(&layout, a.spacing, a.repeats)?;
    let ms = |s: f64| s * 1e3;
    println!(
        "layout {} ({} x {} cells, {} unknowns, {} candidates), medians of {} runs, {} threads",
        a.layout.display(),
        layout.nx(),
        layout.ny(),
        t.unknowns,
        t.candidates,
        a.repeats,
        rayon::current_num_threads()
    );
    println!(
        "  wind solve         {:9.2} ms ({} iterations)",
        ms(t.wind_s),
        t.wind_steps
    );
    println!("  factorisation      {:9.2} ms", ms(t.factor_s));
    println!("  one source         {:9.3} ms", ms(t.one_source_s));
    println!("  whole bank         {:9.2} ms", ms(t.bank_s));
    println!("  wind + factor + bank {:7.2} ms", ms(t.total_s()));
    let mut report = json!({
        "wind_ms": ms(t.wind_s), "wind_iterations": t.wind_steps, "factor_ms": ms(t.factor_s),
        "one_source_ms": ms(t.one_source_s), "bank_ms": ms(t.bank_s), "total_ms": ms(t.total_s()),
        "candidates": t.candidates, "unknowns": t.unknowns,
    });
    if let Some(dir) = &a.model {
        let model = Surrogate::load(dir)?;
        let candidates = layout.candidates(a.spacing)?;
        let bank = timing::time_model_bank(&model, &layout, &candidates, a.repeats)?;
        println!(
            "PlumeNet {} bank (wind, encoding, network, inverse transform): {:.2} ms = {:.2}x \
             the solver's wind + factor + bank",
            dir.display(),
            ms(bank),
            bank / t.total_s()
        );
        report["model"] = json!(dir.display().to_string());
        report["model_bank_ms"] = json!(ms(bank));
        report["model_over_solver"] = json!(bank / t.total_s());
    }
    if !a.no_reference {
        // Removed when dropped, whichever way this block ends.
        let tmp = export_dir("plumenet-bench-")?;
        let dir = tmp.path();
        timing::export_system(&transport, &candidates, dir)?;
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/superlu_bench.py");
        let output = Process::new("python3")
            .arg(&script)
            .arg(dir)
            .args(["--repeats", &a.repeats.to_string()])
            .output()
            .context("cannot run python3 for the SuperLU reference (use --no-reference to skip)")?;
        if !output.status.success() {
            bail!(
                "SuperLU reference failed: {}",
                String::from_utf8_lossy(&output.stderr).trim()
            );
        }
        let r: serde_json::Value =
            serde_json::from_slice(&output.stdout).context("SuperLU reference printed no JSON")?;
        let f = |k: &str| r[k].as_f64().unwrap_or(f64::NAN);
        let superlu = f("factor_s") + f("solve_s");
        println!(
            "scipy {} SuperLU on the same transport system: factor {:.2} ms + bank {:.2} ms = {:.2} ms (max |difference| {:.1e})",
            r["scipy"].as_str().unwrap_or("?"),
            ms(f("factor_s")),
            ms(f("solve_s")),
            ms(superlu),
            f("max_abs_difference")
        );
        println!(
            "  ratio SuperLU (factor + bank) / plumenet (factor + bank):        {:.2}x",
            superlu / (t.factor_s + t.bank_s)
        );
        println!(
            "  ratio SuperLU (factor + bank) / plumenet (wind + factor + bank): {:.2}x",
            superlu / t.total_s()
        );
        report["superlu"] = r;
        report["ratio_transport"] = json!(superlu / (t.factor_s + t.bank_s));
        report["ratio_with_wind"] = json!(superlu / t.total_s());
    }
    if let Some(path) = &a.json {
        io::write_json(path, &report)?;
    }
    Ok(())
}

/// A fresh temporary directory for a benchmark's exports (deleted when dropped).
pub(crate) fn export_dir(prefix: &str) -> Result<tempfile::TempDir> {
    tempfile::Builder::new()
        .prefix(prefix)
        .tempdir()
        .context("cannot create a temporary directory for the reference exports")
}

/// The operator network of `train --operator`, of the coarse form with `--coarse` (its room
/// planes doubled: they are all the room gives each source; `filters` its per-source
/// network's, if given).
fn operator_config(coarse: bool, filters: Option<Vec<usize>>, level: Option<u8>) -> OperatorConfig {
    let op = OperatorConfig::new();
    if !coarse {
        return op;
    }
    let per_source = CoarseConfig::new();
    let filters = filters.unwrap_or_else(|| per_source.filters.clone());
    let level = level.map_or(per_source.level, usize::from);
    op.with_room_planes(16)
        .with_coarse(Some(per_source.with_filters(filters).with_level(level)))
}

fn train(a: TrainArgs) -> Result<()> {
    let dirs: Vec<&Path> = a.data.iter().map(PathBuf::as_path).collect();
    let data = TrainingData::load_all(&dirs)?;
    let chosen = a.inputs.map(|i| match i {
        InputsArg::Geometry => InputSet::Geometry,
        InputsArg::Physics => InputSet::Physics,
        InputsArg::Wind => InputSet::Wind,
        InputsArg::Analytic => InputSet::Analytic,
        InputsArg::Walled => InputSet::Walled,
    });
    let inputs = chosen.unwrap_or_default();
    let mut config = TrainingConfig {
        epochs: a.epochs,
        batch_size: a.batch_size,
        seed: a.seed,
        patience: a.patience,
        learning_rate: a.learning_rate,
        inputs,
        model: PlumeNetConfig::new()
            .with_in_channels(if a.operator {
                ROOM_CHANNELS
            } else {
                inputs.channels()
            })
            .with_operator(
                a.operator
                    .then(|| operator_config(a.coarse, a.coarse_filters.clone(), a.coarse_level)),
            )
            .with_filters(
                a.filters
                    .clone()
                    .unwrap_or_else(|| PlumeNetConfig::new().filters),
            )
            .with_prior_skip(a.prior_skip.then_some(true)),
        encoding: match a.encoding {
            EncodingArg::Gaussian => SourceEncoding::Gaussian,
            EncodingArg::Distance => SourceEncoding::Distance,
        },
        rel_l2_weight: a.rel_l2_weight,
        mirror: a.mirror,
        select_by: match a.select_by {
            SelectArg::Loss => Selection::Loss,
            SelectArg::RelativeL2 => Selection::RelativeL2,
        },
        ..TrainingConfig::default()
    };
    if let Some(dir) = &a.init_from {
        let start = Surrogate::load(dir)?;
        let saved = start.saved();
        config.model = saved.architecture.clone();
        if a.operator && saved.architecture.operator.is_none() {
            // An operator network on the trained U-Net's body.
            config.model = config
                .model
                .with_in_channels(ROOM_CHANNELS)
                .with_prior_skip(None)
                .with_operator(Some(operator_config(
                    a.coarse,
                    a.coarse_filters.clone(),
                    a.coarse_level,
                )));
        }
        if let Some(filters) = &a.filters {
            config.model.filters = filters.clone();
        }
        config.inputs = chosen.unwrap_or(saved.training.inputs);
        config.init_from = Some(WarmStart {
            model: dir.display().to_string(),
            weights_digest: saved.weights_digest.clone(),
        });
    }
    let bar = progress_bar(0, "epoch");
    let mut running = (0.0, 0usize);
    let state = plumenet::surrogate::train(&data, &config, &a.out, &mut |event| match event {
        TrainEvent::Start { epoch, batches } => {
            bar.set_length(batches as u64);
            bar.set_message(format!("epoch {epoch}/{}", config.epochs));
            if epoch > 1 {
                say(&bar, format!("resuming at epoch {epoch}"));
            }
        }
        TrainEvent::Batch(loss) => {
            running = (running.0 + loss, running.1 + 1);
            bar.inc(1);
            bar.set_message(format!("loss {:.4}", running.0 / running.1 as f64));
        }
        TrainEvent::Epoch(e) => {
            let classes = |v: Option<[Option<f64>; 3]>, digits: usize| {
                v.unwrap_or_default()
                    .map(|v| v.map_or("-".to_string(), |v| format!("{v:.digits$}")))
                    .join(" / ")
            };
            say(
                &bar,
                format!(
                    "epoch {:3}  train {:.5}  validation {:.5} (small / medium / large rooms {}), median rel. L2 {:.3} ({})  {:.0} s",
                    e.epoch,
                    e.train,
                    e.validation,
                    classes(e.validation_by_size, 5),
                    e.validation_relative_l2.unwrap_or(f64::NAN),
                    classes(e.validation_relative_l2_by_size, 3),
                    e.seconds.unwrap_or(0.0)
                ),
            );
            bar.reset();
            running = (0.0, 0);
        }
    })?;
    bar.finish_and_clear();
    if let Some(best) = state.best {
        println!(
            "best epoch {} (validation loss {:.5}, median rel. L2 {:.3}); model in {}",
            best.epoch,
            best.validation,
            best.validation_relative_l2.unwrap_or(f64::NAN),
            a.out.display()
        );
    }
    Ok(())
}

fn predict(a: PredictArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let model = Surrogate::load(&a.model)?;
    let field = model.predict(&layout, [a.source.0, a.source.1])?;
    let title = format!(
        "PlumeNet prediction, source ({}, {}) m",
        a.source.0, a.source.1
    );
    write_field(&field, &layout, &a.out, a.png.as_deref(), a.log, title)?;
    println!("wrote {}", a.out.display());
    Ok(())
}

fn eval(a: EvalArgs) -> Result<()> {
    if !(a.floor.is_finite() && (0.0..1.0).contains(&a.floor)) {
        bail!("--floor must be in [0, 1), got {}", a.floor);
    }
    let model = Surrogate::load(&a.model)?;
    let data = TrainingData::load(&a.data)?;
    if a.coarse_bound.is_none() && data.digest == model.saved().dataset_digest {
        eprintln!(
            "warning: this is the model's training dataset; use unseen layouts for an honest score"
        );
    }
    let settings = EvalSettings {
        points: a.points,
        seed: a.seed,
        floor: a.floor,
    };
    let report = match a.coarse_bound {
        Some(level) => {
            let sharing = a
                .coarse_share
                .map_or(BoundSharing::Own, BoundSharing::Anchor);
            coarse_bound(&model, &data, (level, sharing), &settings)?
        }
        None => evaluate(&model, &data, &settings)?,
    };
    let line = |name: &str, s: &Summary| {
        println!(
            "{name:<24} {:>5} maps  median relative L2 {:.3} (p90 {:.3})  median Spearman {:.3} (p10 {:.3})",
            s.maps, s.median_relative_l2, s.p90_relative_l2, s.median_spearman, s.p10_spearman
        );
    };
    line("all", &report.summary);
    for class in report.by_size.iter().chain(&report.by_speed) {
        if let Some(s) = &class.summary {
            line(&class.class, s);
        }
    }
    if let Some(path) = &a.json {
        io::write_json(path, &report)?;
    }
    if let Some(path) = &a.png {
        // The dataset is held in the canonical frame, so the maps are drawn in it.
        let mut maps = Vec::new();
        for score in report.maps.iter().take(3) {
            let s = score.sample;
            let real = &data.layouts()[score.layout];
            let layout = Frame::of(real).layout_to_canonical(real)?;
            let truth = data.concentration(s).mapv(f64::from);
            let pred = model.predict(&layout, data.source_xy[s])?;
            let error = &pred - &truth;
            maps.push((s, layout, [pred, truth, error]));
        }
        let mut panels = Vec::new();
        for (s, layout, fields) in &maps {
            let how = [
                ("PlumeNet", true),
                ("physics", true),
                ("PlumeNet - physics", false),
            ];
            for (field, (what, log)) in fields.iter().zip(how) {
                let plot = FieldPlot {
                    title: format!("map {s}: {what}"),
                    log,
                    unit: "concentration (units/m²)".into(),
                };
                panels.push(Panel::Field(FieldPanel::new(field.clone(), layout, plot)?));
            }
        }
        save_figure(&panels, path)?;
    }
    Ok(())
}
