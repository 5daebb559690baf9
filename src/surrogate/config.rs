//! What defines a training run and what it records: [`TrainingConfig`] (saved in
//! `config.json` and the checkpoint), the per-epoch losses and the progress of a run.

use serde::{Deserialize, Serialize};

use super::data::{Normalization, SourceEncoding};
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
    /// AdamW learning rate (DeepCFD: 1e-3).
    pub learning_rate: f64,
    /// AdamW weight decay (DeepCFD: 0.005).
    pub weight_decay: f32,
    /// Share of layouts held out for validation.
    pub validation_fraction: f64,
    /// Stop after this many epochs without a better validation loss.
    pub patience: usize,
    /// Seed of the weight initialisation and the shuffling.
    pub seed: u64,
    /// Source encoding of the inputs.
    pub encoding: SourceEncoding,
    /// Input and target scales.
    pub normalization: Normalization,
}

impl Default for TrainingConfig {
    fn default() -> Self {
        Self {
            model: PlumeNetConfig::new(),
            epochs: 30,
            batch_size: 16,
            learning_rate: 1e-3,
            weight_decay: 0.005,
            validation_fraction: 0.1,
            patience: 6,
            seed: 0,
            encoding: SourceEncoding::default(),
            normalization: Normalization::default(),
        }
    }
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
    /// Best validation loss and its epoch.
    pub best: Option<EpochLoss>,
    /// Whether early stopping ended the run.
    #[serde(default)]
    pub stopped_early: bool,
}

impl TrainingConfig {
    /// Whether a checkpoint of `other` can be continued with `self`: everything but the epoch
    /// limit and the patience must agree.
    pub fn same_run(&self, other: &TrainingConfig) -> bool {
        let strip = |c: &TrainingConfig| TrainingConfig {
            epochs: 0,
            patience: 0,
            ..c.clone()
        };
        strip(self) == strip(other)
    }
}
