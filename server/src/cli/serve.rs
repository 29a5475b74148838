//! `bdft-server serve` (the default): the database opened, trials left running filed, an
//! account or a set-up link made sure of, the controller links of every site started, and
//! the API and pages served until a signal.

use std::path::PathBuf;

use anyhow::Context;

use crate::config::ServeConfig;
use crate::engine::accounts;
use crate::engine::accounts::login_limiter::LoginLimiter;
use crate::engine::machine::sites::{self, Sites};
use crate::engine::machine::{controller_link, estop_latch};
use crate::engine::operations::schedule::{Backups, Policy};
use crate::engine::operations::{audit_signing, presence};
use crate::engine::procedure::filing;
use crate::files::Holds;
use crate::store;
use crate::store::accounts::Role;
use bdft_protocol::link_auth::LinkKey;

/// Opens the database, files trials left running as incomplete, makes sure an account or a
/// set-up link exists, starts the controller link and serves until a signal.
pub async fn run(config: ServeConfig) -> anyhow::Result<()> {
    // The backup directory is checked before anything starts.
    let backups = match &config.backup.backup_dir {
        Some(_) if matches!(config.db.db, store::db::Location::Postgres(_)) => {
            anyhow::bail!("--backup-dir: a backup {}", store::db::ONLY_SQLITE_BACKUPS)
        }
        Some(dir) => std::sync::Arc::new(Backups::new(Policy {
            dir: dir.clone(),
            every: config.backup.backup_every,
            keep: config.backup.backup_keep as usize,
        })?),
        None => std::sync::Arc::default(),
    };
    // So are the sites and their key files.
    let site_links = site_links(&config)?;
    let keys = config.keys.stem(&config.db.db)?;
    let pool = store::db::open_location(&config.db.db, config.db_max_pages).await?;
    let audit_key = audit_signing::load_or_create(&keys)?;
    let audit_public = audit_key.verifying_key();
    let interrupted = filing::interrupt_running(&pool, "server restart").await?;
    if !interrupted.is_empty() {
        tracing::warn!(trials = ?interrupted, "trials that were running when the server stopped are marked incomplete");
    }
    crate::engine::machine::bench::fail_interrupted(&pool).await?;
    // A pilot process killed while it ran leaves its trials running: they are filed as soon
    // as its heartbeat stops, not at the next restart.
    tokio::spawn(filing::watch_pilots(pool.clone()));
    let listener = tokio::net::TcpListener::bind(config.listen)
        .await
        .with_context(|| format!("listening on {}", config.listen))?;
    let addr = listener.local_addr()?;
    let tls = match (&config.tls.tls_cert, &config.tls.tls_key) {
        (Some(cert), Some(key)) => Some(crate::tls::from_files(cert, key)?),
        _ if config.tls.tls_self_signed => Some(crate::tls::self_signed(
            &keys,
            &crate::tls::machine_names(addr),
        )?),
        _ => None,
    };
    let scheme = if tls.is_some() { "https" } else { "http" };
    if store::accounts::experimenter_count(&pool).await? == 0 {
        match &config.admin_password {
            Some(pw) => {
                accounts::create_experimenter(&pool, "system:startup", "admin", pw, Role::Admin)
                    .await
                    .map_err(|e| anyhow::anyhow!("--admin-password: {e}"))?;
                println!("Created the admin account \"admin\".");
            }
            None => {
                let token = accounts::new_setup_token(&pool).await?;
                println!(
                    "First start: create the experimenter account at {scheme}://{addr}/setup?token={token}"
                );
            }
        }
    }
    if config.lsl {
        crate::engine::procedure::lsl::enable(config.lsl_scope);
        tracing::info!(
            scope = config.lsl_scope.as_str(),
            "LSL: each station's signal and marker streams are published"
        );
    }
    // The E-stop latch before any controller connects: each is told it.
    let latch = estop_latch::EStopLatch::open(&keys, &pool).await?;
    // Every file is made by now: those an older release, a copy or a hand left open to
    // other users are named, with the command that closes them.
    crate::files::warn_open(&kept_files(&config, &keys));
    let events = controller_link::event_channel();
    let filing = filing::LinkFiling::start(pool.clone(), events.clone());
    let links = site_links
        .into_iter()
        .map(|site| {
            controller_link::ControllerLink::start(
                site,
                events.clone(),
                filing.clone(),
                latch.clone(),
            )
        })
        .collect();
    let sites = Sites::new(links, events, latch.clone());
    tokio::spawn(estop_latch::record_pending(latch, pool.clone()));
    tokio::spawn(crate::engine::procedure::lsl::republish_on_reconnect(
        pool.clone(),
        sites.clone(),
    ));
    tokio::spawn(backups.clone().run_schedule(pool.clone()));
    // Before the heartbeat and the address line: a signal from now on ends the heartbeat.
    let signalled = shutdown_signal();
    // A restore refuses to replace the database while this beats.
    let presence = presence::announce(&pool, &addr.to_string()).await?;
    let mut state = crate::state::AppState::new(pool, sites);
    state.web_dir = config.web_dir;
    state.login = std::sync::Arc::new(LoginLimiter::new(config.login.limits()));
    state.pairing = std::sync::Arc::new(crate::engine::procedure::stations::Pairing::new(
        config.connections.pairing_limits(),
    ));
    state.https = tls.is_some();
    state.audit_public = Some(audit_public);
    state.backups = backups;
    // The head after the start's own entries is signed before anyone is served.
    audit_signing::checkpoint_now(&state.pool, &audit_key)
        .await
        .map_err(|e| anyhow::anyhow!("signing the audit chain's head: {}", e.describe()))?;
    tokio::spawn(audit_signing::run_checkpoints(
        state.pool.clone(),
        audit_key,
    ));
    if let Some(t) = &tls {
        // Printed before the address line: whoever reads the address has the fingerprint.
        println!("TLS certificate SHA-256 fingerprint: {}", t.fingerprint);
    }
    println!(
        "Audit log signing key (Ed25519, public): {}",
        store::audit_chain::public_key_hex(&audit_public)
    );
    println!("bdft-lab server on {scheme}://{addr}");
    use std::io::Write;
    let _ = std::io::stdout().flush();
    crate::run(state, listener, &config.connections, tls, signalled).await?;
    presence.end().await?;
    Ok(())
}

/// The files `serve` keeps that hold keys or subject data, for the check of who else may
/// read them (`crate::files`): the database's, the keys, the E-stop latch, the backups.
fn kept_files(config: &ServeConfig, keys: &std::path::Path) -> Vec<(PathBuf, Holds)> {
    let mut files = vec![
        (audit_signing::key_path(keys), Holds::Secret),
        (estop_latch::latch_path(keys), Holds::Data),
    ];
    if let store::db::Location::File(db) = &config.db.db {
        files.extend(
            crate::files::database_files(db)
                .into_iter()
                .map(|f| (f, Holds::Data)),
        );
    }
    match &config.tls.tls_key {
        Some(key) => files.push((key.clone(), Holds::Secret)),
        None if config.tls.tls_self_signed => {
            files.push((crate::tls::self_signed_paths(keys).1, Holds::Secret));
        }
        None => {}
    }
    if let Some(dir) = &config.backup.backup_dir {
        files.push((dir.clone(), Holds::DataDir));
        if let Ok(entries) = std::fs::read_dir(dir) {
            files.extend(entries.flatten().map(|e| (e.path(), Holds::Data)));
        }
    }
    files
}

/// Each site's controller: where it comes from and its link key. Without --site, the one
/// site "main" with --controller or a started controller.
fn site_links(config: &ServeConfig) -> anyhow::Result<Vec<controller_link::LinkConfig>> {
    let silence = std::time::Duration::from_millis(config.controller_silence_ms);
    // A controller this server starts: this executable's own (or --controller-bin), with
    // --lsl when the server publishes streams and the --controller-arg given.
    let spawn = || -> anyhow::Result<controller_link::ControllerSource> {
        let (bin, sub) = match &config.controller_bin {
            Some(bin) => (bin.clone(), "serve"),
            None => (
                std::env::current_exe().context("locating this executable")?,
                "controller",
            ),
        };
        let lsl = config.lsl.then(|| {
            [
                "--lsl".to_string(),
                format!("--lsl-scope={}", config.lsl_scope.as_str()),
            ]
        });
        let args = std::iter::once(sub.to_string())
            .chain(lsl.into_iter().flatten())
            .chain(config.controller_args.iter().cloned())
            .collect();
        Ok(controller_link::ControllerSource::Spawn { bin, args })
    };
    // A started controller gets --controller-key-file's key, or a new one at every start.
    let started_key = || match &config.controller_key_file {
        Some(path) => LinkKey::load(path),
        None => LinkKey::generate(),
    };
    if config.sites.is_empty() {
        let (source, key) = match config.controller {
            Some(a) => {
                let Some(path) = &config.controller_key_file else {
                    anyhow::bail!(
                        "--controller {a} needs --controller-key-file FILE: the key the controller was started with (`bdft-controller keygen FILE`, then `bdft-controller serve --key-file FILE` there)"
                    )
                };
                (
                    controller_link::ControllerSource::Connect(a),
                    LinkKey::load(path)?,
                )
            }
            None => (spawn()?, started_key()?),
        };
        return Ok(vec![controller_link::LinkConfig {
            site: sites::DEFAULT.to_string(),
            source,
            key,
            silence,
        }]);
    }
    let mut seen = std::collections::BTreeSet::new();
    let mut links = Vec::new();
    for site in &config.sites {
        if !seen.insert(site.name.as_str()) {
            anyhow::bail!("--site {}: given twice; each site once", site.name);
        }
        let (source, key) = match &site.remote {
            Some((addr, key_file)) => (
                controller_link::ControllerSource::Connect(*addr),
                LinkKey::load(key_file)
                    .with_context(|| format!("--site {}: its key file", site.name))?,
            ),
            None => (spawn()?, started_key()?),
        };
        links.push(controller_link::LinkConfig {
            site: site.name.clone(),
            source,
            key,
            silence,
        });
    }
    Ok(links)
}

/// SIGINT or SIGTERM, its handlers installed now; logged when it comes.
fn shutdown_signal() -> impl std::future::Future<Output = ()> + Send + 'static {
    let signalled = bdft_controller::runtime::shutdown_signal();
    async move {
        signalled.await;
        tracing::info!("shutting down");
    }
}
