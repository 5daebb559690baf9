//! PlumeNet, the data-driven plume model (DDPM in the paper: a CNN, not a diffusion model):
//! architecture ([`model`]), input encoding and batches ([`data`]), training ([`training`]),
//! loading, prediction and banks ([`inference`]), and throughput against PyTorch ([`bench`]).
//! Tensors meet ndarray only in [`data`], [`inference`] and [`bench`].

pub mod backend;
pub mod bench;
pub mod config;
pub mod conv;
pub mod data;
pub mod eval;
pub mod inference;
pub mod model;
pub mod saved;
pub mod training;

pub use config::TrainingConfig;
pub use data::{Normalization, SourceEncoding, TrainingData};
pub use inference::Surrogate;
pub use model::{PlumeNet, PlumeNetConfig};
pub use saved::SavedModel;
pub use training::{TrainEvent, train};
