//! What tests the estimator: a simulated reality (the filament plume, with its departures
//! from the plume model), the robot that senses it, whole runs, and lawnmower surveys.

pub mod episode;
pub mod reality;
pub mod seed;
pub mod survey;

pub use episode::{Episode, EpisodeConfig, World, run_episode};
pub use reality::{Mismatch, Reality};
pub use seed::derive_seed;
