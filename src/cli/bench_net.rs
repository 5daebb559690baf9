//! `bench-net`: PlumeNet's bank and training throughput with our convolutions, side by side
//! with Burn's own convolutions (the path before ours) and with the identical network in
//! PyTorch (`scripts/torch_unet_bench.py`), in interleaved rounds.

use std::path::{Path, PathBuf};
use std::process::Command as Process;

use anyhow::{Context, Result, bail};
use clap::Args;
use serde_json::{Value, json};

use super::net_timing::{
    conv_layers, cpu_peak, export_reference, forward_macs, time_bank, time_conv_layer,
    time_training,
};
use plumenet::io;
use plumenet::layout::Layout;
use plumenet::stats::median;
use plumenet::surrogate::conv::kernel::Isa;
use plumenet::surrogate::model::ConvImpl;
use plumenet::surrogate::{Surrogate, TrainingConfig};

/// Samples of a 300-layout, 8-source dataset, for the epoch-time estimate.
const EPOCH_SAMPLES: f64 = 2400.0;

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
    /// Skip Burn's own convolutions (the path before ours).
    #[arg(long)]
    no_burn_conv: bool,
    /// Also time every convolution shape of the network alone (batch `--batch`), ours and
    /// Burn's, forward and forward + backward.
    #[arg(long)]
    layers: bool,
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

/// Times each convolution shape of the network alone and prints its GFLOP/s, ours and Burn's.
fn layer_profile(model: &Surrogate, grid: [usize; 2], batch: usize, peak: Option<f64>) -> Value {
    let saved = model.saved();
    println!("convolution layers (batch {batch}, with ReLU; GFLOP/s, % of peak for ours):");
    let mut rows = Vec::new();
    for (shape, count) in conv_layers(&saved.architecture, grid, batch) {
        let flop = 2.0 * shape.macs() as f64;
        let (of, ot) = time_conv_layer(shape, ConvImpl::Own, 5);
        let (bf, bt) = time_conv_layer(shape, ConvImpl::Burn, 3);
        let pct = |g: f64| peak.map_or(String::new(), |p| format!(" ({:.0}%)", 100.0 * g / p));
        let (ours_fwd, ours_step) = (flop / of / 1e9, 3.0 * flop / ot / 1e9);
        println!(
            "  {:>2} -> {:>2} channels, {:>3} x {:<3} (x{count}): forward ours {ours_fwd:5.1}{}, burn {:5.1}; forward + backward ours {ours_step:5.1}{}, burn {:5.1}",
            shape.cin,
            shape.cout,
            shape.h,
            shape.w,
            pct(ours_fwd),
            flop / bf / 1e9,
            pct(ours_step),
            3.0 * flop / bt / 1e9,
        );
        rows.push(json!({
            "cin": shape.cin, "cout": shape.cout, "h": shape.h, "w": shape.w, "k": shape.k,
            "count": count, "ours_forward_s": of, "ours_step_s": ot,
            "burn_forward_s": bf, "burn_step_s": bt,
        }));
    }
    Value::Array(rows)
}

/// Runs `bench-net`.
pub fn bench_net(a: BenchNetArgs) -> Result<()> {
    let layout = Layout::load(&a.layout)?;
    let model = Surrogate::load(&a.model)?;
    let candidates = layout.candidates(a.spacing)?;
    let n = candidates.len();
    let grid = model.grid(&layout);
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
    let (mut ours, mut burn, mut torch) = (Side::default(), Side::default(), Side::default());
    let (batch, steps) = (a.batch.to_string(), a.steps.to_string());
    let defaults = TrainingConfig::default();
    let (lr, weight_decay) = (
        defaults.learning_rate.to_string(),
        defaults.weight_decay.to_string(),
    );
    let mut sides = vec![("ours", ConvImpl::Own)];
    if !a.no_burn_conv {
        sides.push(("burn-conv", ConvImpl::Burn));
    }
    for round in 1..=a.rounds {
        let mut line = format!("round {round}:");
        for &(name, imp) in &sides {
            let side = if imp == ConvImpl::Own {
                &mut ours
            } else {
                &mut burn
            };
            // Images are forward passes: a mirror-averaging model runs two per candidate.
            side.bank
                .push((n * model.views()) as f64 / time_bank(&model, &layout, &candidates, imp)?);
            side.train.push(
                a.batch as f64
                    / time_training(&model, &layout, &candidates, (a.batch, a.steps), imp)?,
            );
            line += &format!(
                " {name} bank {:6.1} img/s, train {:5.1} img/s |",
                side.bank[round - 1],
                side.train[round - 1]
            );
        }
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
                " torch bank {:6.1} img/s, train {:5.1} img/s",
                torch.bank[round - 1],
                torch.train[round - 1]
            );
        }
        println!("{}", line.trim_end_matches(" |"));
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
        "steps": a.steps, "isa": format!("{:?}", Isa::best()),
        "ours_bank_images_per_s": ours.bank, "ours_train_images_per_s": ours.train,
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
    let mut ratios = serde_json::Map::new();
    for (what, key, passes) in [("bank", "bank", 1.0), ("training", "train", 3.0)] {
        let rates = |side: &Side| {
            if key == "bank" {
                side.bank.clone()
            } else {
                side.train.clone()
            }
        };
        let rate = median(&rates(&ours));
        let g = gflops(rate, passes);
        println!(
            "{what:8}: ours      {rate:7.1} img/s ({g:5.1} GFLOP/s{})",
            of_peak(g)
        );
        for (name, side, used) in [
            ("burn-conv", &burn, !a.no_burn_conv),
            ("torch", &torch, !a.no_reference),
        ] {
            if !used {
                continue;
            }
            let other = median(&rates(side));
            let o = gflops(other, passes);
            println!(
                "{:8}  {name:9} {other:7.1} img/s ({o:5.1} GFLOP/s{}); ours / {name} = {:.2}x",
                "",
                of_peak(o),
                rate / other
            );
            let name = name.replace('-', "_");
            report[format!("{name}_{key}_images_per_s")] = json!(rates(side));
            ratios.insert(format!("{what}_ours_over_{name}"), json!(rate / other));
        }
    }
    let train_share = 1.0 - defaults.validation_fraction;
    let bank_s = |side: &Side| (n * model.views()) as f64 / median(&side.bank);
    let epoch_s = |side: &Side| {
        EPOCH_SAMPLES * train_share / median(&side.train)
            + EPOCH_SAMPLES * (1.0 - train_share) / median(&side.bank)
    };
    println!(
        "bank of {n} candidates: ours {:.1} s{}; one epoch of {EPOCH_SAMPLES} samples (estimated from the rates): ours {:.0} s{}",
        bank_s(&ours),
        if a.no_burn_conv {
            String::new()
        } else {
            format!(", burn-conv {:.1} s", bank_s(&burn))
        },
        epoch_s(&ours),
        if a.no_burn_conv {
            String::new()
        } else {
            format!(", burn-conv {:.0} s", epoch_s(&burn))
        },
    );
    report["ratios"] = Value::Object(ratios);
    if a.layers {
        report["layers"] = layer_profile(&model, grid, a.batch, peak_gflops);
    }
    report["identity"] = identity;
    if let Some(path) = &a.json {
        io::write_json(path, &report)?;
    }
    Ok(())
}
