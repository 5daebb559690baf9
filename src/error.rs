//! The crate's error type: one variant per way an input or a file can be wrong.

use std::path::PathBuf;

/// Everything that can go wrong in plumenet's library code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A layout violates one of the rules in [`crate::layout`].
    #[error("invalid layout: {0}")]
    Layout(String),
    /// A source position is outside the arena, inside an obstacle or not finite.
    #[error("invalid source position ({x}, {y}): {reason}")]
    Source {
        /// x coordinate in metres.
        x: f64,
        /// y coordinate in metres.
        y: f64,
        /// Why the position was rejected.
        reason: String,
    },
    /// A numerical solver failed (singular system, no convergence).
    #[error("solver failed: {0}")]
    Solver(String),
    /// A dataset directory or manifest is malformed or inconsistent.
    #[error("invalid dataset: {0}")]
    Dataset(String),
    /// A parameter is out of its documented range.
    #[error("invalid parameter: {0}")]
    Parameter(String),
    /// Reading or writing a file failed.
    #[error("{action} {path}")]
    Io {
        /// What was being done ("cannot read", "cannot write", ...).
        action: &'static str,
        /// The file involved.
        path: PathBuf,
        /// The underlying error.
        source: std::io::Error,
    },
    /// A JSON document could not be parsed.
    #[error("malformed JSON in {path}")]
    Json {
        /// The file involved.
        path: PathBuf,
        /// The underlying parser error.
        source: serde_json::Error,
    },
    /// A `.npy` array could not be read or has the wrong type or shape.
    #[error("bad .npy array {path}: {reason}")]
    Npy {
        /// The file involved.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A trained model is missing, damaged, foreign, or made for another grid.
    #[error("model: {0}")]
    Model(String),
    /// A logged run (CSV readings) is missing columns, malformed, empty or holds NaN.
    #[error("bad readings log {path}: {reason}")]
    Log {
        /// The file involved.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A study's `runs.csv` is malformed or empty.
    #[error("bad study runs {path}: {reason}")]
    Study {
        /// The file involved.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A figure could not be drawn.
    #[error("cannot draw the figure: {0}")]
    Figure(String),
    /// A PNG could not be encoded.
    #[error("cannot encode image {path}: {reason}")]
    Image {
        /// The file involved.
        path: PathBuf,
        /// What went wrong.
        reason: String,
    },
}

/// Plotters' drawing errors (of any backend) as ours.
impl<E: std::error::Error + Send + Sync> From<plotters::drawing::DrawingAreaErrorKind<E>>
    for Error
{
    fn from(e: plotters::drawing::DrawingAreaErrorKind<E>) -> Self {
        Self::Figure(e.to_string())
    }
}

/// The crate's result alias.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Checked settings convert to themselves without error ([`crate::ste::ValidSteParams`]).
impl From<std::convert::Infallible> for Error {
    fn from(never: std::convert::Infallible) -> Self {
        match never {}
    }
}
