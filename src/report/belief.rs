//! The picture of one STE iteration, like the paper's estimation figure: the posterior as a
//! colour map over the arena, obstacles, the robot's trajectory, the samples coloured by their
//! EDF value (the rank feature), the true source and the estimate.

use std::path::{Path, PathBuf};

use image::{Rgb, RgbImage};
use ndarray::Array2;

use crate::error::{Error, Result};
use crate::layout::Layout;
use crate::report::{BLACK, FieldPlot, WHITE, disc, put, render_field_framed, save_png};
use crate::ste::features::{Feature, FeatureParams, FeatureTrack};
use crate::ste::run::Episode;

const TRAJECTORY: Rgb<u8> = Rgb([200, 200, 200]);
const SOURCE: Rgb<u8> = Rgb([230, 30, 30]);

/// What to draw on top of the posterior.
#[derive(Debug, Clone, Copy)]
pub struct BeliefPlot<'a> {
    /// Title above the map.
    pub title: &'a str,
    /// Candidate positions (m) and their spacing (m).
    pub candidates: &'a [[f64; 2]],
    /// Candidate spacing (m): each candidate paints its square.
    pub spacing_m: f64,
    /// Posterior per candidate.
    pub posterior: &'a [f64],
    /// Robot positions `[t, x, y]`.
    pub trajectory: &'a [[f64; 3]],
    /// Sample positions.
    pub samples: &'a [[f64; 2]],
    /// EDF value of each sample, in `[0, 1]`.
    pub edf: &'a [f32],
    /// True source, when known.
    pub source: Option<[f64; 2]>,
    /// The estimate.
    pub estimate: [f64; 2],
}

/// Renders one iteration.
///
/// # Errors
/// [`crate::Error::Parameter`] when the posterior holds NaN.
pub fn render_belief(layout: &Layout, plot: &BeliefPlot<'_>) -> Result<RgbImage> {
    let (ny, nx) = layout.shape();
    let mut field = Array2::<f64>::zeros((ny, nx));
    let half = 0.5 * plot.spacing_m;
    for (&[cx, cy], &p) in plot.candidates.iter().zip(plot.posterior) {
        for ((j, i), v) in field.indexed_iter_mut() {
            let (x, y) = layout.cell_centre(j, i);
            if (x - cx).abs() < half && (y - cy).abs() < half {
                *v = p;
            }
        }
    }
    let (mut img, frame) = render_field_framed(
        &field,
        layout,
        &FieldPlot {
            title: plot.title.to_string(),
            log: false,
            unit: "P".into(),
        },
    )?;
    for &[_, x, y] in plot.trajectory {
        put(&mut img, frame.pixel(x, y), TRAJECTORY);
    }
    for (&[x, y], &e) in plot.samples.iter().zip(plot.edf) {
        let c = colorous::PLASMA.eval_continuous(f64::from(e).clamp(0.0, 1.0));
        disc(&mut img, frame.pixel(x, y), 2, Rgb([c.r, c.g, c.b]));
    }
    if let Some([x, y]) = plot.source {
        let p = frame.pixel(x, y);
        disc(&mut img, p, 7, BLACK);
        disc(&mut img, p, 5, SOURCE);
    }
    let (ex, ey) = frame.pixel(plot.estimate[0], plot.estimate[1]);
    for d in -6i64..=6 {
        for w in -1i64..=1 {
            put(&mut img, (ex + d, ey + d + w), BLACK);
            put(&mut img, (ex + d, ey - d + w), BLACK);
        }
        put(&mut img, (ex + d, ey + d), WHITE);
        put(&mut img, (ex + d, ey - d), WHITE);
    }
    Ok(img)
}

/// Writes one picture per iteration of a run (`iter-01.png`, ...) into `dir` and returns their
/// paths. Each shows the posterior after that iteration with the trajectory and samples so far.
///
/// # Errors
/// [`crate::Error::Parameter`] when the run kept no posteriors (run it with pictures asked
/// for), and rendering or write failures.
pub fn write_episode_pictures(
    layout: &Layout,
    candidates: &[[f64; 2]],
    spacing_m: f64,
    episode: &Episode,
    dir: &Path,
) -> Result<Vec<PathBuf>> {
    let positions: Vec<[f64; 2]> = episode.samples.iter().map(|s| [s.x, s.y]).collect();
    let mut out = Vec::new();
    for rec in &episode.history {
        let posterior = rec
            .posterior
            .as_deref()
            .ok_or_else(|| Error::Parameter("the run kept no posteriors to draw".into()))?;
        let values: Vec<f64> = episode.samples[..rec.samples]
            .iter()
            .map(|s| s.value)
            .collect();
        let mut edf = FeatureTrack::new(Feature::Rank, FeatureParams::default());
        edf.extend(&values);
        let title = format!(
            "iteration {}  {} / {}  H {:.2}  estimate ({:.2}, {:.2})",
            rec.iteration,
            episode.config.ste.feature.name(),
            episode.config.sensor.name(),
            rec.entropy,
            rec.estimate[0],
            rec.estimate[1]
        );
        let img = render_belief(
            layout,
            &BeliefPlot {
                title: &title,
                candidates,
                spacing_m,
                posterior,
                trajectory: &episode.trajectory[..rec.trajectory_len],
                samples: &positions[..rec.samples],
                edf: edf.features(),
                source: Some(episode.source),
                estimate: rec.estimate,
            },
        )?;
        let path = dir.join(format!("iter-{:02}.png", rec.iteration));
        save_png(&img, &path)?;
        out.push(path);
    }
    Ok(out)
}
