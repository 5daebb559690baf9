//! # plumenet
//!
//! Calibration-free gas source localisation with mobile robots: a dispersion simulator, a
//! data-driven plume model and rank-based Bayesian source term estimation.
//!
//! The pipeline (see `DESIGN.md`):
//!
//! ```text
//! Layout (JSON) --> wind field (steady 2D flow around obstacles)        physics::wind
//!               --> mean concentration c(x, y | source)                  physics::transport
//!               --> dataset (many layouts x sources, .npy + manifest)    dataset
//!               --> PlumeNet training, models/<name>/                    surrogate
//! Layout + model --> bank: one predicted field per candidate cell         plume (cached)
//! Reality: intermittent filament plume over the same wind                physics::filament
//!          --> MOX sensor on a robot driving A* paths at 10 Hz           ste::sensor, ste::robot
//! STE: features --> likelihood --> posterior --> planner --> ...         ste
//! ```
//!
//! Modules own one box each: [`layout`] (arena, obstacles, validation), [`frame`] (the arena
//! turned so that the wind comes from the west, where the solvers work), [`physics`] (wind,
//! transport, filaments, analytic reference), [`dataset`] (generation, shards, manifest),
//! [`surrogate`] (PlumeNet in Burn), [`plume`] (the plume-model trait and the bank cache),
//! [`ste`] (sensor, features, posterior, robot, planner, runs, study), [`report`] (figures:
//! PNG and SVG through plotters), [`viewer`] (the HTML run viewer), [`service`] (serving a live session over lines: stdin/stdout, TCP, state file), [`ros`]
//! (the ROS 2 messages and their conversions), [`stats`] (medians and spreads), [`io`] (atomic files), [`bench`](mod@bench)
//! (timings).

#![warn(missing_docs)]

pub mod bench;
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
pub mod stats;
pub mod ste;
pub mod surrogate;
pub mod viewer;

pub use error::{Error, Result};
pub use layout::Layout;
