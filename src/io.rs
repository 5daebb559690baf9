//! File I/O at the edges: atomic writes (temp file + rename), JSON and `.npy` helpers.
//!
//! Every file plumenet writes goes through [`write_atomic`], so a crash or a full disk never
//! leaves a half-written file under the final name.

use std::fs;
use std::io::Write;
use std::path::{Path, PathBuf};

use ndarray::{ArrayBase, Data, Dimension};
use ndarray_npy::{ReadNpyExt, ReadableElement, WritableElement, WriteNpyExt};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::error::{Error, Result};

/// Reads a whole text file.
///
/// # Errors
/// [`Error::Io`] when the file cannot be read.
pub fn read_to_string(path: &Path) -> Result<String> {
    fs::read_to_string(path).map_err(|source| Error::Io {
        action: "cannot read",
        path: path.to_path_buf(),
        source,
    })
}

/// Writes `bytes` produced by `fill` to `path` atomically: into a temporary file in the same
/// directory (created if missing), flushed and synced, then renamed over `path`.
///
/// # Errors
/// [`Error::Io`] when the directory is not writable or the disk is full; the temporary file is
/// removed and `path` is left untouched.
pub fn write_atomic(path: &Path, fill: impl FnOnce(&mut Vec<u8>) -> Result<()>) -> Result<()> {
    let io_err = |action, source| Error::Io {
        action,
        path: path.to_path_buf(),
        source,
    };
    let mut bytes = Vec::new();
    fill(&mut bytes)?;
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    let tmp = dir.join(format!(".{name}.tmp{}", std::process::id()));
    if let Some(file) = dir.ancestors().find(|a| a.is_file()) {
        let reason = format!("{} is a file, not a directory", file.display());
        return Err(io_err("cannot write", std::io::Error::other(reason)));
    }
    let result = (|| {
        fs::create_dir_all(&dir)?;
        let mut f = fs::File::create(&tmp)?;
        f.write_all(&bytes)?;
        f.sync_all()?;
        fs::rename(&tmp, path)
    })();
    if let Err(e) = result {
        let _ = fs::remove_file(&tmp);
        return Err(io_err("cannot write", e));
    }
    Ok(())
}

/// Creates a directory and its parents.
///
/// # Errors
/// [`Error::Io`] when it cannot be created.
pub fn create_dir_all(path: &Path) -> Result<()> {
    fs::create_dir_all(path).map_err(|source| Error::Io {
        action: "cannot create directory",
        path: path.to_path_buf(),
        source,
    })
}

/// Writes a value as pretty JSON, atomically.
///
/// # Errors
/// [`Error::Io`] on write failure.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    write_atomic(path, |buf| {
        serde_json::to_writer_pretty(&mut *buf, value).map_err(|source| Error::Json {
            path: path.to_path_buf(),
            source,
        })?;
        buf.push(b'\n');
        Ok(())
    })
}

/// Reads a JSON document.
///
/// # Errors
/// [`Error::Io`] when unreadable, [`Error::Json`] when malformed.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<T> {
    let text = read_to_string(path)?;
    serde_json::from_str(&text).map_err(|source| Error::Json {
        path: path.to_path_buf(),
        source,
    })
}

/// Writes an array as `.npy`, atomically.
///
/// # Errors
/// [`Error::Io`] on write failure.
pub fn write_npy<A, S, D>(path: &Path, array: &ArrayBase<S, D>) -> Result<()>
where
    A: WritableElement,
    S: Data<Elem = A>,
    D: Dimension,
{
    write_atomic(path, |buf| {
        array.write_npy(&mut *buf).map_err(|e| Error::Npy {
            path: path.to_path_buf(),
            reason: e.to_string(),
        })
    })
}

/// Reads a `.npy` array of a known element type and dimensionality.
///
/// # Errors
/// [`Error::Io`] when unreadable, [`Error::Npy`] for a truncated file or a wrong type or shape.
pub fn read_npy<A, D>(path: &Path) -> Result<ndarray::Array<A, D>>
where
    A: ReadableElement,
    D: Dimension,
{
    let file = fs::File::open(path).map_err(|source| Error::Io {
        action: "cannot read",
        path: path.to_path_buf(),
        source,
    })?;
    ndarray::Array::<A, D>::read_npy(std::io::BufReader::new(file)).map_err(|e| Error::Npy {
        path: path.to_path_buf(),
        reason: e.to_string(),
    })
}

/// Writes rows as CSV with a header (serde field names), atomically.
///
/// # Errors
/// [`Error::Io`] when the file cannot be written.
pub fn write_csv<T: Serialize>(path: &Path, rows: &[T]) -> Result<()> {
    write_atomic(path, |buf| {
        let mut w = csv::Writer::from_writer(buf);
        for row in rows {
            w.serialize(row).map_err(|e| csv_error(path, e))?;
        }
        w.flush().map_err(|e| Error::Io {
            action: "cannot write",
            path: path.to_path_buf(),
            source: e,
        })
    })
}

fn csv_error(path: &Path, e: csv::Error) -> Error {
    Error::Io {
        action: "cannot write",
        path: path.to_path_buf(),
        source: std::io::Error::other(e.to_string()),
    }
}

/// The memory the system can still give a process (`MemAvailable` of `/proc/meminfo`, in
/// bytes), or `None` where that cannot be read (not Linux).
pub fn available_memory_bytes() -> Option<u64> {
    let text = fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Hex SHA-256 of bytes.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest;
    hex(&sha2::Sha256::digest(bytes))
}

/// Lower-case hex of a digest.
pub fn hex(digest: &[u8]) -> String {
    digest.iter().map(|b| format!("{b:02x}")).collect()
}
