//! PlumeNet: training reduces the loss, resumption is exact, save/load is bit-identical, bad
//! models are clear errors, both plume models give the same bank layout, and the export for the
//! PyTorch benchmark holds the bank and every weight.

use std::path::Path;

use ndarray::{Array4, ArrayD};
use plumenet::Error;
use plumenet::dataset::{self, GenerateConfig, GenerateParams};
use plumenet::layout::Layout;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::surrogate::bench::{export_reference, forward_macs, time_bank, time_training};
use plumenet::surrogate::model::ConvImpl;
use plumenet::surrogate::saved::{load_weights, weights_bytes, weights_digest};
use plumenet::surrogate::{PlumeNetConfig, Surrogate, TrainingConfig, TrainingData, train};

use crate::common::wind_tunnel;

const COARSE: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#;

/// The coarse arena with one obstacle.
const BLOCKED: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75},
    "obstacles":[{"x_min":6,"y_min":1,"x_max":7,"y_max":2}]}"#;

fn tiny_dataset(dir: &Path) -> TrainingData {
    let config = GenerateConfig {
        base: Layout::from_json(COARSE).unwrap().spec().clone(),
        layouts: 3,
        sources_per_layout: 4,
        seed: 3,
        shard: None,
        params: GenerateParams::default(),
    };
    dataset::generate(&config, dir, &|| ()).unwrap();
    TrainingData::load(dir).unwrap()
}

fn tiny_config(epochs: usize) -> TrainingConfig {
    TrainingConfig {
        model: PlumeNetConfig::new()
            .with_filters(vec![4, 8])
            .with_convs_per_level(1)
            .with_kernel_size(3),
        epochs,
        batch_size: 4,
        learning_rate: 1e-2,
        patience: 100,
        validation_fraction: 0.34,
        ..TrainingConfig::default()
    }
}

#[test]
fn training_reduces_the_loss_and_resumes_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let straight = train(&data, &tiny_config(20), &tmp.path().join("a"), &mut |_| ()).unwrap();
    let first = straight.history.first().unwrap().train;
    let last = straight.history.last().unwrap().train;
    assert!(last < 0.8 * first, "training loss {first} -> {last}");

    // An interrupted run (10 epochs) continued to 20 gives bit-identical weights.
    let b = tmp.path().join("b");
    train(&data, &tiny_config(10), &b, &mut |_| ()).unwrap();
    let resumed = train(&data, &tiny_config(20), &b, &mut |_| ()).unwrap();
    assert_eq!(resumed.history, straight.history);
    let layout = Layout::from_json(COARSE).unwrap();
    let predict = |dir: &Path| {
        Surrogate::load(dir)
            .unwrap()
            .predict(&layout, [3.0, 2.0])
            .unwrap()
    };
    assert!(
        predict(&tmp.path().join("a")) == predict(&b),
        "resumed weights differ"
    );

    // A checkpoint of a different run is refused, not silently mixed in.
    let other = TrainingConfig {
        seed: 9,
        ..tiny_config(20)
    };
    let err = train(&data, &other, &b, &mut |_| ()).unwrap_err();
    assert!(matches!(err, Error::Model(_)), "{err}");
}

/// Trainings running at the same time in one process start from the same seeded weights and
/// end identical (the initial weights come from the run's own generator, not Burn's global
/// one), and the weights digest names the weights, not the burnpack file's random ids.
#[test]
fn concurrent_trainings_are_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let runs: Vec<_> = std::thread::scope(|scope| {
        let handles: Vec<_> = (0..3)
            .map(|k| {
                let (data, dir) = (&data, tmp.path().join(format!("run{k}")));
                scope.spawn(move || {
                    let state = train(data, &tiny_config(3), &dir, &mut |_| ()).unwrap();
                    (state.history, Surrogate::load(&dir).unwrap())
                })
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (history, model) in &runs[1..] {
        assert_eq!(history, &runs[0].0);
        assert_eq!(
            model.saved().weights_digest,
            runs[0].1.saved().weights_digest
        );
        assert_eq!(
            weights_digest(model.net()).unwrap(),
            model.saved().weights_digest
        );
    }
    // Different seeds, different weights; the same seed twice, the same weights.
    let device = plumenet::surrogate::backend::device();
    let config = tiny_config(1).model;
    let digest = |seed| weights_digest(&config.init_seeded(&device, seed)).unwrap();
    assert_eq!(digest(4), digest(4));
    assert_ne!(digest(4), digest(5));
}

/// The seeded initialisation draws Burn's default distribution: uniform in +-1/sqrt(fan_in).
#[test]
fn seeded_initial_weights_follow_the_default_distribution() {
    let device = plumenet::surrogate::backend::device();
    let net = PlumeNetConfig::new().init_seeded(&device, 0);
    let tensors = plumenet::surrogate::saved::named_tensors(&net).unwrap();
    assert_eq!(tensors.len(), 2 * (4 * 3 + 3 * 3 + 3 + 1));
    for (name, array) in tensors {
        let fan_in = if name.starts_with("ups") {
            // Transposed: [in, out, k, k]; the bias has `out` entries.
            if name.ends_with("bias") {
                array.len() * 4
            } else {
                array.shape()[1] * 4
            }
        } else if name.ends_with("bias") {
            // The bias of a convolution shares its weight's fan-in: checked by the bound only.
            0
        } else {
            array.len() / array.shape()[0]
        };
        let max = array.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        if fan_in > 0 {
            let bound = 1.0 / (fan_in as f32).sqrt();
            assert!(
                max <= bound && max > 0.5 * bound,
                "{name}: {max} vs {bound}"
            );
            if array.len() >= 400 {
                let n = array.len() as f32;
                let mean = array.iter().sum::<f32>() / n;
                let var = array.iter().map(|v| (v - mean).powi(2)).sum::<f32>() / n;
                assert!(mean.abs() < 0.1 * bound, "{name}: mean {mean}");
                let expected = bound * bound / 3.0;
                assert!(
                    (var / expected - 1.0).abs() < 0.15,
                    "{name}: variance {var}"
                );
            }
        } else {
            assert!(max > 0.0 && max < 1.0, "{name}");
        }
    }
}

#[test]
fn saved_models_load_bit_identically_and_bad_files_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let dir = tmp.path().join("model");
    train(&data, &tiny_config(2), &dir, &mut |_| ()).unwrap();
    let layout = Layout::from_json(COARSE).unwrap();
    let (m1, m2) = (
        Surrogate::load(&dir).unwrap(),
        Surrogate::load(&dir).unwrap(),
    );
    let (p1, p2) = (
        m1.predict(&layout, [3.0, 2.0]).unwrap(),
        m2.predict(&layout, [3.0, 2.0]).unwrap(),
    );
    assert_eq!(p1, p2);
    assert_eq!(
        weights_bytes(m1.net()).unwrap(),
        std::fs::read(dir.join("weights.bpk")).unwrap()
    );
    assert!(p1.iter().all(|v| *v >= 0.0 && v.is_finite()));

    // Another grid, a source in an obstacle, a truncated weights file, a missing model.
    let err = m1
        .predict(&wind_tunnel(), [3.0, 2.0])
        .unwrap_err()
        .to_string();
    assert!(err.contains("trained for a [16, 72] grid"), "{err}");
    let blocked = Layout::from_json(BLOCKED).unwrap();
    assert!(matches!(
        m1.predict(&blocked, [6.5, 1.5]),
        Err(Error::Source { .. })
    ));
    let weights = std::fs::read(dir.join("weights.bpk")).unwrap();
    std::fs::write(dir.join("weights.bpk"), &weights[..weights.len() / 2]).unwrap();
    let err = Surrogate::load(&dir).unwrap_err().to_string();
    assert!(err.contains("truncated or replaced"), "{err}");
    assert!(Surrogate::load(&tmp.path().join("nope")).is_err());
    let junk = tmp.path().join("junk.bpk");
    std::fs::write(&junk, b"not a burnpack file").unwrap();
    let net = tiny_config(1)
        .model
        .init(&plumenet::surrogate::backend::device());
    assert!(matches!(load_weights(net, &junk), Err(Error::Model(_))));
}

#[test]
fn both_plume_models_give_the_same_bank_layout() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let dir = tmp.path().join("model");
    train(&data, &tiny_config(1), &dir, &mut |_| ()).unwrap();
    let layout = Layout::from_json(BLOCKED).unwrap();
    let candidates = layout.candidates(0.5).unwrap();
    let surrogate = Surrogate::load(&dir).unwrap();
    let models: [&dyn PlumeModel; 2] = [&PhysicsSolver, &surrogate];
    let banks: Vec<_> = models
        .iter()
        .map(|m| m.bank(&layout, &candidates).unwrap())
        .collect();
    assert_eq!(banks[0].fields.dim(), banks[1].fields.dim());
    assert_eq!(banks[0].fields.dim(), (candidates.len(), 16, 72));
    assert_eq!(banks[0].candidates, banks[1].candidates);
    for bank in &banks {
        for field in bank.fields.outer_iter() {
            for ((j, i), v) in field.indexed_iter() {
                if layout.is_solid(j, i) {
                    assert_eq!(*v, 0.0);
                }
            }
        }
    }
}

#[test]
fn the_pytorch_export_holds_the_bank_and_every_weight_and_the_mac_count_adds_up() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let dir = tmp.path().join("model");
    let config = tiny_config(1);
    train(&data, &config, &dir, &mut |_| ()).unwrap();
    let model = Surrogate::load(&dir).unwrap();
    let layout = Layout::from_json(BLOCKED).unwrap();
    let candidates = &layout.candidates(0.5).unwrap()[..5];
    let out = tmp.path().join("export");
    let tensors = export_reference(&model, &layout, candidates, &out).unwrap();
    // Weight and bias of 2 encoder convolutions, 1 transposed convolution, 1 decoder
    // convolution and the head.
    assert_eq!(tensors, 10);

    // Burn's raw outputs, transformed back, are the bank.
    let raw: Array4<f32> = plumenet::io::read_npy(&out.join("outputs.npy")).unwrap();
    let inputs: Array4<f32> = plumenet::io::read_npy(&out.join("inputs.npy")).unwrap();
    assert_eq!(inputs.dim(), (5, 3, 16, 72));
    let bank = model.predict_many(&layout, candidates).unwrap();
    let norm = model.saved().normalization;
    for ((n, _, j, i), &v) in raw.indexed_iter() {
        let expected = if layout.is_solid(j, i) {
            0.0
        } else {
            norm.inverse(v)
        };
        assert_eq!(bank[[n, j, i]].to_bits(), expected.to_bits());
    }

    // Brute force: every convolution weight times the pixels of the level it writes.
    let levels = config.model.filters.len();
    let mut macs = 0u64;
    for entry in std::fs::read_dir(out.join("weights")).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_stem().unwrap().to_str().unwrap().to_string();
        if !name.ends_with(".weight") {
            continue;
        }
        let w: ArrayD<f32> = plumenet::io::read_npy(&path).unwrap();
        let index = |k: usize| name.split('.').nth(k).unwrap().parse::<usize>().unwrap();
        let level = match name.split('.').next().unwrap() {
            "encoders" => index(1),
            "decoders" | "ups" => levels - 2 - index(1),
            _ => 0,
        };
        let pixels = ((16 >> level) * (72 >> level)) as u64;
        // A 2x2 stride-2 transposed convolution touches each output pixel with one tap.
        let taps = if name.starts_with("ups") { 4 } else { 1 };
        macs += w.len() as u64 * pixels / taps;
    }
    assert_eq!(macs, forward_macs(&config.model, [16, 72]));

    assert!(time_bank(&model, &layout, candidates, ConvImpl::Own).unwrap() > 0.0);
    assert!(time_training(&model, &layout, candidates, (2, 1), ConvImpl::Burn).unwrap() > 0.0);
    assert!(matches!(
        time_training(&model, &layout, candidates, (6, 1), ConvImpl::Own),
        Err(Error::Parameter(_))
    ));
}
