//! Thread count changes no result bit: the solver's bank, PlumeNet's bank, a localisation run
//! and a training run are compared on pools of 1 and 2 threads (every parallel loop of the
//! crate, Burn's backend included, runs on the current rayon pool).

use plumenet::Surrogate;
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;
use plumenet::plume::{PhysicsSolver, PlumeModel};
use plumenet::sim::{EpisodeConfig, World, run_episode};
use plumenet::ste::{Feature, SensorPreset};
use plumenet::surrogate::saved::weights_digest;
use plumenet::surrogate::train;

use crate::common::{repo_path, wind_tunnel};
use crate::surrogate::{tiny_config, tiny_dataset};

/// `f` run on a pool of 1 thread and on a pool of 2.
fn on_one_and_two_threads<T: Send>(f: impl Fn() -> T + Sync) -> [T; 2] {
    [1, 2].map(|threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(&f)
    })
}

#[test]
fn the_solvers_bank_is_bit_identical_on_one_and_two_threads() {
    let l = wind_tunnel();
    let candidates = l.candidates(0.25).unwrap();
    let [one, two] = on_one_and_two_threads(|| {
        let wind = WindField::solve(&l).unwrap();
        let transport = Transport::new(&l, &wind).unwrap();
        (wind, transport.bank(&candidates).unwrap())
    });
    assert!(one.0 == two.0, "wind fields differ");
    assert!(one.1 == two.1, "banks differ");
}

#[test]
fn plumenets_bank_is_bit_identical_on_one_and_two_threads() {
    let model = Surrogate::load(&repo_path("models/default")).unwrap();
    let l = wind_tunnel();
    // Enough candidates for several batches, so that the batches and the convolutions split.
    let candidates: Vec<[f64; 2]> = l
        .candidates(0.25)
        .unwrap()
        .into_iter()
        .step_by(37)
        .collect();
    let [one, two] = on_one_and_two_threads(|| model.bank(&l, &candidates).unwrap());
    assert!(one.fields == two.fields, "PlumeNet banks differ");
}

#[test]
fn a_localisation_run_is_bit_identical_on_one_and_two_threads() {
    let (world, _) = World::build(wind_tunnel(), &PhysicsSolver, 0.25, None).unwrap();
    let config = EpisodeConfig::new(Feature::Rank, SensorPreset::SensorII);
    let [one, two] = on_one_and_two_threads(|| {
        let mut run = run_episode(&world, &config, [4.5, 2.5], [15.0, 1.0], 7, true).unwrap();
        run.wall_time_s = 0.0;
        serde_json::to_string(&run).unwrap()
    });
    assert!(one == two, "runs differ");
}

#[test]
fn a_training_run_is_bit_identical_on_one_and_two_threads() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tiny_dataset(&tmp.path().join("data"));
    let [one, two] = on_one_and_two_threads(|| {
        let dir = tempfile::tempdir_in(tmp.path()).unwrap();
        let state = train(&data, &tiny_config(2), dir.path(), &mut |_| ()).unwrap();
        let losses: Vec<[f64; 2]> = state
            .history
            .iter()
            .map(|e| [e.train, e.validation])
            .collect();
        let model = Surrogate::load(dir.path()).unwrap();
        (losses, weights_digest(model.net()).unwrap())
    });
    assert_eq!(one, two, "trainings differ");
}
