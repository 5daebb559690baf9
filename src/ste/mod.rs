//! Source term estimation: the paper's method, on a plume bank from either plume model.
//!
//! [`sensor`] simulates the MOX sensor, [`features`] extracts the four gas features,
//! [`sampler`] reads the bank at sample positions, [`posterior`] holds the Bayesian filter and
//! the termination rule, [`robot`] the occupancy grid and A* paths, [`planner`] the belief
//! clustering and baseline planners, [`reality`] what the robot senses (and how it may depart
//! from the model), [`run`] one simulated episode, [`survey`] a raster survey flown through
//! reality, [`replay`] the STE over a logged run, [`baseline`] the simple guesses every
//! report shows beside the STE, [`experiment`] the paper's study and [`compare`] the paired
//! comparison of two studies.

pub mod baseline;
pub mod compare;
pub mod experiment;
pub mod features;
pub mod planner;
pub mod posterior;
pub mod protocol;
pub mod reality;
pub mod replay;
pub mod robot;
pub mod run;
pub mod sampler;
pub mod sensor;
pub mod session;
pub mod survey;

pub use baseline::Baselines;
pub use features::{Feature, FeatureParams, FeatureTrack};
pub use planner::{Planner, PlannerKind};
pub use posterior::{Estimator, Sample, Sigmas, SteParams, Termination};
pub use reality::{Mismatch, Reality};
pub use robot::{Occupancy, RobotParams, Sampling};
pub use run::{Bank, Episode, EpisodeConfig, World, run_episode};
pub use sampler::FieldSampler;
pub use sensor::{MoxParams, MoxSensor, SensorPreset};
