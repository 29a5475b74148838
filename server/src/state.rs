//! The one shared state of the HTTP server: the database, the sites' controller links and the few
//! things kept in memory.

use std::sync::Arc;

use sqlx::AnyPool;

use crate::engine::accounts::estop_sessions::EStopSessions;
use crate::engine::accounts::login_limiter::LoginLimiter;
use crate::engine::dry_runs::calibration::run::CalibrationJob;
use crate::engine::dry_runs::pilot::PilotJob;
use crate::engine::dry_runs::power::PlanJob;
use crate::engine::machine::bench::BenchJob;
use crate::engine::machine::sites::Sites;
use crate::engine::operations::schedule::Backups;
use crate::engine::procedure::station_sockets::StationSockets;
use crate::engine::procedure::stations::Pairing;
use crate::engine::study::stability::StabilityCache;

#[derive(Clone, Debug)]
pub struct AppState {
    pub pool: AnyPool,
    /// Every site's controller link.
    pub sites: Sites,
    pub login: Arc<LoginLimiter>,
    /// Sessions the E-stop is authenticated from without the database.
    pub estop_sessions: Arc<EStopSessions>,
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
    /// The backup directory and schedule (off unless `serve --backup-dir`).
    pub backups: Arc<Backups>,
    /// Serve the pages from this directory instead of the embedded copy (development).
    pub web_dir: Option<std::path::PathBuf>,
    /// Whether the server speaks HTTPS: cookies are then `Secure` and every answer carries
    /// HSTS.
    pub https: bool,
    /// The public half of the key that signs the audit chain's checkpoints.
    pub audit_public: Option<ed25519_dalek::VerifyingKey>,
}

impl AppState {
    pub fn new(pool: AnyPool, sites: Sites) -> Self {
        Self {
            pool,
            sites,
            login: Arc::default(),
            estop_sessions: Arc::default(),
            pairing: Arc::default(),
            sockets: Arc::default(),
            pilot: Arc::default(),
            plan: Arc::default(),
            calibration: Arc::default(),
            bench: Arc::default(),
            stability: Arc::default(),
            backups: Arc::default(),
            web_dir: None,
            https: false,
            audit_public: None,
        }
    }
}
