//! Studies of the estimator over many simulated runs: the paper's experiment and its
//! variants, and paired comparisons of two studies.

pub mod calibration;
pub mod compare;
pub mod experiment;
