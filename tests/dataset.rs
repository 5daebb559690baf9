//! Dataset generation: determinism, shards + merge, manifest checks, random layouts and rooms.

use std::path::Path;

use crate::common::assert_err;
use ndarray::{Array1, Ix1};
use plumenet::dataset::{
    self, Distribution, GenerateConfig, GenerateParams, Manifest, RoomParams, Shard,
};
use plumenet::frame::Frame;
use plumenet::io::read_npy;
use plumenet::layout::{Layout, LayoutSpec, WindFrom};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

fn base() -> LayoutSpec {
    // A coarse grid keeps the tests fast; the code path is the same.
    Layout::from_json(r#"{"width_m":18,"height_m":4,"cell_m":0.25,"wind":{"speed_mps":0.75}}"#)
        .unwrap()
        .spec()
        .clone()
}

fn config(shard: Option<Shard>) -> GenerateConfig {
    GenerateConfig {
        distribution: Distribution::Base {
            base: base(),
            params: GenerateParams::default(),
        },
        layouts: 3,
        sources_per_layout: 2,
        seed: 11,
        shard,
    }
}

/// Small rooms on a coarse grid, so that generating them is quick.
pub fn small_rooms() -> RoomParams {
    RoomParams {
        width_m: [4, 8],
        height_m: [3, 5],
        cell_m: 0.25,
        ..RoomParams::default()
    }
}

fn rooms_config(shard: Option<Shard>) -> GenerateConfig {
    GenerateConfig {
        distribution: Distribution::Rooms {
            params: small_rooms(),
        },
        layouts: 5,
        sources_per_layout: 2,
        seed: 3,
        shard,
    }
}

fn bytes(dir: &Path) -> Vec<(String, Vec<u8>)> {
    let mut files: Vec<_> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().path())
        .map(|p| {
            (
                p.file_name().unwrap().to_string_lossy().into_owned(),
                std::fs::read(&p).unwrap(),
            )
        })
        .collect();
    files.sort();
    files
}

#[test]
fn rooms_are_reproducible_and_shard_like_one_run() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    let m = dataset::generate(&rooms_config(None), &a, &|| ()).unwrap();
    dataset::generate(&rooms_config(None), &b, &|| ()).unwrap();
    assert_eq!(bytes(&a), bytes(&b));
    let shards: Vec<_> = (0..3)
        .map(|k| tmp.path().join(format!("shard{k}")))
        .collect();
    for (k, dir) in shards.iter().enumerate() {
        dataset::generate(
            &rooms_config(Some(Shard { index: k, count: 3 })),
            dir,
            &|| (),
        )
        .unwrap();
    }
    let merged = tmp.path().join("merged");
    let paths: Vec<&Path> = shards.iter().rev().map(|p| p.as_path()).collect();
    dataset::merge(&paths, &merged).unwrap();
    assert_eq!(bytes(&a), bytes(&merged));
    // The manifest records the distribution, and the rooms differ in size.
    assert_eq!(
        m.distribution,
        Distribution::Rooms {
            params: small_rooms()
        }
    );
    let sizes: std::collections::BTreeSet<_> = m
        .layouts
        .iter()
        .map(|l| (l.width_m as u32, l.height_m as u32))
        .collect();
    assert!(sizes.len() > 1, "{sizes:?}");
    let cells: usize = m
        .layouts
        .iter()
        .map(|l| dataset::grid_of(l).0 * dataset::grid_of(l).1)
        .sum();
    assert_eq!(m.arrays["concentration"].shape, vec![2 * cells]);
    assert_eq!(m.arrays["wind"].shape, vec![2 * cells]);
}

#[test]
fn random_rooms_follow_the_distribution_and_the_rules() {
    let params = RoomParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(9);
    let mut directions = std::collections::BTreeSet::new();
    let (mut small, mut large) = (Vec::new(), Vec::new());
    for _ in 0..150 {
        let l = dataset::random_room(&params, &mut rng).unwrap();
        let (w, h, u) = (l.width(), l.height(), l.wind_speed());
        assert!(w.fract() == 0.0 && (6.0..=30.0).contains(&w), "width {w}");
        assert!(h.fract() == 0.0 && (3.0..=12.0).contains(&h), "height {h}");
        assert!((0.25..=1.5).contains(&u), "speed {u}");
        assert_eq!(l.cell(), 0.125);
        directions.insert(l.wind_from().name());
        let count = l.spec().obstacles.len();
        assert!(count >= 1);
        if w * h <= 60.0 {
            small.push(count as f64);
        } else if w * h > 150.0 {
            large.push(count as f64);
        }
        // In the canonical frame: every cross-section keeps min_gap free, and the inlet and
        // outlet columns are free.
        let c = Frame::of(&l).layout_to_canonical(&l).unwrap();
        for col in c.solid().columns() {
            let free = col.iter().filter(|s| !**s).count() as f64 * c.cell();
            assert!(free >= params.min_gap_m - 1e-9);
        }
        let solid = c.solid();
        let last = c.nx() - 1;
        assert!((0..c.ny()).all(|j| !solid[[j, 0]] && !solid[[j, last]]));
    }
    assert_eq!(directions.len(), 4, "{directions:?}");
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    assert!(
        mean(&large) > 2.0 * mean(&small),
        "obstacle groups grow with the floor area: {} small vs {} large",
        mean(&small),
        mean(&large)
    );
}

#[test]
fn bad_room_parameters_are_clear_errors() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let bad = [
        RoomParams {
            width_m: [10, 6],
            ..RoomParams::default()
        },
        RoomParams {
            cell_m: 0.3,
            ..RoomParams::default()
        },
        RoomParams {
            directions: Vec::new(),
            ..RoomParams::default()
        },
        RoomParams {
            speed_mps: [f64::NAN, 1.0],
            ..RoomParams::default()
        },
    ];
    for p in bad {
        let err = dataset::random_room(&p, &mut rng).unwrap_err().to_string();
        assert!(
            err.starts_with("room parameters") || err.contains("room parameters"),
            "{err}"
        );
    }
    // A room drawn with one direction only has that direction.
    let only_north = RoomParams {
        directions: vec![WindFrom::North],
        ..RoomParams::default()
    };
    let l = dataset::random_room(&only_north, &mut rng).unwrap();
    assert_eq!(l.wind_from(), WindFrom::North);
}

#[test]
fn same_seed_same_bytes_and_shards_merge_to_the_same_dataset() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = (tmp.path().join("a"), tmp.path().join("b"));
    dataset::generate(&config(None), &a, &|| ()).unwrap();
    dataset::generate(&config(None), &b, &|| ()).unwrap();
    assert_eq!(bytes(&a), bytes(&b));
    assert_eq!(
        bytes(&a).len(),
        7,
        "6 arrays + manifest, no temporary files left"
    );

    let shards: Vec<_> = (0..2)
        .map(|k| tmp.path().join(format!("shard{k}")))
        .collect();
    for (k, dir) in shards.iter().enumerate() {
        dataset::generate(&config(Some(Shard { index: k, count: 2 })), dir, &|| ()).unwrap();
    }
    let merged = tmp.path().join("merged");
    dataset::merge(&[shards[1].as_path(), shards[0].as_path()], &merged).unwrap();
    assert_eq!(bytes(&a), bytes(&merged));

    // A missing shard, or a shard of another dataset, is refused.
    assert_err(
        dataset::merge(&[shards[0].as_path()], &tmp.path().join("m2")),
        "shards cover 1 of 3 layouts; some shards are missing",
    );
    let other = tmp.path().join("other");
    let mut cfg = config(Some(Shard { index: 1, count: 2 }));
    cfg.seed = 12;
    dataset::generate(&cfg, &other, &|| ()).unwrap();
    let err = dataset::merge(
        &[shards[0].as_path(), other.as_path()],
        &tmp.path().join("m3"),
    )
    .unwrap_err();
    assert!(err.to_string().contains("different dataset"), "{err}");
}

#[test]
fn arrays_have_the_documented_shapes_and_contents() {
    let tmp = tempfile::tempdir().unwrap();
    let m = dataset::generate(&config(None), tmp.path(), &|| ()).unwrap();
    assert_eq!(Manifest::load(tmp.path()).unwrap(), m);
    let flat = |name: &str| read_npy::<f32, Ix1>(&tmp.path().join(name)).unwrap();
    let mask = flat("obstacle_mask.npy")
        .into_shape_with_order((3, 16, 72))
        .unwrap();
    let conc = flat("concentration.npy")
        .into_shape_with_order((6, 16, 72))
        .unwrap();
    let owner: Array1<u32> = read_npy::<u32, Ix1>(&tmp.path().join("source_layout.npy")).unwrap();
    assert_eq!(owner.to_vec(), vec![0, 0, 1, 1, 2, 2]);
    for s in 0..6 {
        let l = owner[s] as usize;
        for ((j, i), &c) in conc.index_axis(ndarray::Axis(0), s).indexed_iter() {
            assert!(c.is_finite() && c >= -1e-6);
            if mask[[l, j, i]] == 1.0 {
                assert_eq!(c, 0.0);
            }
        }
    }
    for (k, spec) in m.layouts.iter().enumerate() {
        let layout = spec.clone().check().unwrap();
        let expected = layout.solid().mapv(|s| if s { 1.0 } else { 0.0 });
        assert_eq!(mask.index_axis(ndarray::Axis(0), k), expected);
    }
}

#[test]
fn damaged_datasets_are_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    dataset::generate(&config(None), tmp.path(), &|| ()).unwrap();
    let conc = tmp.path().join("concentration.npy");
    let data = std::fs::read(&conc).unwrap();
    std::fs::write(&conc, &data[..data.len() - 100]).unwrap();
    let err = Manifest::load(tmp.path()).unwrap_err().to_string();
    assert!(err.contains("concentration.npy"), "{err}");
    // A dataset of the first generator version (one grid, before rooms) asks to be generated
    // again.
    let manifest = tmp.path().join("manifest.json");
    let text = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(
        &manifest,
        text.replace("\"generator_version\": 2", "\"generator_version\": 1"),
    )
    .unwrap();
    let err = Manifest::load(tmp.path()).unwrap_err().to_string();
    assert!(err.contains("generate the dataset again"), "{err}");
    std::fs::write(tmp.path().join("manifest.json"), "{ not json").unwrap();
    assert_err(Manifest::load(tmp.path()), "malformed JSON in");
    assert_err(Manifest::load(&tmp.path().join("missing")), "cannot read");
}

#[test]
fn random_layouts_are_valid_varied_and_never_block_the_channel() {
    let params = GenerateParams::default();
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let full = Layout::load(&crate::common::repo_path("data/layouts/wind-tunnel.json")).unwrap();
    let mut counts = [0usize; 5];
    let mut touching = 0;
    for _ in 0..200 {
        let l = dataset::random_layout(full.spec(), &params, &mut rng).unwrap();
        let n = l.spec().obstacles.len();
        counts[n] += 1;
        touching += usize::from(
            l.spec()
                .obstacles
                .iter()
                .any(|o| o.y_min == 0.0 || o.y_max == 4.0),
        );
        for col in l.solid().columns() {
            let free = col.iter().filter(|s| !**s).count() as f64 * l.cell();
            assert!(free >= params.min_gap_m);
        }
    }
    assert_eq!(counts[0], 0);
    assert!(
        counts[1..].iter().all(|&c| c > 20),
        "obstacle counts {counts:?}"
    );
    assert!(
        touching > 20 && touching < 200,
        "{touching} layouts touch a side wall"
    );
}

#[test]
fn bad_generator_settings_are_rejected() {
    let tmp = tempfile::tempdir().unwrap();
    let mut c = config(None);
    c.layouts = 0;
    assert_err(
        dataset::generate(&c, tmp.path(), &|| ()),
        "--layouts and --sources must be at least 1",
    );
    let mut c = config(Some(Shard { index: 0, count: 5 }));
    c.layouts = 3;
    assert_err(
        dataset::generate(&c, tmp.path(), &|| ()),
        "5 shards for 3 layouts would leave empty shards",
    );
    for s in ["2/2", "a/b", "1", "0/0"] {
        assert_err(s.parse::<Shard>(), "shard must be K/N with 0 <= K < N");
    }
}
