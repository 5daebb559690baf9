//! `bench-net`: PlumeNet's bank and training throughput, side by side with the identical
//! network in PyTorch (`scripts/torch_unet_bench.py`), in interleaved rounds.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Value, json};

use plumenet::bench::median;
use plumenet::io;
use plumenet::layout::Layout;
use plumenet::surrogate::bench::{
    cpu_peak, export_reference, forward_macs, time_bank, time_training,
};
use plumenet::surrogate::{Surrogate, TrainingConfig};

/// Flags of `bench-net`.
#[derive(Debug, Args)]
pub struct BenchNetArgs {
    /// Trained model to time.
    #[arg(long, default_value = "models/default")]
    model: PathBuf,
    /// Layout whose candidate bank is timed.
    #[arg(long, default_value = "data/layouts/wind-tunnel.json")]
    layout: PathBuf,
    /// Candidate grid spacing in metres.
    #[arg(long, default_value_t = 0.25)]
    spacing: f64,
    /// Interleaved rounds (medians are reported).
    #[arg(long, default_value_t = 3)]
    rounds: usize,
    /// Samples per training batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Timed training steps per round.
    #[arg(long, default_value_t = 10)]
    steps: usize,
    /// Python interpreter for the PyTorch reference (it installs torch with pip when missing).
    #[arg(long, default_value = "python3")]
    python: PathBuf,
    /// Skip the PyTorch reference.
    #[arg(long)]
    no_reference: bool,
    /// Write the figures as JSON.
    #[arg(long)]
    json: Option<PathBuf>,
}

/// Runs the reference script once and returns its JSON report.
fn reference(python: &Path, dir: &Path, args: &[&str]) -> Result<Value> {
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/torch_unet_bench.py");
    let output = Process::new(python)
        .arg(&script)
        .arg(dir)
        .args(args)
        .output()
        .with_context(|| {
            format!(
                "cannot run {} for the PyTorch reference (use --no-reference to skip)",
                python.display()
            )
        })?;
    if !output.status.success() {
        bail!(
            "PyTorch reference failed: {}",
            String::from_utf8_lossy(&output.stderr).trim()
        );
    }
    serde_json::from_slice(&output.stdout).context("the PyTorch reference printed no JSON")
}

/// One side's rates, one per round: images per second for the bank and for training.
#[derive(Default)]
struct Side {
    bank: Vec<f64>,
    train: Vec<f64>,
}

/// Runs `bench-net`.
pub fn bench_net(a: BenchNetArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let model = Surrogate::load(&a.model)?;
    let candidates = layout.candidates(a.spacing)?;
    let n = candidates.len();
    let grid = model.saved().grid;
    let macs = forward_macs(&model.saved().architecture, grid) as f64;
    let threads = rayon::current_num_threads();
    println!(
        "PlumeNet {} on {} ({}x{} grid, {:.1} M multiply-adds per image), {} candidates, {} rounds, {} threads",
        a.model.display(),
        a.layout.display(),
        grid[0],
        grid[1],
        macs / 1e6,
        n,
        a.rounds,
        threads
    );
    // The reference's exports, removed when dropped, whichever way this command ends.
    let tmp = (!a.no_reference)
        .then(|| super::export_dir("plumenet-bench-net-"))
        .transpose()?;
    let mut identity = Value::Null;
    if let Some(dir) = tmp.as_ref().map(|t| t.path()) {
        let tensors = export_reference(&model, &layout, &candidates, dir)?;
        identity = reference(&a.python, dir, &["--mode", "check"])?;
        println!(
            "PyTorch {} loaded the same {} weight tensors: max |burn - torch| over the bank {:.1e} (outputs up to {:.1})",
            identity["torch"].as_str().unwrap_or("?"),
            tensors,
            identity["max_abs_difference"].as_f64().unwrap_or(f64::NAN),
            identity["max_abs_output"].as_f64().unwrap_or(f64::NAN),
        );
    }
    let (mut burn, mut torch) = (Side::default(), Side::default());
    let (batch, steps) = (a.batch.to_string(), a.steps.to_string());
    let defaults = TrainingConfig::default();
    let (lr, weight_decay) = (
        defaults.learning_rate.to_string(),
        defaults.weight_decay.to_string(),
    );
    for round in 1..=a.rounds {
        burn.bank
            .push(n as f64 / time_bank(&model, &layout, &candidates)?);
        burn.train
            .push(a.batch as f64 / time_training(&model, &layout, &candidates, a.batch, a.steps)?);
        let mut line = format!(
            "round {round}: burn bank {:7.1} img/s, train {:6.1} img/s",
            burn.bank[round - 1],
            burn.train[round - 1]
        );
        if let Some(dir) = tmp.as_ref().map(|t| t.path()) {
            let r = reference(&a.python, dir, &["--mode", "bank"])?;
            torch
                .bank
                .push(n as f64 / r["seconds"].as_f64().unwrap_or(f64::NAN));
            let r = reference(
                &a.python,
                dir,
                &[
                    "--mode",
                    "train",
                    "--batch",
                    &batch,
                    "--steps",
                    &steps,
                    "--lr",
                    &lr,
                    "--weight-decay",
                    &weight_decay,
                ],
            )?;
            torch
                .train
                .push(a.batch as f64 / r["seconds_per_step"].as_f64().unwrap_or(f64::NAN));
            line += &format!(
                " | torch bank {:7.1} img/s, train {:6.1} img/s",
                torch.bank[round - 1],
                torch.train[round - 1]
            );
        }
        println!("{line}");
    }

    // A training step is a forward pass and a backward pass; the backward pass computes the
    // gradients of inputs and weights, about twice the forward's work: three passes in all.
    let gflops = |images: f64, passes: f64| images * 2.0 * macs * passes / 1e9;
    let peak = cpu_peak();
    let peak_gflops = peak.as_ref().map(|p| p.gflops());
    let of_peak = |g: f64| {
        peak_gflops.map_or(String::new(), |p| {
            format!(" = {:.1}% of peak", 100.0 * g / p)
        })
    };
    let mut report = json!({
        "model": a.model, "layout": a.layout, "candidates": n, "grid": grid,
        "forward_macs": macs, "threads": threads, "rounds": a.rounds, "batch": a.batch,
        "steps": a.steps, "burn_bank_images_per_s": burn.bank, "burn_train_images_per_s": burn.train,
    });
    if let Some(p) = &peak {
        println!(
            "peak estimate: {:.0} GFLOP/s ({} cores x {:.0} MHz x {} flop/cycle: two FMA units of the widest vectors)",
            p.gflops(),
            p.cores,
            p.mhz,
            p.flops_per_cycle
        );
        report["peak_gflops"] = json!(p.gflops());
    }
    for (what, burn_rates, torch_rates, passes) in [
        ("bank", &burn.bank, &torch.bank, 1.0),
        ("training", &burn.train, &torch.train, 3.0),
    ] {
        let burn_rate = median(burn_rates.clone());
        let g = gflops(burn_rate, passes);
        let mut line = format!(
            "{what:8}: burn {burn_rate:7.1} img/s ({g:.1} GFLOP/s{})",
            of_peak(g)
        );
        if !a.no_reference {
            let torch_rate = median(torch_rates.clone());
            let t = gflops(torch_rate, passes);
            line += &format!(
                ", torch {torch_rate:7.1} img/s ({t:.1} GFLOP/s{}); burn / torch = {:.2}x",
                of_peak(t),
                burn_rate / torch_rate
            );
            report[format!("torch_{what}_images_per_s")] = json!(torch_rates);
            report[format!("ratio_{what}")] = json!(burn_rate / torch_rate);
        }
        println!("{line}");
    }
    report["identity"] = identity;
    if let Some(path) = &a.json {
        io::write_json(path, &report)?;
    }
    Ok(())
}
