//! The picture of one STE iteration, like the paper's estimation figure: the posterior over the
//! arena (each candidate paints its square), obstacles, the robot's trajectory, the readings
//! coloured by their rank, the true source and the estimate, with a legend.

use std::path::{Path, PathBuf};

use colorous::PLASMA;
use ndarray::{Array2, s};
use plotters::coord::CoordTranslate;
use plotters::prelude::*;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::report::{FieldPanel, FieldPlot, Panel, colour, legend, save_figure};
use crate::sim::episode::Episode;
use crate::ste::credible::{outline, region_cells};
use crate::ste::features::{Feature, FeatureParams, FeatureTrack};

const TRAJECTORY: RGBColor = RGBColor(215, 215, 215);
const SOURCE: RGBColor = RGBColor(230, 30, 30);
/// The 90% credible region's outline.
const REGION: RGBColor = RGBColor(255, 60, 220);
/// The credible level whose region's outline is drawn.
const REGION_LEVEL: f64 = 0.9;

/// What to draw.
#[derive(Debug, Clone, Copy)]
pub struct BeliefPlot<'a> {
    /// Title above the map.
    pub title: &'a str,
    /// Candidate positions (m).
    pub candidates: &'a [[f64; 2]],
    /// Candidate spacing (m): each candidate paints its square.
    pub spacing_m: f64,
    /// Posterior per candidate.
    pub posterior: &'a [f64],
    /// Robot positions `[t, x, y]`.
    pub trajectory: &'a [[f64; 3]],
    /// Sample positions.
    pub samples: &'a [[f64; 2]],
    /// Rank (EDF) of each sample among the samples, in `[0, 1]`.
    pub edf: &'a [f32],
    /// True source, when known.
    pub source: Option<[f64; 2]>,
    /// The estimate.
    pub estimate: [f64; 2],
}

/// The panel of one iteration: the posterior as a [`FieldPanel`] with the run on top.
///
/// # Errors
/// [`Error::Parameter`] when the posterior holds NaN or is not one value per candidate.
pub fn belief_panel<'a>(layout: &'a Layout, plot: BeliefPlot<'a>) -> Result<FieldPanel<'a>> {
    if plot.posterior.len() != plot.candidates.len() {
        return Err(Error::Parameter(format!(
            "{} posterior values for {} candidates",
            plot.posterior.len(),
            plot.candidates.len()
        )));
    }
    let (ny, nx) = layout.shape();
    let mut field = Array2::zeros((ny, nx));
    // Cell k (centre (k + 0.5) cell) lies in the square around c when
    // |(k + 0.5) cell - c| < spacing / 2.
    let span = |c: f64, n: usize| {
        let (lo, hi) = ((c - 0.5 * plot.spacing_m), (c + 0.5 * plot.spacing_m));
        let first = ((lo / layout.cell() - 0.5).floor() + 1.0).max(0.0) as usize;
        first..((hi / layout.cell() - 0.5).ceil().max(0.0) as usize).min(n)
    };
    for (&[x, y], &p) in plot.candidates.iter().zip(plot.posterior) {
        field.slice_mut(s![span(y, ny), span(x, nx)]).fill(p);
    }
    let map = FieldPlot {
        title: plot.title.to_string(),
        log: false,
        unit: "posterior probability".into(),
    };
    let mut panel = FieldPanel::new(field, layout, map)?;
    panel.run = Some(Box::new(plot));
    Ok(panel)
}

/// Draws a run on a map's chart (metres), with its legend.
pub(crate) fn draw_run<'a, DB: DrawingBackend + 'a, CT>(
    chart: &mut ChartContext<'a, DB, CT>,
    p: &BeliefPlot<'_>,
) -> Result<()>
where
    CT: CoordTranslate<From = (f64, f64)>,
{
    let path = p.trajectory.iter().map(|&[_, x, y]| (x, y));
    chart
        .draw_series(LineSeries::new(path, TRAJECTORY.stroke_width(2)))?
        .label("trajectory")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], TRAJECTORY.stroke_width(3)));
    let rank = |e: &f32| colour(&PLASMA, f64::from(*e)).filled();
    let dots = p.samples.iter().zip(p.edf);
    chart
        .draw_series(dots.map(|(&[x, y], e)| Circle::new((x, y), 3, rank(e))))?
        .label("readings (colour: rank, low to high)")
        .legend(|(x, y)| Circle::new((x + 8, y), 4, colour(&PLASMA, 0.8).filled()));
    if let Some([x, y]) = p.source {
        let marks = [(8, BLACK), (6, SOURCE)].map(|(r, c)| Circle::new((x, y), r, c.filled()));
        chart
            .draw_series(marks)?
            .label("true source")
            .legend(|(x, y)| Circle::new((x + 8, y), 5, SOURCE.filled()));
    }
    let cells = region_cells(p.candidates, p.posterior, REGION_LEVEL);
    let sides = outline(&cells, p.spacing_m);
    let side = |[a, b]: [[f64; 2]; 2]| {
        PathElement::new([(a[0], a[1]), (b[0], b[1])], REGION.stroke_width(2))
    };
    chart
        .draw_series(sides.into_iter().map(side))?
        .label("90% credible region")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 16, y)], REGION.stroke_width(2)));
    let [x, y] = p.estimate;
    let marks = [(BLACK, 4), (WHITE, 2)].map(|(c, w)| Cross::new((x, y), 8, c.stroke_width(w)));
    chart
        .draw_series(marks)?
        .label("estimate")
        .legend(|(x, y)| Cross::new((x + 8, y), 5, BLACK.stroke_width(2)));
    legend(chart, SeriesLabelPosition::UpperRight)
}

/// Writes one picture per iteration of a run (`iter-01.png`, ...) into `dir` and returns their
/// paths. Each shows the posterior after that iteration with the trajectory and readings so
/// far, the readings coloured by their rank among those so far.
///
/// # Errors
/// [`Error::Parameter`] when the run kept no posteriors (run it with pictures asked for), and
/// rendering or write failures.
pub fn write_episode_pictures(
    layout: &Layout,
    candidates: &[[f64; 2]],
    spacing_m: f64,
    episode: &Episode,
    dir: &Path,
) -> Result<Vec<PathBuf>> {
    let positions: Vec<[f64; 2]> = episode.samples.iter().map(|s| [s.x, s.y]).collect();
    let values: Vec<f64> = episode.samples.iter().map(|s| s.value).collect();
    let mut ranks = FeatureTrack::new(Feature::Rank, FeatureParams::default());
    let mut out = Vec::new();
    for rec in &episode.history {
        let Some(posterior) = rec.posterior.as_deref() else {
            return Err(Error::Parameter(
                "the run kept no posteriors to draw".into(),
            ));
        };
        ranks.extend(&values[ranks.len()..rec.samples]);
        let [ex, ey] = rec.estimate;
        let title = format!(
            "iteration {}   {} / {}   entropy {:.2} nats   estimate ({ex:.2}, {ey:.2}) m",
            rec.iteration,
            episode.config.ste.feature.name(),
            episode.config.sensor.name(),
            rec.entropy,
        );
        let plot = BeliefPlot {
            title: &title,
            candidates,
            spacing_m,
            posterior,
            trajectory: &episode.trajectory[..rec.trajectory_len],
            samples: &positions[..rec.samples],
            edf: ranks.features(),
            source: Some(episode.source),
            estimate: rec.estimate,
        };
        let path = dir.join(format!("iter-{:02}.png", rec.iteration));
        save_figure(&[Panel::Field(belief_panel(layout, plot)?)], &path)?;
        out.push(path);
    }
    Ok(out)
}
