//! What defines a training run and what it records: [`TrainingConfig`] (saved in
//! `config.json` and the checkpoint), the per-epoch losses and the progress of a run.

use serde::{Deserialize, Serialize};

use super::data::{InputSet, Normalization, SourceEncoding};
use super::model::PlumeNetConfig;

/// Everything that defines a training run (saved in `config.json` and the checkpoint).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainingConfig {
    /// Architecture.
    pub model: PlumeNetConfig,
    /// Maximum epochs.
    pub epochs: usize,
    /// Samples per batch.
    pub batch_size: usize,
    /// Peak AdamW learning rate (DeepCFD: 1e-3; 3e-4 here, `docs/plumenet.md`).
    pub learning_rate: f64,
    /// AdamW weight decay (DeepCFD: 0.005).
    pub weight_decay: f32,
    /// Share of layouts held out for validation.
    pub validation_fraction: f64,
    /// Stop after this many epochs without a better validation score ([`Selection`]).
    pub patience: usize,
    /// Seed of the weight initialisation and the shuffling.
    pub seed: u64,
    /// Source encoding of the inputs.
    pub encoding: SourceEncoding,
    /// Input and target scales.
    pub normalization: Normalization,
    /// Input channels (one-room models, format `plumenet-model-v1`: geometry only).
    #[serde(default = "legacy_inputs")]
    pub inputs: InputSet,
    /// Rooms are padded to multiples of this many cells, in training (so that rooms of nearby
    /// sizes share a batch) and in inference alike.
    #[serde(default = "legacy_pad_cells")]
    pub pad_cells: usize,
    /// Learning rate over the run.
    #[serde(default)]
    pub schedule: LrSchedule,
    /// Weight of the maps' squared relative L2 error (in concentration, over free cells) added
    /// to the loss; 0, the default and every model before it, trains on the transformed
    /// target's squared error alone.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub rel_l2_weight: f32,
    /// Mirror each training sample across the wind (`y -> H - y`) with probability 1/2, drawn
    /// anew every epoch: an exact symmetry of the physics, so the network sees twice as many
    /// rooms. False, the default and every model before it, trains on the maps as they are.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub mirror: bool,
    /// Which validation score picks the kept epoch and drives early stopping: the loss (the
    /// default, and every model before it) or the maps' median relative L2 error.
    #[serde(default, skip_serializing_if = "Selection::is_loss")]
    pub select_by: Selection,
    /// Start from the weights of this trained model (same architecture) instead of random ones:
    /// its weights digest, recorded so a resumed run can check it starts from the same model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub init_from: Option<WarmStart>,
}

/// The trained model a run starts from.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WarmStart {
    /// Model directory.
    pub model: String,
    /// Its weights digest.
    pub weights_digest: String,
}

fn legacy_inputs() -> InputSet {
    InputSet::Geometry
}

fn legacy_pad_cells() -> usize {
    1
}

/// How the learning rate changes over a run.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, Default)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum LrSchedule {
    /// The same rate throughout.
    #[default]
    Constant,
    /// Half a cosine from the rate down to `final_fraction` of it at the last epoch, batch by
    /// batch (a resumed run with more epochs stretches the rest of the curve).
    Cosine {
        /// Rate at the end as a fraction of the start.
        final_fraction: f64,
    },
}

impl LrSchedule {
    /// The rate after `progress` (0 at the start, 1 at the end) of a run starting at `rate`.
    pub fn rate(&self, rate: f64, progress: f64) -> f64 {
        match *self {
            LrSchedule::Constant => rate,
            LrSchedule::Cosine { final_fraction } => {
                let p = progress.clamp(0.0, 1.0);
                let shape = 0.5 * (1.0 + (std::f64::consts::PI * p).cos());
                rate * (final_fraction + (1.0 - final_fraction) * shape)
            }
        }
    }
}

impl Default for TrainingConfig {
    fn default() -> Self {
        Self {
            model: PlumeNetConfig::new(),
            epochs: 30,
            batch_size: 16,
            learning_rate: 3e-4,
            weight_decay: 0.005,
            validation_fraction: 0.1,
            patience: 6,
            seed: 0,
            encoding: SourceEncoding::default(),
            normalization: Normalization::default(),
            inputs: InputSet::default(),
            pad_cells: 32,
            schedule: LrSchedule::Cosine {
                final_fraction: 0.02,
            },
            rel_l2_weight: 0.0,
            mirror: false,
            select_by: Selection::Loss,
            init_from: None,
        }
    }
}

/// The validation score that picks the kept epoch (lower is better).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "kebab-case")]
pub enum Selection {
    /// The validation loss.
    #[default]
    Loss,
    /// The median relative L2 error of the held-out maps (the evaluation's measure).
    RelativeL2,
}

impl Selection {
    fn is_loss(&self) -> bool {
        *self == Selection::Loss
    }

    /// The score of an epoch; an epoch recorded before relative L2 was measured has none
    /// (infinite), so any epoch that has it is better.
    pub fn score(&self, epoch: &EpochLoss) -> f64 {
        match self {
            Selection::Loss => epoch.validation,
            Selection::RelativeL2 => epoch.validation_relative_l2.unwrap_or(f64::INFINITY),
        }
    }
}

fn is_zero(v: &f32) -> bool {
    *v == 0.0
}

/// Per-epoch losses (mean squared error of the transformed target over free cells).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EpochLoss {
    /// Epoch number, from 1.
    pub epoch: usize,
    /// Mean training loss.
    pub train: f64,
    /// Validation loss (unseen layouts).
    pub validation: f64,
    /// Validation loss per room size class ([`super::data::SIZE_CLASSES`]; `None` for a class
    /// without validation layouts), absent in one-room models (format `plumenet-model-v1`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_by_size: Option<[Option<f64>; 3]>,
    /// Median relative L2 error of the held-out maps' concentration over free cells (one
    /// network pass each); absent in models trained before it was measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_relative_l2: Option<f64>,
    /// The same per room size class.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub validation_relative_l2_by_size: Option<[Option<f64>; 3]>,
    /// Seconds the epoch took (training and validation).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub seconds: Option<f64>,
}

/// Progress of a run, saved in the checkpoint.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainState {
    /// Configuration of the run (a resume must match it).
    pub config: TrainingConfig,
    /// Dataset digest (a resume must match it).
    pub dataset_digest: String,
    /// Losses of the finished epochs.
    pub history: Vec<EpochLoss>,
    /// The kept epoch (best validation score, [`TrainingConfig::select_by`]).
    pub best: Option<EpochLoss>,
    /// Whether early stopping ended the run.
    #[serde(default)]
    pub stopped_early: bool,
}

impl TrainingConfig {
    /// Whether a checkpoint of `other` can be continued with `self`: everything but the epoch
    /// limit, the patience and the warm-start model's path must agree.
    pub fn same_run(&self, other: &TrainingConfig) -> bool {
        // The warm-start model counts by its weights, not by the path it was read from.
        let strip = |c: &TrainingConfig| TrainingConfig {
            epochs: 0,
            patience: 0,
            init_from: c.init_from.as_ref().map(|w| WarmStart {
                model: String::new(),
                ..w.clone()
            }),
            ..c.clone()
        };
        strip(self) == strip(other)
    }
}
