//! Shared fixtures.

use plumenet::layout::Layout;

/// The shipped paper arena.
pub fn wind_tunnel() -> Layout {
    Layout::load(&repo_path("data/layouts/wind-tunnel.json")).expect("shipped layout is valid")
}

/// The paper arena without obstacles.
pub fn empty_tunnel() -> Layout {
    Layout::from_json(r#"{"width_m":18,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#)
        .expect("empty arena is valid")
}

/// A path inside the repository.
pub fn repo_path(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}
