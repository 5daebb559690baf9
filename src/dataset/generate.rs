//! Random layouts and sources, solved with the physics model, written as a dataset.

use std::path::Path;

use ndarray::Array3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::GENERATOR_VERSION;
use super::manifest::{Arrays, Distribution, GenerateParams, Manifest, ShardInfo};
use super::rooms::random_room;
use super::snap::{SNAP_M, snapped};
use crate::error::{Error, Result};
use crate::io;
use crate::layout::{Layout, LayoutSpec, Obstacle};
use crate::physics::transport::Transport;
use crate::physics::wind::WindField;

/// Give up drawing a layout (or a source) after this many rejected attempts.
const MAX_ATTEMPTS: usize = 10_000;

/// One shard `index` of `count` (`--shard K/N`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Shard {
    /// Zero-based shard index `K`.
    pub index: usize,
    /// Number of shards `N`.
    pub count: usize,
}

impl std::str::FromStr for Shard {
    type Err = Error;

    /// Parses `K/N` with `0 <= K < N`.
    fn from_str(s: &str) -> Result<Self> {
        let bad = || Error::Parameter(format!("shard must be K/N with 0 <= K < N, got {s:?}"));
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = k.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if count == 0 || index >= count {
            return Err(bad());
        }
        Ok(Self { index, count })
    }
}

/// What to generate.
#[derive(Debug, Clone, PartialEq)]
pub struct GenerateConfig {
    /// What the layouts are drawn from (a base arena's obstacles are ignored).
    pub distribution: Distribution,
    /// Number of layouts in the whole dataset (all shards).
    pub layouts: usize,
    /// Sources per layout.
    pub sources_per_layout: usize,
    /// Master seed.
    pub seed: u64,
    /// Which part to generate; `None` for all.
    pub shard: Option<Shard>,
}

impl GenerateConfig {
    fn check(&self) -> Result<()> {
        if self.layouts == 0 || self.sources_per_layout == 0 {
            return Err(Error::Parameter(
                "--layouts and --sources must be at least 1".into(),
            ));
        }
        if let Some(shard) = self.shard
            && shard.count > self.layouts
        {
            return Err(Error::Parameter(format!(
                "{} shards for {} layouts would leave empty shards",
                shard.count, self.layouts
            )));
        }
        self.distribution.check()
    }

    /// The global layout indices this run generates.
    pub fn layout_range(&self) -> std::ops::Range<usize> {
        match self.shard {
            None => 0..self.layouts,
            Some(Shard { index, count }) => {
                index * self.layouts / count..(index + 1) * self.layouts / count
            }
        }
    }
}

/// Draws a random valid layout: 1 to `max_obstacles` rectangles of varied sizes, some touching
/// a side wall, kept `inlet_clearance_m` from the inlet and outlet, always leaving at least
/// `min_gap_m` of free height in every column (so the channel is never blocked).
///
/// # Errors
/// [`Error::Parameter`] when no valid layout is found in many attempts (impossible parameters).
pub fn random_layout(
    base: &LayoutSpec,
    params: &GenerateParams,
    rng: &mut ChaCha8Rng,
) -> Result<Layout> {
    let (w, h) = (base.width_m, base.height_m);
    for _ in 0..MAX_ATTEMPTS {
        let count = rng.random_range(1..=params.max_obstacles);
        let obstacles: Vec<Obstacle> = (0..count)
            .map(|_| {
                let ow = snapped(rng, params.min_size_m, params.max_width_m);
                let oh = snapped(
                    rng,
                    params.min_size_m,
                    params.max_height_m.min(h - params.min_gap_m),
                );
                let x_min = snapped(
                    rng,
                    params.inlet_clearance_m,
                    w - params.inlet_clearance_m - ow,
                );
                let y_min = match rng.random_range(0..10) {
                    0..=1 => 0.0,
                    2..=3 => h - oh,
                    _ => snapped(rng, SNAP_M, h - oh - SNAP_M),
                };
                Obstacle {
                    x_min,
                    y_min,
                    x_max: x_min + ow,
                    y_max: y_min + oh,
                }
            })
            .collect();
        let spec = LayoutSpec {
            obstacles,
            ..base.clone()
        };
        let Ok(layout) = spec.check() else { continue };
        let min_free = layout
            .solid()
            .columns()
            .into_iter()
            .map(|col| col.iter().filter(|s| !**s).count())
            .min()
            .unwrap_or(0) as f64
            * layout.cell();
        if min_free + 1e-9 >= params.min_gap_m {
            return Ok(layout);
        }
    }
    Err(Error::Parameter(
        "no valid random layout found: relax the obstacle parameters".into(),
    ))
}

/// Draws a source uniformly in free space, at least `margin` from walls and obstacles.
fn random_source(layout: &Layout, margin: f64, rng: &mut ChaCha8Rng) -> Result<[f64; 2]> {
    for _ in 0..MAX_ATTEMPTS {
        let x = rng.random_range(margin..layout.width() - margin);
        let y = rng.random_range(margin..layout.height() - margin);
        let clear = layout
            .spec()
            .obstacles
            .iter()
            .all(|o| o.signed_distance(x, y) >= margin);
        if clear && layout.is_free(x, y) {
            return Ok([x, y]);
        }
    }
    Err(Error::Parameter(
        "no free source position found: the source margin is too large".into(),
    ))
}

/// Everything generated for one layout.
struct LayoutSample {
    layout: Layout,
    wind: Array3<f32>,
    sources: Vec<[f64; 2]>,
    fields: Array3<f32>,
}

/// Redraw a room whose wind cannot be solved at most this many times.
const MAX_UNSOLVED_ROOMS: usize = 10;

fn generate_layout(config: &GenerateConfig, k: usize) -> Result<LayoutSample> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    rng.set_stream(k as u64);
    let (layout, wind) = match &config.distribution {
        Distribution::Base { base, params } => {
            let layout = random_layout(base, params, &mut rng)?;
            let wind = WindField::solve(&layout)?;
            (layout, wind)
        }
        Distribution::Rooms { params } => {
            // A room whose steady wind cannot be found is replaced by the next draw of its
            // stream (deterministic like everything else).
            let mut attempt = 0;
            loop {
                let layout = random_room(params, &mut rng)?;
                match WindField::solve(&layout) {
                    Ok(wind) => break (layout, wind),
                    Err(e) if attempt + 1 >= MAX_UNSOLVED_ROOMS => return Err(e),
                    Err(_) => attempt += 1,
                }
            }
        }
    };
    let margin = config.distribution.source_margin_m();
    let sources = (0..config.sources_per_layout)
        .map(|_| random_source(&layout, margin, &mut rng))
        .collect::<Result<Vec<_>>>()?;
    let fields = Transport::new(&layout, &wind)?.bank(&sources)?;
    Ok(LayoutSample {
        wind: wind.centred().mapv(|x| x as f32),
        layout,
        sources,
        fields,
    })
}

/// Generates a dataset (or one shard of it) into `out`, calling `progress` after each layout.
/// A directory that already holds the complete output of the same configuration is left as it
/// is, so an interrupted sharded run is resumed by re-running every shard command.
///
/// # Errors
/// [`Error::Parameter`] for bad settings, [`Error::Solver`] if a layout cannot be solved,
/// [`Error::Io`] when `out` is not writable.
pub fn generate(
    config: &GenerateConfig,
    out: &Path,
    progress: &(dyn Fn() + Sync),
) -> Result<Manifest> {
    config.check()?;
    let distribution = config.distribution.normalized();
    if let Ok(done) = Manifest::load(out)
        && done.seed == config.seed
        && done.layouts_total == config.layouts
        && done.sources_per_layout == config.sources_per_layout
        && done.distribution == distribution
        && done.shard.map(|s| (s.index, s.count)) == config.shard.map(|s| (s.index, s.count))
    {
        // Already complete (a re-run after an interruption elsewhere): nothing to redo.
        return Ok(done);
    }
    io::create_dir_all(out)?;
    let range = config.layout_range();
    let samples = range
        .clone()
        .into_par_iter()
        .map(|k| {
            let sample = generate_layout(config, k);
            progress();
            sample
        })
        .collect::<Result<Vec<_>>>()?;
    let mut arrays = Arrays::default();
    for (sample, k) in samples.iter().zip(range.clone()) {
        let layout = &sample.layout;
        arrays
            .obstacle_mask
            .extend(layout.solid().iter().map(|&s| f32::from(u8::from(s))));
        arrays
            .signed_distance
            .extend(layout.signed_distance().iter().map(|&d| d as f32));
        arrays.wind.extend(sample.wind.iter());
        arrays.concentration.extend(sample.fields.iter());
        for &[x, y] in &sample.sources {
            arrays.source_layout.push(k as u32);
            arrays.source_xy.extend([x as f32, y as f32]);
        }
    }
    let manifest = Manifest {
        format: "plumenet-dataset".into(),
        generator_version: GENERATOR_VERSION,
        seed: config.seed,
        layouts_total: config.layouts,
        sources_per_layout: config.sources_per_layout,
        shard: config.shard.map(|s| ShardInfo {
            index: s.index,
            count: s.count,
            first_layout: range.start,
            layouts: samples.len(),
        }),
        distribution,
        layouts: samples.iter().map(|s| s.layout.spec().clone()).collect(),
        arrays: Default::default(),
    };
    manifest.write_arrays(out, arrays)
}
