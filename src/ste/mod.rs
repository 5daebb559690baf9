//! Source term estimation, the estimator a robot runs: no simulated truth here.
//!
//! [`sensor`] models the MOX sensor, [`features`] extracts the four gas features, [`banks`]
//! holds the plume model's banks of a room, [`sampler`] reads a bank at reading positions,
//! [`params`] holds the estimator's settings, [`posterior`] the Bayesian filter, [`termination`] the
//! stopping rule, [`probe`] where the robot must have sensed before it stops, [`credible`] the credible regions and uncertainty every report states, [`robot`] the occupancy
//! grid and A* paths, [`planner`] the belief-clustering and baseline planners, [`session`] the
//! live session a robot drives and [`protocol`] its line protocol, [`replay`] the estimator
//! over a logged run, [`baseline`] the simple guesses every report shows beside the estimate.

pub mod banks;
pub mod baseline;
pub mod credible;
pub mod features;
pub mod params;
pub mod planner;
pub mod posterior;
pub mod probe;
pub mod protocol;
pub mod replay;
pub mod robot;
pub mod sampler;
pub mod sensor;
pub mod session;
pub mod termination;

pub use banks::{Bank, RoomBanks};
pub use baseline::Baselines;
pub use credible::{CredibleRegion, SourceScore, Uncertainty};
pub use features::{Feature, FeatureParams, FeatureTrack};
pub use planner::{Planner, PlannerKind};
pub use posterior::{Estimator, Sample, Sigmas, SteParams, ValidSteParams};
pub use robot::{Occupancy, RobotParams, Sampling};
pub use sampler::FieldSampler;
pub use sensor::{MoxParams, MoxSensor, SensorPreset};
pub use session::{Iteration, Session, SessionConfig};
pub use termination::Termination;
