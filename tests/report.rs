//! Figures: the colours land on the right cells, text is drawn with the embedded font, the
//! colour bar is labelled, SVG carries the same text, box statistics follow the type-7 rule.

use ndarray::Array2;
use plumenet::report::boxplot::{BoxPanel, group_values};
use plumenet::report::{FieldPanel, FieldPlot, Panel, colour, save_figure};
use plumenet::stats::BoxStats;

use crate::common::wind_tunnel;

fn count(img: &image::RgbImage, rgb: [u8; 3]) -> usize {
    img.pixels().filter(|p| p.0 == rgb).count()
}

#[test]
fn a_field_figure_paints_cells_obstacles_text_and_a_labelled_log_bar() {
    let layout = wind_tunnel();
    let (ny, nx) = layout.shape();
    // A field that is 1 in one free cell and 1e-6 elsewhere.
    let mut field = Array2::from_elem((ny, nx), 1e-6);
    let (j, i) = (16, 20);
    assert!(!layout.is_solid(j, i));
    field[[j, i]] = 1.0;
    let plot = FieldPlot {
        title: "mean concentration".into(),
        log: true,
        unit: "concentration (units/m²)".into(),
    };
    let tmp = tempfile::tempdir().unwrap();
    let png = tmp.path().join("f.png");
    let panel = || Panel::Field(FieldPanel::new(field.clone(), &layout, plot.clone()).unwrap());
    save_figure(&[panel()], &png).unwrap();
    let img = image::open(&png).unwrap().to_rgb8();
    // 960 / 144 columns -> 6 pixels a cell.
    let s = 6;
    let top = colour(&colorous::VIRIDIS, 1.0);
    let bottom = colour(&colorous::VIRIDIS, 0.0);
    let solid = (0..ny)
        .flat_map(|j| (0..nx).map(move |i| (j, i)))
        .filter(|&(j, i)| layout.is_solid(j, i))
        .count();
    // The hot cell is one s x s square (the colour bar's top step is a near colour, not this).
    let hot = count(&img, [top.0, top.1, top.2]);
    assert!((s * s..=s * s + 30).contains(&hot), "{hot} hot pixels");
    // Values 6 decades below the maximum sit at the bottom of the 4-decade scale.
    let cold = count(&img, [bottom.0, bottom.1, bottom.2]);
    assert!(cold > (nx * ny - solid - 1) * s * s * 9 / 10, "{cold}");
    let grey = count(&img, [90, 90, 90]);
    let expected = solid * s * s;
    assert!(
        grey.abs_diff(expected) < expected / 20,
        "{grey} vs {expected}"
    );
    // Text was rasterised: dark pixels in the title band, left of the map.
    let dark = |x0: u32, x1: u32, y0: u32, y1: u32| {
        (y0..y1)
            .flat_map(|y| (x0..x1).map(move |x| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 100))
            .count()
    };
    assert!(dark(60, 400, 0, 30) > 150, "no title text");
    assert!(dark(0, 70, 40, 220) > 100, "no y tick labels");
    // The SVG holds the same figure with its text as text: the title, the unit and the
    // whole decades of the colour bar.
    let svg = tmp.path().join("f.svg");
    save_figure(&[panel()], &svg).unwrap();
    let doc = std::fs::read_to_string(&svg).unwrap();
    for label in [
        "mean concentration",
        "concentration (units/m²)",
        "x (m)",
        "y (m)",
        "1",
        "0.1",
        "0.01",
        "0.001",
    ] {
        assert!(doc.lines().any(|l| l == label), "missing {label}");
    }
}

#[test]
fn bad_fields_and_paths_are_errors() {
    let layout = wind_tunnel();
    let plot = FieldPlot {
        title: String::new(),
        log: false,
        unit: String::new(),
    };
    let wrong = Array2::zeros((3, 3));
    let err = FieldPanel::new(wrong, &layout, plot.clone()).unwrap_err();
    assert!(
        err.to_string().contains("does not match the layout grid"),
        "{err}"
    );
    let mut nan = Array2::zeros(layout.shape());
    nan[[0, 0]] = f64::NAN;
    let err = FieldPanel::new(nan, &layout, plot.clone()).unwrap_err();
    assert!(err.to_string().contains("NaN"), "{err}");
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("file");
    std::fs::write(&file, "").unwrap();
    let panel = FieldPanel::new(Array2::zeros(layout.shape()), &layout, plot).unwrap();
    let err = save_figure(&[Panel::Field(panel)], &file.join("f.png")).unwrap_err();
    assert!(err.to_string().contains("f.png"), "{err}");
}

#[test]
fn box_statistics_follow_type_7_quartiles_and_whiskers_stop_at_data() {
    // numpy.percentile([1..9, 100], [25, 50, 75]) = 3.25, 5.5, 7.75; IQR 4.5, so the upper
    // reach is 14.5: the whisker stops at 9 and 100 is an outlier.
    let v = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 100.0, f64::NAN];
    let s = BoxStats::of(&v).unwrap();
    assert_eq!(s.five, [1.0, 3.25, 5.5, 7.75, 9.0]);
    assert_eq!(s.outliers, [100.0]);
    assert_eq!(BoxStats::of(&[f64::NAN]), None);
    let one = BoxStats::of(&[2.0]).unwrap();
    assert_eq!(one.five, [2.0; 5]);

    let groups = group_values(&[
        ("rank".into(), "sensor-i".into(), 1.0),
        ("value".into(), "sensor-ii".into(), 2.0),
        ("rank".into(), "sensor-i".into(), 3.0),
        ("rank".into(), "sensor-ii".into(), 4.0),
    ]);
    // Groups and the series within each keep the order they first appear in.
    let order: Vec<(&str, Vec<&str>)> = groups
        .iter()
        .map(|(g, b)| (g.as_str(), b.keys().map(String::as_str).collect()))
        .collect();
    assert_eq!(
        order,
        [
            ("rank", vec!["sensor-i", "sensor-ii"]),
            ("value", vec!["sensor-ii"])
        ]
    );
    assert_eq!(groups["rank"]["sensor-i"], [1.0, 3.0]);
    assert_eq!(groups["rank"]["sensor-ii"], [4.0]);
    assert_eq!(groups["value"]["sensor-ii"], [2.0]);
    // The figure draws every box in its series' colour, with its group labels as text.
    let tmp = tempfile::tempdir().unwrap();
    let svg = tmp.path().join("b.svg");
    let panel = BoxPanel {
        title: "localisation error".into(),
        y_desc: "error (m)".into(),
        groups,
    };
    save_figure(&[Panel::Boxes(panel.clone())], &svg).unwrap();
    let doc = std::fs::read_to_string(&svg).unwrap();
    for label in [
        "localisation error",
        "error (m)",
        "rank",
        "value",
        "sensor-i",
        "sensor-ii",
    ] {
        assert!(doc.lines().any(|l| l == label), "missing {label}");
    }
    let png = tmp.path().join("b.png");
    save_figure(&[Panel::Boxes(panel.clone()), Panel::Boxes(panel)], &png).unwrap();
    let img = image::open(&png).unwrap().to_rgb8();
    assert_eq!((img.width(), img.height()), (960, 680));
    let c = colorous::TABLEAU10[1];
    assert!(count(&img, [c.r, c.g, c.b]) > 100, "no sensor-ii box");
}
