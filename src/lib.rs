//! # plumenet
//!
//! Calibration-free gas source localisation with mobile robots: a dispersion simulator, a
//! data-driven plume model (PlumeNet, a U-Net in Burn) and rank-based Bayesian source term
//! estimation (STE) that never needs the gas sensor calibrated.
//!
//! The crate's three uses, each an example under `examples/`:
//! - generate plume maps with the physics solver and train PlumeNet on them
//!   ([`generate`], [`train`]; `examples/train.rs`);
//! - batch-predict the plume of every candidate source in a room ([`PlumeModel::bank`] of a
//!   [`Surrogate`] or the [`PhysicsSolver`]; `examples/predict.rs`);
//! - drive an STE [`Session`] from a robot's own loop: readings in, goals out, until the
//!   source is found (`examples/robot_loop.rs`).
//!
//! The physics solver's plume of one source in the paper's arena, and the shipped PlumeNet's
//! prediction of the same field:
//!
//! ```
//! use plumenet::{Layout, PlumeModel, PhysicsSolver, Surrogate};
//!
//! # fn main() -> plumenet::Result<()> {
//! let room = Layout::load("data/layouts/wind-tunnel.json".as_ref())?;
//! let source = [[4.5, 2.5]];
//! let exact = PhysicsSolver.bank(&room, &source)?;
//! let model = Surrogate::load("models/default".as_ref())?;
//! let predicted = model.bank(&room, &source)?;
//! // One [rows, columns] field per source, on the layout's grid.
//! assert_eq!(exact.fields.dim(), predicted.fields.dim());
//! # Ok(())
//! # }
//! ```
//!
//! A room of your own, solved exactly by the physics solver:
//!
//! ```
//! use plumenet::{Layout, PlumeModel, PhysicsSolver};
//!
//! let room = Layout::from_json(
//!     r#"{"width_m": 6, "height_m": 3, "cell_m": 0.25, "wind": {"speed_mps": 0.5},
//!         "obstacles": [{"x_min": 2.5, "y_min": 0.0, "x_max": 3.0, "y_max": 1.5}]}"#,
//! )?;
//! let bank = PhysicsSolver.bank(&room, &[[1.0, 2.0]])?;
//! let field = bank.fields.index_axis(ndarray::Axis(0), 0);
//! // Downwind of the source there is gas; inside the obstacle there is none.
//! let (j, i) = room.cell_of(4.0, 2.0);
//! assert!(field[[j, i]] > 0.0);
//! let (j, i) = room.cell_of(2.75, 0.5);
//! assert_eq!(field[[j, i]], 0.0);
//! # Ok::<(), plumenet::Error>(())
//! ```
//!
//! Modules, from the ground up: [`layout`] (rooms, obstacles, validation), [`frame`] (the room
//! turned so that the wind comes from the west), [`physics`] (wind, transport, filament plume,
//! analytic reference), [`dataset`] (generated maps), [`surrogate`] (PlumeNet),
//! [`plume`] (the plume-model trait and the bank cache), [`ste`] (the estimator: sensor,
//! features, posterior, planner, sessions), [`sim`] (the simulated reality and runs that test
//! it), [`study`] (studies over many runs), [`report`] and [`viewer`]
//! (figures and the HTML run viewer), [`service`] and [`ros`] (serving a session to a robot),
//! [`io`] (atomic files), [`stats`]; `docs/` in the repository explains the method.

#![warn(missing_docs)]

pub mod dataset;
pub mod error;
pub mod frame;
pub mod io;
pub mod layout;
pub mod physics;
pub mod plume;
pub mod report;
pub mod ros;
pub mod service;
pub mod sim;
pub mod stats;
pub mod ste;
pub mod study;
pub mod surrogate;
pub mod viewer;

pub use dataset::{Distribution, GenerateConfig, RoomParams, generate};
pub use error::{Error, Result};
pub use layout::Layout;
pub use physics::transport::Transport;
pub use physics::wind::WindField;
pub use plume::{PhysicsSolver, PlumeBank, PlumeModel};
pub use sim::{Episode, EpisodeConfig, Mismatch, World, run_episode};
pub use ste::{
    Baselines, Estimator, Feature, Iteration, MoxSensor, RoomBanks, Sample, SensorPreset, Session,
    SessionConfig, SteParams,
};
pub use surrogate::{PlumeNetConfig, Surrogate, TrainEvent, TrainingConfig, TrainingData, train};
