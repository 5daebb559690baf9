//! PlumeNet, the data-driven plume model (DDPM in the paper: a CNN, not a diffusion model):
//! architecture ([`model`]) with its own convolution operation and kernels ([`conv`]), input
//! encoding and batches ([`data`]; an operator network's in [`room_batch`]), the definition of
//! a training run ([`config`]), training ([`training`]), the files of a trained model
//! ([`saved`]), loading, prediction and banks ([`inference`]; an operator network's per-source
//! head fused on the CPU in [`head`], the coarse form's pooling and upsampling in [`coarse`],
//! the inverse transform vectorised in [`expm1`]), accuracy
//! ([`eval`]). Tensors meet ndarray or plain slices only in [`data`], [`room_batch`],
//! [`conv`], [`head`], [`saved`] and [`inference`].

pub mod backend;
pub mod coarse;
pub mod config;
pub mod conv;
pub mod data;
pub mod eval;
pub mod expm1;
pub mod head;
pub mod inference;
pub mod model;
pub mod room_batch;
pub mod saved;
pub mod training;
pub mod widen;

pub use config::TrainingConfig;
pub use data::{Normalization, SourceEncoding, TrainingData};
pub use inference::Surrogate;
pub use model::{PlumeNet, PlumeNetConfig};
pub use saved::SavedModel;
pub use training::{TrainEvent, train};
