//! The dataset manifest, array I/O and shard merging.

use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{Array1, Array2, ArrayD, Axis, Ix1, IxDyn, concatenate};
use serde::{Deserialize, Serialize};

use super::GENERATOR_VERSION;
use super::rooms::RoomParams;
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

/// What the layouts of a dataset are drawn from (recorded in the manifest).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "kebab-case", deny_unknown_fields)]
pub enum Distribution {
    /// Random rooms ([`super::random_room`]): sizes, wind speeds, directions and obstacles.
    Rooms {
        /// The room distribution.
        params: RoomParams,
    },
    /// Random obstacles in one fixed arena (`generate --base`, [`super::random_layout`]).
    Base {
        /// Arena, grid, wind and coefficients shared by all layouts (no obstacles).
        base: LayoutSpec,
        /// Obstacle and source sampling parameters.
        params: GenerateParams,
    },
}

impl Distribution {
    /// Sources keep this distance from walls and obstacles (m).
    pub fn source_margin_m(&self) -> f64 {
        match self {
            Distribution::Rooms { params } => params.source_margin_m,
            Distribution::Base { params, .. } => params.source_margin_m,
        }
    }

    /// The distribution with a base arena's obstacles removed (they are never used).
    pub(super) fn normalized(&self) -> Self {
        match self {
            Distribution::Base { base, params } => Distribution::Base {
                base: LayoutSpec {
                    obstacles: Vec::new(),
                    ..base.clone()
                },
                params: params.clone(),
            },
            rooms => rooms.clone(),
        }
    }

    pub(super) fn check(&self) -> Result<()> {
        match self {
            Distribution::Rooms { params } => params.check(),
            Distribution::Base { base, params } => {
                params.check()?;
                base.clone().check().map(|_| ())
            }
        }
    }
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
    /// What the layouts are drawn from.
    pub distribution: Distribution,
    /// The layouts, in order (each with its own grid, wind and direction).
    pub layouts: Vec<LayoutSpec>,
    /// The arrays, by name.
    pub arrays: BTreeMap<String, ArrayInfo>,
}

/// Array names in write order, with their numpy dtype.
const ARRAYS: [(&str, &str); 6] = [
    ("obstacle_mask", "<f4"),
    ("signed_distance", "<f4"),
    ("wind", "<f4"),
    ("source_layout", "<u4"),
    ("source_xy", "<f4"),
    ("concentration", "<f4"),
];

/// The arrays of a dataset (or shard), flat over layouts and sources as described in
/// [`crate::dataset`].
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Arrays {
    /// 1 in obstacle cells, layout after layout.
    pub obstacle_mask: Vec<f32>,
    /// Signed distance (m), layout after layout.
    pub signed_distance: Vec<f32>,
    /// `u` plane then `v` plane (m/s), layout after layout.
    pub wind: Vec<f32>,
    /// Layout index of each source.
    pub source_layout: Vec<u32>,
    /// Source positions (m), `[S, 2]`.
    pub source_xy: Vec<f32>,
    /// Mean concentration, source after source.
    pub concentration: Vec<f32>,
}

/// Cells `(H, W)` of a layout's grid (without rasterising it).
pub fn grid_of(spec: &LayoutSpec) -> (usize, usize) {
    (
        (spec.height_m / spec.cell_m).round() as usize,
        (spec.width_m / spec.cell_m).round() as usize,
    )
}

impl Manifest {
    /// The expected shape of each array, from the layouts and the sources per layout.
    fn expected_shapes(&self) -> [Vec<usize>; 6] {
        let cells: usize = self
            .layouts
            .iter()
            .map(|l| {
                let (h, w) = grid_of(l);
                h * w
            })
            .sum();
        let m = self.sources_per_layout;
        let sources = self.layouts.len() * m;
        [
            vec![cells],
            vec![cells],
            vec![2 * cells],
            vec![sources],
            vec![sources, 2],
            vec![cells * m],
        ]
    }

    /// Writes the arrays, then the manifest last (so a directory with a manifest is complete).
    pub(super) fn write_arrays(mut self, dir: &Path, a: Arrays) -> Result<Self> {
        let shapes = self.expected_shapes();
        for ((name, dtype), shape) in ARRAYS.iter().zip(shapes) {
            self.arrays.insert(
                name.to_string(),
                ArrayInfo {
                    file: format!("{name}.npy"),
                    dtype: dtype.to_string(),
                    shape,
                },
            );
        }
        // The manifest goes first and comes back last, so a run killed between the arrays
        // leaves no manifest: the directory is never taken for a complete dataset.
        let manifest = dir.join("manifest.json");
        match std::fs::remove_file(&manifest) {
            Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                return Err(Error::Io {
                    action: "cannot remove",
                    path: manifest,
                    source: e,
                });
            }
            _ => {}
        }
        let path = |name: &str| dir.join(format!("{name}.npy"));
        let sources = a.source_layout.len();
        io::write_npy(&path("obstacle_mask"), &Array1::from(a.obstacle_mask))?;
        io::write_npy(&path("signed_distance"), &Array1::from(a.signed_distance))?;
        io::write_npy(&path("wind"), &Array1::from(a.wind))?;
        io::write_npy(&path("source_layout"), &Array1::from(a.source_layout))?;
        let xy = Array2::from_shape_vec((sources, 2), a.source_xy)
            .map_err(|e| Error::Dataset(format!("source positions: {e}")))?;
        io::write_npy(&path("source_xy"), &xy)?;
        io::write_npy(&path("concentration"), &Array1::from(a.concentration))?;
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
                "generator version {} is not the supported {GENERATOR_VERSION}; \
                 generate the dataset again with this version of plumenet",
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
        if m.layouts.iter().any(|l| {
            let (h, w) = grid_of(l);
            !(l.cell_m > 0.0 && h > 0 && w > 0 && h * w < 1 << 26)
        }) {
            return bad("a listed layout has an impossible grid".into());
        }
        for ((name, dtype), expected) in ARRAYS.into_iter().zip(m.expected_shapes()) {
            let Some(info) = m.arrays.get(name) else {
                return bad(format!("array {name} is not listed"));
            };
            if info.dtype != dtype || info.shape != expected {
                return bad(format!(
                    "array {name} is listed as {} {:?}, expected {dtype} {expected:?}",
                    info.dtype, info.shape
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
    fn identity(&self) -> (u32, u64, usize, usize, &Distribution) {
        (
            self.generator_version,
            self.seed,
            self.layouts_total,
            self.sources_per_layout,
            &self.distribution,
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
