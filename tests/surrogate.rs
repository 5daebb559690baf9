//! PlumeNet: training reduces the loss, resumption is exact, save/load is bit-identical, bad
//! models are clear errors, both plume models give the same bank layout, and the export for the
//! PyTorch benchmark holds the bank and every weight.

use std::path::Path;

use plumenet::Error;
use plumenet::dataset::{self, Distribution, GenerateConfig, GenerateParams};
use plumenet::layout::Layout;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::surrogate::config::EpochLoss;

use plumenet::frame::Frame;
use plumenet::surrogate::conv::kernel::Isa;
use plumenet::surrogate::model::{CoarseConfig, ConvImpl, OperatorConfig, ROOM_CHANNELS};
use plumenet::surrogate::saved::{load_weights, named_tensors, weights_bytes, weights_digest};
use plumenet::surrogate::{
    PlumeNetConfig, Surrogate, TrainEvent, TrainingConfig, TrainingData, train,
};

use crate::common::{assert_err, wind_tunnel};

const COARSE: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#;

/// The coarse arena with one obstacle.
const BLOCKED: &str = r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75},
    "obstacles":[{"x_min":6,"y_min":1,"x_max":7,"y_max":2}]}"#;

/// Three coarse arenas of four sources each.
pub fn tiny_dataset(dir: &Path) -> TrainingData {
    let config = GenerateConfig {
        distribution: Distribution::Base {
            base: Layout::from_json(COARSE).unwrap().spec().clone(),
            params: GenerateParams::default(),
        },
        layouts: 3,
        sources_per_layout: 4,
        seed: 3,
        shard: None,
    };
    dataset::generate(&config, dir, &|| ()).unwrap();
    TrainingData::load(dir).unwrap()
}

/// A run's losses without the wall-clock times.
fn losses(history: &[EpochLoss]) -> Vec<EpochLoss> {
    history
        .iter()
        .map(|e| EpochLoss {
            seconds: None,
            ..*e
        })
        .collect()
}

/// A two-level network of a few filters, trained for `epochs`.
pub fn tiny_config(epochs: usize) -> TrainingConfig {
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
        pad_cells: 8,
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
    assert!(last < first, "training loss {first} -> {last}");

    // A run interrupted after epoch 10 (a panic right after the checkpoint is written) and
    // started again gives bit-identical losses and weights, learning-rate schedule included.
    let b = tmp.path().join("b");
    let interrupted = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        train(&data, &tiny_config(20), &b, &mut |event| {
            if matches!(event, TrainEvent::Epoch(e) if e.epoch == 10) {
                panic!("interrupted");
            }
        })
    }));
    assert!(interrupted.is_err());
    let resumed = train(&data, &tiny_config(20), &b, &mut |_| ()).unwrap();
    assert_eq!(losses(&resumed.history), losses(&straight.history));
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
        assert_eq!(losses(history), losses(&runs[0].0));
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
    // 5 levels: 5 encoder and 4 decoder blocks of 3 convolutions, 4 up-convolutions, the head.
    assert_eq!(tensors.len(), 2 * (5 * 3 + 4 * 3 + 4 + 1));
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

    // Rooms outside the trained ranges (cell, length, speed, diffusivity), a source in an
    // obstacle, a truncated weights file, a missing model.
    assert_eq!(
        m1.saved().ranges.unwrap().length_m,
        [18.0, 18.0],
        "the ranges are those of the training rooms"
    );
    let err = m1
        .predict(&wind_tunnel(), [3.0, 2.0])
        .unwrap_err()
        .to_string();
    assert!(err.contains("differs from the 0.25 m cells"), "{err}");
    for (json, expected) in [
        (
            r#"{"width_m":20,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#,
            "room length along the wind (m) is 20, outside the trained range [18, 18]",
        ),
        (
            r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":1.0}}"#,
            "wind speed (m/s) is 1, outside the trained range [0.75, 0.75]",
        ),
        (
            r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75},"diffusivity_m2ps":0.1}"#,
            "diffusivity_m2ps is 0.1, outside the trained range [0.05, 0.05]",
        ),
    ] {
        let room = Layout::from_json(json).unwrap();
        let err = m1.predict(&room, [3.0, 2.0]).unwrap_err().to_string();
        assert!(
            err.contains(expected) && err.contains("plumenet train"),
            "{err}"
        );
        // One category prefix, the model named once, then the reason.
        assert!(
            err.starts_with("model: ") && err.matches("model:").count() == 1,
            "{err}"
        );
        assert!(
            err.contains("was not trained for this room: the layout's"),
            "{err}"
        );
    }
    // The same arena turned (wind from the south) is covered: length and width are taken
    // along and across the wind.
    let turned = Layout::from_json(
        r#"{"width_m":4,"height_m":18,"cell_m":0.25,"wind":{"speed_mps":0.75,"from":"south"}}"#,
    )
    .unwrap();
    assert!(m1.predict(&turned, [2.0, 3.0]).is_ok());
    let blocked = Layout::from_json(BLOCKED).unwrap();
    assert!(matches!(
        m1.predict(&blocked, [6.5, 1.5]),
        Err(Error::Source { .. })
    ));
    let weights = std::fs::read(dir.join("weights.bpk")).unwrap();
    std::fs::write(dir.join("weights.bpk"), &weights[..weights.len() / 2]).unwrap();
    let err = Surrogate::load(&dir).unwrap_err().to_string();
    assert!(err.contains("truncated or replaced"), "{err}");
    assert_err(Surrogate::load(&tmp.path().join("nope")), "cannot read");
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

/// A dataset of small rooms of several sizes, speeds and wind directions (coarse cells).
fn rooms_dataset(dir: &Path, layouts: usize, seed: u64) -> TrainingData {
    let config = GenerateConfig {
        distribution: Distribution::Rooms {
            params: crate::dataset::small_rooms(),
        },
        layouts,
        sources_per_layout: 3,
        seed,
        shard: None,
    };
    dataset::generate(&config, dir, &|| ()).unwrap();
    TrainingData::load(dir).unwrap()
}

/// Rooms are held in their canonical frame: each stored field equals the physics solved in the
/// turned (wind from the west) layout for the turned source, to round-off.
#[test]
fn room_datasets_load_in_the_canonical_frame() {
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 6, 4);
    let directions: std::collections::BTreeSet<_> = data
        .layouts()
        .iter()
        .map(|l| l.wind_from().name())
        .collect();
    assert!(directions.len() >= 2, "{directions:?}");
    for s in 0..data.len() {
        let real = &data.layouts()[data.source_layout[s]];
        let canonical = plumenet::frame::Frame::of(real)
            .layout_to_canonical(real)
            .unwrap();
        let bank = PhysicsSolver
            .bank(&canonical, &[data.source_xy[s]])
            .unwrap();
        let stored = data.concentration(s);
        let expected = bank.fields.index_axis(ndarray::Axis(0), 0);
        assert_eq!(stored.dim(), expected.dim());
        let peak = expected.iter().fold(0.0f32, |m, v| m.max(*v));
        let worst = stored
            .iter()
            .zip(expected.iter())
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 1e-4 * peak, "sample {s}: {worst} vs peak {peak}");
        assert_eq!(data.room(data.source_layout[s]).shape(), canonical.shape());
    }
    // Buckets hold samples of one padded grid, and cover every sample once.
    let all: Vec<usize> = (0..data.len()).collect();
    let buckets = data.buckets(&all, 8);
    assert_eq!(buckets.iter().map(Vec::len).sum::<usize>(), data.len());
    for bucket in &buckets {
        let shapes: std::collections::BTreeSet<_> = bucket
            .iter()
            .map(|&s| {
                let (h, w) = data.room(data.source_layout[s]).shape();
                (h.div_ceil(8), w.div_ceil(8))
            })
            .collect();
        assert_eq!(shapes.len(), 1);
    }
}

/// One model for rooms of several sizes: training on them lowers the loss, records the ranges
/// it saw, predicts rooms of other sizes within them (any grid), and evaluates per class.
#[test]
fn one_model_trains_on_rooms_of_several_sizes_and_reports_per_class() {
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 6, 4);
    let dir = tmp.path().join("model");
    let state = train(&data, &tiny_config(12), &dir, &mut |_| ()).unwrap();
    let (first, last) = (&state.history[0], state.history.last().unwrap());
    assert!(
        last.train < 0.8 * first.train,
        "{} -> {}",
        first.train,
        last.train
    );
    let by_size = last.validation_by_size.unwrap();
    assert!(by_size.iter().any(Option::is_some));
    let model = Surrogate::load(&dir).unwrap();
    let ranges = model.saved().ranges.unwrap();
    let lengths: Vec<f64> = data
        .layouts()
        .iter()
        .map(|l| {
            if l.wind_from().downwind()[0] != 0.0 {
                l.width()
            } else {
                l.height()
            }
        })
        .collect();
    let min = lengths.iter().cloned().fold(f64::INFINITY, f64::min);
    let max = lengths.iter().cloned().fold(0.0, f64::max);
    assert_eq!(ranges.length_m, [min, max]);
    assert_eq!(ranges.cell_m, 0.25);
    // A room of a size not in the dataset, inside the ranges, is predicted on its own grid.
    let speed = 0.5 * (ranges.speed_mps[0] + ranges.speed_mps[1]);
    let across = ranges.across_m[0];
    let room = Layout::from_json(&format!(
        r#"{{"width_m":{max},"height_m":{across},"cell_m":0.25,"wind":{{"speed_mps":{speed}}}}}"#
    ))
    .unwrap();
    let field = model.predict(&room, [1.0, across / 2.0]).unwrap();
    assert_eq!(field.dim(), room.shape());
    assert!(field.iter().all(|v| v.is_finite() && *v >= 0.0));
    // Per-class evaluation covers every map once in each table (on the training rooms, which
    // the model's ranges cover by construction).
    let settings = plumenet::surrogate::eval::EvalSettings {
        points: 50,
        ..Default::default()
    };
    let report = plumenet::surrogate::eval::evaluate(&model, &data, &settings).unwrap();
    // The floor, by brute force on the first map of the first dataset's room: both fields
    // raised to 1e-3 of the true peak at the same sampled cells give the reported rho.
    let floored = plumenet::surrogate::eval::EvalSettings {
        floor: 1e-3,
        ..settings
    };
    {
        let with_floor = plumenet::surrogate::eval::evaluate(&model, &data, &floored).unwrap();
        let s = with_floor.maps[0].sample;
        let real = &data.layouts()[data.source_layout[s]];
        let canonical = plumenet::frame::Frame::of(real)
            .layout_to_canonical(real)
            .unwrap();
        let pred = model
            .predict_many(&canonical, &[data.source_xy[s]])
            .unwrap();
        let truth = data.concentration(s);
        let free: Vec<(usize, usize)> = canonical
            .solid()
            .indexed_iter()
            .filter(|(_, x)| !**x)
            .map(|(ji, _)| ji)
            .collect();
        use rand::SeedableRng;
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        rng.set_stream(s as u64);
        let picks = rand::seq::index::sample(&mut rng, free.len(), 50.min(free.len()));
        let floor = 1e-3 * f64::from(truth.iter().fold(0.0f32, |m, v| m.max(*v)));
        let (a, b): (Vec<f64>, Vec<f64>) = picks
            .iter()
            .map(|k| {
                let (j, i) = free[k];
                (
                    f64::from(pred[[0, j, i]]).max(floor),
                    f64::from(truth[[j, i]]).max(floor),
                )
            })
            .unzip();
        let (rho, reported) = (
            plumenet::surrogate::eval::spearman(&a, &b),
            with_floor.maps[0].spearman,
        );
        // Equal, or both undefined (every sampled cell below the floor in one field).
        assert!(
            (rho - reported).abs() < 1e-12 || (rho.is_nan() && reported.is_nan()),
            "{rho} vs {reported}"
        );
    }
    let count = |classes: &[plumenet::surrogate::eval::ClassSummary]| {
        classes
            .iter()
            .filter_map(|c| c.summary.map(|s| s.maps))
            .sum::<usize>()
    };
    assert_eq!(count(&report.by_size), report.summary.maps);
    assert_eq!(count(&report.by_speed), report.summary.maps);
    assert_eq!(report.summary.maps, data.len());
}

#[test]
fn the_cosine_schedule_decays_from_the_rate_to_its_final_fraction() {
    use plumenet::surrogate::config::LrSchedule;
    let cosine = LrSchedule::Cosine {
        final_fraction: 0.02,
    };
    assert_eq!(cosine.rate(1e-3, 0.0), 1e-3);
    assert!((cosine.rate(1e-3, 1.0) - 2e-5).abs() < 1e-12);
    assert!((cosine.rate(1e-3, 0.5) - 0.51e-3).abs() < 1e-12);
    let rates: Vec<f64> = (0..=10)
        .map(|k| cosine.rate(1e-3, k as f64 / 10.0))
        .collect();
    assert!(rates.windows(2).all(|w| w[1] < w[0]));
    assert_eq!(LrSchedule::Constant.rate(1e-3, 0.7), 1e-3);
}

/// The analytic prior channel: the unbounded point source (equal to the walled reference when
/// the walls are far away), transformed like the target, zero in obstacles and outside the room.
#[test]
fn the_analytic_input_is_the_transformed_unbounded_plume() {
    use plumenet::physics::analytic::{point_source_between_walls, point_source_unbounded};
    use plumenet::surrogate::data::{InputSet, Normalization, RoomPlanes, SourceEncoding};
    // Far walls: the walled reference and the unbounded plume agree.
    for (x, y) in [(3.0, 50.0), (6.0, 50.5), (2.2, 49.0)] {
        let walled = point_source_between_walls((x, y), (2.0, 50.0), 0.5, 0.05, 100.0, 1.0);
        let free = point_source_unbounded((x, y), (2.0, 50.0), 0.5, 0.05, 1.0, 1e-9);
        assert!((walled - free).abs() <= 1e-9 * walled, "{walled} vs {free}");
    }
    let layout = Layout::from_json(BLOCKED).unwrap();
    let room = RoomPlanes::new(
        &layout,
        Some(&plumenet::physics::wind::WindField::solve(&layout).unwrap()),
    );
    let norm = Normalization::default();
    let (h, w) = (24, 80);
    let mut out = vec![0.0f32; 7 * h * w];
    room.encode(
        [3.0, 2.0],
        InputSet::Analytic,
        SourceEncoding::Gaussian,
        &norm,
        (h, w),
        &mut out,
    )
    .unwrap();
    let plane = |c: usize, j: usize, i: usize| out[c * h * w + j * w + i];
    let (j, i) = (9, 20); // cell centre (5.125, 2.375), free, downwind of the source
    let expected = norm.forward(
        point_source_unbounded((5.125, 2.375), (3.0, 2.0), 0.75, 0.05, 1.0, 0.0625) as f32,
        0.75,
    );
    assert!((plane(6, j, i) - expected).abs() < 1e-6 && expected > 0.1);
    assert_eq!(plane(6, 5, 25), 0.0, "inside the obstacle");
    assert_eq!(plane(6, 20, 75), 0.0, "outside the room");
    assert!(plane(6, 8, 12) > plane(6, 8, 4), "downwind above upwind");
}

/// The walled prior channel is the transformed plume between the room's side walls, and in the
/// empty tunnel, whose only boundaries upwind of the outlet are those walls, it is far closer to
/// the solver's field than the unbounded prior.
#[test]
fn the_walled_input_is_the_plume_between_the_side_walls() {
    use plumenet::physics::analytic::point_source_between_walls;
    use plumenet::physics::transport::Transport;
    use plumenet::physics::wind::WindField;
    use plumenet::surrogate::data::{InputSet, Normalization, RoomPlanes, SourceEncoding};
    let layout = crate::common::empty_tunnel();
    let wind = WindField::solve(&layout).unwrap();
    let room = RoomPlanes::new(&layout, Some(&wind));
    let norm = Normalization::default();
    let (h, w) = room.shape();
    let source = [3.0, 0.6];
    let prior = |inputs| {
        let mut out = vec![0.0f32; 7 * h * w];
        room.encode(
            source,
            inputs,
            SourceEncoding::Gaussian,
            &norm,
            (h, w),
            &mut out,
        )
        .unwrap();
        out.split_off(6 * h * w)
    };
    let (walled, free) = (prior(InputSet::Walled), prior(InputSet::Analytic));
    let (j, i) = (30, 120); // cell centre (15.0625, 3.8125), far downwind, by the far wall
    let (x, y) = ((i as f64 + 0.5) * 0.125, (j as f64 + 0.5) * 0.125);
    let expected =
        point_source_between_walls((x, y), (3.0, 0.6), 0.75, layout.diffusivity(), 4.0, 1.0);
    let got = norm.inverse(walled[j * w + i], 0.75) as f64;
    assert!(
        (got - expected).abs() <= 1e-4 * expected,
        "{got} vs {expected}"
    );
    let field = Transport::new(&layout, &wind)
        .unwrap()
        .solve(3.0, 0.6)
        .unwrap();
    let error = |plane: &[f32]| {
        let (mut num, mut den) = (0.0, 0.0);
        for ((j, i), &c) in field.indexed_iter() {
            let x = (i as f64 + 0.5) * 0.125;
            if (x - 3.0).hypot((j as f64 + 0.5) * 0.125 - 0.6) < 0.5 || x > 17.0 {
                continue;
            }
            let p = f64::from(norm.inverse(plane[j * w + i], 0.75));
            num += (p - c).powi(2);
            den += c * c;
        }
        (num / den).sqrt()
    };
    let (e_walled, e_free) = (error(&walled), error(&free));
    assert!(
        e_walled < 0.05 && e_free > 0.25,
        "walled {e_walled}, unbounded {e_free}"
    );
}

/// A network widened at some levels computes what the trained one did (the new channels feed
/// nothing yet), with and without the prior skip, with more weights; a narrower or deeper
/// network is refused.
#[test]
fn a_widened_network_computes_what_it_was_widened_from() {
    use burn::tensor::Tensor;
    let device = plumenet::surrogate::backend::device();
    let input: Vec<f32> = (0..2 * 7 * 16 * 24)
        .map(|k| ((k * 7919) % 1000) as f32 / 500.0 - 1.0)
        .collect();
    let x = || {
        Tensor::<4>::from_data(
            burn::tensor::TensorData::new(input.clone(), [2, 7, 16, 24]),
            &device,
        )
    };
    for skip in [None, Some(true)] {
        let from = PlumeNetConfig::new()
            .with_filters(vec![4, 6, 8])
            .with_convs_per_level(2)
            .with_kernel_size(3)
            .with_prior_skip(skip);
        let to = from.clone().with_filters(vec![5, 6, 12]);
        let net = from.init_seeded(&device, 3);
        let wide = net.widened(&from, &to, 9, &device).unwrap();
        let a: Vec<f32> = net.forward(x()).into_data().try_to_vec::<f32>().unwrap();
        let b: Vec<f32> = wide.forward(x()).into_data().try_to_vec::<f32>().unwrap();
        let worst = a
            .iter()
            .zip(&b)
            .map(|(p, q)| (p - q).abs())
            .fold(0.0, f32::max);
        let scale = a.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(
            worst <= 1e-5 * scale.max(1.0),
            "{skip:?}: {worst} of {scale}"
        );
        let sizes = |n: &plumenet::surrogate::PlumeNet| {
            plumenet::surrogate::saved::named_tensors(n)
                .unwrap()
                .iter()
                .map(|(_, t)| t.len())
                .sum::<usize>()
        };
        assert!(sizes(&wide) > sizes(&net));
    }
    let from = PlumeNetConfig::new().with_filters(vec![4, 8]);
    let net = from.init_seeded(&device, 0);
    for bad in [vec![4, 6], vec![4, 8, 8]] {
        let to = from.clone().with_filters(bad);
        let err = net.widened(&from, &to, 0, &device).unwrap_err();
        assert!(err.to_string().contains("do not widen"), "{err}");
    }
}

/// `train` with wider filters than its warm start widens the start and saves the wider
/// network; narrower filters are refused.
#[test]
fn training_can_widen_the_model_it_starts_from() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let base = tiny_config(1);
    train(&data, &base, &tmp.path().join("base"), &mut |_| ()).unwrap();
    let start = plumenet::surrogate::Surrogate::load(&tmp.path().join("base")).unwrap();
    let mut wide = tiny_config(1);
    wide.model = base.model.clone().with_filters(vec![6, 12]);
    wide.init_from = Some(plumenet::surrogate::config::WarmStart {
        model: tmp.path().join("base").display().to_string(),
        weights_digest: start.saved().weights_digest.clone(),
    });
    let state = train(&data, &wide, &tmp.path().join("wide"), &mut |_| ()).unwrap();
    let saved = plumenet::surrogate::Surrogate::load(&tmp.path().join("wide")).unwrap();
    assert_eq!(saved.saved().architecture.filters, vec![6, 12]);
    assert!(state.best.unwrap().validation.is_finite());
    // Narrower than the start: refused before training.
    wide.model = base.model.clone().with_filters(vec![2, 8]);
    let err = train(&data, &wide, &tmp.path().join("narrow"), &mut |_| ()).unwrap_err();
    assert!(
        err.to_string().contains("not the model to start from"),
        "{err}"
    );
}

/// The prior skip feeds the analytic channel to the head beside the decoder's channels, and
/// needs the analytic inputs.
#[test]
fn the_prior_skip_widens_the_head_and_needs_the_analytic_inputs() {
    let device = plumenet::surrogate::backend::device();
    let head = |skip: Option<bool>| {
        let config = tiny_config(1).model.with_prior_skip(skip);
        let net = config.init_seeded(&device, 0);
        let tensors = plumenet::surrogate::saved::named_tensors(&net).unwrap();
        let (_, w) = tensors.iter().find(|(n, _)| n == "head.weight").unwrap();
        // And the network runs: [1, 7, 16, 24] in, [1, 1, 16, 24] out.
        let x = burn::tensor::Tensor::<4>::ones([1, 7, 16, 24], &device);
        assert_eq!(net.forward(x).dims(), [1, 1, 16, 24]);
        w.shape().to_vec()
    };
    assert_eq!(head(None), vec![1, 4, 1, 1]);
    assert_eq!(head(Some(true)), vec![1, 5, 1, 1]);
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let mut config = tiny_config(1);
    config.model = config.model.with_prior_skip(Some(true)).with_in_channels(6);
    config.inputs = plumenet::surrogate::data::InputSet::Wind;
    let err = train(&data, &config, &tmp.path().join("m"), &mut |_| ()).unwrap_err();
    assert!(
        err.to_string().contains("needs the analytic inputs"),
        "{err}"
    );
}

/// Several datasets train as one: rooms and an arena together, each holding out its own last
/// layouts for validation; datasets of different cells are refused.
#[test]
fn rooms_and_an_arena_train_together() {
    let tmp = tempfile::tempdir().unwrap();
    let arena = tmp.path().join("arena");
    let rooms = tmp.path().join("rooms");
    let a = tiny_dataset(&arena);
    let r = rooms_dataset(&rooms, 4, 6);
    let both = TrainingData::load_all(&[arena.as_path(), rooms.as_path()]).unwrap();
    assert_eq!(both.len(), a.len() + r.len());
    assert_eq!(both.layouts().len(), 3 + 4);
    assert_eq!(both.manifests.len(), 2);
    let (train_idx, val_idx) = both.split_by_layout(0.34);
    // ceil(0.34 L) of each: the arena's last two layouts (1, 2) and the rooms' last two (5, 6).
    let held: std::collections::BTreeSet<usize> =
        val_idx.iter().map(|&s| both.source_layout[s]).collect();
    assert_eq!(held, [1, 2, 5, 6].into_iter().collect());
    assert_eq!(train_idx.len() + val_idx.len(), both.len());
    // The rooms' samples follow the arena's, with their layouts renumbered.
    assert_eq!(both.source_xy[a.len()..], r.source_xy[..]);
    assert_eq!(both.concentration(a.len()), r.concentration(0));
    let state = train(&both, &tiny_config(2), &tmp.path().join("m"), &mut |_| ()).unwrap();
    assert_eq!(state.history.len(), 2);
    let model = Surrogate::load(&tmp.path().join("m")).unwrap();
    let ranges = model.saved().ranges.unwrap();
    assert_eq!(ranges.speed_mps[1].max(0.75), ranges.speed_mps[1]);
    assert_ne!(both.digest, a.digest);
    // Other cells are refused.
    let fine = tmp.path().join("fine");
    let config = GenerateConfig {
        distribution: Distribution::Base {
            base: Layout::from_json(
                r#"{"width_m":9,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#,
            )
            .unwrap()
            .spec()
            .clone(),
            params: GenerateParams {
                inlet_clearance_m: 1.0,
                ..GenerateParams::default()
            },
        },
        layouts: 1,
        sources_per_layout: 1,
        seed: 1,
        shard: None,
    };
    dataset::generate(&config, &fine, &|| ()).unwrap();
    let err = TrainingData::load_all(&[arena.as_path(), fine.as_path()]).unwrap_err();
    assert!(err.to_string().contains("other cells"), "{err}");
}

/// A run can start from a trained model's weights: its first epoch starts where that model
/// ended, a wrong digest or architecture is refused, and a warm-started run resumes exactly.
#[test]
fn a_run_can_start_from_a_trained_model() {
    use plumenet::surrogate::config::WarmStart;
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let first = tmp.path().join("first");
    let trained = train(&data, &tiny_config(8), &first, &mut |_| ()).unwrap();
    let digest = Surrogate::load(&first)
        .unwrap()
        .saved()
        .weights_digest
        .clone();
    let warm = |digest: String| TrainingConfig {
        init_from: Some(WarmStart {
            model: first.display().to_string(),
            weights_digest: digest,
        }),
        ..tiny_config(2)
    };
    let fresh = train(
        &data,
        &tiny_config(2),
        &tmp.path().join("fresh"),
        &mut |_| (),
    )
    .unwrap();
    let cont = train(
        &data,
        &warm(digest.clone()),
        &tmp.path().join("warm"),
        &mut |_| (),
    )
    .unwrap();
    let best = trained.best.unwrap().validation;
    assert!(
        cont.history[0].train < fresh.history[0].train && cont.history[0].validation < 2.0 * best,
        "warm {:?} vs fresh {:?}, first run's best {best}",
        cont.history[0],
        fresh.history[0]
    );
    // Resuming a warm-started run needs no second look at the first model, and is exact.
    let again = train(
        &data,
        &warm(digest.clone()),
        &tmp.path().join("warm"),
        &mut |_| (),
    )
    .unwrap();
    assert_eq!(losses(&again.history), losses(&cont.history));
    // The same weights read from another path resume the run too.
    let copy = tmp.path().join("copy");
    std::fs::create_dir_all(&copy).unwrap();
    for f in ["weights.bpk", "config.json"] {
        std::fs::copy(first.join(f), copy.join(f)).unwrap();
    }
    let moved = TrainingConfig {
        init_from: Some(WarmStart {
            model: copy.display().to_string(),
            weights_digest: digest.clone(),
        }),
        ..tiny_config(2)
    };
    let resumed = train(&data, &moved, &tmp.path().join("warm"), &mut |_| ()).unwrap();
    assert_eq!(losses(&resumed.history), losses(&cont.history));
    let err = train(
        &data,
        &warm("0".repeat(64)),
        &tmp.path().join("bad"),
        &mut |_| (),
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("not the model to start from"), "{err}");
    let other = TrainingConfig {
        model: tiny_config(1).model.with_filters(vec![4, 4]),
        ..warm(digest)
    };
    let err = train(&data, &other, &tmp.path().join("bad2"), &mut |_| ())
        .unwrap_err()
        .to_string();
    assert!(err.contains("not the model to start from"), "{err}");
}

/// The shipped any-room model (`models/default`, trained on 7000 random rooms) runs on a room of a size
/// it never saw, close to the physics solver there, and refuses a room longer than any it
/// trained on, naming the range.
#[test]
fn the_any_room_model_predicts_an_unseen_room_and_refuses_a_too_long_one() {
    use plumenet::physics::transport::Transport;
    use plumenet::physics::wind::WindField;
    let model = Surrogate::load(&crate::common::repo_path("models/default")).unwrap();
    let office = Layout::load(&crate::common::repo_path(
        "data/layouts/rooms/office-9.25x7.5.json",
    ))
    .unwrap();
    let source = [4.0, 1.0];
    let field = model.predict(&office, source).unwrap();
    assert_eq!(field.dim(), office.shape());
    assert!(field.iter().all(|v| v.is_finite() && *v >= 0.0));
    let wind = WindField::solve(&office).unwrap();
    let exact = Transport::new(&office, &wind)
        .unwrap()
        .solve(source[0], source[1])
        .unwrap();
    let l2 = |a: &ndarray::Array2<f64>| a.iter().map(|v| v * v).sum::<f64>().sqrt();
    let rel = l2(&(&field - &exact)) / l2(&exact);
    // A broken model or a wrong frame gives errors near 1; a working one is far below this.
    assert!(rel < 0.6, "relative L2 {rel}");
    let long = Layout::from_json(
        r#"{"width_m":36,"height_m":6,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#,
    )
    .unwrap();
    let err = model.predict(&long, [3.0, 3.0]).unwrap_err().to_string();
    assert!(err.contains("30"), "{err}");
}

/// The training loss with a relative-L2 term is the transformed target's masked MSE plus the
/// weight times the mean over maps of the squared relative L2 error of `exp(y) - 1` over free
/// cells (brute force); with weight 0 it is the masked MSE alone.
#[test]
fn the_relative_l2_loss_term_matches_its_formula() {
    use burn::prelude::{Tensor, TensorData};
    use plumenet::surrogate::backend::device;
    use plumenet::surrogate::training::loss;
    let dev = device();
    let pred = [0.5f32, 1.0, 2.0, 0.1, 3.0, 0.0, 1.5, 2.5];
    let y = [0.4f32, 1.2, 1.8, 0.0, 2.5, 0.3, 1.5, 3.0];
    let free = [1.0f32, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0];
    let t = |v: &[f32]| Tensor::<4>::from_data(TensorData::new(v.to_vec(), [2, 1, 2, 2]), &dev);
    let mut config = TrainingConfig::default();
    let value = |c: &TrainingConfig| -> f64 {
        f64::from(loss(c, t(&pred), t(&y), t(&free)).into_scalar::<f32>())
    };
    let n: f32 = free.iter().sum();
    let mse: f32 = (0..8)
        .map(|i| free[i] * (pred[i] - y[i]).powi(2))
        .sum::<f32>()
        / n;
    assert!((value(&config) - f64::from(mse)).abs() < 1e-6);
    let rel = |m: usize| -> f32 {
        let (mut err, mut norm) = (0.0, 0.0);
        for i in 4 * m..4 * m + 4 {
            let c = y[i].exp() - 1.0;
            err += free[i] * (pred[i].exp() - 1.0 - c).powi(2);
            norm += free[i] * c * c;
        }
        err / norm
    };
    config.rel_l2_weight = 0.5;
    let expected = mse + 0.5 * 0.5 * (rel(0) + rel(1));
    assert!(
        (value(&config) - f64::from(expected)).abs() < 1e-5,
        "{} vs {expected}",
        value(&config)
    );
}

/// `train --mirror` rests on an exact symmetry: a room mirrored across the wind has the
/// mirrored mean field. A training batch's mirrored sample equals the encoding of the truly
/// mirrored room (built from mirrored obstacles, its wind and plume solved anew) with the
/// mirrored source, inputs and target alike; unmirrored samples are left as they are.
#[test]
fn a_mirrored_training_sample_is_the_mirrored_room_solved_anew() {
    use plumenet::surrogate::data::{InputSet, Normalization, RoomPlanes, SourceEncoding};
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 3, 7);
    let device = Default::default();
    let norm = Normalization::default();
    let batch = |samples: &[usize], mirror: Option<&[bool]>| {
        let (x, y, free) = data
            .batch(
                samples,
                mirror,
                InputSet::Analytic,
                SourceEncoding::Gaussian,
                &norm,
                8,
                &device,
            )
            .unwrap();
        let v = |t: burn::Tensor<4>| (t.dims(), t.into_data().try_to_vec::<f32>().unwrap());
        (v(x), v(y), v(free))
    };
    let mut checked_asymmetric = false;
    for s in 0..data.len() {
        let real = &data.layouts()[data.source_layout[s]];
        let canonical = plumenet::frame::Frame::of(real)
            .layout_to_canonical(real)
            .unwrap();
        let mut spec = canonical.spec().clone();
        let height = spec.height_m;
        for o in &mut spec.obstacles {
            (o.y_min, o.y_max) = (height - o.y_max, height - o.y_min);
        }
        let mirrored = spec.check().unwrap();
        checked_asymmetric |= mirrored.solid() != canonical.solid();
        let [sx, sy] = data.source_xy[s];
        let wind = plumenet::physics::wind::WindField::solve(&mirrored).unwrap();
        let field = PhysicsSolver.bank(&mirrored, &[[sx, height - sy]]).unwrap();
        let room = RoomPlanes::new(&mirrored, Some(&wind));

        let ((dims, input), (_, target), (_, free)) = batch(&[s], Some(&[true]));
        let [_, channels, hp, wp] = dims;
        let mut expected = vec![0.0f32; channels * hp * wp];
        room.encode(
            [sx, height - sy],
            InputSet::Analytic,
            SourceEncoding::Gaussian,
            &norm,
            (hp, wp),
            &mut expected,
        )
        .unwrap();
        let worst = input
            .iter()
            .zip(&expected)
            .fold(0.0f32, |m, (a, b)| m.max((a - b).abs()));
        assert!(worst <= 1e-4, "sample {s}: inputs differ by {worst}");
        let (h, w) = room.shape();
        for j in 0..h {
            for i in 0..w {
                let k = j * wp + i;
                let c = field.fields[[0, j, i]];
                assert!(
                    (target[k] - norm.forward(c, real.wind_speed())).abs() <= 1e-3,
                    "sample {s}, cell ({j}, {i})"
                );
                assert_eq!(free[k], 1.0 - room.mask[[j, i]]);
            }
        }
        // Flags of false, or none, leave the sample as it is.
        assert_eq!(batch(&[s], Some(&[false])), batch(&[s], None));
        assert_ne!(batch(&[s], Some(&[true])).1, batch(&[s], None).1);
    }
    assert!(checked_asymmetric, "every room was its own mirror image");
}

/// A mirrored run is reproducible (its flags come from the run's seed), is not the plain run,
/// and records the setting, so a resume with another setting is refused.
#[test]
fn mirrored_training_is_seeded_and_recorded() {
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 3, 8);
    let mirrored = TrainingConfig {
        mirror: true,
        ..tiny_config(2)
    };
    let run = |config: &TrainingConfig, name: &str| {
        train(&data, config, &tmp.path().join(name), &mut |_| ())
            .unwrap()
            .history
    };
    let a = run(&mirrored, "a");
    assert_eq!(losses(&a), losses(&run(&mirrored, "b")));
    assert_ne!(losses(&a), losses(&run(&tiny_config(2), "plain")));
    let saved = Surrogate::load(&tmp.path().join("a")).unwrap();
    assert!(saved.saved().training.mirror);
    let err = train(&data, &tiny_config(3), &tmp.path().join("a"), &mut |_| ()).unwrap_err();
    assert!(matches!(err, Error::Model(_)), "{err}");
}

/// A copy of the model in `from` in `dir`, with `mirror_average` set as given.
fn with_mirror_average(from: &Path, dir: &Path, on: bool) -> Surrogate {
    std::fs::create_dir_all(dir).unwrap();
    std::fs::copy(from.join("weights.bpk"), dir.join("weights.bpk")).unwrap();
    let mut config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(from.join("config.json")).unwrap()).unwrap();
    config["mirror_average"] = serde_json::Value::Bool(on);
    std::fs::write(dir.join("config.json"), config.to_string()).unwrap();
    Surrogate::load(dir).unwrap()
}

/// A mirror-averaging model predicts the mean of two one-view predictions: of the room, and of
/// the room mirrored across the wind (built from mirrored obstacles, its wind solved anew, the
/// source mirrored with it) flipped back. So its fields are mirror-symmetric: predicting the
/// mirrored room gives the mirrored field. The office's wind blows from the south (along +y),
/// so its mirror flips x.
#[test]
fn mirror_averaging_is_the_mean_of_the_room_and_its_mirror() {
    let tmp = tempfile::tempdir().unwrap();
    let shipped = crate::common::repo_path("models/default");
    let single = with_mirror_average(&shipped, &tmp.path().join("one"), false);
    let both = with_mirror_average(&shipped, &tmp.path().join("two"), true);
    assert_eq!((single.views(), both.views()), (1, 2));
    assert_ne!(
        single.digest(),
        both.digest(),
        "bank caches must tell them apart"
    );
    let office = Layout::load(&crate::common::repo_path(
        "data/layouts/rooms/office-9.25x7.5.json",
    ))
    .unwrap();
    let width = office.width();
    let mut spec = office.spec().clone();
    for o in &mut spec.obstacles {
        (o.x_min, o.x_max) = (width - o.x_max, width - o.x_min);
    }
    let mirrored = spec.check().unwrap();
    assert_ne!(
        mirrored.solid(),
        office.solid(),
        "the office is its own mirror image"
    );
    let sources = [[4.0, 1.0], [7.0, 5.0]];
    let flipped_sources: Vec<[f64; 2]> = sources.iter().map(|&[x, y]| [width - x, y]).collect();
    let flip = |a: &ndarray::Array3<f32>| a.slice(ndarray::s![.., .., ..;-1]).to_owned();
    let plain = single.predict_many(&office, &sources).unwrap();
    let plain_mirror = flip(&single.predict_many(&mirrored, &flipped_sources).unwrap());
    let averaged = both.predict_many(&office, &sources).unwrap();
    let peak = averaged.iter().fold(0.0f32, |m, v| m.max(*v));
    let worst = |a: &ndarray::Array3<f32>, b: &ndarray::Array3<f32>| {
        a.iter()
            .zip(b)
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()))
            / peak
    };
    // The two views differ (the network is not symmetric by itself), and the average is
    // their mean up to the round-off of the two wind solves.
    assert!(worst(&plain, &plain_mirror) > 1e-3);
    let mean = (&plain + &plain_mirror) * 0.5;
    assert!(
        worst(&averaged, &mean) < 1e-4,
        "{}",
        worst(&averaged, &mean)
    );
    let averaged_mirror = flip(&both.predict_many(&mirrored, &flipped_sources).unwrap());
    assert!(worst(&averaged, &averaged_mirror) < 1e-4);
    assert!(averaged.iter().all(|v| v.is_finite() && *v >= 0.0));
}

/// The validation's relative L2 error is the evaluation's measure per map, brute force: the
/// output mapped back as in inference (negative outputs are zero concentration), against
/// `exp(y) - 1`, over free cells.
#[test]
fn the_validation_relative_l2_is_the_evaluation_measure() {
    use burn::prelude::{Tensor, TensorData};
    use plumenet::surrogate::backend::device;
    use plumenet::surrogate::training::relative_l2_per_map;
    let dev = device();
    let pred = [0.5f32, -1.0, 2.0, 0.1, 3.0, 0.0, 1.5, 2.5];
    let y = [0.4f32, 1.2, 1.8, 0.0, 2.5, 0.3, 1.5, 3.0];
    let free = [1.0f32, 1.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0];
    let t = |v: &[f32]| Tensor::<4>::from_data(TensorData::new(v.to_vec(), [2, 1, 2, 2]), &dev);
    let got = relative_l2_per_map(t(&pred), t(&y), t(&free)).unwrap();
    for (m, value) in got.iter().enumerate() {
        let (mut err, mut norm) = (0.0f64, 0.0f64);
        for i in 4 * m..4 * m + 4 {
            let c = f64::from(y[i]).exp_m1();
            let p = f64::from(pred[i]).max(0.0).exp_m1();
            err += f64::from(free[i]) * (p - c).powi(2);
            norm += f64::from(free[i]) * c * c;
        }
        let expected = (err / norm).sqrt();
        assert!(
            (value - expected).abs() < 1e-5,
            "map {m}: {value} vs {expected}"
        );
    }
}

/// Every epoch records the held-out maps' median relative L2 error, overall and per size
/// class, and `select_by` picks the kept epoch by the chosen score: the run selecting by
/// relative L2 keeps its epoch of least relative L2, the default its epoch of least loss; the
/// setting is part of the run (a resume with the other one is refused).
#[test]
fn the_kept_epoch_is_the_best_by_the_chosen_validation_score() {
    use plumenet::surrogate::config::Selection;
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 6, 4);
    let by_rel = TrainingConfig {
        select_by: Selection::RelativeL2,
        ..tiny_config(6)
    };
    let argmin = |history: &[EpochLoss], score: &dyn Fn(&EpochLoss) -> f64| {
        history
            .iter()
            .min_by(|a, b| score(a).total_cmp(&score(b)))
            .unwrap()
            .epoch
    };
    for (config, name) in [(&by_rel, "rel"), (&tiny_config(6), "loss")] {
        let dir = tmp.path().join(name);
        let state = train(&data, config, &dir, &mut |_| ()).unwrap();
        for e in &state.history {
            let rel = e.validation_relative_l2.unwrap();
            assert!(rel.is_finite() && rel > 0.0, "epoch {}: {rel}", e.epoch);
            let by_size = e.validation_relative_l2_by_size.unwrap();
            assert_eq!(
                by_size.map(|v| v.is_some()),
                e.validation_by_size.unwrap().map(|v| v.is_some())
            );
        }
        let best = state.best.unwrap().epoch;
        let expected = match config.select_by {
            Selection::RelativeL2 => argmin(&state.history, &|e| e.validation_relative_l2.unwrap()),
            Selection::Loss => argmin(&state.history, &|e| e.validation),
        };
        assert_eq!(best, expected, "{name}");
        let saved = Surrogate::load(&dir).unwrap();
        assert_eq!(saved.saved().best.unwrap().epoch, best);
        assert_eq!(saved.saved().training.select_by, config.select_by);
    }
    let other = TrainingConfig {
        epochs: 7,
        ..tiny_config(7)
    };
    let err = train(&data, &other, &tmp.path().join("rel"), &mut |_| ()).unwrap_err();
    assert!(matches!(err, Error::Model(_)), "{err}");
}

/// A tiny operator network: two groups of two terms, two room planes, five hidden units (the
/// fused head pads them to whole blocks).
fn tiny_operator(epochs: usize) -> TrainingConfig {
    let mut config = tiny_config(epochs);
    config.model = config
        .model
        .with_in_channels(ROOM_CHANNELS)
        .with_operator(Some(
            OperatorConfig::new()
                .with_groups(2)
                .with_group_size(2)
                .with_room_planes(2)
                .with_hidden(5),
        ));
    config
}

/// The operator network trains (its loss falls), and a bank, which runs the per-source head
/// fused on the CPU (`surrogate::head`: tables of the prior, room terms computed once), gives
/// the fields of the training pass (Burn tensors, per-source planes encoded cell by cell) to
/// single-precision round-off, in every room of a dataset of several sizes and wind directions.
#[test]
fn the_operator_networks_fused_bank_is_its_training_pass() {
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 6, 4);
    // The tiny sizes run the fused kernel's general path; the default bilinear sizes (16
    // groups of 8) the path compiled for them.
    let mut default_sizes = tiny_operator(4);
    default_sizes.model.operator = default_sizes
        .model
        .operator
        .map(|op| op.with_groups(16).with_group_size(8));
    for (name, config) in [("tiny", tiny_operator(4)), ("default", default_sizes)] {
        assert_fused_bank_is_training_pass(&data, &config, &tmp.path().join(name));
    }
}

/// A tiny operator network of the coarse form: a three-level room U-Net decoding to level 1,
/// where a two-level per-source network (one pooling) corrects the prior.
fn tiny_coarse(epochs: usize) -> TrainingConfig {
    let mut config = tiny_operator(epochs);
    config.model = config.model.with_filters(vec![4, 8, 8]);
    config.model.operator = config.model.operator.map(|op| {
        op.with_coarse(Some(
            CoarseConfig::new().with_level(1).with_filters(vec![4, 6]),
        ))
    });
    config
}

/// The coarse form trains, and its bank (the room's share of the first convolution computed
/// once and broadcast, the network run once per block of sources, the anchors' pooled planes
/// read from tables, the correction upsampled and added to the prior in a fused loop) gives
/// the fields of the training pass (the share expanded to every source of a batch of whole
/// rooms, the anchors' planes encoded cell by cell and pooled, Burn's bilinear interpolation)
/// to single-precision round-off, in rooms of several sizes and wind directions. Operator
/// networks do not average the mirror image.
#[test]
fn the_coarse_operator_networks_bank_is_its_training_pass() {
    let tmp = tempfile::tempdir().unwrap();
    let data = rooms_dataset(&tmp.path().join("data"), 6, 4);
    assert_fused_bank_is_training_pass(&data, &tiny_coarse(4), &tmp.path().join("coarse"));
    let model = Surrogate::load(&tmp.path().join("coarse").join("model")).unwrap();
    assert!(model.net().is_coarse());
    assert_eq!(
        model.views(),
        1,
        "an operator network does not average mirror images"
    );
}

/// A coarse per-source network that pools deeper than the room's U-Net, or has no levels, is
/// refused before training starts, and a model whose `config.json` says so (its weights fit
/// any level), or names a field of the coarse network this plumenet does not know, is refused
/// on loading with one line.
#[test]
fn a_coarse_operator_network_refuses_levels_the_room_net_lacks() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let out = tmp.path().join("model");
    let with = |c: CoarseConfig| {
        let mut config = tiny_coarse(1);
        config.model.operator = config.model.operator.map(|op| op.with_coarse(Some(c)));
        config
    };
    let deep = with(CoarseConfig::new().with_level(2).with_filters(vec![4, 6]));
    assert_err(train(&data, &deep, &out, &mut |_| ()), "pools deeper");
    let empty = with(CoarseConfig::new().with_level(1).with_filters(vec![]));
    assert_err(train(&data, &empty, &out, &mut |_| ()), "non-empty");
    assert!(!out.join("config.json").exists());

    train(&data, &tiny_coarse(1), &out, &mut |_| ()).unwrap();
    let path = out.join("config.json");
    let mut config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
    let trained = config.clone();
    config["architecture"]["operator"]["coarse"]["level"] = serde_json::json!(5);
    std::fs::write(&path, config.to_string()).unwrap();
    let err = Surrogate::load(&out).unwrap_err();
    assert!(matches!(err, Error::Model(_)), "{err}");
    assert!(err.to_string().contains("pools deeper"), "{err}");
    // A field of the coarse network this plumenet does not know is refused, not ignored.
    let mut config = trained;
    config["architecture"]["operator"]["coarse"]["stride"] = serde_json::json!(2);
    std::fs::write(&path, config.to_string()).unwrap();
    let err = Surrogate::load(&out).unwrap_err();
    assert!(
        err.to_string()
            .contains("has a field \"operator.coarse.stride\""),
        "{err}"
    );
}

/// Trains `config` on `data` into `dir` and compares its fused bank with its training pass in
/// every room of `data`.
fn assert_fused_bank_is_training_pass(data: &TrainingData, config: &TrainingConfig, dir: &Path) {
    let state = train(data, config, &dir.join("model"), &mut |_| ()).unwrap();
    let (first, last) = (state.history[0].train, state.history[3].train);
    assert!(last < first, "training loss {first} -> {last}");
    let model = with_mirror_average(&dir.join("model"), &dir.join("one"), false);
    let net = model.net();
    let device = plumenet::surrogate::backend::device();
    let norm = config.normalization;
    let samples: Vec<usize> = (0..data.len()).collect();
    let mut directions = std::collections::BTreeSet::new();
    for room in data.rooms_of(&samples) {
        let l = data.source_layout[room[0]];
        let layout = &data.layouts()[l];
        directions.insert(format!("{:?}", layout.spec().wind.from));
        let (batch, _, _) = data
            .room_batch(
                std::slice::from_ref(&room),
                None,
                (&norm, config.pad_cells, config.model.coarse_pooling()),
                &device,
            )
            .unwrap();
        let y = net.source_fields(
            net.room_planes(batch.rooms, ConvImpl::Own),
            &batch.taps,
            batch.sources,
            ConvImpl::Own,
        );
        let [_, _, hp, wp] = y.dims();
        let y: Vec<f32> = y.into_data().try_to_vec::<f32>().unwrap();
        let frame = Frame::of(layout);
        let real: Vec<[f64; 2]> = room
            .iter()
            .map(|&s| {
                let [x, y] = data.source_xy[s];
                let (a, b) = frame.from_canonical(x, y);
                [a, b]
            })
            .collect();
        let fields = model.predict_many(layout, &real).unwrap();
        let mask = &data.room(l).mask;
        for (n, field) in fields.outer_iter().enumerate() {
            let canonical = frame.cells_to_canonical(field);
            let expected =
                |j: usize, i: usize| norm.inverse(y[(n * hp + j) * wp + i], layout.wind_speed());
            let peak = canonical.iter().fold(0.0f32, |m, &c| m.max(c));
            assert!(peak > 0.0);
            for ((j, i), &c) in canonical.indexed_iter() {
                if mask[[j, i]] == 0.0 {
                    let e = expected(j, i);
                    assert!(
                        (c - e).abs() <= 1e-5 * peak + 1e-5 * e.abs(),
                        "room {l} source {n} cell ({j}, {i}): bank {c}, training pass {e}"
                    );
                }
            }
        }
    }
    assert!(directions.len() > 1, "rooms of one wind direction only");
}

/// An operator network takes the analytic inputs without the prior skip, and rooms padded to
/// whole pooling steps; anything else is refused before training starts.
#[test]
fn an_operator_network_refuses_inputs_and_padding_it_cannot_use() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let out = tmp.path().join("model");
    let mut walled = tiny_operator(1);
    walled.inputs = plumenet::surrogate::data::InputSet::Walled;
    assert_err(train(&data, &walled, &out, &mut |_| ()), "analytic inputs");
    let mut odd = tiny_operator(1);
    odd.pad_cells = 3;
    assert_err(train(&data, &odd, &out, &mut |_| ()), "multiple of 2");
    let mut channels = tiny_operator(1);
    channels.model.in_channels = 7;
    assert_err(train(&data, &channels, &out, &mut |_| ()), "input channels");
    assert!(!out.join("config.json").exists());
}

/// The vectorised inverse of the target transform equals `scale * expm1(max(y, 0))` computed in
/// f64 to a few units in the last place of f32, over the whole range a network gives (dense
/// near 0, where `exp(y) - 1` cancels, and at the switch between its two branches, 1/2), on
/// every instruction set through the tail of a slice too; arguments past 80 are taken as 80.
#[test]
fn the_vectorised_inverse_transform_is_expm1() {
    let mut ys: Vec<f32> = (0..20_000).map(|k| k as f32 * 1e-3).collect();
    ys.extend((1..2000).map(|k| 0.5 + (k as f32 - 1000.0) * 1e-6));
    ys.extend((0..400).map(|k| 1e-8 * 1.05f32.powi(k)));
    ys.extend([-3.0, 0.0, 79.9, 80.0, 95.0, 1e-30]);
    ys.push(0.123); // an odd length: the last values take the scalar tail
    let scale = 0.013;
    let mut worst = 0.0f64;
    for isa in Isa::available() {
        let mut values = ys.clone();
        plumenet::surrogate::expm1::expm1_scaled_on(isa, &mut values, scale);
        for (&y, &v) in ys.iter().zip(&values) {
            let exact = f64::from(scale) * f64::from(y.clamp(0.0, 80.0)).exp_m1();
            if exact == 0.0 {
                assert_eq!(v, 0.0, "{isa:?}, y = {y}");
            } else {
                worst = worst.max((f64::from(v) - exact).abs() / exact);
            }
        }
    }
    // A few units in the last place (f32's is 6e-8).
    assert!(worst < 5e-7, "worst relative error {worst:e}");
}

/// An operator network started from a trained U-Net (`train --operator --init-from`) carries
/// the U-Net's body: every convolution and up-sampling of the encoder and decoder as trained
/// (of the decoder, the levels the coarse form keeps), the first one reading the room's five
/// channels of the seven; a U-Net of another body or inputs is refused.
#[test]
fn an_operator_network_starts_from_a_trained_unets_body() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let device = plumenet::surrogate::backend::device();
    for (name, to, least) in [
        ("bilinear", tiny_operator(1).model, 8),
        ("coarse", tiny_coarse(1).model, 10),
    ] {
        let mut unet_config = tiny_config(1);
        unet_config.model = unet_config.model.with_filters(to.filters.clone());
        train(&data, &unet_config, &tmp.path().join(name), &mut |_| ()).unwrap();
        let unet = Surrogate::load(&tmp.path().join(name)).unwrap();
        let net = unet
            .net()
            .operator_from(&unet_config.model, &to, 7, &device)
            .unwrap();
        let old: std::collections::BTreeMap<_, _> =
            named_tensors(unet.net()).unwrap().into_iter().collect();
        let mut copied = 0;
        for (tensor, new) in named_tensors(&net).unwrap() {
            if ["head", "operator", "coarse"]
                .iter()
                .any(|p| tensor.starts_with(p))
            {
                continue;
            }
            let old = &old[&tensor];
            if tensor == "encoders.0.convs.0.weight" {
                for (c, &i) in [0, 1, 3, 4, 5].iter().enumerate() {
                    assert_eq!(
                        new.index_axis(ndarray::Axis(1), c),
                        old.index_axis(ndarray::Axis(1), i),
                        "{name}: input {c}"
                    );
                }
            } else {
                assert_eq!(&new, old, "{name}: {tensor}");
            }
            copied += 1;
        }
        assert!(copied >= least, "{name}: {copied} tensors copied");
    }
    let unet_config = tiny_config(1);
    let unet = Surrogate::load(&tmp.path().join("bilinear")).unwrap();
    let other = tiny_operator(1).model.with_filters(vec![4, 6]);
    assert_err(
        unet.net()
            .operator_from(&unet_config.model, &other, 7, &device),
        "same body",
    );
}

/// A coarse network's anchor is the centre of the block of cells that holds the source: every
/// source of the block has that anchor, within half a block of it, and the anchor's block is
/// the source's.
#[test]
fn coarse_anchors_are_the_centres_of_their_blocks() {
    let (cell, k) = (0.125, 4);
    let block_m = 0.5;
    for source in [
        [0.0, 0.0],
        [0.49, 0.26],
        [0.5, 0.5],
        [7.3, 2.9],
        [29.99, 11.51],
    ] {
        let anchor = plumenet::surrogate::coarse::anchor(source, cell, k);
        let block = plumenet::surrogate::coarse::block(source, cell, k);
        assert_eq!(plumenet::surrogate::coarse::block(anchor, cell, k), block);
        for axis in 0..2 {
            assert!(
                (anchor[axis] - source[axis]).abs() <= block_m / 2.0,
                "{source:?}"
            );
            let centre = (anchor[axis] / block_m - 0.5).round() * block_m + block_m / 2.0;
            assert!((anchor[axis] - centre).abs() < 1e-12, "{anchor:?}");
        }
        assert_eq!(
            block,
            (
                (source[1] / block_m).floor() as i64,
                (source[0] / block_m).floor() as i64
            )
        );
    }
}

/// The coarse form's accuracy bound: the best correction on coarse cells recovers a field that
/// is itself a coarse field upsampled (bilinear with half-pixel centres and clamped edges,
/// computed here from the definition), and for any other target no coarse field does better on
/// the free cells (a perturbation of the fit only adds error).
#[test]
fn the_best_coarse_correction_is_the_least_squares_fit() {
    use plumenet::surrogate::coarse::best_correction;
    let (h, w, k) = (13usize, 22usize, 4usize);
    let (hc, wc) = (h.div_ceil(k), w.div_ceil(k));
    let free = ndarray::Array2::from_shape_fn((h, w), |(j, i)| {
        !((4..7).contains(&j) && (5..12).contains(&i))
    });
    let coarse = |seed: f32| {
        ndarray::Array2::from_shape_fn((hc, wc), |(j, i)| {
            ((j * 7 + i * 13) as f32 * 0.37 + seed).sin()
        })
    };
    let upsampled = |g: &ndarray::Array2<f32>| {
        ndarray::Array2::from_shape_fn((h, w), |(j, i)| {
            let at =
                |o: usize, n: usize| ((o as f32 + 0.5) / k as f32 - 0.5).clamp(0.0, (n - 1) as f32);
            let (y, x) = (at(j, hc), at(i, wc));
            let (y0, x0) = (y.floor() as usize, x.floor() as usize);
            let (y1, x1) = ((y0 + 1).min(hc - 1), (x0 + 1).min(wc - 1));
            let (fy, fx) = (y - y0 as f32, x - x0 as f32);
            (1.0 - fy) * ((1.0 - fx) * g[[y0, x0]] + fx * g[[y0, x1]])
                + fy * ((1.0 - fx) * g[[y1, x0]] + fx * g[[y1, x1]])
        })
    };
    let target = upsampled(&coarse(0.0));
    let fit = best_correction(target.view(), free.view(), k);
    for ((t, f), &m) in target.iter().zip(&fit).zip(&free) {
        if m {
            assert!((t - f).abs() < 1e-5, "{t} against {f}");
        }
    }

    let target = ndarray::Array2::from_shape_fn((h, w), |(j, i)| ((j * j + 3 * i) as f32).cos());
    let fit = best_correction(target.view(), free.view(), k);
    let error = |field: &ndarray::Array2<f32>| -> f64 {
        ndarray::Zip::from(field)
            .and(&target)
            .and(&free)
            .fold(0.0, |e, &f, &t, &m| {
                e + if m { f64::from(f - t).powi(2) } else { 0.0 }
            })
    };
    let best = error(&fit);
    assert!(best > 1e-3, "a rough target is not a coarse field: {best}");
    for seed in [1.0, 2.0, 3.0] {
        for step in [-0.05, 0.05] {
            let moved = &fit + &(upsampled(&coarse(seed)) * step);
            assert!(
                error(&moved) > best,
                "seed {seed}, step {step}: {} <= {best}",
                error(&moved)
            );
        }
    }
}
