//! A trained PlumeNet on disk: `config.json` ([`SavedModel`]: architecture, grid, encoding,
//! normalisation, training history and a digest of the weights) beside `weights.bpk`
//! (burnpack), and the weights' serialisation and digest.

use std::path::Path;

use burn::module::{Module, ModuleVisitor, Param};
use burn::prelude::*;
use burn::store::ModuleRecord;
use ndarray::{ArrayD, IxDyn};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::config::{EpochLoss, TrainState, TrainingConfig};
use super::data::{Normalization, SourceEncoding, TrainedRanges, TrainingData};
use super::model::{PlumeNet, PlumeNetConfig};
use crate::error::{Error, Result};
use crate::io;

/// Format tag of `config.json`.
pub const MODEL_FORMAT: &str = "plumenet-model-v2";
/// Format tag of one-room models (one grid, geometry inputs), still
/// loaded for their own grid.
pub const LEGACY_MODEL_FORMAT: &str = "plumenet-model-v1";

/// `config.json` of a trained model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SavedModel {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// Architecture.
    pub architecture: PlumeNetConfig,
    /// The one grid `[H, W]` a one-room model was trained for (absent in
    /// any-room models, which have `ranges`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<[usize; 2]>,
    /// Cell size (m).
    pub cell_m: f64,
    /// Rooms the model was trained on (absent in one-room models).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranges: Option<TrainedRanges>,
    /// Source encoding of the inputs.
    pub encoding: SourceEncoding,
    /// Input and target scales.
    pub normalization: Normalization,
    /// SHA-256 of the training dataset's `manifest.json`.
    pub dataset_digest: String,
    /// The training configuration.
    pub training: TrainingConfig,
    /// Losses per epoch, and the best (kept) epoch.
    pub history: Vec<EpochLoss>,
    /// The kept epoch.
    pub best: Option<EpochLoss>,
    /// SHA-256 of the weight tensors ([`weights_digest`]; models written before it hold the
    /// SHA-256 of `weights.bpk`, which is still accepted).
    pub weights_digest: String,
    /// Predictions average the room and its mirror image across the wind (an exact symmetry of
    /// the physics; two forward passes per field; [`super::Surrogate::predict_many`]). True
    /// for every U-Net trained since, false for operator networks (whose bank it would cost
    /// twice) and in models written before, unless their `config.json` sets it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub mirror_average: bool,
}

impl SavedModel {
    /// The description of a model trained with `config` on `data`, as of `state`.
    pub fn new(config: &TrainingConfig, data: &TrainingData, state: &TrainState) -> Self {
        let ranges = data.ranges();
        Self {
            format: MODEL_FORMAT.into(),
            architecture: config.model.clone(),
            grid: None,
            cell_m: ranges.cell_m,
            ranges: Some(ranges),
            encoding: config.encoding,
            normalization: config.normalization,
            dataset_digest: data.digest.clone(),
            training: config.clone(),
            history: state.history.clone(),
            best: state.best,
            weights_digest: String::new(),
            mirror_average: config.model.operator.is_none(),
        }
    }

    /// Writes `weights.bpk` then `config.json` (both atomically) into `dir`.
    ///
    /// # Errors
    /// [`Error::Io`] when `dir` is not writable, [`Error::Model`] when serialisation fails.
    pub fn write(mut self, dir: &Path, net: &PlumeNet) -> Result<()> {
        let bytes = weights_bytes(net)?;
        self.weights_digest = weights_digest(net)?;
        io::write_atomic(&dir.join("weights.bpk"), |b| {
            b.extend_from_slice(&bytes);
            Ok(())
        })?;
        io::write_json(&dir.join("config.json"), &self)
    }

    /// Reads `dir/config.json` and the network in `dir/weights.bpk` onto `device`, checking
    /// the format and the weights' digest.
    ///
    /// # Errors
    /// [`Error::Io`]/[`Error::Json`] for missing or malformed files, [`Error::Model`] for another
    /// format or a weights file that does not match its digest (truncated or replaced).
    pub fn load(dir: &Path, device: &Device) -> Result<(Self, PlumeNet)> {
        let config = dir.join("config.json");
        let written: serde_json::Value = io::read_json(&config)?;
        let saved: SavedModel =
            serde_json::from_value(written.clone()).map_err(|e| Error::Json {
                path: config.clone(),
                source: e,
            })?;
        // The architecture is Burn's config type, which takes unknown fields silently: an
        // architecture this crate does not know is refused here instead.
        let known = serde_json::to_value(&saved.architecture).map_err(|e| Error::Json {
            path: config.clone(),
            source: e,
        })?;
        if let (Some(written), Some(known)) = (
            written.get("architecture").and_then(|a| a.as_object()),
            known.as_object(),
        ) && let Some(unknown) = unknown_field(written, known)
        {
            return Err(Error::Model(format!(
                "{}: the architecture has a field {unknown:?} this plumenet does not know \
                 (a model of another architecture or a newer plumenet)",
                dir.display()
            )));
        }
        let legacy = saved.format == LEGACY_MODEL_FORMAT;
        if !(saved.format == MODEL_FORMAT || legacy)
            || legacy != saved.ranges.is_none()
            || saved.grid.is_none() && saved.ranges.is_none()
        {
            return Err(Error::Model(format!(
                "{}: format {:?} is not {MODEL_FORMAT} (or a consistent {LEGACY_MODEL_FORMAT})",
                dir.display(),
                saved.format
            )));
        }
        if let Some(problem) = saved.architecture.coarse_problem() {
            return Err(Error::Model(format!("{}: {problem}", dir.display())));
        }
        let path = dir.join("weights.bpk");
        let mismatch = || {
            Error::Model(format!(
                "{} does not match the digest in config.json (truncated or replaced)",
                path.display()
            ))
        };
        let bytes = read(&path)?;
        let file_digest = io::sha256_hex(&bytes) == saved.weights_digest;
        let net = weights_from_bytes(saved.architecture.init(device), bytes, &path)
            .map_err(|_| mismatch())?;
        if !file_digest && weights_digest(&net)? != saved.weights_digest {
            return Err(mismatch());
        }
        Ok((saved, net))
    }
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| Error::Io {
        action: "cannot read",
        path: path.to_path_buf(),
        source,
    })
}

/// Collects every float parameter with its dotted module path.
#[derive(Default)]
struct Collect {
    path: Vec<String>,
    tensors: Vec<(String, ArrayD<f32>)>,
    error: Option<String>,
}

impl ModuleVisitor for Collect {
    fn enter_module(&mut self, name: &str, _container_type: &str) {
        self.path.push(name.to_string());
    }

    fn exit_module(&mut self, _name: &str, _container_type: &str) {
        self.path.pop();
    }

    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let tensor = param.val();
        let shape = tensor.dims().to_vec();
        match tensor.into_data().try_to_vec::<f32>() {
            Ok(values) => match ArrayD::from_shape_vec(IxDyn(&shape), values) {
                Ok(array) => self.tensors.push((self.path.join("."), array)),
                Err(e) => self.error = Some(e.to_string()),
            },
            Err(e) => self.error = Some(format!("{e:?}")),
        }
    }
}

/// Every weight tensor of `net` with its dotted module path (also its PyTorch `state_dict`
/// key), in the network's order.
///
/// # Errors
/// [`Error::Model`] when a tensor cannot be read as f32.
pub fn named_tensors(net: &PlumeNet) -> Result<Vec<(String, ArrayD<f32>)>> {
    let mut collect = Collect::default();
    net.visit(&mut collect);
    match collect.error {
        Some(e) => Err(Error::Model(format!("cannot read a weight tensor: {e}"))),
        None => Ok(collect.tensors),
    }
}

/// SHA-256 of the weights: every tensor's path, shape and little-endian values, in the
/// network's order. Unlike the burnpack bytes, which carry random parameter ids, two networks
/// with equal weights have equal digests.
///
/// # Errors
/// As [`named_tensors`].
pub fn weights_digest(net: &PlumeNet) -> Result<String> {
    let mut hash = Sha256::new();
    for (name, array) in named_tensors(net)? {
        hash.update(name.as_bytes());
        hash.update([0]);
        for &d in array.shape() {
            hash.update((d as u64).to_le_bytes());
        }
        for v in &array {
            hash.update(v.to_le_bytes());
        }
    }
    Ok(io::hex(&hash.finalize()))
}

/// Serialises a network's parameters to burnpack bytes.
///
/// # Errors
/// [`Error::Model`] when Burn cannot serialise the record.
pub fn weights_bytes(net: &PlumeNet) -> Result<Vec<u8>> {
    let bytes = net
        .clone()
        .into_record()
        .into_bytes()
        .map_err(|e| Error::Model(format!("cannot serialise weights: {e:?}")))?;
    Ok(bytes.to_vec())
}

/// Loads burnpack weights into a network of the matching architecture.
///
/// # Errors
/// [`Error::Io`] when unreadable, [`Error::Model`] for a truncated, foreign or mismatched file.
pub fn load_weights(net: PlumeNet, path: &Path) -> Result<PlumeNet> {
    weights_from_bytes(net, read(path)?, path)
}

/// The first field of `written` that `known` lacks, looking into the objects both hold (an
/// operator network's sizes, its coarse network's), as a dotted path.
fn unknown_field(
    written: &serde_json::Map<String, serde_json::Value>,
    known: &serde_json::Map<String, serde_json::Value>,
) -> Option<String> {
    written
        .iter()
        .find_map(|(key, value)| match known.get(key) {
            None => Some(key.clone()),
            Some(inner) => match (value.as_object(), inner.as_object()) {
                (Some(value), Some(inner)) => {
                    unknown_field(value, inner).map(|field| format!("{key}.{field}"))
                }
                _ => None,
            },
        })
}

/// Loads burnpack `bytes` (read from `path`) into a network of the matching architecture.
fn weights_from_bytes(net: PlumeNet, bytes: Vec<u8>, path: &Path) -> Result<PlumeNet> {
    let record =
        ModuleRecord::from_bytes(burn::tensor::Bytes::from_bytes_vec(bytes)).map_err(|e| {
            Error::Model(format!(
                "{} is not a PlumeNet weights file: {e:?}",
                path.display()
            ))
        })?;
    net.try_load_record(record).map_err(|e| {
        Error::Model(format!(
            "{} does not fit this architecture: {e:?}",
            path.display()
        ))
    })
}
