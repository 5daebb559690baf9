//! Every input a user can hand over, attacked: layout JSON and replay logs (property tests),
//! model directories, dataset directories and the bank cache; and interruptions: a training
//! killed while it writes its checkpoint, a damaged optimizer state, a dataset generation that
//! stops half way. Each failure is checked for its message, not only for failing.

use std::path::Path;

use ndarray::{Array1, Array2, Ix1, Ix2, Ix3};
use proptest::prelude::*;

use plumenet::dataset::{self, Distribution, GenerateConfig, GenerateParams};
use plumenet::io::{read_npy, write_npy};
use plumenet::layout::Layout;
use plumenet::plume::{PhysicsSolver, PlumeModel, cached_bank};
use plumenet::ste::replay::read_log;
use plumenet::surrogate::{Surrogate, TrainingData, train};

use crate::common::assert_err;
use crate::surrogate::{tiny_config, tiny_dataset};

const ROOM: &str = r#"{"width_m":6,"height_m":3,"cell_m":0.25,"wind":{"speed_mps":0.5},
    "obstacles":[{"x_min":2,"y_min":1,"x_max":3,"y_max":2}]}"#;

/// Tokens a damaged or hostile file may hold where a number belongs.
fn token() -> impl Strategy<Value = String> {
    prop_oneof![
        (-1e3f64..1e3).prop_map(|v| format!("{v}")),
        Just("0".to_string()),
        Just("-1".to_string()),
        Just("1e999".to_string()),
        Just("-1e999".to_string()),
        Just("NaN".to_string()),
        Just("null".to_string()),
        Just("\"3\"".to_string()),
        Just("[]".to_string()),
        Just(String::new()),
    ]
}

proptest! {
    #![proptest_config(crate::common::proptest_config(256))]

    /// Any text is a valid layout or one clear error; never a panic.
    #[test]
    fn any_text_is_a_layout_or_one_clear_error(text in "\\PC{0,200}") {
        if let Err(e) = Layout::from_json(&text) {
            let message = e.to_string();
            prop_assert!(message.starts_with("invalid layout: "), "{}", message);
        }
    }

    /// A layout with any of its numbers replaced by a hostile token is valid (and then every
    /// invariant holds) or refused with a message that names the problem.
    #[test]
    fn a_layout_with_a_hostile_number_is_refused_or_sound(
        field in 0usize..7,
        value in token(),
    ) {
        let mut numbers = ["6", "3", "0.25", "0.5", "2", "1", "3"].map(String::from);
        numbers[field] = value;
        let [w, h, c, s, x0, y0, x1] = numbers;
        let text = format!(
            r#"{{"width_m":{w},"height_m":{h},"cell_m":{c},"wind":{{"speed_mps":{s}}},
                "obstacles":[{{"x_min":{x0},"y_min":{y0},"x_max":{x1},"y_max":2}}]}}"#
        );
        match Layout::from_json(&text) {
            Ok(l) => {
                let (ny, nx) = l.shape();
                prop_assert!(nx >= 4 && ny >= 4);
                prop_assert!((nx as f64 * l.cell() - l.width()).abs() < 1e-6 * l.width());
                prop_assert!(l.wind_speed() > 0.0 && l.wind_speed().is_finite());
                prop_assert!(l.solid().iter().any(|&s| s) && l.solid().iter().any(|&s| !s));
            }
            Err(e) => {
                let message = e.to_string();
                prop_assert!(message.starts_with("invalid layout: "), "{}", message);
                prop_assert!(message.len() > "invalid layout: ".len() + 10, "{}", message);
            }
        }
    }

    /// A replay log with one hostile field is read exactly when every value is a finite number
    /// and time never goes back; otherwise the error names the line.
    #[test]
    fn a_log_with_a_hostile_field_is_refused_by_line(
        rows in 1usize..6,
        row in 0usize..6,
        column in 0usize..4,
        value in token(),
    ) {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.csv");
        let mut cells: Vec<[String; 4]> = (0..rows)
            .map(|k| [format!("{}", k as f64 * 0.1), "5".into(), "1.5".into(), "0.7".into()])
            .collect();
        let hit = row < rows;
        if hit {
            cells[row][column] = value.clone();
        }
        let text: String = std::iter::once("t,x,y,value".to_string())
            .chain(cells.iter().map(|c| c.join(",")))
            .collect::<Vec<_>>()
            .join("\n");
        std::fs::write(&path, &text).unwrap();
        let numbers: Option<Vec<[f64; 4]>> = cells
            .iter()
            .map(|c| {
                let v: Option<Vec<f64>> = c
                    .iter()
                    .map(|s| {
                        // A quoted CSV field is its content.
                        let s = s.strip_prefix('"').and_then(|s| s.strip_suffix('"')).unwrap_or(s);
                        s.parse::<f64>().ok().filter(|x| x.is_finite())
                    })
                    .collect();
                v.map(|v| [v[0], v[1], v[2], v[3]])
            })
            .collect();
        let ordered = numbers
            .as_ref()
            .is_some_and(|n| n.windows(2).all(|w| w[1][0] >= w[0][0]));
        match read_log(&path) {
            Ok(samples) => {
                prop_assert!(ordered, "accepted {}", text);
                let n = numbers.unwrap();
                prop_assert_eq!(samples.len(), rows);
                for (s, v) in samples.iter().zip(&n) {
                    prop_assert_eq!([s.t, s.x, s.y, s.value], *v);
                }
            }
            Err(e) => {
                prop_assert!(hit && !ordered, "refused a good log: {}", e);
                let message = e.to_string();
                let line = |k: usize| message.contains(&format!("line {k}:"));
                if numbers.is_none() {
                    // The hostile field's own line (its header line is line 1).
                    prop_assert!(line(row + 2), "{}", message);
                } else {
                    // Time goes back at the hostile line or at the one after it.
                    prop_assert!(message.contains("time goes backwards"), "{}", message);
                    prop_assert!(line(row + 2) || line(row + 3), "{}", message);
                }
            }
        }
    }
}

/// A tiny trained model in `dir`.
fn trained_model(dir: &Path) -> std::path::PathBuf {
    let data = tiny_dataset(&dir.join("data"));
    let model = dir.join("model");
    train(&data, &tiny_config(1), &model, &mut |_| ()).unwrap();
    model
}

/// A copy of `model` under `name` whose `config.json` is edited by `edit`.
fn damaged(model: &Path, name: &str, edit: impl Fn(&mut serde_json::Value)) -> std::path::PathBuf {
    let copy = model.with_file_name(name);
    std::fs::create_dir_all(&copy).unwrap();
    std::fs::copy(model.join("weights.bpk"), copy.join("weights.bpk")).unwrap();
    let mut config: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(model.join("config.json")).unwrap()).unwrap();
    edit(&mut config);
    std::fs::write(copy.join("config.json"), config.to_string()).unwrap();
    copy
}

#[test]
fn damaged_model_directories_are_refused_with_one_clear_line() {
    let tmp = tempfile::tempdir().unwrap();
    let model = trained_model(tmp.path());
    assert!(Surrogate::load(&model).is_ok());
    let cases: Vec<(std::path::PathBuf, &str)> = vec![
        (
            damaged(&model, "format", |c| {
                c["format"] = "plumenet-model-v9".into()
            }),
            "format \"plumenet-model-v9\" is not plumenet-model-v2",
        ),
        (
            damaged(&model, "unknown", |c| {
                c["architecture"]["kind"] = "fno".into()
            }),
            "the architecture has a field \"kind\" this plumenet does not know",
        ),
        (
            damaged(&model, "wider", |c| {
                c["architecture"]["filters"] = serde_json::json!([8, 16]);
            }),
            "does not match the digest in config.json",
        ),
        (
            damaged(&model, "typed", |c| {
                c["architecture"]["kernel_size"] = "five".into()
            }),
            "malformed JSON in",
        ),
        (
            damaged(&model, "extra", |c| c["comment"] = "hello".into()),
            "malformed JSON in",
        ),
    ];
    for (dir, needle) in cases {
        assert_err(Surrogate::load(&dir), needle);
    }
    // A config.json cut short, weights of another model, no weights at all.
    let cut = damaged(&model, "cut", |_| ());
    let text = std::fs::read(cut.join("config.json")).unwrap();
    std::fs::write(cut.join("config.json"), &text[..text.len() / 2]).unwrap();
    assert_err(Surrogate::load(&cut), "malformed JSON in");
    let other = damaged(&model, "other", |_| ());
    let default = Surrogate::load(&crate::common::repo_path("models/default")).unwrap();
    std::fs::write(
        other.join("weights.bpk"),
        plumenet::surrogate::saved::weights_bytes(default.net()).unwrap(),
    )
    .unwrap();
    assert_err(
        Surrogate::load(&other),
        "does not match the digest in config.json",
    );
    let bare = damaged(&model, "bare", |_| ());
    std::fs::remove_file(bare.join("weights.bpk")).unwrap();
    assert_err(Surrogate::load(&bare), "cannot read");
}

/// Rewrites the `f32` array `name` of a dataset through `edit`.
fn edit_array(dir: &Path, name: &str, edit: impl Fn(&mut ndarray::ArrayD<f32>)) {
    let path = dir.join(format!("{name}.npy"));
    let mut a = read_npy::<f32, ndarray::IxDyn>(&path).unwrap();
    edit(&mut a);
    write_npy(&path, &a).unwrap();
}

#[test]
fn damaged_datasets_are_refused_with_one_clear_line() {
    let tmp = tempfile::tempdir().unwrap();
    let good = tmp.path().join("good");
    tiny_dataset(&good);
    let copy = |name: &str| {
        let dir = tmp.path().join(name);
        std::fs::create_dir_all(&dir).unwrap();
        for entry in std::fs::read_dir(&good).unwrap() {
            let entry = entry.unwrap();
            std::fs::copy(entry.path(), dir.join(entry.file_name())).unwrap();
        }
        dir
    };
    let truncated = copy("truncated");
    let bytes = std::fs::read(truncated.join("concentration.npy")).unwrap();
    std::fs::write(
        truncated.join("concentration.npy"),
        &bytes[..bytes.len() / 2],
    )
    .unwrap();
    let nan = copy("nan");
    edit_array(&nan, "concentration", |a| a[[7]] = f32::NAN);
    let sdf = copy("sdf");
    edit_array(&sdf, "signed_distance", |a| a[[3]] = f32::INFINITY);
    let shape = copy("shape");
    std::fs::copy(
        shape.join("obstacle_mask.npy"),
        shape.join("concentration.npy"),
    )
    .unwrap();
    let missing = copy("missing");
    std::fs::remove_file(missing.join("wind.npy")).unwrap();
    let outside = copy("outside");
    edit_array(&outside, "source_xy", |a| a[[0, 0]] = 100.0);
    let rows = copy("rows");
    let xy = read_npy::<f32, Ix2>(&rows.join("source_xy.npy")).unwrap();
    write_npy(
        &rows.join("source_xy.npy"),
        &xy.slice(ndarray::s![..2, ..]).to_owned(),
    )
    .unwrap();
    let owner = copy("owner");
    let mut layouts = read_npy::<u32, Ix1>(&owner.join("source_layout.npy")).unwrap();
    layouts[0] = 9;
    write_npy(&owner.join("source_layout.npy"), &layouts).unwrap();
    for (dir, needle) in [
        (&truncated, "bad .npy array"),
        (&nan, "concentration.npy holds NaN or infinity"),
        (&sdf, "signed_distance.npy holds NaN or infinity"),
        (&shape, "differs from the manifest's"),
        (&missing, "cannot read"),
        (&outside, "source 0: invalid source position (100, "),
        (&rows, "differs from the manifest's"),
        (&owner, "source 0 names layout 9, which is not listed"),
    ] {
        assert_err(TrainingData::load(dir), needle);
    }
    assert!(TrainingData::load(&good).is_ok());
}

#[test]
fn a_damaged_bank_cache_is_recomputed_and_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let l = Layout::from_json(ROOM).unwrap();
    let candidates = l.candidates(0.25).unwrap();
    let (fresh, hit) = cached_bank(&PhysicsSolver, &l, &candidates, tmp.path()).unwrap();
    assert!(!hit);
    let file = std::fs::read_dir(tmp.path())
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let good = std::fs::read(&file).unwrap();
    type Damage<'a> = (&'a str, Box<dyn Fn() + 'a>);
    let damages: [Damage; 4] = [
        (
            "cut short",
            Box::new(|| std::fs::write(&file, &good[..good.len() / 3]).unwrap()),
        ),
        (
            "not an array",
            Box::new(|| std::fs::write(&file, b"garbage").unwrap()),
        ),
        (
            "another shape",
            Box::new(|| write_npy(&file, &Array2::<f32>::zeros((3, 4))).unwrap()),
        ),
        (
            "a NaN",
            Box::new(|| {
                let mut a = read_npy::<f32, Ix3>(&file).unwrap();
                a[[0, 0, 0]] = f32::NAN;
                write_npy(&file, &a).unwrap();
            }),
        ),
    ];
    for (what, damage) in damages {
        std::fs::write(&file, &good).unwrap();
        damage();
        let (bank, hit) = cached_bank(&PhysicsSolver, &l, &candidates, tmp.path()).unwrap();
        assert!(!hit, "{what}: a damaged cache was used");
        assert!(
            bank.fields == fresh.fields,
            "{what}: the recomputed bank differs"
        );
        assert_eq!(
            std::fs::read(&file).unwrap(),
            good,
            "{what}: the cache was not replaced"
        );
        assert!(
            cached_bank(&PhysicsSolver, &l, &candidates, tmp.path())
                .unwrap()
                .1
        );
    }
    assert_eq!(
        PhysicsSolver.bank(&l, &candidates).unwrap().fields,
        fresh.fields
    );
}

/// The losses of a run, without the wall-clock times.
fn losses(out: &Path) -> Vec<[f64; 2]> {
    Surrogate::load(out)
        .unwrap()
        .saved()
        .history
        .iter()
        .map(|e| [e.train, e.validation])
        .collect()
}

#[test]
fn a_training_killed_while_writing_its_checkpoint_resumes_exactly() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let straight = tmp.path().join("straight");
    train(&data, &tiny_config(3), &straight, &mut |_| ()).unwrap();
    // A run stopped after epoch 2's checkpoint, and the files epoch 3 writes before its state:
    // the state of a run killed in the middle of epoch 3's checkpoint.
    let killed = tmp.path().join("killed");
    let stop = |out: &Path, epochs: usize| {
        let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            train(&data, &tiny_config(3), out, &mut |e| {
                if matches!(e, plumenet::surrogate::TrainEvent::Epoch(r) if r.epoch == epochs) {
                    panic!("stopped");
                }
            })
        }));
    };
    stop(&killed, 2);
    let ahead = tmp.path().join("ahead");
    stop(&ahead, 3);
    for entry in std::fs::read_dir(ahead.join("checkpoint")).unwrap() {
        let entry = entry.unwrap();
        if entry.file_name() != "state.json" {
            std::fs::copy(
                entry.path(),
                killed.join("checkpoint").join(entry.file_name()),
            )
            .unwrap();
        }
    }
    // A write torn by the kill leaves a temporary file beside them.
    std::fs::write(
        killed.join("checkpoint").join(".model-3.bpk.tmp999"),
        b"torn",
    )
    .unwrap();
    train(&data, &tiny_config(3), &killed, &mut |_| ()).unwrap();
    assert_eq!(losses(&killed), losses(&straight));
    assert_eq!(
        Surrogate::load(&killed).unwrap().saved().weights_digest,
        Surrogate::load(&straight).unwrap().saved().weights_digest
    );
    // Only the last epoch's checkpoint is kept.
    let mut left: Vec<String> = std::fs::read_dir(killed.join("checkpoint"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["model-3.bpk", "optimizer-3.bin", "state.json"]);

    // A checkpoint in the format's first version (`model.bpk`, `optimizer.bin`) resumes the
    // same way, and the next checkpoint is written in the epoch-stamped form.
    let first = tmp.path().join("first");
    stop(&first, 2);
    let dir = first.join("checkpoint");
    std::fs::rename(dir.join("model-2.bpk"), dir.join("model.bpk")).unwrap();
    std::fs::rename(dir.join("optimizer-2.bin"), dir.join("optimizer.bin")).unwrap();
    train(&data, &tiny_config(3), &first, &mut |_| ()).unwrap();
    assert_eq!(losses(&first), losses(&straight));
    let mut left: Vec<String> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    left.sort();
    assert_eq!(left, ["model-3.bpk", "optimizer-3.bin", "state.json"]);

    // A damaged optimizer state is refused, not silently restarted.
    let damaged = tmp.path().join("damaged");
    stop(&damaged, 1);
    std::fs::write(damaged.join("checkpoint").join("optimizer-1.bin"), b"junk").unwrap();
    assert_err(
        train(&data, &tiny_config(3), &damaged, &mut |_| ()),
        "damaged optimizer checkpoint",
    );
}

#[test]
fn a_dataset_generation_that_stops_half_way_is_never_taken_for_complete() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("data");
    let config = |seed| GenerateConfig {
        distribution: Distribution::Base {
            base: Layout::from_json(ROOM).unwrap().spec().clone(),
            params: GenerateParams::default(),
        },
        layouts: 2,
        sources_per_layout: 2,
        seed,
        shard: None,
    };
    dataset::generate(&config(1), &out, &|| ()).unwrap();
    let first = std::fs::read(out.join("concentration.npy")).unwrap();
    // Another generation into the same folder stops half way (here its last array cannot be
    // written): the first dataset's manifest is gone with it.
    std::fs::remove_file(out.join("concentration.npy")).unwrap();
    std::fs::create_dir(out.join("concentration.npy")).unwrap();
    assert_err(dataset::generate(&config(2), &out, &|| ()), "cannot write");
    assert!(!out.join("manifest.json").exists());
    assert_err(TrainingData::load(&out), "cannot read");
    // Re-running the first generation makes it again, byte for byte.
    std::fs::remove_dir(out.join("concentration.npy")).unwrap();
    dataset::generate(&config(1), &out, &|| ()).unwrap();
    assert_eq!(std::fs::read(out.join("concentration.npy")).unwrap(), first);
    assert_eq!(
        read_npy::<u32, Ix1>(&out.join("source_layout.npy")).unwrap(),
        Array1::from(vec![0u32, 0, 1, 1])
    );
}
