//! The browser pages: plain HTML, CSS and ES modules from `web/`, embedded in the binary at
//! build time (a lab without internet needs nothing else), or read from a directory with
//! `--web-dir` while developing them.

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
