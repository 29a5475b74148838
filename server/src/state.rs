//! The one shared state of the HTTP server.

use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use sqlx::SqlitePool;

use crate::controller_link::ControllerLink;

#[derive(Clone, Debug)]
pub struct AppState {
    pub pool: SqlitePool,
    pub controller: ControllerLink,
    pub inner: Arc<Shared>,
    /// Serve the pages from this directory instead of the embedded copy (development).
    pub web_dir: Option<std::path::PathBuf>,
}

#[derive(Debug, Default)]
pub struct Shared {
    /// Failed logins per (username, client address), for rate limiting.
    pub login_failures: Mutex<HashMap<String, Vec<Instant>>>,
    /// Stations that showed a pairing code and wait for the experimenter: code → (token,
    /// created).
    pub pending_stations: Mutex<HashMap<String, (String, Instant)>>,
    /// The pilot run started from the dashboard, if any: (study, progress, outcome).
    pub pilot: Mutex<Option<PilotRun>>,
}

#[derive(Debug, Clone)]
pub struct PilotRun {
    pub study_id: i64,
    pub progress: Arc<crate::pilot::Progress>,
    /// None while running; then Ok(summary) or Err(message).
    pub outcome: Option<Result<serde_json::Value, String>>,
}

impl AppState {
    pub fn new(pool: SqlitePool, controller: ControllerLink) -> Self {
        Self {
            pool,
            controller,
            inner: Arc::new(Shared::default()),
            web_dir: None,
        }
    }
}
