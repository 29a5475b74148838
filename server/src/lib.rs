//! bdft-lab's experiment server: runs the ethics-board-approved protocol of a
//! biodynamic-feedthrough study — studies, subjects, schedules, targets, consent, trials on
//! the real-time controller, surveys — stores everything in SQLite and exports it.
//!
//! Three layers, each importing only the ones below it: [`http`] (routes, extractors, the
//! OpenAPI document) → [`engine`] (the protocol's rules, no HTTP) → [`store`] (the only SQL).
//! [`http::app`] is the whole HTTP surface; [`run`] serves it on a listener until shutdown
//! (with the connection bounds of [`serve`]), so tests bind port 0.
//!
//! Files beside the layers:
//!
//! - `main.rs` → `cli/` (one module per command, `mod.rs` the list and the dispatch):
//!   `bdft-server`'s commands — `serve` (the default), `pilot`, `plan`,
//!   `calibrate`, `findings`, `export`, `backup`, `restore`, `audit verify`, and the hidden
//!   `controller`, which is how `serve` starts its controller from the same executable.
//! - `config.rs` — every setting as one `clap::Args` struct per command with its environment
//!   variable (`.env.sample`; one is for tests only: `--db-max-pages` caps the database as a full
//!   disk would).
//! - `state.rs` — `AppState` (pool, controller link, login limiter, pairing codes, pilot job).
//! - `serve.rs` — the accept loop on hyper's HTTP/1 builder: header-read timeout, a request body's
//!   deadline (408 and the connection closed past `--body-timeout-ms`, unless it keeps arriving at
//!   `--min-body-rate`), connection cap (a WebSocket holds its slot until it closes) and the cap
//!   per client address (one more from that address is answered 429 with Retry-After and closed
//!   without taking a slot), TCP_NODELAY, and TLS when on (the handshake in the connection's task,
//!   bounded like a request head; a first byte that is not a TLS handshake is plain HTTP, answered
//!   by a 308 to `https://` at a checked Host on that same connection, slots held, one request of
//!   at most 8 KiB). *Invariant:* one address never holds more than `--max-connections-per-address`
//!   of the `--max-connections` slots, so other addresses — the experimenter's session, the E-stop,
//!   health — are served through its flood.
//! - `tls.rs` — HTTPS: the lab's PEM certificate and key, or a self-signed certificate made at the
//!   first start (subject `bdft-lab server HOST`) and kept beside the database, its SHA-256
//!   fingerprint printed at every start (`Secure` cookies and HSTS follow `AppState::https`).
//! - `files.rs` — the files of keys and subject data: created 0600 (the SQLite file made empty
//!   before SQLite opens it, so its `-wal`/`-shm` follow), their directories 0700, and `serve`'s
//!   start-up warning about those others may read, with the `chmod` to run. *Invariant:* no such
//!   file is created open and narrowed afterwards.
//! - `error.rs` — `AppError`, the one error type of every layer (no HTTP in it); a database error
//!   from a race between users (a unique or foreign key broken, an erased subject's trigger) is a
//!   conflict, never an internal error; a busy database and a full disk are `Unavailable`, 503 with
//!   what to do, not a bug; `TooManyRequests` carries when to ask again, sent as a 429's
//!   `Retry-After` (whole seconds, at least 1).

pub mod cli;
pub mod config;
pub mod engine;
pub mod error;
pub mod files;
pub mod http;
pub mod serve;
pub mod state;
pub mod store;
pub mod tls;

pub use http::app;
use state::AppState;

/// Serves `app` on `listener` until `shutdown` resolves.
pub async fn run(
    state: AppState,
    listener: tokio::net::TcpListener,
    limits: &config::ConnectionConfig,
    tls: Option<tls::Tls>,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    serve::serve(
        app(state),
        listener,
        limits,
        tls.map(|t| t.acceptor),
        shutdown,
    )
    .await
}
