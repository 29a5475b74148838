//! The one shared state of the HTTP server: the database, the controller link and the few
//! things kept in memory.

use std::sync::Arc;

use sqlx::SqlitePool;

use crate::engine::bench::BenchJob;
use crate::engine::calibration::run::CalibrationJob;
use crate::engine::controller_link::ControllerLink;
use crate::engine::login_limiter::LoginLimiter;
use crate::engine::pilot::PilotJob;
use crate::engine::power::PlanJob;
use crate::engine::stability::StabilityCache;
use crate::engine::station_sockets::StationSockets;
use crate::engine::stations::Pairing;

#[derive(Clone, Debug)]
pub struct AppState {
    pub pool: SqlitePool,
    pub controller: ControllerLink,
    pub login: Arc<LoginLimiter>,
    pub pairing: Arc<Pairing>,
    /// Each station's one live socket.
    pub sockets: Arc<StationSockets>,
    pub pilot: Arc<PilotJob>,
    pub plan: Arc<PlanJob>,
    /// The one calibration at a time.
    pub calibration: Arc<CalibrationJob>,
    /// The one bench run at a time.
    pub bench: Arc<BenchJob>,
    pub stability: Arc<StabilityCache>,
    /// Serve the pages from this directory instead of the embedded copy (development).
    pub web_dir: Option<std::path::PathBuf>,
}

impl AppState {
    pub fn new(pool: SqlitePool, controller: ControllerLink) -> Self {
        Self {
            pool,
            controller,
            login: Arc::default(),
            pairing: Arc::default(),
            sockets: Arc::default(),
            pilot: Arc::default(),
            plan: Arc::default(),
            calibration: Arc::default(),
            bench: Arc::default(),
            stability: Arc::default(),
            web_dir: None,
        }
    }
}
