//! The reality plume: its time average converges to the mean field; single readings are
//! intermittent; runs are reproducible from the seed.

use plumenet::physics::filament::{FilamentConfig, FilamentPlume};
use plumenet::physics::transport::Transport;
use plumenet::physics::wind::WindField;

use crate::common::{empty_tunnel, wind_tunnel};

const SOURCE: (f64, f64) = (3.0, 2.0);
const PROBES: [(f64, f64); 6] = [
    (5.0, 2.0),
    (8.0, 2.0),
    (8.0, 2.6),
    (12.0, 2.0),
    (12.0, 1.0),
    (16.0, 2.0),
];

#[test]
fn long_time_average_converges_to_the_mean_field() {
    let l = empty_tunnel();
    let w = WindField::solve(&l).unwrap();
    let mean = Transport::new(&l, &w)
        .unwrap()
        .solve(SOURCE.0, SOURCE.1)
        .unwrap();
    let mut plume = FilamentPlume::new(&l, &w, SOURCE, FilamentConfig::default(), 7).unwrap();
    plume.advance(40.0); // one flow-through to fill the arena
    let steps = 20_000; // 2000 s at 10 Hz
    let mut sums = [0.0; PROBES.len()];
    for _ in 0..steps {
        plume.step();
        for (s, &(x, y)) in sums.iter_mut().zip(&PROBES) {
            *s += plume.concentration_at(x, y);
        }
    }
    let mut total = 0.0;
    for (s, &(x, y)) in sums.iter().zip(&PROBES) {
        let (j, i) = l.cell_of(x, y);
        let rel = (s / steps as f64 / mean[[j, i]] - 1.0).abs();
        total += rel;
        assert!(rel < 0.15, "probe ({x}, {y}): time average off by {rel}");
    }
    let mean_rel = total / PROBES.len() as f64;
    assert!(mean_rel < 0.06, "mean relative deviation {mean_rel}");
}

#[test]
fn single_readings_are_intermittent_and_reproducible() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let run = |seed| {
        let mut plume =
            FilamentPlume::new(&l, &w, SOURCE, FilamentConfig::default(), seed).unwrap();
        plume.advance(40.0);
        (0..3000)
            .map(|_| {
                plume.step();
                plume.concentration_at(8.0, 2.0)
            })
            .collect::<Vec<f64>>()
    };
    let series = run(3);
    assert_eq!(series, run(3));
    assert_ne!(series, run(4));
    let n = series.len() as f64;
    let avg = series.iter().sum::<f64>() / n;
    let sd = (series.iter().map(|c| (c - avg).powi(2)).sum::<f64>() / n).sqrt();
    let quiet = series.iter().filter(|&&c| c < 0.1 * avg).count() as f64 / n;
    assert!(sd / avg > 0.8, "coefficient of variation {}", sd / avg);
    assert!(
        quiet > 0.05,
        "only {quiet} of readings below 10% of the mean"
    );
}

#[test]
fn no_gas_inside_obstacles_and_bad_sources_rejected() {
    let l = wind_tunnel();
    let w = WindField::solve(&l).unwrap();
    let mut plume = FilamentPlume::new(&l, &w, (5.5, 1.2), FilamentConfig::default(), 1).unwrap();
    plume.advance(30.0);
    assert!(!plume.is_empty());
    assert_eq!(plume.concentration_at(7.0, 1.2), 0.0);
    assert!(FilamentPlume::new(&l, &w, (7.0, 1.2), FilamentConfig::default(), 1).is_err());
    let bad = FilamentConfig {
        walk_fraction: 1.5,
        ..FilamentConfig::default()
    };
    assert!(FilamentPlume::new(&l, &w, SOURCE, bad, 1).is_err());
}
