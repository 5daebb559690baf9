//! Layout contract: parsing, every validation rule, rasterisation, signed distance, candidates.

use plumenet::Error;
use plumenet::layout::{DEFAULT_DIFFUSIVITY_M2PS, Layout};

use crate::common::{assert_err, repo_path, wind_tunnel};

fn layout_err(json: &str) -> String {
    match Layout::from_json(json) {
        Err(Error::Layout(msg)) => msg,
        other => panic!("expected a layout error for {json}, got {other:?}"),
    }
}

fn with(fields: &str, obstacles: &str) -> String {
    format!(r#"{{{fields}, "wind": {{"speed_mps": 0.75}}, "obstacles": [{obstacles}]}}"#)
}

const ARENA: &str = r#""width_m": 18, "height_m": 4, "cell_m": 0.125"#;

#[test]
fn shipped_wind_tunnel_is_the_paper_arena() {
    let l = wind_tunnel();
    assert_eq!(l.shape(), (32, 144));
    assert_eq!(l.spec().obstacles.len(), 2);
    assert_eq!(l.diffusivity(), DEFAULT_DIFFUSIVITY_M2PS);
    // Two 1.0 m x 1.25 m blocks = 8 x 10 cells each.
    assert_eq!(l.solid().iter().filter(|s| **s).count(), 2 * 8 * 10);
    // Free floor: 72 m² less the two 1.25 m² blocks.
    assert!((l.free_area_m2() - (72.0 - 2.0 * 1.25)).abs() < 1e-12);
}

#[test]
fn every_bad_layout_is_rejected_with_its_reason() {
    let cases = [
        (with(r#""width_m": -18, "height_m": 4, "cell_m": 0.125"#, ""), "width_m must be a positive"),
        (with(r#""width_m": 18, "height_m": 0, "cell_m": 0.125"#, ""), "height_m must be a positive"),
        (with(r#""width_m": 18, "height_m": 4, "cell_m": 0.3"#, ""), "does not divide"),
        (with(r#""width_m": 1, "height_m": 4, "cell_m": 0.5"#, ""), "at least 4"),
        (with(ARENA, r#"{"x_min": 17, "y_min": 1, "x_max": 19, "y_max": 2}"#), "leaves the arena"),
        (with(ARENA, r#"{"x_min": 5, "y_min": 2, "x_max": 4, "y_max": 3}"#), "x_min < x_max"),
        (with(ARENA, r#"{"x_min": 5.0, "y_min": 2.0, "x_max": 5.05, "y_max": 2.05}"#), "covers no cell"),
        (with(ARENA, r#"{"x_min": 5, "y_min": 0, "x_max": 6, "y_max": 4}"#), "block the channel"),
        (
            with(
                ARENA,
                r#"{"x_min": 5, "y_min": 1, "x_max": 8, "y_max": 1.5}, {"x_min": 5, "y_min": 2.5, "x_max": 8, "y_max": 3},
                   {"x_min": 5, "y_min": 1, "x_max": 5.5, "y_max": 3}, {"x_min": 7.5, "y_min": 1, "x_max": 8, "y_max": 3}"#,
            ),
            "enclosed",
        ),
        (r#"{"width_m": 18}"#.to_string(), "malformed JSON"),
        (r#"{"width_m": 18, "height_m": 4, "cell_m": 0.125, "wind": {"speed_mps": 0.75}, "extra": 1}"#.to_string(), "unknown field"),
        (with(ARENA, "").replace("0.75", "0"), "speed_mps must be a positive"),
        (with(ARENA, "").replace("\"obstacles\"", "\"diffusivity_m2ps\": -1, \"obstacles\""), "diffusivity_m2ps"),
    ];
    for (json, reason) in cases {
        let msg = layout_err(&json);
        assert!(
            msg.contains(reason),
            "{json}: expected {reason:?} in {msg:?}"
        );
    }
}

#[test]
fn missing_and_truncated_files_are_errors() {
    assert!(matches!(
        Layout::load(&repo_path("data/layouts/nope.json")),
        Err(Error::Io { .. })
    ));
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cut.json");
    let text = std::fs::read_to_string(repo_path("data/layouts/wind-tunnel.json")).unwrap();
    std::fs::write(&path, &text[..text.len() / 2]).unwrap();
    let msg = Layout::load(&path).unwrap_err().to_string();
    assert!(
        msg.contains("cut.json") && msg.contains("malformed JSON"),
        "{msg}"
    );
}

#[test]
fn sources_outside_inside_or_nan_are_rejected() {
    let l = wind_tunnel();
    assert!(l.check_source(3.0, 2.0).is_ok());
    for (x, y, reason) in [
        (-1.0, 2.0, "outside the arena"),
        (3.0, 4.0, "outside the arena"),
        (7.0, 1.2, "inside obstacle 0"),
        (f64::NAN, 1.0, "finite"),
        (3.0, f64::INFINITY, "finite"),
    ] {
        let msg = l.check_source(x, y).unwrap_err().to_string();
        assert!(msg.contains(reason), "({x}, {y}): {msg}");
    }
}

#[test]
fn signed_distance_is_negative_inside_and_exact_outside() {
    let l = wind_tunnel();
    let sdf = l.signed_distance();
    for ((j, i), &d) in sdf.indexed_iter() {
        assert_eq!(
            d < 0.0,
            l.is_solid(j, i),
            "cell ({j}, {i}) has distance {d}"
        );
    }
    // Brute force: the nearest of many points sampled every millimetre along each obstacle's
    // perimeter, and the walls.
    let perimeter: Vec<(f64, f64)> = l
        .spec()
        .obstacles
        .iter()
        .flat_map(|o| {
            let (w, h) = (o.x_max - o.x_min, o.y_max - o.y_min);
            let n = ((2.0 * (w + h)) / 1e-3) as usize;
            (0..n).map(move |k| {
                let s = k as f64 * 1e-3;
                if s < w {
                    (o.x_min + s, o.y_min)
                } else if s < w + h {
                    (o.x_max, o.y_min + s - w)
                } else if s < 2.0 * w + h {
                    (o.x_max - (s - w - h), o.y_max)
                } else {
                    (o.x_min, o.y_max - (s - 2.0 * w - h))
                }
            })
        })
        .collect();
    for (j, i) in [(16, 40), (3, 60), (30, 100), (20, 84)] {
        let (x, y) = l.cell_centre(j, i);
        let brute = perimeter
            .iter()
            .map(|&(px, py)| (px - x).hypot(py - y))
            .fold(y.min(4.0 - y), f64::min);
        let brute = if l.is_solid(j, i) { -brute } else { brute };
        assert!(
            (sdf[[j, i]] - brute).abs() < 1e-3,
            "({j}, {i}): {} vs {brute}",
            sdf[[j, i]]
        );
    }
}

#[test]
fn candidates_cover_free_space_on_the_quarter_metre_grid() {
    let l = wind_tunnel();
    let c = l.candidates(0.25).unwrap();
    // 72 x 16 points minus those inside the two 1.0 x 1.2 m obstacles (4 x 5 each).
    assert_eq!(c.len(), 72 * 16 - 2 * 4 * 5);
    assert!(c.iter().all(|&[x, y]| l.is_free(x, y)));
    assert_err(
        l.candidates(0.2),
        "candidate spacing 0.2 m must be a positive multiple of the cell size 0.125 m",
    );
}
