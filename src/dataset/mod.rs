//! Training data for the plume surrogate: random layouts x random sources, solved with the
//! physics model and written as `.npy` arrays plus a `manifest.json`.
//!
//! **Determinism.** Layout `k` of a dataset draws everything (obstacles, sources) from its own
//! ChaCha8 stream `(seed, k)`, so a dataset's bytes depend only on the seed and parameters, not
//! on threads or sharding.
//!
//! **Shards.** `--shard K/N` generates the contiguous block of layouts
//! `[K * L / N, (K + 1) * L / N)`; [`merge`] concatenates the shards of one dataset (checking
//! that they agree and cover every layout exactly once) into files byte-identical to an unsharded
//! run.
//!
//! **Arrays** (`L` layouts, `S = L * M` sources, grid `[H, W]`, all little-endian):
//! - `obstacle_mask.npy` `[L, H, W]` f32: 1 in obstacle cells.
//! - `signed_distance.npy` `[L, H, W]` f32: metres to the nearest obstacle or side wall,
//!   negative inside obstacles.
//! - `wind.npy` `[L, 2, H, W]` f32: `u` then `v` (m/s) at cell centres.
//! - `source_layout.npy` `[S]` u32: layout index of each source.
//! - `source_xy.npy` `[S, 2]` f32: source position (m).
//! - `source_encoding.npy` `[S, H, W]` f32: `exp(-d^2 / (2 s^2))` with `d` the distance from the
//!   cell centre to the source and `s` = [`SOURCE_ENCODING_SIGMA_CELLS`] cells.
//! - `concentration.npy` `[S, H, W]` f32: mean concentration (units/m^2) of a 1 unit/s source,
//!   exactly zero in obstacle cells.

mod generate;
mod manifest;

pub use generate::{GenerateConfig, Shard, generate, random_layout, source_encoding};
pub use manifest::{ArrayInfo, GenerateParams, Manifest, ShardInfo, merge};

/// Width of the Gaussian source encoding, in cells.
pub const SOURCE_ENCODING_SIGMA_CELLS: f64 = 1.0;

/// Version of the dataset format and generator; bumped whenever the bytes would change.
pub const GENERATOR_VERSION: u32 = 1;
