//! The command line: clap definitions and the thin glue from flags to library calls.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{Context, Result, bail};
use clap::{Args, Parser, Subcommand};
use indicatif::{ProgressBar, ProgressStyle};
use ndarray::{Array2, Axis};
use serde_json::json;

use plumenet::dataset::{self, GenerateConfig, GenerateParams, Shard};
use plumenet::layout::Layout;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;
use plumenet::report::{FieldPlot, render_field, save_png};
use plumenet::{bench, io};

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
struct BankArgs {
    /// Use the physics solver as plume model.
    #[arg(long, required = true)]
    solver: bool,
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
    /// Arena, grid, wind and coefficients (obstacles ignored).
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    base: PathBuf,
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

impl Cli {
    /// Runs the chosen command.
    pub fn run(self) -> Result<()> {
        match self.command {
            Command::Simulate(a) => simulate(a),
            Command::Bank(a) => bank(a),
            Command::Generate(a) => generate(a),
            Command::Merge(a) => merge(a),
            Command::Bench(a) => run_bench(a),
        }
    }
}

fn simulate(a: SimulateArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    layout.check_source(a.source.0, a.source.1)?;
    let wind = WindField::solve(&layout)?;
    let transport = Transport::new(&layout, &wind)?;
    let field = transport.solve(a.source.0, a.source.1)?;
    io::write_npy(&a.out, &field.mapv(|v| v as f32))?;
    if let Some(path) = &a.wind_out {
        io::write_npy(path, &wind.centred().mapv(|v| v as f32))?;
    }
    if let Some(path) = &a.png {
        let title = format!(
            "mean concentration, source ({}, {}) m",
            a.source.0, a.source.1
        );
        let plot = FieldPlot {
            title,
            log: a.log,
            unit: "units/m2".into(),
        };
        save_png(&render_field(&field, &layout, &plot)?, path)?;
    }
    let outlet = transport.outlet_flux(&field);
    let peak = field.iter().copied().fold(0.0, f64::max);
    println!(
        "wind: {} iterations, residual {:.1e}; outlet flux {:.4} of 1 unit/s; peak {:.4} units/m2",
        wind.steps, wind.residual, outlet, peak
    );
    println!("wrote {}", a.out.display());
    if let Some(path) = &a.json {
        let report = json!({
            "layout": a.layout, "source": [a.source.0, a.source.1], "out": a.out,
            "wind_iterations": wind.steps, "wind_residual": wind.residual,
            "outlet_flux": outlet, "peak": peak, "grid": [layout.ny(), layout.nx()],
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
    let wind = WindField::solve(&layout)?;
    let bank = Transport::new(&layout, &wind)?.bank(&candidates)?;
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
    let base = Layout::load(&a.base)?.spec().clone();
    let config = GenerateConfig {
        base,
        layouts: a.layouts,
        sources_per_layout: a.sources,
        seed: a.seed,
        shard: a.shard,
        params: GenerateParams::default(),
    };
    let bar = progress_bar(config.layout_range().len(), "layouts");
    let manifest = dataset::generate(&config, &a.out, &|| bar.inc(1))?;
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
    let (t, transport, candidates) = bench::time_bank(&layout, a.spacing, a.repeats)?;
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
    if !a.no_reference {
        let dir = tempfile_dir()?;
        bench::export_system(&transport, &candidates, &dir)?;
        let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/superlu_bench.py");
        let output = Process::new("python3")
            .arg(&script)
            .arg(&dir)
            .args(["--repeats", &a.repeats.to_string()])
            .output()
            .context("cannot run python3 for the SuperLU reference (use --no-reference to skip)")?;
        let _ = std::fs::remove_dir_all(&dir);
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

fn tempfile_dir() -> Result<PathBuf> {
    let dir = std::env::temp_dir().join(format!("plumenet-bench-{}", std::process::id()));
    io::create_dir_all(&dir)?;
    Ok(dir)
}
