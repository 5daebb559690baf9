//! The line protocol of `plumenet serve`, without I/O: one JSON request in, one JSON reply out.
//!
//! Requests are `{"id": N, "op": OP, ...}`; every reply is `{"id": N, "ok": true, ...}` or
//! `{"id": N, "ok": false, "error": "..."}` (`id` is echoed as sent, `null` when the line had
//! none or could not be read). Operations:
//!
//! - `hello`: `protocol`, `layout`, `model`, `feature`, `candidates`;
//! - `readings` with `"readings": [{"t", "x", "y", "value"}, ...]`: `accepted` (the count so far);
//! - `iterate`, optionally with `"position": [x, y]` (default: the last reading's): `iteration`,
//!   `readings`, `estimate`, `entropy`, `fit`, `plume_signal`, `plume_reached`,
//!   `credible_region`, `probe`, `converged`,
//!   `done`, `goal` and `path` (see [`Iteration`](crate::ste::session::Iteration));
//! - `belief`: `estimate`, `posterior` (`x`, `y`, `p` per candidate) and `uncertainty` (the
//!   credible regions and expected distance, [`Uncertainty`](crate::ste::Uncertainty)) as of
//!   the last iteration, as `replay --json` writes them;
//! - `reset`: back to the prior, every reading forgotten.
//!
//! A rejected request leaves the session as it was. Accepted readings and resets go to a
//! [`Journal`] before the reply is made, so a server can keep them on disk.

use serde::Deserialize;
use serde_json::{Value, json};

use crate::error::Result;
use crate::ste::posterior::Sample;
use crate::ste::session::Session;

/// Version of the protocol, reported by `hello`.
pub const PROTOCOL_VERSION: u32 = 1;

/// Where accepted readings and resets are recorded before the reply (a state file).
pub trait Journal {
    /// Records an accepted batch.
    ///
    /// # Errors
    /// When the record cannot be made durable; the batch is then refused.
    fn append(&mut self, batch: &[Sample]) -> Result<()>;

    /// Records a reset.
    ///
    /// # Errors
    /// When the record cannot be made durable; the reset is then refused.
    fn clear(&mut self) -> Result<()>;
}

/// A journal that keeps nothing.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoJournal;

impl Journal for NoJournal {
    fn append(&mut self, _: &[Sample]) -> Result<()> {
        Ok(())
    }

    fn clear(&mut self) -> Result<()> {
        Ok(())
    }
}

#[derive(Debug, Deserialize)]
#[serde(tag = "op", rename_all = "lowercase", deny_unknown_fields)]
enum Op {
    // Struct variants, even when empty: serde lets a unit variant carry unknown fields.
    Hello {},
    Readings { readings: Vec<Sample> },
    Iterate { position: Option<[f64; 2]> },
    Belief {},
    Reset {},
}

/// The JSON type of a value, for messages.
fn kind(value: &Value) -> &'static str {
    match value {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

/// A session behind the protocol.
#[derive(Debug, Clone)]
pub struct Protocol {
    session: Session,
    hello: Value,
}

impl Protocol {
    /// Serves `session`; `hello` names its layout, model and feature.
    pub fn new(session: Session, layout: &str, model: &str) -> Self {
        let hello = json!({
            "protocol": PROTOCOL_VERSION,
            "layout": layout,
            "model": model,
            "feature": session.estimator().params().feature.name(),
            "candidates": session.estimator().candidates().len(),
        });
        Self { session, hello }
    }

    /// The session.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Answers one request line (without its line break) with one reply line.
    pub fn handle(&mut self, line: &str, journal: &mut dyn Journal) -> String {
        let (id, reply) = match serde_json::from_str::<Value>(line) {
            Err(e) => (Value::Null, Err(format!("malformed request: {e}"))),
            Ok(mut request) => {
                let id = request
                    .as_object_mut()
                    .and_then(|o| o.remove("id"))
                    .unwrap_or(Value::Null);
                let reply = if request.is_object() {
                    serde_json::from_value::<Op>(request).map_err(|e| format!("bad request: {e}"))
                } else {
                    Err(format!(
                        "bad request: a request is a JSON object such as {{\"id\": 1, \"op\": \"hello\"}}, got {}",
                        kind(&request)
                    ))
                }
                .and_then(|op| self.run(op, journal).map_err(|e| e.to_string()));
                (id, reply)
            }
        };
        let mut out = match reply {
            Ok(Value::Object(fields)) => fields,
            Ok(_) => serde_json::Map::new(),
            Err(error) => {
                let mut m = serde_json::Map::new();
                m.insert("error".into(), Value::String(error));
                m
            }
        };
        let ok = !out.contains_key("error");
        out.insert("id".into(), id);
        out.insert("ok".into(), Value::Bool(ok));
        Value::Object(out).to_string()
    }

    fn run(&mut self, op: Op, journal: &mut dyn Journal) -> Result<Value> {
        Ok(match op {
            Op::Hello {} => self.hello.clone(),
            Op::Readings { readings } => {
                self.session.check_readings(&readings)?;
                journal.append(&readings)?;
                json!({ "accepted": self.session.add_readings(&readings)? })
            }
            Op::Iterate { position } => json!(self.session.iterate(position)?),
            Op::Belief {} => {
                let est = self.session.estimator();
                json!({
                    "estimate": est.estimate(),
                    "posterior": est.posterior_cells(),
                    "uncertainty": est.uncertainty(None),
                })
            }
            Op::Reset {} => {
                journal.clear()?;
                self.session.reset()?;
                json!({})
            }
        })
    }
}
