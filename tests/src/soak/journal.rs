//! The soak's own log of what it did: every start, request, fault and what it expected, one
//! JSON object a line in `soak.jsonl`, and in memory for the checks at the end (which compare
//! it with the exports and the audit log).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::Path;
use std::sync::Mutex;
use std::time::{Duration, Instant};

use serde_json::{Value, json};

/// What came of a request: its status and body, or the transport's error, when it is
/// unknown whether the server acted on it.
pub type Answer = Result<(u16, Value), String>;

/// The journal of one soak run.
#[derive(Debug)]
pub struct Journal {
    start: Instant,
    file: Mutex<BufWriter<File>>,
    entries: Mutex<Vec<Value>>,
    /// Echo every entry of these events to standard error (progress).
    loud: &'static [&'static str],
}

impl Journal {
    pub fn create(path: &Path) -> std::io::Result<Self> {
        Ok(Self {
            start: Instant::now(),
            file: Mutex::new(BufWriter::new(File::create(path)?)),
            entries: Mutex::new(Vec::new()),
            loud: &[
                "server.start",
                "fault",
                "fault.outcome",
                "quiet",
                "violation",
                "phase",
            ],
        })
    }

    /// Time since the soak started.
    pub fn elapsed(&self) -> Duration {
        self.start.elapsed()
    }

    /// Records `event` with `fields` (an object), stamped with the seconds since the start
    /// (`t`) and the wall clock in ms since the Unix epoch (`wall_ms`, the unit of the
    /// server's time columns).
    pub fn log(&self, event: &str, fields: Value) {
        let mut entry = json!({
            "t": (self.elapsed().as_secs_f64() * 1000.0).round() / 1000.0,
            "wall_ms": wall_ms(),
            "event": event,
        });
        if let (Some(e), Value::Object(f)) = (entry.as_object_mut(), fields) {
            e.extend(f);
        }
        let line = entry.to_string();
        if self.loud.contains(&event) {
            eprintln!("soak: {line}");
        }
        let mut file = self.file.lock().unwrap_or_else(|p| p.into_inner());
        let _ = writeln!(file, "{line}");
        drop(file);
        self.entries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(entry);
    }

    /// Records a request and what came of it: `status` (null when unknown) and `error`.
    pub fn request(&self, event: &str, mut fields: Value, answer: &Answer) {
        match answer {
            Ok((code, body)) => {
                fields["status"] = json!(code);
                if *code >= 300 {
                    fields["error"] = body.get("error").cloned().unwrap_or_else(|| body.clone());
                }
            }
            Err(e) => {
                fields["status"] = Value::Null;
                fields["error"] = json!(e);
            }
        }
        self.log(event, fields);
    }

    /// Records a broken rule (the run fails).
    pub fn violation(&self, what: impl Into<String>) {
        self.log("violation", json!({ "what": what.into() }));
    }

    /// The entries of `event` so far.
    pub fn of(&self, event: &str) -> Vec<Value> {
        self.entries
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .iter()
            .filter(|e| e["event"] == event)
            .cloned()
            .collect()
    }

    pub fn flush(&self) {
        let _ = self.file.lock().unwrap_or_else(|p| p.into_inner()).flush();
    }
}

/// Milliseconds since the Unix epoch.
pub fn wall_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}
