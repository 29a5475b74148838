//! The browser pages: plain HTML, CSS and ES modules from `web/`, embedded in the binary at
//! build time (a lab without internet needs nothing else), or read from a directory with
//! `--web-dir` while developing them.
//!
//! `web/` is plain HTML, CSS and ES modules, no build step, nothing from the internet; every page
//! is sent with a strict CSP (`default-src 'self'`, no inline script or style). Its files:
//!
//! - `common.js` — API calls, DOM helper; shared.
//! - `station.*` — the subject-facing station, `station.js` starting it from its parts:
//!   `station-connection.js` (token and pairing, the state poll, the socket), `station-phases.js`
//!   (which phase shows; a test's run starts and ends there), `station-instructions.js` and
//!   `station-consent.js` (the study's texts; the consent form and decision), `station-survey.js`,
//!   `station-pursuit.js` (the pursuit display: live samples, drawing, shaking), `station-input.js`
//!   (pointer and gamepad, sent to the controller), `station-timing.js` (the display's health and
//!   timing, which the server judges a test by) and `station-errors.js` (the error banner).
//! - `subject.*` — the subject's own page (progress, withdrawal; the token leaves the address at
//!   once).
//! - `index.html` + `dashboard*.js` — the dashboard: `dashboard-monitor.js` the live monitor, with
//!   its live feed (socket, samples, E-stop latch) in `dashboard-monitor-live.js`, what it knows of
//!   each station in `dashboard-monitor-state.js`, a station's panel in
//!   `dashboard-monitor-panel.js` and the panel's Start, Abort, redo and accept in
//!   `dashboard-monitor-actions.js`; `dashboard-accounts.js` accounts and what the role shows;
//!   `dashboard-confirm.js` the confirmation of irreversible actions; `dashboard-workbench.js` the
//!   Workbench's analysis in `#wb-analysis`, drawn on canvases from the server's numbers;
//!   `dashboard-conditions.js` its machine-conditions table;
//!   `dashboard-configs.js` and `dashboard-bench.js` its configuration versions and bench runs,
//!   plots drawn as SVG from the stored traces; `dashboard-plan.js` the power planner;
//!   `dashboard-backups.js` the admins' Backups panel; `dashboard-erasure.js` an admin's erasure
//!   with its confirmation and the erasures with the backups still holding their data;
//!   `dashboard-protocol.js` the link to the study's ethics-board package, a page styled by
//!   `protocol.css` — its head and foot, carrying the protocol hash, repeat on every printed page —
//!   with `protocol.js`'s print button. The other `dashboard-*.js` are one panel or helper each,
//!   named by it (`-core`, `-study`, `-subjects`, `-stations`, `-pilot`, `-calibrate`, `-results`,
//!   `-audit`, `-identification`, `-chart`, `-download`).
//! - `setup.*` — the first account.
//!
//! *Invariant:* the station page and the subject's page never show a controller's name (their APIs
//! never send one).

use std::path::PathBuf;

use axum::extract::{Path, State};
use axum::response::{IntoResponse, Response};
use include_dir::{Dir, include_dir};

use super::error::AppError;
use super::page;
use crate::state::AppState;

static WEB: Dir<'static> = include_dir!("$CARGO_MANIFEST_DIR/../web");

fn content_type(name: &str) -> &'static str {
    match name.rsplit('.').next() {
        Some("html") => "text/html; charset=utf-8",
        Some("js") => "text/javascript; charset=utf-8",
        Some("css") => "text/css; charset=utf-8",
        Some("svg") => "image/svg+xml",
        Some("png") => "image/png",
        Some("json") => "application/json",
        Some("txt") | Some("md") => "text/plain; charset=utf-8",
        Some("woff2") => "font/woff2",
        Some("ttf") => "font/ttf",
        _ => "application/octet-stream",
    }
}

async fn file(dir: &Option<PathBuf>, name: &str) -> Option<Vec<u8>> {
    // Only plain names below web/: no traversal, no hidden files.
    if name.is_empty() || name.split('/').any(|p| p.is_empty() || p.starts_with('.')) {
        return None;
    }
    match dir {
        Some(d) => tokio::fs::read(d.join(name)).await.ok(),
        None => WEB.get_file(name).map(|f| f.contents().to_vec()),
    }
}

async fn serve(s: &AppState, name: &str) -> Response {
    match file(&s.web_dir, name).await {
        Some(body) => page::response(content_type(name), body),
        None => AppError::NotFound("page").into_response(),
    }
}

/// `/` → the dashboard, `/station`, `/setup`, `/subject` → their pages, `/<file>` → a file.
async fn page(State(s): State<AppState>, Path(path): Path<String>) -> Response {
    let name = match path.as_str() {
        "station" => "station.html",
        "setup" => "setup.html",
        "subject" => "subject.html",
        other => other,
    };
    serve(&s, name).await
}

async fn index(State(s): State<AppState>) -> Response {
    serve(&s, "index.html").await
}

/// The pages: `/` and every file below it (unknown API paths end here too, as JSON 404s).
pub fn routes() -> axum::Router<AppState> {
    use axum::routing::get;
    axum::Router::new()
        .route("/", get(index))
        .route("/{*path}", get(page))
}
