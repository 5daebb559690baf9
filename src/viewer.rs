//! The run viewer: one self-contained HTML file (no server, no network, no external script or
//! font; the data embedded as JSON) with a slider over a run's iterations. Each iteration shows
//! the posterior as a heat map with its 90% credible region outlined, the obstacles, the trajectory so far, the readings so far
//! coloured by their feature value, the true source where known and the estimate; a small chart
//! shows the entropy and the error per iteration.
//!
//! To stay small (a few hundred kB for a 30-iteration run), the posterior of each iteration is
//! stored relative to its maximum in 1000 steps, the readings drawn are at most
//! [`MAX_READINGS_SHOWN`] (every k-th) with their feature value in 100 steps, and the trajectory
//! at most [`MAX_TRAJECTORY_POINTS`] points.

use std::path::Path;

use serde_json::json;

use crate::error::{Error, Result};
use crate::io;
use crate::layout::Layout;
use crate::sim::episode::{Episode, IterationRecord};
use crate::ste::credible::{cell_area_m2, outline, region_cells};
use crate::ste::features::{Feature, FeatureParams, FeatureTrack};
use crate::ste::posterior::{Sample, SteParams};
use crate::ste::replay::ReplayStep;

/// The most readings drawn per iteration; longer runs show every k-th.
pub const MAX_READINGS_SHOWN: usize = 2000;
/// The most trajectory points stored; longer trajectories keep every k-th.
pub const MAX_TRAJECTORY_POINTS: usize = 4000;

const TEMPLATE: &str = include_str!("viewer.html");
const DATA_MARK: &str = "/*PLUMENET-DATA*/";

/// The state after one iteration.
#[derive(Debug, Clone, PartialEq)]
pub struct ViewerFrame {
    /// 1-based iteration.
    pub iteration: usize,
    /// Readings so far.
    pub samples: usize,
    /// Trajectory points so far.
    pub trajectory: usize,
    /// Posterior entropy (nats).
    pub entropy: f64,
    /// MAP estimate (m).
    pub estimate: [f64; 2],
    /// Posterior of every candidate.
    pub posterior: Vec<f64>,
}

impl TryFrom<&IterationRecord> for ViewerFrame {
    type Error = Error;

    fn try_from(rec: &IterationRecord) -> Result<Self> {
        let posterior = rec
            .posterior
            .clone()
            .ok_or_else(|| Error::Parameter("the run kept no posteriors to show".into()))?;
        Ok(Self {
            iteration: rec.iteration,
            samples: rec.samples,
            trajectory: rec.trajectory_len,
            entropy: rec.entropy,
            estimate: rec.estimate,
            posterior,
        })
    }
}

/// A run to show.
#[derive(Debug, Clone)]
pub struct RunView<'a> {
    /// Heading of the page.
    pub title: String,
    /// The arena.
    pub layout: &'a Layout,
    /// Candidate sources (m).
    pub candidates: &'a [[f64; 2]],
    /// Candidate spacing (m).
    pub spacing_m: f64,
    /// The feature the readings are coloured by.
    pub feature: Feature,
    /// Its settings.
    pub feature_params: FeatureParams,
    /// The readings, in time order.
    pub samples: &'a [Sample],
    /// The robot's path (m), in time order.
    pub trajectory: Vec<[f64; 2]>,
    /// The true source, where known.
    pub source: Option<[f64; 2]>,
    /// One frame per iteration.
    pub frames: Vec<ViewerFrame>,
}

impl<'a> RunView<'a> {
    /// The view of a simulated run (it must have kept its posteriors).
    ///
    /// # Errors
    /// [`Error::Parameter`] when the run kept no posteriors.
    pub fn from_episode(
        title: String,
        layout: &'a Layout,
        candidates: &'a [[f64; 2]],
        spacing_m: f64,
        episode: &'a Episode,
    ) -> Result<Self> {
        let frames = episode
            .history
            .iter()
            .map(ViewerFrame::try_from)
            .collect::<Result<Vec<_>>>()?;
        Ok(Self {
            title,
            layout,
            candidates,
            spacing_m,
            feature: episode.config.ste.feature,
            feature_params: episode.config.ste.features,
            samples: &episode.samples,
            trajectory: episode.trajectory.iter().map(|&[_, x, y]| [x, y]).collect(),
            source: Some(episode.source),
            frames,
        })
    }

    /// The page's data: everything the script draws.
    ///
    /// # Errors
    /// [`Error::Parameter`] when a frame's posterior is not one value per candidate, or holds
    /// NaN, or the run has no frames.
    pub fn data(&self) -> Result<serde_json::Value> {
        if self.frames.is_empty() {
            return Err(Error::Parameter("the run has no iterations to show".into()));
        }
        let (ny, nx) = self.layout.shape();
        let solid: String = (0..ny)
            .flat_map(|j| (0..nx).map(move |i| (j, i)))
            .map(|(j, i)| if self.layout.is_solid(j, i) { '1' } else { '0' })
            .collect();
        let r3 = |v: f64| (v * 1000.0).round() / 1000.0;
        let sample_stride = self.samples.len().div_ceil(MAX_READINGS_SHOWN).max(1);
        let traj_stride = self.trajectory.len().div_ceil(MAX_TRAJECTORY_POINTS).max(1);
        let shown: Vec<[f64; 2]> = self
            .samples
            .iter()
            .step_by(sample_stride)
            .map(|s| [r3(s.x), r3(s.y)])
            .collect();
        let trajectory: Vec<[f64; 2]> = self
            .trajectory
            .iter()
            .step_by(traj_stride)
            .map(|&[x, y]| [r3(x), r3(y)])
            .collect();
        let mut frames = Vec::with_capacity(self.frames.len());
        for f in &self.frames {
            frames.push(self.frame_data(f, sample_stride, traj_stride)?);
        }
        let table = |map: &colorous::Gradient| -> Vec<[u8; 3]> {
            (0..=32)
                .map(|k| {
                    let c = map.eval_continuous(f64::from(k) / 32.0);
                    [c.r, c.g, c.b]
                })
                .collect()
        };
        Ok(json!({
            "title": self.title,
            "width_m": self.layout.width(),
            "height_m": self.layout.height(),
            "cell_m": self.layout.cell(),
            "nx": nx,
            "ny": ny,
            "solid": solid,
            "spacing_m": self.spacing_m,
            "candidates": self.candidates.iter().map(|&[x, y]| [r3(x), r3(y)]).collect::<Vec<_>>(),
            "feature": self.feature.name(),
            "readings": self.samples.len(),
            "readings_shown": shown,
            "trajectory": trajectory,
            "source": self.source,
            "frames": frames,
            "viridis": table(&colorous::VIRIDIS),
            "plasma": table(&colorous::PLASMA),
        }))
    }

    fn frame_data(
        &self,
        f: &ViewerFrame,
        sample_stride: usize,
        traj_stride: usize,
    ) -> Result<serde_json::Value> {
        if f.posterior.len() != self.candidates.len() || f.posterior.iter().any(|p| p.is_nan()) {
            return Err(Error::Parameter(format!(
                "iteration {}: the posterior must be one finite value per candidate ({} values, {} candidates)",
                f.iteration,
                f.posterior.len(),
                self.candidates.len()
            )));
        }
        let n = f.samples.min(self.samples.len());
        let values: Vec<f64> = self.samples[..n].iter().map(|s| s.value).collect();
        let mut track = FeatureTrack::new(self.feature, self.feature_params);
        track.extend(&values);
        let m = track.features();
        let (lo, hi) = m
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| {
                (a.min(v), b.max(v))
            });
        let (lo, hi) = match self.feature {
            // Ranks and hits already lie in [0, 1]; values are scaled to this iteration's range.
            Feature::Value if hi > lo => (lo, hi),
            _ => (0.0, 1.0),
        };
        let feature: Vec<u8> = m
            .iter()
            .step_by(sample_stride)
            .map(|&v| (((v - lo) / (hi - lo)).clamp(0.0, 1.0) * 99.0).round() as u8)
            .collect();
        let pmax = f.posterior.iter().copied().fold(0.0_f64, f64::max);
        let posterior: Vec<u16> = f
            .posterior
            .iter()
            .map(|&p| {
                if pmax > 0.0 {
                    (p / pmax * 1000.0).round() as u16
                } else {
                    0
                }
            })
            .collect();
        let error_m = self
            .source
            .map(|[x, y]| (f.estimate[0] - x).hypot(f.estimate[1] - y));
        let cells = region_cells(self.candidates, &f.posterior, 0.9);
        let r3 = |v: f64| (v * 1000.0).round() / 1000.0;
        let sides: Vec<[f64; 4]> = outline(&cells, self.spacing_m)
            .into_iter()
            .map(|[a, b]| [r3(a[0]), r3(a[1]), r3(b[0]), r3(b[1])])
            .collect();
        Ok(json!({
            "iteration": f.iteration,
            "readings": n,
            "trajectory": f.trajectory.min(self.trajectory.len()).div_ceil(traj_stride),
            "entropy": f.entropy,
            "estimate": f.estimate,
            "error_m": error_m,
            "posterior_max": pmax,
            "posterior": posterior,
            "region90_m2": cells.len() as f64 * cell_area_m2(self.candidates),
            "region90": sides,
            "feature": feature,
        }))
    }

    /// The HTML page.
    ///
    /// # Errors
    /// As [`RunView::data`].
    pub fn html(&self) -> Result<String> {
        let data = serde_json::to_string(&self.data()?)
            .map_err(|e| Error::Parameter(format!("cannot encode the viewer's data: {e}")))?;
        // Inside a <script> element "</" must not appear; "<\/" is the same JSON string.
        Ok(TEMPLATE.replacen(DATA_MARK, &data.replace("</", "<\\/"), 1))
    }

    /// Writes the page atomically.
    ///
    /// # Errors
    /// As [`RunView::data`], and [`Error::Io`] when the file cannot be written.
    pub fn write(&self, path: &Path) -> Result<()> {
        let page = self.html()?;
        io::write_atomic(path, |buf| {
            buf.extend_from_slice(page.as_bytes());
            Ok(())
        })
    }
}

impl<'a> RunView<'a> {
    /// The view of a replayed log taken in steps (see
    /// [`crate::ste::replay::replay_in_steps`]): each step is an iteration, and the readings'
    /// positions are the trajectory. The title is empty and the source unknown: set them with
    /// struct update syntax.
    pub fn from_replay(
        layout: &'a Layout,
        candidates: &'a [[f64; 2]],
        spacing_m: f64,
        params: &SteParams,
        samples: &'a [Sample],
        steps: &[ReplayStep],
    ) -> Self {
        let frames = steps
            .iter()
            .enumerate()
            .map(|(k, s)| ViewerFrame {
                iteration: k + 1,
                samples: s.samples,
                trajectory: s.samples,
                entropy: s.entropy,
                estimate: s.estimate,
                posterior: s.posterior.clone(),
            })
            .collect();
        Self {
            title: String::new(),
            layout,
            candidates,
            spacing_m,
            feature: params.feature,
            feature_params: params.features,
            samples,
            trajectory: samples.iter().map(|s| [s.x, s.y]).collect(),
            source: None,
            frames,
        }
    }
}
