//! Results: summary statistics, box plots, streamed CSV exports and the audit log.

use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::Deserialize;
use serde_json::json;
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson};
use super::extract::Experimenter;
use crate::engine::export::{self, ExportKind};
use crate::engine::inference_table::{StatsRow, study_table};
use crate::engine::learning::{LearningCurve, learning_curve};
use crate::engine::power::{PlanReport, PlanRequest, plan_study};
use crate::engine::results::{parse_file, plot as draw_plot};
use crate::engine::stats::{Stats, summary_stats};
use crate::state::AppState;
use crate::store::audit::AuditEntry;
use crate::store::{self, Change};

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(summary))
        .routes(routes!(inference))
        .routes(routes!(plan))
        .routes(routes!(plot))
        .routes(routes!(learning))
        .routes(routes!(download))
        .routes(routes!(audit_log))
        .routes(routes!(audit_export))
}

/// Statistics per compensator × seat of every metric and rating.
#[utoipa::path(get, path = "/api/studies/{id}/summary", tag = "results", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<Stats>)))]
async fn summary(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Vec<Stats>> {
    store::studies::get(&s.pool, id).await?;
    Ok(AppJson(summary_stats(&s.pool, id).await?))
}

/// The study's inferential statistics (Friedman, pairwise exact Wilcoxon with Holm,
/// on against off, RM-ANOVA), with a statement on every comparison that cannot reach
/// significance at this n.
#[utoipa::path(get, path = "/api/studies/{id}/stats", tag = "results", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<StatsRow>)))]
async fn inference(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Vec<StatsRow>> {
    Ok(AppJson(study_table(&s.pool, id).await?))
}

/// The power planner: for candidate numbers of subjects, the chance that each pair of
/// compensators differs significantly (exact Wilcoxon, Holm), simulated with the spread of
/// this study's data (a pilot's dry-run copy); pairs the small-n floor rules out are said
/// to be impossible.
#[utoipa::path(post, path = "/api/studies/{id}/plan", tag = "results", params(("id" = i64, Path)),
    request_body = PlanRequest, responses((status = 200, body = PlanReport)))]
async fn plan(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
    AppJson(req): AppJson<PlanRequest>,
) -> ApiResult<PlanReport> {
    Ok(AppJson(plan_study(&s.pool, id, req).await?))
}

/// A figure: the box plot of one variable by compensator and seat (`{variable}.svg` or
/// `.png`), or the learning curve (`learning_curve.svg` or `.png`).
#[utoipa::path(get, path = "/api/studies/{id}/plots/{file}", tag = "results",
    params(("id" = i64, Path), ("file" = String, Path, description = "e.g. mse_tracking_mm2.svg or learning_curve.png")),
    responses((status = 200, description = "SVG or PNG image", content_type = "image/svg+xml")))]
async fn plot(
    State(s): State<AppState>,
    _who: Experimenter,
    Path((id, file)): Path<(i64, String)>,
) -> Result<Response, AppError> {
    let (which, format) = parse_file(&file)?;
    let body = draw_plot(&s.pool, id, which, format).await?;
    Ok((
        [
            (header::CONTENT_TYPE, format.mime()),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response())
}

/// The learning curve's numbers: each subject's tracking error by test position (1 … 2k
/// across both seats; the latest complete attempt of each test), the median per seat and
/// position, and the learning slope (median over subjects of the least-squares slope of
/// ln MSE on position).
#[utoipa::path(get, path = "/api/studies/{id}/learning", tag = "results", params(("id" = i64, Path)),
    responses((status = 200, body = LearningCurve)))]
async fn learning(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<LearningCurve> {
    Ok(AppJson(learning_curve(&s.pool, id).await?))
}

/// A CSV export (`trials`, `samples`, `summary` or `notes`, optionally with `.csv`), streamed: the
/// response starts at once and is written as rows are read.
#[utoipa::path(get, path = "/api/studies/{id}/export/{kind}", tag = "results",
    params(("id" = i64, Path), ("kind" = String, Path, description = "trials, samples, summary, stats or notes")),
    responses((status = 200, description = "CSV", content_type = "text/csv")))]
async fn download(
    State(s): State<AppState>,
    who: Experimenter,
    Path((id, kind)): Path<(i64, String)>,
) -> Result<Response, AppError> {
    let kind_name = kind.trim_end_matches(".csv").to_string();
    let kind: ExportKind = kind_name.parse().map_err(AppError::BadRequest)?;
    if !kind.per_study() {
        return Err(AppError::BadRequest(
            "kind: the audit log is not one study's; it is at /api/audit/export".into(),
        ));
    }
    let study = store::studies::get(&s.pool, id).await?;
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit(
            "export",
            Some(format!("study:{id}")),
            json!({ "kind": kind_name }),
        )
        .await?;
    let body = stream(&s, id, kind);
    let filename = format!(
        "bdft-study{}-{kind_name}-{}.csv",
        study.id,
        &study
            .protocol_hash
            .unwrap_or_default()
            .get(..8)
            .unwrap_or("unlocked")
    );
    Ok(csv(body, &filename))
}

/// The export written into the response as it is read (`study_id` unused for `audit`).
fn stream(s: &AppState, study_id: i64, kind: ExportKind) -> Body {
    let (w, r) = tokio::io::duplex(1 << 16);
    let pool = s.pool.clone();
    tokio::spawn(async move {
        if let Err(e) = export::write(&pool, study_id, kind, w).await {
            tracing::error!("export {kind:?} (study {study_id}) failed mid-stream: {e}");
        }
    });
    Body::from_stream(tokio_util::io::ReaderStream::new(r))
}

fn csv(body: Body, filename: &str) -> Response {
    (
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{filename}\""),
            ),
        ],
        body,
    )
        .into_response()
}

/// The whole audit log as CSV, oldest first (`id, at, actor, action, target, detail` with
/// the detail as JSON), streamed.
#[utoipa::path(get, path = "/api/audit/export", tag = "results",
    responses((status = 200, description = "CSV", content_type = "text/csv")))]
async fn audit_export(State(s): State<AppState>, who: Experimenter) -> Result<Response, AppError> {
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit("export", None, json!({ "kind": "audit" }))
        .await?;
    let body = stream(&s, 0, ExportKind::Audit);
    Ok(csv(body, "bdft-audit.csv"))
}

#[derive(Debug, Deserialize, IntoParams)]
struct AuditQuery {
    /// How many of the newest rows: 1 to 10000 (default 200).
    limit: Option<i64>,
}

/// The audit log, newest first.
#[utoipa::path(get, path = "/api/audit", tag = "results", params(AuditQuery),
    responses((status = 200, body = Vec<AuditEntry>)))]
async fn audit_log(
    State(s): State<AppState>,
    _who: Experimenter,
    Query(q): Query<AuditQuery>,
) -> ApiResult<Vec<AuditEntry>> {
    let limit = q.limit.unwrap_or(200).clamp(1, 10_000);
    Ok(AppJson(store::audit::newest(&s.pool, limit).await?))
}
