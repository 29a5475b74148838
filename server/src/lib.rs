//! bdft-lab's experiment server: runs the ethics-board-approved protocol of a
//! biodynamic-feedthrough study — studies, subjects, schedules, targets, consent, trials on
//! the real-time controller, surveys — stores everything in SQLite and exports it.
//!
//! Three layers, each importing only the ones below it: [`http`] (routes, extractors, the
//! OpenAPI document) → [`engine`] (the protocol's rules, no HTTP) → [`store`] (the only SQL).
//! [`http::app`] is the whole HTTP surface; [`run`] serves it on a listener until shutdown
//! (with the connection bounds of [`serve`]), so tests bind port 0.

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
