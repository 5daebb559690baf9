//! Source term estimation: the paper's method, on a plume bank from either plume model.
//!
//! [`sensor`] simulates the MOX sensor, [`features`] extracts the four gas features,
//! [`sampler`] reads the bank at sample positions, [`posterior`] holds the Bayesian filter and
//! the termination rule, [`robot`] the occupancy grid and A* paths, [`planner`] the belief
//! clustering and baseline planners, [`run`] one simulated episode and [`replay`] the STE over
//! a logged run.

pub mod experiment;
pub mod features;
pub mod planner;
pub mod posterior;
pub mod replay;
pub mod robot;
pub mod run;
pub mod sampler;
pub mod sensor;

pub use features::{Feature, FeatureParams, FeatureTrack};
pub use planner::{Planner, PlannerKind};
pub use posterior::{Estimator, Sample, Sigmas, SteParams, Termination};
pub use robot::{Occupancy, RobotParams, Sampling};
pub use run::{Episode, EpisodeConfig, World, run_episode};
pub use sampler::FieldSampler;
pub use sensor::{MoxParams, MoxSensor, SensorPreset};
