//! Training PlumeNet: AdamW, a train/validation split by layout, best-checkpoint keeping, early
//! stopping and resumption after an interruption.
//!
//! `out/` receives `weights.bpk` (burnpack) and `config.json` whenever the validation score
//! ([`super::config::Selection`]: the loss, or the maps' median relative L2 error) improves
//! (both written atomically), and `out/checkpoint/` the latest epoch's model, optimizer state
//! and progress (`state.json`, written last, names the epoch whose files to read), from which a
//! run interrupted anywhere, in the middle of writing a checkpoint too, resumes with identical
//! results. Re-running with a higher `epochs` continues a finished run.

use std::path::Path;

use burn::optim::{AdamWConfig, GradientsParams};
use burn::prelude::*;
use rand::seq::SliceRandom;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::config::{EpochLoss, TrainState, TrainingConfig};
use super::data::{InputSet, TrainingData, size_class};
use super::inference::Surrogate;
use super::model::{ConvImpl, PlumeNet, ROOM_CHANNELS};
use super::room_batch::{RoomBatch, RoomSamples};
use super::saved::{SavedModel, load_weights, weights_bytes};
use crate::error::{Error, Result};
use crate::io;
use crate::stats::median;

/// What the caller is told while training runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum TrainEvent {
    /// A run starts (or resumes) with this many batches per epoch.
    Start {
        /// First epoch to run.
        epoch: usize,
        /// Batches per epoch.
        batches: usize,
    },
    /// One batch done with this loss.
    Batch(f64),
    /// One epoch done.
    Epoch(EpochLoss),
}

fn check(config: &TrainingConfig, data: &TrainingData) -> Result<()> {
    let bad = |m: &str| Err(Error::Parameter(m.to_string()));
    if config.epochs == 0 || config.batch_size == 0 {
        return bad("epochs and batch size must be at least 1");
    }
    if !(config.learning_rate > 0.0 && config.learning_rate.is_finite()) {
        return bad("learning rate must be positive");
    }
    if !(0.0..1.0).contains(&config.validation_fraction) {
        return bad("validation fraction must be in [0, 1)");
    }
    if config.model.filters.is_empty()
        || config.model.filters.contains(&0)
        || config.model.kernel_size % 2 == 0
    {
        return bad("filters must be non-empty and positive, and the kernel size odd");
    }
    let expected = if config.model.operator.is_some() {
        ROOM_CHANNELS
    } else {
        config.inputs.channels()
    };
    if config.model.in_channels != expected {
        return Err(Error::Parameter(format!(
            "the network takes {} input channels but the {:?} inputs have {expected}",
            config.model.in_channels, config.inputs,
        )));
    }
    if let Some(op) = &config.model.operator {
        if config.inputs != InputSet::Analytic || config.model.skips_prior() {
            return bad("an operator network takes the analytic inputs, without the prior skip");
        }
        if op.groups == 0 || op.group_size == 0 || op.hidden == 0 {
            return bad("an operator network needs at least one group, term and hidden channel");
        }
        if let Some(problem) = config.model.coarse_problem() {
            return Err(Error::Parameter(problem));
        }
        let step = 1 << (config.model.filters.len() - 1);
        if config.pad_cells % step != 0 {
            return Err(Error::Parameter(format!(
                "an operator network pads rooms to whole pooling steps: pad_cells must be a \
                 multiple of {step}"
            )));
        }
    }
    if config.model.skips_prior() && !config.inputs.has_prior() {
        return bad("the prior skip needs the analytic inputs (analytic or walled)");
    }
    if config.pad_cells == 0 {
        return bad("pad_cells must be at least 1");
    }
    if data.len() < 2 {
        return Err(Error::Dataset(
            "a training set needs at least two samples".into(),
        ));
    }
    Ok(())
}

/// Mean of the squared error over free cells.
pub(crate) fn masked_mse(pred: Tensor<4>, target: Tensor<4>, free: Tensor<4>) -> Tensor<1> {
    let count = free.clone().sum();
    (pred - target).powi_scalar(2).mul(free).sum().div(count)
}

/// Each map's squared relative L2 error of `exp(pred) - 1` against `exp(y) - 1` over free
/// cells, `[B, 1, 1, 1]`. The target is `y = ln(1 + c f / s)`, so `c` is proportional to
/// `exp(y) - 1` with a factor that cancels in the ratio.
fn squared_relative_l2(pred: Tensor<4>, y: Tensor<4>, free: Tensor<4>) -> Tensor<4> {
    let per_map = |t: Tensor<4>| t.sum_dim(3).sum_dim(2).sum_dim(1);
    let c = y.exp().sub_scalar(1.0);
    let diff = pred.exp().sub_scalar(1.0).sub(c.clone());
    let err = per_map(diff.powi_scalar(2).mul(free.clone()));
    let norm = per_map(c.powi_scalar(2).mul(free)).add_scalar(1e-12);
    err.div(norm)
}

/// The training loss: `masked_mse` of the transformed target, plus `rel_l2_weight` times the
/// batch's mean squared relative L2 error of the concentration over free cells
/// (predictions capped at `y = 20` inside the exponential).
pub fn loss(config: &TrainingConfig, pred: Tensor<4>, y: Tensor<4>, free: Tensor<4>) -> Tensor<1> {
    let mse = masked_mse(pred.clone(), y.clone(), free.clone());
    if config.rel_l2_weight == 0.0 {
        return mse;
    }
    let rel = squared_relative_l2(pred.clamp_max(20.0), y, free);
    mse.add(rel.mean().mul_scalar(config.rel_l2_weight))
}

/// Each map's relative L2 error of the predicted concentration over free cells, the
/// evaluation's measure ([`super::eval`]): the network's output is mapped back as in
/// inference (negative outputs are zero concentration).
///
/// # Errors
/// [`Error::Model`] when the values cannot be read.
pub fn relative_l2_per_map(pred: Tensor<4>, y: Tensor<4>, free: Tensor<4>) -> Result<Vec<f64>> {
    let squared = squared_relative_l2(pred.clamp(0.0, 20.0), y, free)
        .into_data()
        .try_to_vec::<f32>()
        .map_err(|e| Error::Model(format!("cannot read the relative L2 errors: {e:?}")))?;
    Ok(squared.into_iter().map(|v| f64::from(v).sqrt()).collect())
}

/// A batch as the network takes it: maps of room and source together, or rooms with their
/// sources for an operator network.
enum Inputs {
    Maps(Box<Tensor<4>>),
    Rooms(Box<RoomBatch>),
}

/// The transformed concentration `[n, 1, H, W]` the network predicts for a batch.
fn predict(model: &PlumeNet, inputs: Inputs) -> Tensor<4> {
    match inputs {
        Inputs::Maps(x) => model.forward(*x),
        Inputs::Rooms(batch) => model.source_fields(
            model.room_planes(batch.rooms, ConvImpl::Own),
            &batch.taps,
            batch.sources,
            ConvImpl::Own,
        ),
    }
}

/// The batching units of `samples`, grouped into buckets of one padded grid: single samples,
/// or for an operator network the samples of one room (grouped by source count too).
fn unit_buckets(
    data: &TrainingData,
    samples: &[usize],
    config: &TrainingConfig,
) -> Vec<Vec<Vec<usize>>> {
    if config.model.operator.is_some() {
        data.room_buckets(&data.rooms_of(samples), config.pad_cells)
    } else {
        data.buckets(samples, config.pad_cells)
            .into_iter()
            .map(|bucket| bucket.into_iter().map(|s| vec![s]).collect())
            .collect()
    }
}

/// Units per batch in a bucket of `units`: `batch_size` maps, as whole rooms for an operator
/// network (at least one).
fn units_per_batch(units: &[Vec<usize>], batch_size: usize) -> usize {
    let maps = units.first().map_or(1, Vec::len).max(1);
    (batch_size / maps).max(1)
}

/// The batch of `units` with the run's inputs, encoding, normalisation and padding, and its
/// target and weight tensors; `mirror` flags each unit.
fn batch(
    data: &TrainingData,
    units: &[Vec<usize>],
    mirror: Option<&[bool]>,
    config: &TrainingConfig,
    device: &Device,
) -> Result<(Inputs, Tensor<4>, Tensor<4>)> {
    if config.model.operator.is_some() {
        let (rooms, y, free) = data.room_batch(
            units,
            mirror,
            (
                &config.normalization,
                config.pad_cells,
                config.model.coarse_pooling(),
            ),
            device,
        )?;
        return Ok((Inputs::Rooms(Box::new(rooms)), y, free));
    }
    let samples: Vec<usize> = units.iter().flatten().copied().collect();
    let (x, y, free) = data.batch(
        &samples,
        mirror,
        config.inputs,
        config.encoding,
        &config.normalization,
        config.pad_cells,
        device,
    )?;
    Ok((Inputs::Maps(Box::new(x)), y, free))
}

/// Summed loss of `model` over `samples` (no gradients), in batches of one padded grid, and
/// each sample's relative L2 error.
fn scores(
    model: &PlumeNet,
    data: &TrainingData,
    samples: &[usize],
    config: &TrainingConfig,
    device: &Device,
) -> Result<(f64, Vec<f64>)> {
    let (mut sum, mut relative) = (0.0, Vec::with_capacity(samples.len()));
    for bucket in unit_buckets(data, samples, config) {
        let per_batch = units_per_batch(&bucket, config.batch_size.max(1) * 2);
        for chunk in bucket.chunks(per_batch) {
            let maps: usize = chunk.iter().map(Vec::len).sum();
            let (x, y, free) = batch(data, chunk, None, config, device)?;
            let pred = predict(model, x);
            relative.extend(relative_l2_per_map(pred.clone(), y.clone(), free.clone())?);
            let loss: f32 = loss(config, pred, y, free).into_scalar();
            sum += f64::from(loss) * maps as f64;
        }
    }
    Ok((sum, relative))
}

/// Validation scores of a model on held-out samples: the mean loss and the median relative L2
/// error of the maps (the goal's measure), overall and per room size class
/// ([`super::data::SIZE_CLASSES`]; `None` for a class without samples).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Validation {
    /// Mean loss (NaN without samples).
    pub loss: f64,
    /// Mean loss per size class.
    pub loss_by_size: [Option<f64>; 3],
    /// Median relative L2 error of the maps (NaN without samples).
    pub relative_l2: f64,
    /// Median relative L2 error per size class.
    pub relative_l2_by_size: [Option<f64>; 3],
}

/// Validation scores of `model` over `samples` (no gradients).
///
/// # Errors
/// As [`TrainingData::batch`].
pub fn validate(
    model: &PlumeNet,
    data: &TrainingData,
    samples: &[usize],
    config: &TrainingConfig,
    device: &Device,
) -> Result<Validation> {
    let mut out = Validation {
        loss: f64::NAN,
        loss_by_size: [None; 3],
        relative_l2: f64::NAN,
        relative_l2_by_size: [None; 3],
    };
    let (mut sum, mut all) = (0.0, Vec::new());
    for class in 0..out.loss_by_size.len() {
        let members: Vec<usize> = samples
            .iter()
            .copied()
            .filter(|&s| size_class(&data.layouts()[data.source_layout[s]]) == class)
            .collect();
        let (class_sum, relative) = scores(model, data, &members, config, device)?;
        if !members.is_empty() {
            out.loss_by_size[class] = Some(class_sum / members.len() as f64);
            out.relative_l2_by_size[class] = Some(median(&relative));
        }
        sum += class_sum;
        all.extend(relative);
    }
    if !all.is_empty() {
        out.loss = sum / all.len() as f64;
        out.relative_l2 = median(&all);
    }
    Ok(out)
}

/// The batches of one epoch: `samples` shuffled, cut into batches of one padded grid
/// ([`unit_buckets`]: single samples, or whole rooms for an operator network), and the batches
/// shuffled; with [`TrainingConfig::mirror`], each batch's mirror flags, one per unit (all from
/// `rng`, the flags drawn last so that runs without mirroring shuffle as before).
fn epoch_batches(
    data: &TrainingData,
    samples: &[usize],
    config: &TrainingConfig,
    rng: &mut ChaCha8Rng,
) -> Vec<(Vec<RoomSamples>, Option<Vec<bool>>)> {
    let mut order = samples.to_vec();
    order.shuffle(rng);
    let mut batches: Vec<Vec<Vec<usize>>> = unit_buckets(data, &order, config)
        .iter()
        .flat_map(|bucket| {
            bucket
                .chunks(units_per_batch(bucket, config.batch_size))
                .map(<[Vec<usize>]>::to_vec)
        })
        .collect();
    batches.shuffle(rng);
    batches
        .into_iter()
        .map(|chunk| {
            let flags = config
                .mirror
                .then(|| chunk.iter().map(|_| rng.random_bool(0.5)).collect());
            (chunk, flags)
        })
        .collect()
}

/// The weights a fresh run starts from: seeded random ones, or those of the warm-start model.
fn initial_model(config: &TrainingConfig, device: &Device) -> Result<PlumeNet> {
    let Some(warm) = &config.init_from else {
        return Ok(config.model.init_seeded(device, config.seed));
    };
    let (saved, net) = SavedModel::load(Path::new(&warm.model), device)?;
    if saved.weights_digest != warm.weights_digest {
        return Err(Error::Model(format!(
            "{} is not the model to start from: its weights differ from the run's",
            warm.model
        )));
    }
    if config.model.operator.is_some() && saved.architecture.operator.is_none() {
        return net.operator_from(&saved.architecture, &config.model, config.seed, device);
    }
    if !config.model.widens(&saved.architecture) {
        return Err(Error::Model(format!(
            "{} is not the model to start from: its architecture (filters {:?}) is not the \
             run's (filters {:?}) and the run's does not widen it (same levels, kernel, \
             convolutions per level, inputs and prior skip, at least as many channels at each)",
            warm.model, saved.architecture.filters, config.model.filters
        )));
    }
    if saved.architecture == config.model {
        return Ok(net);
    }
    net.widened(&saved.architecture, &config.model, config.seed, device)
}

/// Trains (or resumes training) on `data`, writing the model to `out`.
///
/// # Errors
/// [`Error::Parameter`] for a bad configuration, [`Error::Dataset`] for too little data,
/// [`Error::Model`] when a checkpoint in `out` belongs to another run or is damaged,
/// [`Error::Io`] when `out` is not writable.
pub fn train(
    data: &TrainingData,
    config: &TrainingConfig,
    out: &Path,
    progress: &mut dyn FnMut(TrainEvent),
) -> Result<TrainState> {
    check(config, data)?;
    let device = super::backend::device().autodiff();
    let valid_device = super::backend::device();
    let checkpoint = out.join("checkpoint");
    let (train_idx, val_idx) = data.split_by_layout(config.validation_fraction);
    if train_idx.is_empty() {
        return Err(Error::Dataset(
            "no training layouts left after the validation split".into(),
        ));
    }

    let fresh_optim = || {
        AdamWConfig::new()
            .with_weight_decay(config.weight_decay)
            .init()
    };

    let (mut model, mut optim, mut state) = if checkpoint.join("state.json").exists() {
        let state: TrainState = io::read_json(&checkpoint.join("state.json"))?;
        if !state.config.same_run(config) || state.dataset_digest != data.digest {
            return Err(Error::Model(format!(
                "{} holds a checkpoint of another run (configuration or dataset differ); \
                 remove it or choose another --out",
                checkpoint.display()
            )));
        }
        let (model_file, optim_file) = resume_files(&checkpoint, state.history.len());
        let model = load_weights(config.model.init(&device), &model_file)?;
        let bytes = std::fs::read(&optim_file).map_err(|source| Error::Io {
            action: "cannot read",
            path: optim_file.clone(),
            source,
        })?;
        let optim = fresh_optim()
            .from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes))
            .map_err(|e| Error::Model(format!("damaged optimizer checkpoint: {e:?}")))?;
        // A resumed run may extend the epoch limit or the patience.
        let state = TrainState {
            config: config.clone(),
            ..state
        };
        (model, optim, state)
    } else {
        let state = TrainState {
            config: config.clone(),
            dataset_digest: data.digest.clone(),
            history: Vec::new(),
            best: None,
            stopped_early: false,
        };
        (initial_model(config, &device)?, fresh_optim(), state)
    };
    if state.stopped_early || state.history.len() >= config.epochs {
        return Ok(state);
    }
    let first_epoch = state.history.len() + 1;
    let epoch_rng = |epoch: usize| {
        let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
        rng.set_stream(epoch as u64);
        rng
    };
    let batches = epoch_batches(data, &train_idx, config, &mut epoch_rng(first_epoch)).len();
    progress(TrainEvent::Start {
        epoch: first_epoch,
        batches,
    });
    for epoch in first_epoch..=config.epochs {
        let started = std::time::Instant::now();
        let batches = epoch_batches(data, &train_idx, config, &mut epoch_rng(epoch));
        let mut sum = 0.0;
        for (b, (chunk, flags)) in batches.iter().enumerate() {
            let (x, y, free) = batch(data, chunk, flags.as_deref(), config, &device)?;
            let loss = loss(config, predict(&model, x), y, free);
            let value = f64::from(loss.clone().into_scalar::<f32>());
            let grads = GradientsParams::from_grads(loss.backward(), &model);
            let progress_in_run =
                ((epoch - 1) as f64 + b as f64 / batches.len() as f64) / config.epochs as f64;
            let rate = config.schedule.rate(config.learning_rate, progress_in_run);
            model = optim.step(rate, model, grads);
            sum += value * chunk.iter().map(Vec::len).sum::<usize>() as f64;
            progress(TrainEvent::Batch(value));
        }
        let valid = model.valid();
        let scores = validate(&valid, data, &val_idx, config, &valid_device)?;
        let record = EpochLoss {
            epoch,
            train: sum / train_idx.len() as f64,
            validation: scores.loss,
            validation_by_size: Some(scores.loss_by_size),
            validation_relative_l2: Some(scores.relative_l2),
            validation_relative_l2_by_size: Some(scores.relative_l2_by_size),
            seconds: Some(started.elapsed().as_secs_f64()),
        };
        state.history.push(record);
        let improved = state.best.is_none_or(|b| {
            config.select_by.score(&record) < config.select_by.score(&b) || val_idx.is_empty()
        });
        if improved {
            state.best = Some(record);
            SavedModel::new(config, data, &state).write(out, &valid)?;
        }
        let since_best = epoch - state.best.map_or(epoch, |b| b.epoch);
        state.stopped_early = since_best >= config.patience;
        let finished = epoch == config.epochs || state.stopped_early;
        // The epoch's model and optimizer go to files of their own, then state.json names the
        // epoch: a run killed anywhere in between resumes from the previous epoch's files,
        // which are removed only after the new state.json is in place.
        io::create_dir_all(&checkpoint)?;
        let (model_file, optim_file) = checkpoint_files(&checkpoint, state.history.len());
        let model_bytes = weights_bytes(&model)?;
        io::write_atomic(&model_file, |b| {
            b.extend_from_slice(&model_bytes);
            Ok(())
        })?;
        let optim_bytes = optim
            .into_bytes()
            .map_err(|e| Error::Model(format!("cannot serialise the optimizer: {e:?}")))?;
        io::write_atomic(&optim_file, |b| {
            b.extend_from_slice(&optim_bytes);
            Ok(())
        })?;
        io::write_json(&checkpoint.join("state.json"), &state)?;
        remove_other_checkpoints(&checkpoint, &[&model_file, &optim_file]);
        // The final config.json carries the full history.
        if finished {
            let best = Surrogate::load(out)?;
            SavedModel::new(config, data, &state).write(out, best.net())?;
        }
        progress(TrainEvent::Epoch(record));
        if finished {
            break;
        }
    }
    Ok(state)
}

/// The model and optimizer files of the checkpoint after `epochs` epochs.
fn checkpoint_files(dir: &Path, epochs: usize) -> (std::path::PathBuf, std::path::PathBuf) {
    (
        dir.join(format!("model-{epochs}.bpk")),
        dir.join(format!("optimizer-{epochs}.bin")),
    )
}

/// The checkpoint files to resume from after `epochs` epochs: [`checkpoint_files`], or those of
/// the format's first version (`model.bpk`, `optimizer.bin`) when only they are there.
fn resume_files(dir: &Path, epochs: usize) -> (std::path::PathBuf, std::path::PathBuf) {
    let (model, optim) = checkpoint_files(dir, epochs);
    if !model.exists() && dir.join("model.bpk").exists() {
        return (dir.join("model.bpk"), dir.join("optimizer.bin"));
    }
    (model, optim)
}

/// Removes the checkpoint's model and optimizer files other than `keep` (earlier epochs, an
/// epoch interrupted before its state was written, temporary files of a killed write). A file
/// that cannot be removed is left: it is never read.
fn remove_other_checkpoints(dir: &Path, keep: &[&Path]) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for path in entries.flatten().map(|e| e.path()) {
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        let ours = name.starts_with("model")
            || name.starts_with("optimizer")
            || name.starts_with(".model")
            || name.starts_with(".optimizer");
        if ours && !keep.contains(&path.as_path()) {
            let _ = std::fs::remove_file(&path);
        }
    }
}
