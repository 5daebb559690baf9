//! The dataset manifest, array I/O and shard merging.

use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{Array1, Array2, Array3, Array4, ArrayD, Axis, Ix1, IxDyn, concatenate};
use serde::{Deserialize, Serialize};

use super::GENERATOR_VERSION;
use crate::error::{Error, Result};
use crate::io;
use crate::layout::LayoutSpec;

/// Layout and source sampling parameters of the generator (recorded in the manifest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GenerateParams {
    /// Most obstacles per layout (at least one is always drawn).
    pub max_obstacles: usize,
    /// Smallest obstacle side (m).
    pub min_size_m: f64,
    /// Largest obstacle length along the wind (m).
    pub max_width_m: f64,
    /// Largest obstacle extent across the wind (m).
    pub max_height_m: f64,
    /// Obstacles stay this far from the inlet and the outlet (m).
    pub inlet_clearance_m: f64,
    /// Least free height left in every column (m): the channel is never blocked.
    pub min_gap_m: f64,
    /// Sources keep this distance from walls and obstacles (m).
    pub source_margin_m: f64,
}

impl Default for GenerateParams {
    fn default() -> Self {
        Self {
            max_obstacles: 4,
            min_size_m: 0.5,
            max_width_m: 2.5,
            max_height_m: 2.0,
            inlet_clearance_m: 2.0,
            min_gap_m: 1.0,
            source_margin_m: 0.25,
        }
    }
}

impl GenerateParams {
    pub(super) fn check(&self) -> Result<()> {
        let lengths = [
            self.min_size_m,
            self.max_width_m,
            self.max_height_m,
            self.inlet_clearance_m,
            self.min_gap_m,
            self.source_margin_m,
        ];
        if self.max_obstacles == 0
            || lengths.iter().any(|v| !(v.is_finite() && *v >= 0.0))
            || self.min_size_m > self.max_width_m.min(self.max_height_m)
        {
            return Err(Error::Parameter(format!(
                "bad generator parameters {self:?}"
            )));
        }
        Ok(())
    }
}

/// Which part of a sharded dataset a directory holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShardInfo {
    /// Zero-based shard index.
    pub index: usize,
    /// Number of shards.
    pub count: usize,
    /// Global index of the first layout in this shard.
    pub first_layout: usize,
    /// Number of layouts in this shard.
    pub layouts: usize,
}

/// Name, element type and shape of one `.npy` array.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ArrayInfo {
    /// File name inside the dataset directory.
    pub file: String,
    /// numpy dtype string (`<f4`, `<u4`).
    pub dtype: String,
    /// Shape.
    pub shape: Vec<usize>,
}

/// `manifest.json` of a dataset directory.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always `plumenet-dataset`.
    pub format: String,
    /// [`GENERATOR_VERSION`] of the writer.
    pub generator_version: u32,
    /// Master seed.
    pub seed: u64,
    /// Layouts in the whole dataset (all shards).
    pub layouts_total: usize,
    /// Sources per layout.
    pub sources_per_layout: usize,
    /// Present in a shard directory, absent in a complete dataset.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shard: Option<ShardInfo>,
    /// Arena, grid, wind and coefficients shared by all layouts.
    pub base: LayoutSpec,
    /// Sampling parameters.
    pub params: GenerateParams,
    /// Grid shape `[H, W]`.
    pub grid: [usize; 2],
    /// How `source_encoding.npy` was computed.
    pub source_encoding: String,
    /// The layouts, in order.
    pub layouts: Vec<LayoutSpec>,
    /// The arrays, by name.
    pub arrays: BTreeMap<String, ArrayInfo>,
}

/// Array names in write order, with their numpy dtype.
const ARRAYS: [(&str, &str); 7] = [
    ("obstacle_mask", "<f4"),
    ("signed_distance", "<f4"),
    ("wind", "<f4"),
    ("source_layout", "<u4"),
    ("source_xy", "<f4"),
    ("source_encoding", "<f4"),
    ("concentration", "<f4"),
];

impl Manifest {
    /// Writes the arrays, then the manifest last (so a directory with a manifest is complete).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn write_arrays(
        mut self,
        dir: &Path,
        mask: &Array3<f32>,
        sdf: &Array3<f32>,
        wind: &Array4<f32>,
        source_layout: &Array1<u32>,
        source_xy: &Array2<f32>,
        encoding: &Array3<f32>,
        concentration: &Array3<f32>,
    ) -> Result<Self> {
        let shapes = [
            mask.shape(),
            sdf.shape(),
            wind.shape(),
            source_layout.shape(),
            source_xy.shape(),
            encoding.shape(),
            concentration.shape(),
        ];
        for ((name, dtype), shape) in ARRAYS.iter().zip(shapes) {
            self.arrays.insert(
                name.to_string(),
                ArrayInfo {
                    file: format!("{name}.npy"),
                    dtype: dtype.to_string(),
                    shape: shape.to_vec(),
                },
            );
        }
        let path = |name: &str| dir.join(format!("{name}.npy"));
        io::write_npy(&path("obstacle_mask"), mask)?;
        io::write_npy(&path("signed_distance"), sdf)?;
        io::write_npy(&path("wind"), wind)?;
        io::write_npy(&path("source_layout"), source_layout)?;
        io::write_npy(&path("source_xy"), source_xy)?;
        io::write_npy(&path("source_encoding"), encoding)?;
        io::write_npy(&path("concentration"), concentration)?;
        io::write_json(&dir.join("manifest.json"), &self)?;
        Ok(self)
    }

    /// Reads and checks `dir/manifest.json` and the shapes of the arrays it lists.
    ///
    /// # Errors
    /// [`Error::Io`]/[`Error::Json`] for a missing or malformed manifest, [`Error::Dataset`] for
    /// a wrong format, version, layout count or array list, [`Error::Npy`] for a missing,
    /// truncated or mis-shaped array.
    pub fn load(dir: &Path) -> Result<Self> {
        let m: Manifest = io::read_json(&dir.join("manifest.json"))?;
        let bad = |msg: String| Err(Error::Dataset(format!("{}: {msg}", dir.display())));
        if m.format != "plumenet-dataset" {
            return bad(format!(
                "format is {:?}, expected \"plumenet-dataset\"",
                m.format
            ));
        }
        if m.generator_version != GENERATOR_VERSION {
            return bad(format!(
                "generator version {} is not the supported {GENERATOR_VERSION}",
                m.generator_version
            ));
        }
        let expected_layouts = m.shard.map_or(m.layouts_total, |s| s.layouts);
        if m.layouts.len() != expected_layouts {
            return bad(format!(
                "{} layouts listed, expected {expected_layouts}",
                m.layouts.len()
            ));
        }
        for (name, dtype) in ARRAYS {
            let Some(info) = m.arrays.get(name) else {
                return bad(format!("array {name} is not listed"));
            };
            if info.dtype != dtype {
                return bad(format!(
                    "array {name} has dtype {}, expected {dtype}",
                    info.dtype
                ));
            }
            let path = dir.join(&info.file);
            let found = if dtype == "<u4" {
                io::read_npy::<u32, Ix1>(&path)?.shape().to_vec()
            } else {
                io::read_npy::<f32, IxDyn>(&path)?.shape().to_vec()
            };
            if found != info.shape {
                return Err(Error::Npy {
                    path,
                    reason: format!(
                        "shape {found:?} differs from the manifest's {:?}",
                        info.shape
                    ),
                });
            }
        }
        Ok(m)
    }

    /// The manifest with shard information removed, for comparing shards of one dataset.
    fn identity(
        &self,
    ) -> (
        u32,
        u64,
        usize,
        usize,
        &LayoutSpec,
        &GenerateParams,
        [usize; 2],
    ) {
        (
            self.generator_version,
            self.seed,
            self.layouts_total,
            self.sources_per_layout,
            &self.base,
            &self.params,
            self.grid,
        )
    }
}

/// Merges shard directories of one dataset into `out`; the result is byte-identical to an
/// unsharded run with the same seed and parameters.
///
/// # Errors
/// [`Error::Dataset`] when the shards come from different runs, overlap or leave layouts out;
/// errors of [`Manifest::load`] for a damaged shard; [`Error::Io`] when `out` is not writable.
pub fn merge(shards: &[&Path], out: &Path) -> Result<Manifest> {
    let mut loaded = shards
        .iter()
        .map(|dir| Manifest::load(dir).map(|m| (m, *dir)))
        .collect::<Result<Vec<_>>>()?;
    loaded.sort_by_key(|(m, _)| m.shard.map_or(0, |s| s.first_layout));
    let Some((first, _)) = loaded.first() else {
        return Err(Error::Dataset("no shard directories given".into()));
    };
    let first_identity = first.identity();
    for (m, dir) in &loaded {
        if m.identity() != first_identity {
            return Err(Error::Dataset(format!(
                "{} comes from a different dataset (seed, parameters or version differ)",
                dir.display()
            )));
        }
        if m.shard.is_none() {
            return Err(Error::Dataset(format!(
                "{} is a complete dataset, not a shard",
                dir.display()
            )));
        }
    }
    let mut next = 0;
    for (m, dir) in &loaded {
        let s = m.shard.unwrap_or(ShardInfo {
            index: 0,
            count: 0,
            first_layout: 0,
            layouts: 0,
        });
        if s.first_layout != next {
            return Err(Error::Dataset(format!(
                "shards do not tile the dataset: {} starts at layout {}, expected {next}",
                dir.display(),
                s.first_layout
            )));
        }
        next += s.layouts;
    }
    if next != first.layouts_total {
        return Err(Error::Dataset(format!(
            "shards cover {next} of {} layouts; some shards are missing",
            first.layouts_total
        )));
    }
    io::create_dir_all(out)?;
    let mut merged = loaded[0].0.clone();
    merged.shard = None;
    merged.layouts = loaded.iter().flat_map(|(m, _)| m.layouts.clone()).collect();
    for (name, dtype) in ARRAYS {
        let path = out.join(format!("{name}.npy"));
        let shape = if dtype == "<u4" {
            let parts = loaded
                .iter()
                .map(|(_, d)| io::read_npy::<u32, Ix1>(&d.join(format!("{name}.npy"))))
                .collect::<Result<Vec<_>>>()?;
            let joined = join(&parts, &path)?;
            io::write_npy(&path, &joined)?;
            joined.shape().to_vec()
        } else {
            let parts = loaded
                .iter()
                .map(|(_, d)| io::read_npy::<f32, IxDyn>(&d.join(format!("{name}.npy"))))
                .collect::<Result<Vec<ArrayD<f32>>>>()?;
            let joined = join(&parts, &path)?;
            io::write_npy(&path, &joined)?;
            joined.shape().to_vec()
        };
        if let Some(info) = merged.arrays.get_mut(name) {
            info.shape = shape;
        }
    }
    io::write_json(&out.join("manifest.json"), &merged)?;
    Ok(merged)
}

fn join<A: Clone, D: ndarray::RemoveAxis>(
    parts: &[ndarray::Array<A, D>],
    path: &Path,
) -> Result<ndarray::Array<A, D>> {
    let views: Vec<_> = parts.iter().map(|p| p.view()).collect();
    concatenate(Axis(0), &views).map_err(|e| Error::Npy {
        path: path.to_path_buf(),
        reason: format!("shard arrays do not fit together: {e}"),
    })
}
