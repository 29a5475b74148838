//! Bench runs: start one (in the background, one at a time), its progress, the stored runs
//! with their metrics, reductions and traces, and a run as CSV.

use axum::extract::{DefaultBodyLimit, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use bdft_protocol::study::RigKind;
use serde::Serialize;
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson};
use super::extract::{AppPath, Experimenter};
use crate::engine::accounts::Drive;
use crate::engine::machine::bench::{self, BenchRequest, BenchStatus, RunView};
use crate::engine::results::export::ExportedAll;
use crate::state::AppState;
use crate::store::bench::BenchRun;
use crate::store::{self, Change};

/// Largest bench request: an uploaded reference of `MAX_SAMPLES` lines fits.
const MAX_BENCH_BODY: usize = 4 * 1024 * 1024;
/// Runs listed, newest first.
const LIST_LIMIT: i64 = 50;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(start_bench, bench_status))
        .layer(DefaultBodyLimit::max(MAX_BENCH_BODY))
        .route_layer(axum::middleware::from_fn(refuse_announced_oversize))
        .routes(routes!(list_runs))
        .routes(routes!(get_run))
        .routes(routes!(export_run))
}

/// A request that announces a body beyond the limit is refused from its header, before any
/// of it is read: the client learns at once, and nothing is buffered. (The body limit alone
/// would read up to the limit first.)
async fn refuse_announced_oversize(
    req: axum::extract::Request,
    next: axum::middleware::Next,
) -> axum::response::Response {
    let announced = req
        .headers()
        .get(axum::http::header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok());
    if announced.is_some_and(|n| n > MAX_BENCH_BODY as u64) {
        return AppError::TooLarge.into_response();
    }
    next.run(req).await
}

#[derive(Debug, Serialize, ToSchema)]
pub struct BenchStarted {
    pub run_id: i64,
}

/// Starts a bench run in the background (progress at GET /api/bench); 409 while one runs.
/// A run on the real rig drives its site's machine: an account limited to sites runs it on
/// theirs only. A simulated run (in the server) drives no site's.
#[utoipa::path(post, path = "/api/bench", tag = "bench", request_body = BenchRequest,
    responses((status = 200, body = BenchStarted)))]
async fn start_bench(
    State(s): State<AppState>,
    who: Experimenter,
    AppJson(req): AppJson<BenchRequest>,
) -> ApiResult<BenchStarted> {
    let link = match &req.site {
        Some(name) => s.sites.named(name)?,
        None => s.sites.first(),
    };
    if let Some(study) = req.study_id {
        let study = store::studies::get(&s.pool, study).await?;
        if study.params.rig == RigKind::Real {
            who.may_drive(&s.pool, Drive::Bench, &[link.site()]).await?;
        }
    }
    let run_id = s.bench.start(&s.pool, link, &who.username, &req).await?;
    Ok(AppJson(BenchStarted { run_id }))
}

/// Whether a bench run is going, and how far it is.
#[utoipa::path(get, path = "/api/bench", tag = "bench", responses((status = 200, body = BenchStatus)))]
async fn bench_status(State(s): State<AppState>, _who: Experimenter) -> AppJson<BenchStatus> {
    AppJson(s.bench.status())
}

/// The newest 50 bench runs.
#[utoipa::path(get, path = "/api/bench/runs", tag = "bench", responses((status = 200, body = Vec<BenchRun>)))]
async fn list_runs(State(s): State<AppState>, _who: Experimenter) -> ApiResult<Vec<BenchRun>> {
    Ok(AppJson(store::bench::runs(&s.pool, LIST_LIMIT).await?))
}

/// A run with its results (metrics, reductions against each design's twin) and traces.
#[utoipa::path(get, path = "/api/bench/runs/{id}", tag = "bench", params(("id" = i64, Path)),
    responses((status = 200, body = RunView)))]
async fn get_run(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<RunView> {
    Ok(AppJson(bench::view(&s.pool, id).await?))
}

/// A run as CSV: its results' metrics and reductions, and the decimated traces.
#[utoipa::path(get, path = "/api/bench/runs/{id}/export", tag = "bench", params(("id" = i64, Path)),
    responses((status = 200, description = "CSV", body = String, content_type = "text/csv")))]
async fn export_run(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> Result<Response, AppError> {
    let view = bench::view(&s.pool, id).await?;
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit(
            "export",
            Some(format!("bench_run:{id}")),
            ExportedAll { kind: "bench" },
        )
        .await?;
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"bdft-bench{id}.csv\""),
            ),
        ],
        crate::engine::results::export::bench::csv(&view),
    )
        .into_response())
}
