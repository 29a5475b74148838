//! bdft-lab's experiment server: runs the ethics-board-approved protocol of a
//! biodynamic-feedthrough study — studies, subjects, schedules, targets, consent, trials on
//! the real-time controller, surveys — stores everything in SQLite and exports it.
//!
//! `app(state)` is the whole HTTP surface; `run` serves it on a listener until shutdown, so
//! tests bind port 0.

pub mod api;
pub mod auth;
pub mod cli;
pub mod controller_link;
pub mod db;
pub mod error;
pub mod export;
pub mod openapi;
pub mod orchestrator;
pub mod pilot;
pub mod plots;
pub mod state;
pub mod station;
pub mod store;
pub mod study;
pub mod web;

use std::net::SocketAddr;

use axum::Router;
use axum::extract::{DefaultBodyLimit, State};
use axum::routing::{get, post};
use serde_json::json;

use crate::auth::SubjectAuth;
use crate::error::{ApiResult, AppJson};
use crate::state::AppState;

/// Largest request body accepted (study parameters are a few kB).
const MAX_BODY: usize = 256 * 1024;

pub fn app(state: AppState) -> Router {
    Router::new()
        .route("/api/health", get(health))
        .route(
            "/api/openapi.json",
            get(|| async { axum::Json(openapi::document()) }),
        )
        .route("/api/setup", get(auth::setup_status).post(auth::setup))
        .route("/api/login", post(auth::login))
        .route("/api/subject", get(subject_self))
        .merge(api::router())
        .merge(station::router())
        .route("/", get(web::index))
        .route("/{*path}", get(web::page))
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .with_state(state)
}

async fn health(State(s): State<AppState>) -> AppJson<serde_json::Value> {
    AppJson(json!({ "ok": true, "controller_connected": s.controller.is_connected() }))
}

/// The subject's own page data: progress without controller names.
async fn subject_self(State(s): State<AppState>, who: SubjectAuth) -> ApiResult<serde_json::Value> {
    let subject = store::subject(&s.pool, who.id).await?;
    let trials = store::trials_of(&s.pool, who.id).await?;
    let tests: Vec<_> = api::latest_attempts(&trials).map(|t| json!({ "label": t.blinded_label, "station": t.station, "status": t.status, "practice": t.practice })).collect();
    Ok(AppJson(
        json!({ "code": subject.code, "consent": subject.consent_decision, "withdrawn": subject.withdrawn_at.is_some(), "tests": tests }),
    ))
}

/// Serves `app` on `listener` until `shutdown` resolves.
pub async fn run(
    state: AppState,
    listener: tokio::net::TcpListener,
    shutdown: impl std::future::Future<Output = ()> + Send + 'static,
) -> std::io::Result<()> {
    axum::serve(
        listener,
        app(state).into_make_service_with_connect_info::<SocketAddr>(),
    )
    .with_graceful_shutdown(shutdown)
    .await
}
