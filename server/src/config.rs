//! The server's configuration: one typed struct per command, every setting a flag with an
//! environment variable (see `.env.sample`), defaults that work on a laptop.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use bdft_controller::lsl::streams::Scope;

use crate::engine::accounts::login_limiter::LoginLimits;
use crate::engine::procedure::stations::{MAX_PENDING, PairingLimits};
use crate::store::db::Location;

/// Where the data live.
#[derive(Debug, Clone, clap::Args)]
pub struct DbConfig {
    /// The store: a SQLite file (created if missing), or a PostgreSQL database's URL
    /// (`postgres://…`, one store for several labs); migrations are applied at start.
    #[arg(long, env = "BDFT_DB", default_value = "bdft-lab.db")]
    pub db: Location,
}

/// Where the server keeps its own secrets.
#[derive(Debug, Clone, clap::Args)]
pub struct KeysConfig {
    /// Directory of the audit log's signing key and the self-signed certificate
    /// [default: beside the SQLite file]; needed with a PostgreSQL store, whose server has
    /// no file of its own.
    #[arg(long, env = "BDFT_KEYS_DIR")]
    pub keys_dir: Option<PathBuf>,
}

impl KeysConfig {
    /// The path the key files are named after (`<stem>.audit-key`, `<stem>.tls-cert.pem`):
    /// the SQLite file itself, or `bdft-lab` in --keys-dir.
    pub fn stem(&self, db: &Location) -> anyhow::Result<PathBuf> {
        match (&self.keys_dir, db) {
            (Some(dir), _) => {
                anyhow::ensure!(
                    dir.is_dir(),
                    "--keys-dir {}: no such directory",
                    dir.display()
                );
                Ok(dir.join("bdft-lab"))
            }
            (None, Location::File(path)) => Ok(path.clone()),
            (None, Location::Postgres(_)) => anyhow::bail!(
                "--db {db}: a PostgreSQL store needs --keys-dir DIR, where this server keeps the audit log's signing key (and a self-signed certificate)"
            ),
        }
    }
}

/// `bdft-server serve`.
#[derive(Debug, Clone, clap::Args)]
pub struct ServeConfig {
    #[command(flatten)]
    pub db: DbConfig,
    #[command(flatten)]
    pub keys: KeysConfig,
    /// Address the server listens on.
    #[arg(long, env = "BDFT_LISTEN", default_value = "127.0.0.1:8080")]
    pub listen: SocketAddr,
    /// Connect to a controller already running there (e.g. a real-time PC) instead of
    /// starting one.
    #[arg(long, env = "BDFT_CONTROLLER")]
    pub controller: Option<SocketAddr>,
    /// A site this server serves, with its own machine and controller (repeatable; in
    /// BDFT_SITES separated by ';'): `NAME` for one whose controller this server starts
    /// (as without --site), `NAME=ADDRESS,KEY_FILE` for one running there with that link
    /// key. Names: 1 to 40 of a-z, 0-9 and '-'. Without --site the server has one site,
    /// "main", whose controller --controller names or this server starts.
    #[arg(
        long = "site",
        env = "BDFT_SITES",
        value_delimiter = ';',
        conflicts_with = "controller"
    )]
    pub sites: Vec<SiteArg>,
    /// The link key file shared with the controller (made by `bdft-controller keygen FILE`,
    /// readable only by its owner): needed with --controller. A controller this server
    /// starts gets this key, or a new one made at every start when no file is given.
    #[arg(long, env = "BDFT_CONTROLLER_KEY_FILE")]
    pub controller_key_file: Option<PathBuf>,
    /// A bdft-controller binary to start [default: this executable runs the controller in
    /// a child process of its own].
    #[arg(long, env = "BDFT_CONTROLLER_BIN")]
    pub controller_bin: Option<PathBuf>,
    /// Extra argument for the started controller (repeatable), e.g. --controller-arg=--rig
    /// --controller-arg=udp.
    #[arg(long = "controller-arg", allow_hyphen_values = true)]
    pub controller_args: Vec<String>,
    /// Create the account "admin" with this password if there is no experimenter yet
    /// (otherwise a one-time set-up link is printed).
    #[arg(long, env = "BDFT_ADMIN_PASSWORD", hide_env_values = true)]
    pub admin_password: Option<String>,
    /// The controller counts as lost after this long without a message from it (ms); it
    /// heartbeats every 25 ms.
    #[arg(long, env = "BDFT_CONTROLLER_SILENCE_MS", default_value_t = crate::engine::machine::controller_link::DEFAULT_SILENCE.as_millis() as u64, value_parser = clap::value_parser!(u64).range(60..=10_000))]
    pub controller_silence_ms: u64,
    /// Serve the pages from this directory instead of the copy built into the binary
    /// (for developing them).
    #[arg(long, env = "BDFT_WEB_DIR")]
    pub web_dir: Option<PathBuf>,
    /// For tests: the database may grow to at most this many pages (SQLite's
    /// `max_page_count`, 4 KiB pages), so that writes beyond it fail as on a full disk
    /// (`bdft-tests`' soak fills the room up to it and frees it again). Unlimited by default.
    #[arg(long, env = "BDFT_DB_MAX_PAGES", value_parser = clap::value_parser!(u32).range(1024..))]
    pub db_max_pages: Option<u32>,
    /// Publish each station's streams over the Lab Streaming Layer: its 1 kHz signals (from
    /// the controller this server starts, which gets --lsl too) and its markers (test start
    /// and end, survey, redo, E-stop, interlock). Off by default: without it no LSL socket
    /// is opened (LSL discovery answers multicast and broadcast queries).
    #[arg(long, env = "BDFT_LSL")]
    pub lsl: bool,
    /// How far LSL discovery answers: machine (this host only), link or site.
    #[arg(long, env = "BDFT_LSL_SCOPE", value_enum, default_value_t = Scope::Machine, requires = "lsl")]
    pub lsl_scope: Scope,
    #[command(flatten)]
    pub connections: ConnectionConfig,
    #[command(flatten)]
    pub login: LoginConfig,
    #[command(flatten)]
    pub tls: TlsConfig,
    #[command(flatten)]
    pub backup: BackupConfig,
}

/// HTTPS (off by default: a server on loopback needs none; one on a lab network does).
#[derive(Debug, Clone, clap::Args)]
pub struct TlsConfig {
    /// Serve HTTPS with this certificate chain (PEM file); needs --tls-key.
    #[arg(
        long,
        env = "BDFT_TLS_CERT",
        requires = "tls_key",
        conflicts_with = "tls_self_signed"
    )]
    pub tls_cert: Option<PathBuf>,
    /// The private key of --tls-cert (PEM file: PKCS#8, PKCS#1 or SEC1).
    #[arg(long, env = "BDFT_TLS_KEY", requires = "tls_cert")]
    pub tls_key: Option<PathBuf>,
    /// Serve HTTPS with a self-signed certificate for this machine's names, made at the first
    /// start and kept beside the database (`<db>.tls-cert.pem`, `<db>.tls-key.pem`); its
    /// fingerprint is printed at every start for the stations to check.
    #[arg(long, env = "BDFT_TLS_SELF_SIGNED")]
    pub tls_self_signed: bool,
}

/// Scheduled backups (`serve`).
#[derive(Debug, Clone, clap::Args)]
pub struct BackupConfig {
    /// Directory of the scheduled backups and the dashboard's "Back up now" (created if
    /// missing; must be writable). Without it no backup is scheduled.
    #[arg(long, env = "BDFT_BACKUP_DIR")]
    pub backup_dir: Option<PathBuf>,
    /// How often to back up: a whole number and a unit, s, m, h or d (90s, 30m, 6h, 1d), from
    /// 1s to 30d. The first backup is made at start when the directory holds none this
    /// recent.
    #[arg(long, env = "BDFT_BACKUP_EVERY", default_value = "1d", requires = "backup_dir", value_parser = crate::engine::operations::schedule::parse_every)]
    pub backup_every: Duration,
    /// How many backups the directory keeps: after a new one has passed its checks, the
    /// oldest beyond this are deleted.
    #[arg(long, env = "BDFT_BACKUP_KEEP", default_value_t = 14, requires = "backup_dir", value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub backup_keep: u32,
}

/// What one client may hold of the server: its connections, the time its request takes to
/// arrive, and the pairing codes it makes the server keep.
#[derive(Debug, Clone, clap::Args)]
pub struct ConnectionConfig {
    /// A connection that has not sent a whole request head within this long (ms) is closed:
    /// slow or idle clients (also idle keep-alive connections) cannot hold it.
    #[arg(long, env = "BDFT_HEADER_TIMEOUT_MS", default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(100..=600_000))]
    pub header_timeout_ms: u64,
    /// A request body that has not arrived within this long (ms) after its head is answered
    /// 408 and its connection closed, unless it keeps arriving at --min-body-rate.
    #[arg(long, env = "BDFT_BODY_TIMEOUT_MS", default_value_t = 10_000, value_parser = clap::value_parser!(u64).range(100..=600_000))]
    pub body_timeout_ms: u64,
    /// Past --body-timeout-ms, a body still arriving is given more time only while it has
    /// averaged at least this many bytes a second since its head (0: never more time).
    #[arg(long, env = "BDFT_MIN_BODY_RATE", default_value_t = 16_384, value_parser = clap::value_parser!(u64).range(0..=1_000_000_000))]
    pub min_body_rate: u64,
    /// Connections served at once (open WebSockets included); further clients wait to be
    /// accepted.
    #[arg(long, env = "BDFT_MAX_CONNECTIONS", default_value_t = 512, value_parser = clap::value_parser!(u64).range(8..=65_536))]
    pub max_connections: u64,
    /// Connections one client address may hold at once (open WebSockets included): one more
    /// is answered 429 with Retry-After and closed, so one address cannot take every slot of
    /// --max-connections. Every client behind one proxy or NAT shares one address.
    #[arg(long, env = "BDFT_MAX_CONNECTIONS_PER_ADDRESS", default_value_t = 128, value_parser = clap::value_parser!(u64).range(1..=65_536))]
    pub max_connections_per_address: u64,
    /// Stations one client address may register per minute (`POST /api/station/register`,
    /// anonymous): more are answered 429 with Retry-After.
    #[arg(long, env = "BDFT_STATION_REGISTRATIONS_PER_MINUTE", default_value_t = PairingLimits::default().per_minute as u32, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub station_registrations_per_minute: u32,
    /// Pairing codes one client address may have shown at once (of the server's 256): its
    /// next registration withdraws its oldest code, so one address cannot take them all.
    #[arg(long, env = "BDFT_PAIRING_CODES_PER_ADDRESS", default_value_t = PairingLimits::default().codes_per_address as u32, value_parser = clap::value_parser!(u32).range(1..=MAX_PENDING as i64))]
    pub pairing_codes_per_address: u32,
}

impl ConnectionConfig {
    pub fn header_timeout(&self) -> Duration {
        Duration::from_millis(self.header_timeout_ms)
    }

    pub fn body_timeout(&self) -> Duration {
        Duration::from_millis(self.body_timeout_ms)
    }

    pub fn pairing_limits(&self) -> PairingLimits {
        PairingLimits {
            per_minute: self.station_registrations_per_minute as usize,
            codes_per_address: self.pairing_codes_per_address as usize,
        }
    }
}

/// The login rate limit.
#[derive(Debug, Clone, clap::Args)]
pub struct LoginConfig {
    /// Failed logins allowed per minute for one username from one client address.
    #[arg(long, env = "BDFT_LOGIN_ATTEMPTS", default_value_t = LoginLimits::default().per_user_address as u32, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub login_attempts: u32,
    /// Failed logins allowed per minute from one client address, whatever the usernames.
    #[arg(long, env = "BDFT_LOGIN_ADDRESS_ATTEMPTS", default_value_t = LoginLimits::default().per_address as u32, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub login_address_attempts: u32,
}

impl LoginConfig {
    pub fn limits(&self) -> LoginLimits {
        LoginLimits {
            per_user_address: self.login_attempts as usize,
            per_address: self.login_address_attempts as usize,
            ..LoginLimits::default()
        }
    }
}

/// One `--site`: a name, and where its controller is (none: this server starts it).
#[derive(Debug, Clone, PartialEq)]
pub struct SiteArg {
    pub name: String,
    /// The address and link key file of a controller running there.
    pub remote: Option<(SocketAddr, PathBuf)>,
}

impl std::str::FromStr for SiteArg {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, String> {
        let (name, remote) = match s.split_once('=') {
            None => (s, None),
            Some((name, rest)) => {
                let (addr, key) = rest.split_once(',').ok_or_else(|| {
                    format!("{s:?}: NAME, or NAME=ADDRESS,KEY_FILE (a controller running there, with its link key file)")
                })?;
                let addr: SocketAddr = addr.trim().parse().map_err(|e| {
                    format!("{s:?}: the address {addr:?}: {e} (e.g. 192.168.1.20:7000)")
                })?;
                if key.trim().is_empty() {
                    return Err(format!("{s:?}: the key file is missing after the comma"));
                }
                (name, Some((addr, PathBuf::from(key.trim()))))
            }
        };
        let name = name.trim();
        crate::engine::machine::sites::check_name(name)?;
        Ok(Self {
            name: name.to_string(),
            remote,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::SiteArg;

    /// The heartbeat period `serve --help` states (and `.env.sample` repeats, which the
    /// integration test `env_sample` compares with the help) is the controller's.
    #[test]
    fn the_help_states_the_controllers_heartbeat() {
        use clap::Args;
        let command = super::ServeConfig::augment_args(clap::Command::new("serve"));
        let arg = command
            .get_arguments()
            .find(|a| a.get_id() == "controller_silence_ms")
            .unwrap();
        let help = arg.get_help().unwrap().to_string();
        let beat = crate::engine::machine::controller_link::HEARTBEAT.as_millis();
        assert!(
            help.contains(&format!("heartbeats every {beat} ms")),
            "{help}"
        );
    }

    #[test]
    fn a_site_is_a_name_or_a_name_with_a_controller_address_and_key() {
        let local: SiteArg = "delft".parse().unwrap();
        assert_eq!(local.name, "delft");
        assert_eq!(local.remote, None);
        let remote: SiteArg = "tampere=[::1]:7000, /etc/bdft/tampere.key".parse().unwrap();
        assert_eq!(remote.name, "tampere");
        let (addr, key) = remote.remote.unwrap();
        assert_eq!(addr, "[::1]:7000".parse().unwrap());
        assert_eq!(key, std::path::PathBuf::from("/etc/bdft/tampere.key"));
        for (bad, says) in [
            ("Delft", "a-z, 0-9 and '-'"),
            ("lab=127.0.0.1:7000", "NAME=ADDRESS,KEY_FILE"),
            ("lab=somewhere,key", "the address \"somewhere\""),
            ("lab=127.0.0.1:7000,", "the key file is missing"),
            ("=127.0.0.1:7000,k", "site name \"\""),
        ] {
            let e = bad.parse::<SiteArg>().unwrap_err();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
