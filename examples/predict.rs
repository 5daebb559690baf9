//! Batch-predict plume fields: the shipped PlumeNet's mean concentration for several candidate
//! sources of a room at once, side by side with the physics solver it learned from.
//!
//! ```sh
//! cargo run --release --example predict [LAYOUT.json]
//! ```
//!
//! Without an argument it takes the paper's arena (`data/layouts/wind-tunnel.json`). A room
//! outside the model's trained ranges is refused with a message that says how to retrain.

use std::path::PathBuf;

use plumenet::{Layout, PhysicsSolver, PlumeModel, Surrogate};

fn main() -> plumenet::Result<()> {
    let path = std::env::args().nth(1).map_or_else(
        || PathBuf::from("data/layouts/wind-tunnel.json"),
        PathBuf::from,
    );
    let room = Layout::load(&path)?;
    let model = Surrogate::load("models/default".as_ref())?;

    // Candidate sources: the free cells of a 2 m grid (the STE uses 0.25 m; any list works).
    let sources = room.candidates(2.0)?;
    let predicted = model.bank(&room, &sources)?;
    let exact = PhysicsSolver.bank(&room, &sources)?;
    let (n, rows, columns) = predicted.fields.dim();
    println!(
        "{}: {n} sources, fields of {rows} x {columns} cells ({} m)",
        path.display(),
        room.cell()
    );

    // How close each predicted field is to the solver's (relative L2 over the room).
    let mut errors = Vec::with_capacity(n);
    for (k, source) in sources.iter().enumerate() {
        let p = predicted.fields.index_axis(ndarray::Axis(0), k);
        let e = exact.fields.index_axis(ndarray::Axis(0), k);
        let diff: f64 = p
            .iter()
            .zip(e.iter())
            .map(|(&a, &b)| f64::from(a - b).powi(2))
            .sum();
        let norm: f64 = e.iter().map(|&b| f64::from(b).powi(2)).sum();
        let relative = (diff / norm).sqrt();
        assert!(relative.is_finite(), "source {source:?}: {relative}");
        errors.push(relative);
        println!(
            "  source ({:5.2}, {:4.2}) m: relative L2 error {relative:.3}",
            source[0], source[1]
        );
    }
    let median = plumenet::stats::median(&errors);
    println!("median relative L2 error against the solver: {median:.3}");
    // A model that learned nothing is off by about 1; the shipped one is far closer.
    assert!(median < 0.5, "median relative L2 {median}");
    Ok(())
}
