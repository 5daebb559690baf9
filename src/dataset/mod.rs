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
//! **Rooms.** Without `--base`, every layout is a random room ([`random_room`]: size, wind
//! speed and direction, obstacle groups); with `--base`, random obstacles in one fixed arena
//! ([`random_layout`]). The manifest records the distribution and every layout.
//!
//! **Arrays.** Layouts may differ in grid, so arrays are flat: layout `k` with grid `[H_k, W_k]`
//! (its own frame, row = `y` index) occupies `H_k * W_k` consecutive values (twice that in
//! `wind.npy`), after the layouts before it; source `s` of layout `k` occupies `H_k * W_k`
//! consecutive values of `concentration.npy`. `L` layouts, `S = L * M` sources, all
//! little-endian:
//! - `obstacle_mask.npy` `[sum H W]` f32: 1 in obstacle cells.
//! - `signed_distance.npy` `[sum H W]` f32: metres to the nearest obstacle or side wall,
//!   negative inside obstacles.
//! - `wind.npy` `[2 sum H W]` f32: per layout the `u` plane then the `v` plane (m/s) at cell
//!   centres.
//! - `source_layout.npy` `[S]` u32: layout index of each source.
//! - `source_xy.npy` `[S, 2]` f32: source position (m).
//! - `concentration.npy` `[M sum H W]` f32: mean concentration (units/m^2) of a 1 unit/s source,
//!   exactly zero in obstacle cells.

mod generate;
mod manifest;
mod rooms;
mod snap;

pub use generate::{GenerateConfig, Shard, generate, random_layout};
pub use manifest::{
    ArrayInfo, Arrays, Distribution, GenerateParams, Manifest, ShardInfo, grid_of, merge,
};
pub use rooms::{GroupKind, RoomParams, random_room};

/// Version of the dataset format and generator; bumped whenever the bytes would change.
pub const GENERATOR_VERSION: u32 = 2;
