//! Serving a live STE session ([`crate::ste::protocol`]) over lines of text: standard
//! input/output or TCP, one client at a time, with an optional state file so that nothing
//! accepted is lost when the server dies; and the client side ([`RemoteSession`]) that a
//! robot, simulated or real, steers by.
//!
//! **State file.** A header line naming the session it belongs to (`{"plumenet_state": 1,
//! "session": "..."}`: the layout, the plume model and the feature), then one line per accepted
//! batch: the batch's readings as a JSON array, written, flushed and synced before the reply
//! goes out; a reset keeps only the header (synced too). On start the file is read back into
//! the session; a file of another session is refused, and a file written before the header
//! existed is read as it is and given the header. A last line cut short by a crash (no
//! line break, or not a whole batch) is dropped and the file truncated to the intact lines;
//! damage anywhere else is an error.

use std::fs::{File, OpenOptions};
use std::io::{BufRead, BufReader, Write};
use std::net::{TcpListener, TcpStream, ToSocketAddrs};
use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::io;
use crate::sim::episode::Steering;
use crate::ste::posterior::Sample;
use crate::ste::protocol::{Journal, Protocol};
use crate::ste::session::Iteration;

/// The state file of a session.
#[derive(Debug)]
pub struct StateFile {
    file: File,
    path: PathBuf,
    /// The header line, with its line break.
    header: Vec<u8>,
}

/// Version of the state file's format, in its header.
pub const STATE_VERSION: u32 = 1;

/// The header line of a state file: which session its readings belong to.
#[derive(Debug, Clone, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct StateHeader {
    plumenet_state: u32,
    session: String,
}

/// What [`StateFile::open`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Restored {
    /// Every reading kept, in order.
    pub readings: Vec<Sample>,
    /// Batches kept.
    pub batches: usize,
    /// Whether a torn last line was dropped.
    pub dropped_torn_line: bool,
}

impl StateFile {
    /// Opens (or creates) the state file of the session named `session` (its layout, plume
    /// model and feature, as the server words them) and reads back what it holds.
    ///
    /// # Errors
    /// [`Error::Io`] when it cannot be read or written, [`Error::Log`] when it belongs to another
    /// session, or a line other than the last is not a batch of readings.
    pub fn open(path: &Path, session: &str) -> Result<(Self, Restored)> {
        let io_err = |action, source| Error::Io {
            action,
            path: path.to_path_buf(),
            source,
        };
        let log_err = |reason: String| Error::Log {
            path: path.to_path_buf(),
            reason,
        };
        let text = match std::fs::read(path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
            Err(e) => return Err(io_err("cannot read", e)),
        };
        let mut header = serde_json::to_vec(&StateHeader {
            plumenet_state: STATE_VERSION,
            session: session.to_string(),
        })
        .map_err(|e| log_err(format!("cannot write the header: {e}")))?;
        header.push(b'\n');
        let mut readings = Vec::new();
        let mut batches = 0;
        let mut rest = text.as_slice();
        let mut intact = 0;
        let mut dropped_torn_line = false;
        let mut legacy = false;
        if !rest.is_empty() {
            let first = rest.split(|&b| b == b'\n').next().unwrap_or_default();
            match serde_json::from_slice::<StateHeader>(first) {
                Ok(found) if found.plumenet_state != STATE_VERSION => {
                    return Err(log_err(format!(
                        "state format {} is not this server's {STATE_VERSION}",
                        found.plumenet_state
                    )));
                }
                Ok(found) if found.session != session => {
                    return Err(log_err(format!(
                        "holds the readings of another session ({}), not this server's ({session}): \
                         remove it or choose another --state",
                        found.session
                    )));
                }
                Ok(_) if first.len() < rest.len() => {
                    rest = &rest[first.len() + 1..];
                    intact = first.len() + 1;
                }
                // A file written before state files named their session: batches from the
                // first line, read as they are, and the header put in front of them below.
                _ if first.starts_with(b"[") => legacy = true,
                // A header cut short by a crash before its line break: start afresh.
                _ if first.len() == rest.len() => {
                    rest = &[];
                    dropped_torn_line = true;
                }
                _ => {
                    return Err(log_err(
                        "has no session header on its first line (not a plumenet state file)"
                            .into(),
                    ));
                }
            }
        }
        while !rest.is_empty() {
            let (line, whole, next) = match rest.iter().position(|&b| b == b'\n') {
                Some(k) => (&rest[..k], true, &rest[k + 1..]),
                None => (rest, false, &rest[rest.len()..]),
            };
            match serde_json::from_slice::<Vec<Sample>>(line) {
                Ok(batch) if whole => {
                    readings.extend(batch);
                    batches += 1;
                    intact += line.len() + 1;
                }
                _ if next.is_empty() => dropped_torn_line = true,
                other => {
                    let why = other.err().map_or(String::new(), |e| format!(": {e}"));
                    return Err(log_err(format!(
                        "state line {} is damaged{why}",
                        batches + 1
                    )));
                }
            }
            rest = next;
        }
        if legacy {
            // Rewritten whole (temporary file and rename), so a crash leaves either the old
            // file or the new one.
            io::write_atomic(path, |b| {
                b.extend_from_slice(&header);
                b.extend_from_slice(&text[..intact]);
                Ok(())
            })?;
            intact += header.len();
        }
        let mut file = OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)
            .map_err(|e| io_err("cannot open", e))?;
        if dropped_torn_line && !legacy {
            file.set_len(intact as u64)
                .and_then(|()| file.sync_all())
                .map_err(|e| io_err("cannot truncate", e))?;
        }
        if intact == 0 {
            file.write_all(&header)
                .and_then(|()| file.sync_all())
                .map_err(|e| io_err("cannot write", e))?;
        }
        Ok((
            Self {
                file,
                path: path.to_path_buf(),
                header,
            },
            Restored {
                readings,
                batches,
                dropped_torn_line,
            },
        ))
    }

    fn io_err(&self, action: &'static str, source: std::io::Error) -> Error {
        Error::Io {
            action,
            path: self.path.clone(),
            source,
        }
    }
}

impl Journal for StateFile {
    fn append(&mut self, batch: &[Sample]) -> Result<()> {
        let mut line = serde_json::to_vec(batch).map_err(|e| Error::Json {
            path: self.path.clone(),
            source: e,
        })?;
        line.push(b'\n');
        self.file
            .write_all(&line)
            .and_then(|()| self.file.flush())
            .and_then(|()| self.file.sync_data())
            .map_err(|e| self.io_err("cannot append to", e))
    }

    fn clear(&mut self) -> Result<()> {
        self.file
            .set_len(0)
            .and_then(|()| self.file.write_all(&self.header))
            .and_then(|()| self.file.sync_all())
            .map_err(|e| self.io_err("cannot empty", e))
    }
}

/// Answers every request line from `input` on `output`, in order, until the input ends (empty
/// lines are skipped). Returns the number of requests answered.
///
/// # Errors
/// [`Error::Io`] when a line cannot be read or a reply cannot be written (a client that went
/// away).
pub fn serve_lines(
    protocol: &mut Protocol,
    journal: &mut dyn Journal,
    input: impl BufRead,
    mut output: impl Write,
) -> Result<usize> {
    let io_err = |action, source| Error::Io {
        action,
        path: PathBuf::from("<connection>"),
        source,
    };
    let mut answered = 0;
    for line in input.lines() {
        let line = line.map_err(|e| io_err("cannot read from", e))?;
        if line.trim().is_empty() {
            continue;
        }
        let reply = protocol.handle(&line, journal);
        writeln!(output, "{reply}")
            .and_then(|()| output.flush())
            .map_err(|e| io_err("cannot write to", e))?;
        answered += 1;
    }
    Ok(answered)
}

/// Serves clients on `address` one at a time, for ever; `ready` is told the bound address
/// (port 0 picks a free one). A client that disconnects, or whose connection fails, ends only
/// its own connection: the session goes on for the next.
///
/// # Errors
/// [`Error::Io`] when the address cannot be bound.
pub fn serve_tcp(
    protocol: &mut Protocol,
    journal: &mut dyn Journal,
    address: impl ToSocketAddrs,
    ready: impl FnOnce(std::net::SocketAddr),
) -> Result<()> {
    let io_err = |action, source| Error::Io {
        action,
        path: PathBuf::from("<listen address>"),
        source,
    };
    let listener = TcpListener::bind(address).map_err(|e| io_err("cannot listen on", e))?;
    ready(
        listener
            .local_addr()
            .map_err(|e| io_err("cannot read", e))?,
    );
    for stream in listener.incoming() {
        let Ok(stream) = stream else { continue };
        let Ok(reader) = stream.try_clone() else {
            continue;
        };
        // A failed connection is the client's end; the session carries on.
        let _ = serve_lines(protocol, journal, BufReader::new(reader), stream);
    }
    Ok(())
}

/// The client side of the protocol: a session behind `plumenet serve --listen`, steering a
/// robot (see [`crate::sim::episode::Steering`]).
#[derive(Debug)]
pub struct RemoteSession {
    reader: BufReader<TcpStream>,
    writer: TcpStream,
    next_id: u64,
}

impl RemoteSession {
    /// Connects to a server.
    ///
    /// # Errors
    /// [`Error::Io`] when the connection cannot be made.
    pub fn connect(address: impl ToSocketAddrs) -> Result<Self> {
        let io_err = |source| Error::Io {
            action: "cannot connect to",
            path: PathBuf::from("<server>"),
            source,
        };
        let writer = TcpStream::connect(address).map_err(io_err)?;
        let reader = BufReader::new(writer.try_clone().map_err(io_err)?);
        Ok(Self {
            reader,
            writer,
            next_id: 0,
        })
    }

    /// Sends one request and returns the reply's fields.
    ///
    /// # Errors
    /// [`Error::Io`] when the connection fails, [`Error::Parameter`] when the server refuses
    /// the request (with its message) or answers out of order.
    pub fn call(&mut self, op: &str, fields: serde_json::Value) -> Result<serde_json::Value> {
        let io_err = |action, source| Error::Io {
            action,
            path: PathBuf::from("<server>"),
            source,
        };
        self.next_id += 1;
        let mut request = serde_json::json!({"id": self.next_id, "op": op});
        if let (Some(r), Some(f)) = (request.as_object_mut(), fields.as_object()) {
            r.extend(f.clone());
        }
        writeln!(self.writer, "{request}")
            .and_then(|()| self.writer.flush())
            .map_err(|e| io_err("cannot write to", e))?;
        let mut line = String::new();
        self.reader
            .read_line(&mut line)
            .map_err(|e| io_err("cannot read from", e))?;
        let reply: serde_json::Value = serde_json::from_str(&line).map_err(|e| {
            Error::Parameter(format!("the server's reply is not JSON ({e}): {line:?}"))
        })?;
        if reply["id"] != self.next_id {
            return Err(Error::Parameter(format!(
                "the server answered request {} to request {}",
                reply["id"], self.next_id
            )));
        }
        if reply["ok"] != true {
            return Err(Error::Parameter(format!(
                "the server refused {op}: {}",
                reply["error"].as_str().unwrap_or("no reason given")
            )));
        }
        Ok(reply)
    }
}

impl Steering for RemoteSession {
    fn send_readings(&mut self, batch: &[Sample]) -> Result<usize> {
        let reply = self.call("readings", serde_json::json!({ "readings": batch }))?;
        reply["accepted"]
            .as_u64()
            .map(|n| n as usize)
            .ok_or_else(|| Error::Parameter("the server's reply has no count".into()))
    }

    fn iterate(&mut self, position: [f64; 2]) -> Result<Iteration> {
        let reply = self.call("iterate", serde_json::json!({ "position": position }))?;
        serde_json::from_value(reply)
            .map_err(|e| Error::Parameter(format!("the server's iteration is malformed: {e}")))
    }
}
