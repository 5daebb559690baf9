//! Generate plume maps with the physics solver and train PlumeNet on them.
//!
//! ```sh
//! cargo run --release --example train
//! ```
//!
//! A tiny run that finishes in seconds: six small random rooms with two sources each, a
//! narrow network, 30 short epochs, written to a temporary directory, then loaded back and asked
//! for one field. The command-line equivalent at full size is `plumenet generate` and
//! `plumenet train` (`docs/plumenet.md` has the recipe of the shipped model).

use plumenet::surrogate::TrainEvent;
use plumenet::{
    Distribution, GenerateConfig, Layout, PlumeNetConfig, RoomParams, Surrogate, TrainingConfig,
    TrainingData,
};

fn main() -> plumenet::Result<()> {
    let work = tempfile::tempdir().map_err(|source| plumenet::Error::Io {
        action: "cannot create",
        path: std::env::temp_dir(),
        source,
    })?;
    let data_dir = work.path().join("maps");
    let model_dir = work.path().join("model");

    // 1. Maps: rooms of 6 x 3 to 8 x 4 m with the wind from any wall, each source's mean
    //    concentration solved exactly. Each room draws from its own stream of the seed.
    let rooms = RoomParams {
        width_m: [6, 8],
        height_m: [3, 4],
        ..RoomParams::default()
    };
    let generate = GenerateConfig {
        distribution: Distribution::Rooms { params: rooms },
        layouts: 6,
        sources_per_layout: 2,
        seed: 1,
        shard: None,
    };
    let manifest = plumenet::generate(&generate, &data_dir, &|| {})?;
    println!(
        "generated {} rooms x {} sources",
        manifest.layouts.len(),
        manifest.sources_per_layout
    );

    // 2. Training: the shipped architecture's five levels, narrower, at a high learning rate
    //    for 30 epochs; the last room is held out for validation.
    let data = TrainingData::load(&data_dir)?;
    let defaults = TrainingConfig::default();
    let config = TrainingConfig {
        epochs: 30,
        batch_size: 4,
        learning_rate: 3e-3,
        patience: 30,
        model: PlumeNetConfig::new()
            .with_in_channels(defaults.inputs.channels())
            .with_filters(vec![4, 4, 8, 8, 8]),
        ..defaults
    };
    let state = plumenet::train(&data, &config, &model_dir, &mut |event| {
        if let TrainEvent::Epoch(epoch) = event
            && epoch.epoch % 5 == 0
        {
            println!(
                "epoch {}: training loss {:.3}, validation loss {:.3}",
                epoch.epoch, epoch.train, epoch.validation
            );
        }
    })?;
    let (first, best) = (
        &state.history[0],
        state.best.as_ref().expect("a kept epoch"),
    );
    println!(
        "kept epoch {} of {} in {}: validation loss {:.3} (first epoch {:.3})",
        best.epoch,
        state.history.len(),
        model_dir.display(),
        best.validation,
        first.validation
    );
    assert!(best.validation < first.validation, "training did not learn");

    // 3. The saved model predicts like the shipped one: weights and config.json.
    let model = Surrogate::load(&model_dir)?;
    let room = Layout::from_json(
        r#"{"width_m": 7, "height_m": 3, "cell_m": 0.125, "wind": {"speed_mps": 0.8, "from": "east"}}"#,
    )?;
    let field = model.predict(&room, [5.0, 1.5])?;
    assert!(field.iter().all(|c| c.is_finite() && *c >= 0.0));
    println!(
        "predicted a {} x {} field, peak {:.3} units/m2",
        field.nrows(),
        field.ncols(),
        field.iter().copied().fold(0.0, f64::max)
    );
    Ok(())
}
