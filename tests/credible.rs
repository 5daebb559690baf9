//! Credible regions and the source's level, against their definitions computed by brute force:
//! a region is the smallest set of cells holding the mass, the source's level is the smallest
//! level whose region holds it, and a calibrated posterior gives uniform levels.

use plumenet::ste::Uncertainty;
use plumenet::ste::credible::{cell_area_m2, credible_set, outline, pit};
use proptest::prelude::*;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A grid of `nx` x `ny` candidates `spacing` apart, the first at half a spacing from 0.
fn grid(nx: usize, ny: usize, spacing: f64) -> Vec<[f64; 2]> {
    let at = |k: usize| (k as f64 + 0.5) * spacing;
    (0..ny)
        .flat_map(|j| (0..nx).map(move |i| [at(i), at(j)]))
        .collect()
}

fn normalised(w: &[f64]) -> Vec<f64> {
    let total: f64 = w.iter().sum();
    w.iter().map(|v| v / total).collect()
}

/// A candidate drawn from the posterior `p`: the source of a run whose posterior is calibrated.
fn draw(candidates: &[[f64; 2]], p: &[f64], rng: &mut ChaCha8Rng) -> [f64; 2] {
    let u: f64 = rng.random();
    let mut acc = 0.0;
    let k = p.iter().position(|&q| {
        acc += q;
        acc > u
    });
    candidates[k.unwrap_or(p.len() - 1)]
}

#[test]
fn regions_of_a_known_posterior() {
    // Four cells with masses 0.5, 0.25, 0.1875, 0.0625 (in scrambled order; sums exact in
    // binary floating point).
    let candidates = grid(4, 1, 0.5);
    let posterior = [0.1875, 0.5, 0.0625, 0.25];
    let u = Uncertainty::of(&candidates, &posterior, candidates[1], Some(candidates[0]));
    let r50 = u.region(0.5).unwrap();
    let r90 = u.region(0.9).unwrap();
    // 0.5 reaches 50% alone; 90% needs three cells (0.5 + 0.25 + 0.1875).
    assert_eq!(r50.cells, vec![candidates[1]]);
    assert_eq!(r90.cells, vec![candidates[1], candidates[3], candidates[0]]);
    assert!((r50.area_m2 - 0.25).abs() < 1e-12);
    assert!((r90.area_m2 - 3.0 * 0.25).abs() < 1e-12);
    // The source's cell (mass 0.1875) is ranked after 0.5 and 0.25: level 0.75.
    let s = u.source.unwrap();
    assert!((s.level - 0.75).abs() < 1e-12);
    assert!((s.log_posterior - 0.1875f64.ln()).abs() < 1e-12);
    assert_eq!(r50.covers_source, Some(false));
    assert_eq!(r90.covers_source, Some(true));
    // Expected distance from the estimate: 0.1875 * 0.5 + 0.0625 * 0.5 + 0.25 * 1.0.
    assert!((u.expected_distance_m - 0.375).abs() < 1e-12);
}

#[test]
fn without_a_source_nothing_is_scored() {
    let candidates = grid(3, 3, 0.25);
    let posterior = vec![1.0 / 9.0; 9];
    let u = Uncertainty::of(&candidates, &posterior, candidates[4], None);
    assert!(u.source.is_none());
    assert!(u.regions.iter().all(|r| r.covers_source.is_none()));
    // A flat posterior over 9 cells: 5 cells reach 50%, 9 cells reach 90%.
    assert_eq!(u.region(0.5).unwrap().cells.len(), 5);
    assert_eq!(u.region(0.9).unwrap().cells.len(), 9);
}

#[test]
fn a_source_on_a_cell_border_takes_the_most_probable_of_its_cells() {
    // 2 x 2 cells of 0.5 m; the source at their common corner (0.5, 0.5).
    let candidates = grid(2, 2, 0.5);
    let posterior = [0.1, 0.2, 0.6, 0.1];
    let u = Uncertainty::of(&candidates, &posterior, candidates[2], Some([0.5, 0.5]));
    let s = u.source.unwrap();
    assert_eq!(s.cell, candidates[2]);
    assert_eq!(s.level, 0.0);
    assert_eq!(u.region(0.5).unwrap().covers_source, Some(true));
}

#[test]
fn cell_area_of_regular_grids() {
    assert!((cell_area_m2(&grid(5, 3, 0.25)) - 0.0625).abs() < 1e-12);
    assert!((cell_area_m2(&grid(5, 1, 0.5)) - 0.25).abs() < 1e-12);
    assert_eq!(cell_area_m2(&grid(1, 1, 0.5)), 0.0);
    // A grid with holes (cells left out inside obstacles) keeps its spacing.
    let holed: Vec<[f64; 2]> = grid(6, 4, 0.25)
        .into_iter()
        .enumerate()
        .filter(|(k, _)| k % 3 != 1)
        .map(|(_, c)| c)
        .collect();
    assert!((cell_area_m2(&holed) - 0.0625).abs() < 1e-12);
}

#[test]
fn outline_of_a_block_is_its_perimeter() {
    // A 2 x 3 block of 0.5 m cells: perimeter 2 * (1.0 + 1.5) = 5 m in 10 unit sides.
    let cells = grid(2, 3, 0.5);
    let sides = outline(&cells, 0.5);
    assert_eq!(sides.len(), 10);
    let length: f64 = sides
        .iter()
        .map(|[a, b]| (b[0] - a[0]).hypot(b[1] - a[1]))
        .sum();
    assert!((length - 5.0).abs() < 1e-12);
    // Every side lies on the block's boundary.
    for [a, b] in &sides {
        for p in [a, b] {
            let on_x = p[0].abs() < 1e-12 || (p[0] - 1.0).abs() < 1e-12;
            let on_y = p[1].abs() < 1e-12 || (p[1] - 1.5).abs() < 1e-12;
            assert!(on_x || on_y, "{p:?} is inside the block");
        }
    }
    assert!(outline(&[], 0.5).is_empty());
}

#[test]
fn levels_of_a_calibrated_posterior_are_uniform() {
    // Draw the source from the posterior itself: the region at level L then holds it with
    // probability L up to the cells' discreteness (at most the largest cell mass), and the
    // levels are uniform on [0, 1).
    let candidates = grid(10, 8, 0.25);
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let runs = 4000;
    let mut levels = Vec::with_capacity(runs);
    let (mut hits50, mut hits90) = (0, 0);
    let mut largest: f64 = 0.0;
    for _ in 0..runs {
        let w: Vec<f64> = (0..candidates.len())
            .map(|_| rng.random::<f64>().powi(4))
            .collect();
        let p = normalised(&w);
        largest = largest.max(p.iter().copied().fold(0.0, f64::max));
        let source = draw(&candidates, &p, &mut rng);
        let un = Uncertainty::of(&candidates, &p, candidates[0], Some(source));
        levels.push(un.source.unwrap().level);
        hits50 += usize::from(un.region(0.5).unwrap().covers_source.unwrap());
        hits90 += usize::from(un.region(0.9).unwrap().covers_source.unwrap());
    }
    // Binomial standard error at 4000 runs is under 0.008; allow 4 of them plus a cell.
    let tolerance = 4.0 * (0.25f64 / runs as f64).sqrt() + largest;
    let share = |h: usize| h as f64 / runs as f64;
    assert!((share(hits50) - 0.5).abs() < tolerance, "{}", share(hits50));
    assert!((share(hits90) - 0.9).abs() < tolerance, "{}", share(hits90));
    // Kolmogorov-Smirnov distance of the levels from uniform, within the 1% critical value
    // (1.63 / sqrt(n)) plus the cells' discreteness.
    levels.sort_by(f64::total_cmp);
    let ks = levels
        .iter()
        .enumerate()
        .map(|(i, &l)| {
            (l - i as f64 / runs as f64)
                .abs()
                .max((l - (i + 1) as f64 / runs as f64).abs())
        })
        .fold(0.0, f64::max);
    assert!(
        ks < 1.63 / (runs as f64).sqrt() + largest,
        "KS distance {ks}"
    );
}

/// A sharp posterior's regions overshoot their level by their last cell's share, so a
/// calibrated posterior's 50% regions hold the source in more than half of the runs: in the
/// share their mean mass says. The nonrandomised PIT of the source's cell has no such bias:
/// its mean at every level is the level.
#[test]
fn sharp_calibrated_posteriors_cover_by_their_regions_mass() {
    let candidates = grid(10, 8, 0.25);
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    let runs = 4000;
    let levels = [0.1, 0.3, 0.5, 0.7, 0.9];
    let (mut hits, mut masses, mut pits) = ([0usize; 2], [0.0f64; 2], [0.0f64; 5]);
    for _ in 0..runs {
        // A peak on a random cell whose neighbours fall off by a random factor: the most
        // probable cell holds a third to nearly all of the mass.
        let peak = candidates[rng.random_range(0..candidates.len())];
        let width = rng.random_range(0.08..0.3);
        let w: Vec<f64> = candidates
            .iter()
            .map(|c| {
                (-((c[0] - peak[0]).powi(2) + (c[1] - peak[1]).powi(2)) / (2.0 * width * width))
                    .exp()
            })
            .collect();
        let p = normalised(&w);
        let source = draw(&candidates, &p, &mut rng);
        let un = Uncertainty::of(&candidates, &p, peak, Some(source));
        for (j, at) in [0.5, 0.9].into_iter().enumerate() {
            let region = un.region(at).unwrap();
            hits[j] += usize::from(region.covers_source.unwrap());
            masses[j] += region.mass.unwrap();
        }
        let score = un.source.unwrap();
        for (j, &at) in levels.iter().enumerate() {
            pits[j] += score.pit(at);
            assert_eq!(score.pit(at), pit(score.level, score.log_posterior, at));
        }
    }
    let n = runs as f64;
    // Binomial standard error at 4000 runs is under 0.008: allow 4 of them.
    let tolerance = 4.0 * (0.25 / n).sqrt();
    let mean_mass = masses.map(|m| m / n);
    assert!(
        mean_mass[0] > 0.6,
        "the 50% regions overshoot: {mean_mass:?}"
    );
    for j in 0..2 {
        let share = hits[j] as f64 / n;
        assert!(
            (share - mean_mass[j]).abs() < tolerance,
            "{share} against {mean_mass:?}"
        );
    }
    assert!(hits[0] as f64 / n - 0.5 > 3.0 * tolerance, "{}", hits[0]);
    for (j, &at) in levels.iter().enumerate() {
        assert!(
            (pits[j] / n - at).abs() < tolerance,
            "PIT at {at}: {}",
            pits[j] / n
        );
    }
}

/// The nonrandomised PIT spreads the source's cell over the levels it spans: zero below its
/// level, one above the level plus its mass, linear between; a cell the prior excluded is a
/// step at its level.
#[test]
fn the_pit_spreads_the_source_cell_over_its_levels() {
    let lp = 0.4f64.ln();
    assert_eq!(pit(0.3, lp, 0.2), 0.0);
    assert!((pit(0.3, lp, 0.5) - 0.5).abs() < 1e-12);
    assert_eq!(pit(0.3, lp, 0.75), 1.0);
    assert_eq!(pit(0.3, f64::NEG_INFINITY, 0.3), 0.0);
    assert_eq!(pit(0.3, f64::NEG_INFINITY, 0.31), 1.0);
}

proptest! {
    #![proptest_config(crate::common::proptest_config(64))]

    /// The region at a level is the smallest set reaching it: brute force over subsets
    /// counts the fewest cells whose mass reaches the level.
    #[test]
    fn region_is_the_smallest_set_reaching_the_level(
        w in prop::collection::vec(0.001f64..1.0, 1..9),
        level in 0.05f64..0.99,
    ) {
        let p = normalised(&w);
        let set = credible_set(&p, level);
        let mass: f64 = set.iter().map(|&k| p[k]).sum();
        prop_assert!(mass >= level - 1e-12);
        let n = p.len();
        let fewest = (0u32..1 << n)
            .filter(|m| (0..n).filter(|&k| m >> k & 1 == 1).map(|k| p[k]).sum::<f64>() >= level - 1e-12)
            .map(|m| m.count_ones() as usize)
            .min()
            .unwrap();
        prop_assert_eq!(set.len(), fewest);
    }

    /// The region at level L covers the source exactly when the source's level is below L.
    #[test]
    fn covers_exactly_below_the_source_level(
        w in prop::collection::vec(0.001f64..1.0, 2..30),
        pick in 0usize..30,
    ) {
        let p = normalised(&w);
        let candidates = grid(p.len(), 1, 0.25);
        let source = candidates[pick % p.len()];
        let u = Uncertainty::of(&candidates, &p, candidates[0], Some(source));
        let level = u.source.unwrap().level;
        for r in &u.regions {
            prop_assert_eq!(r.covers_source, Some(level < r.level));
            prop_assert_eq!(r.cells.contains(&source), level < r.level);
        }
    }
}

/// Records written before the uncertainty and the tempered likelihood existed read as what
/// they meant: readings independent, the entropy rule with a fixed budget, no regions.
#[test]
fn records_without_the_new_fields_stay_readable() {
    use plumenet::ste::{Feature, SteParams, Termination};
    use plumenet::study::experiment::RunRow;
    let rank = SteParams::for_feature(Feature::Rank);
    let mut v = serde_json::to_value(rank).unwrap();
    for key in [
        "evidence_weight",
        "evidence_saturation",
        "fit_reference",
        "misfit_reference",
        "background_odds",
        "model_rank_factor",
    ] {
        v.as_object_mut().unwrap().remove(key).unwrap();
    }
    let old: SteParams = serde_json::from_value(v).unwrap();
    assert_eq!((old.evidence_weight, old.fit_reference), (1.0, None));
    assert_eq!(old.evidence_saturation, None);
    assert_eq!(old.misfit_reference, None);
    // Saturating evidence: each of n readings weighs W 2S / (S + n), W at n = S, and all of
    // them together approach 2S readings of weight W.
    let saturating = SteParams {
        evidence_saturation: Some(3000.0),
        ..rank
    };
    assert!((saturating.reading_weight(0) - 0.4).abs() < 1e-15);
    assert!((saturating.reading_weight(3000) - 0.2).abs() < 1e-15);
    let total = |n: usize| n as f64 * saturating.reading_weight(n);
    assert!(total(1_000_000) < 2.0 * 3000.0 * 0.2 && total(1_000_000) > 0.99 * 1200.0);
    assert_eq!(rank.reading_weight(5000), rank.evidence_weight);
    assert_eq!(old.rank.model_rank_factor, 1.0, "exact model ranks");
    assert_eq!(old.background_odds, None);
    assert_eq!(old.background_odds(), 1.0, "all three rises equally likely");
    // The calibrated default makes a rise unlikely; set, the odds stay what they are.
    assert_eq!(rank.background_odds(), 0.01);
    let set = SteParams {
        background_odds: Some(0.5),
        ..rank
    };
    assert_eq!(set.background_odds(), 0.5);
    // The tempered likelihood knows no model's ranks closer than its floor; independent
    // readings take the model's own factor, and a wider one stays.
    assert_eq!(rank.rank.model_rank_factor, 1.5);
    for (weight, own, expected) in [
        (0.2, 1.0, 1.5),
        (0.2, 3.0, 3.0),
        (1.0, 1.0, 1.0),
        (1.0, 3.0, 3.0),
    ] {
        let p = SteParams {
            evidence_weight: weight,
            ..rank
        };
        assert_eq!(
            p.rank_factor_for(own),
            expected,
            "weight {weight}, own {own}"
        );
    }
    assert_eq!(
        SteParams::for_model(Feature::Rank, 3.0)
            .rank
            .model_rank_factor,
        3.0
    );
    // The misfit check goes with the tempered likelihood, for every plume model; the check
    // per reading only for an exact one.
    for (own, fit) in [(1.0, Some(0.02)), (3.0, None)] {
        let p = SteParams::for_model(Feature::Rank, own);
        assert_eq!((p.misfit_reference, p.fit_reference), (Some(50.0), fit));
    }
    for (weight, misfit, fit) in [(0.2, Some(50.0), Some(0.02)), (1.0, None, None)] {
        let p = SteParams {
            evidence_weight: weight,
            ..rank
        };
        assert_eq!(p.misfit_reference_for(), misfit, "weight {weight}");
        assert_eq!(p.fit_reference_for(1.0), fit, "weight {weight}");
        assert_eq!(p.fit_reference_for(3.0), None, "weight {weight}");
    }
    // The planner's revisit radius goes with the exact model and the tempered likelihood.
    for (weight, exact, other) in [(0.2, 0.25, 0.0), (1.0, 0.0, 0.0)] {
        let p = SteParams {
            evidence_weight: weight,
            ..rank
        };
        assert_eq!(p.revisit_radius_for(1.0), exact, "weight {weight}");
        assert_eq!(p.revisit_radius_for(3.0), other, "weight {weight}");
    }
    let paper = rank.papers_rank();
    assert_eq!((paper.misfit_reference, paper.fit_reference), (None, None));
    assert_eq!(paper.revisit_radius_for(1.0), 0.0);
    let mut t = serde_json::to_value(Termination::for_params(&rank)).unwrap();
    assert_eq!(t["target_area_m2"], 1.0);
    assert_eq!(t["region_radius_m"], 1.5);
    for key in ["target_area_m2", "grow_with_room", "region_radius_m"] {
        t.as_object_mut().unwrap().remove(key).unwrap();
    }
    let old: Termination = serde_json::from_value(t).unwrap();
    assert_eq!(
        (old.target_area_m2, old.grow_with_room, old.region_radius_m),
        (None, false, None)
    );
    // A study's runs.csv from before the uncertainty columns.
    let csv = "layout,model,reality,paths,feature,sensor,run,seed,source_x,source_y,start_x,\
        start_y,estimate_x,estimate_y,error_m,highest_x,highest_y,highest_error_m,\
        centre_error_m,iterations,converged,samples,distance_m,wall_time_s,fit\n\
        wind-tunnel,solver,none,planner,rank,sensor-ii,0,1,1,2,15,1,1.2,2,0.2,2,2,1,4,12,true,\
        100,10,0.1,0.01\n";
    let mut reader = csv::Reader::from_reader(csv.as_bytes());
    let rows: Vec<RunRow> = reader.deserialize().collect::<Result<_, _>>().unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!((rows[0].covers_50, rows[0].covers_90), (None, None));
    assert!(rows[0].area_90_m2.is_nan() && rows[0].source_level.is_nan());
    assert!(rows[0].mass_50.is_nan() && rows[0].mass_90.is_nan());
    assert_eq!(rows[0].error_m, 0.2);
    // A region from before its mass was recorded.
    let candidates = grid(4, 2, 0.25);
    let u = Uncertainty::of(&candidates, &normalised(&[1.0; 8]), [0.0, 0.0], None);
    let mut region = serde_json::to_value(u.region(0.5).unwrap()).unwrap();
    assert_eq!(region["mass"], 0.5);
    region.as_object_mut().unwrap().remove("mass").unwrap();
    let old: plumenet::ste::CredibleRegion = serde_json::from_value(region).unwrap();
    assert_eq!((old.cells.len(), old.mass), (4, None));
}
