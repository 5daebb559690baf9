//! The one integration-test binary (each extra binary would re-link every dependency).

mod common;

mod cli;
mod compare;
mod conv;
mod credible;
mod dataset;
mod determinism;
mod filament;
mod frame;
mod golden;
mod hostile;
mod layout;
mod project_files;
mod reality;
mod report;
mod ros;
mod service;
mod ste;
mod surrogate;
mod transport;
mod verification;
mod viewer;
mod wind;
