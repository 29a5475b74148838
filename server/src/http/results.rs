//! Results: summary statistics, box plots, streamed CSV and Parquet exports and the audit
//! log.

use axum::body::Body;
use axum::extract::State;
use axum::http::header;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppError, AppJson};
use super::extract::{AppPath, AppQuery, Experimenter};
use crate::engine::dry_runs::job::JobStatus;
use crate::engine::dry_runs::power::{PlanReport, PlanRequest, PlanSource, PlanStatus, plan_study};
use crate::engine::results::export::{
    self, ExportFormat, ExportKind, ExportRequest, ExportedAll, SampleCut, bids,
};
use crate::engine::results::inference_table::{StatsRow, study_table};
use crate::engine::results::learning::{LearningCurve, learning_curve};
use crate::engine::results::page::{parse_file, plot as draw_plot};
use crate::engine::results::stats::{Stats, summary_stats};
use crate::state::AppState;
use crate::store::audit::AuditEntry;
use crate::store::audit_chain::{self, Verdict};
use crate::store::{self, Change};

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(summary))
        .routes(routes!(inference))
        .routes(routes!(plan))
        .routes(routes!(start_plan_job))
        .routes(routes!(plan_job_status))
        .routes(routes!(plot))
        .routes(routes!(learning))
        .routes(routes!(download))
        .routes(routes!(bids_zip))
        .routes(routes!(audit_log))
        .routes(routes!(audit_export))
        .routes(routes!(audit_verify))
}

/// Statistics per compensator × seat of every metric and rating.
#[utoipa::path(get, path = "/api/studies/{id}/summary", tag = "results", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<Stats>)))]
async fn summary(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
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
    AppPath(id): AppPath<i64>,
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
    AppPath(id): AppPath<i64>,
    AppJson(req): AppJson<PlanRequest>,
) -> ApiResult<PlanReport> {
    if req.source == PlanSource::Population {
        return Err(AppError::BadRequest(format!(
            "source: a plan with the population runs full trials for minutes: start it with \
             POST /api/studies/{id}/plan-job and follow GET /api/plan-job"
        )));
    }
    Ok(AppJson(
        plan_study(&s.pool, id, req, Default::default()).await?,
    ))
}

#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct PlanStarted {
    pub started: bool,
}

/// The power planner in the background, with progress at GET /api/plan-job: with the
/// study's synthetic population (whole simulated studies of full trials) or a pilot's
/// model. One plan at a time.
#[utoipa::path(post, path = "/api/studies/{id}/plan-job", tag = "results", params(("id" = i64, Path)),
    request_body = PlanRequest, responses((status = 200, body = PlanStarted)))]
async fn start_plan_job(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(req): AppJson<PlanRequest>,
) -> ApiResult<PlanStarted> {
    s.plan.start(&s.pool, id, req).await?;
    Ok(AppJson(PlanStarted { started: true }))
}

/// Where the background power plan stands: progress (simulated trials), then its report or
/// error.
#[utoipa::path(get, path = "/api/plan-job", tag = "results", responses((status = 200, body = JobStatus<PlanReport>)))]
async fn plan_job_status(State(s): State<AppState>, _who: Experimenter) -> AppJson<PlanStatus> {
    AppJson(s.plan.status())
}

/// A figure: the box plot of one variable by compensator and seat (`{variable}.svg` or
/// `.png`), or the learning curve (`learning_curve.svg` or `.png`).
#[utoipa::path(get, path = "/api/studies/{id}/plots/{file}", tag = "results",
    params(("id" = i64, Path), ("file" = String, Path, description = "e.g. mse_tracking_mm2.svg or learning_curve.png")),
    responses((status = 200, description = "the figure as SVG (`.svg`) or PNG (`.png`)",
        content((String = "image/svg+xml"), ("image/png")))))]
async fn plot(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath((id, file)): AppPath<(i64, String)>,
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
    AppPath(id): AppPath<i64>,
) -> ApiResult<LearningCurve> {
    Ok(AppJson(learning_curve(&s.pool, id).await?))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct ExportQuery {
    /// `csv` (default) or `parquet`.
    format: Option<String>,
    /// Samples only: one subject's, by code (`S01`).
    subject: Option<String>,
    /// Samples only: one test attempt's, by its `trial_id`.
    trial: Option<String>,
}

impl ExportQuery {
    /// The request for `kind` (its name, optionally with `.csv` or `.parquet`).
    fn request(self, kind: &str) -> Result<ExportRequest, AppError> {
        let (name, extension) = kind.split_once('.').unwrap_or((kind, ""));
        let kind: ExportKind = name
            .parse()
            .map_err(|e| AppError::BadRequest(format!("kind: {e}")))?;
        let format = match (self.format.as_deref(), extension) {
            (Some(f), _) | (None, f @ ("csv" | "parquet")) => f,
            (None, "") => "csv",
            (None, other) => other,
        };
        let format: ExportFormat = format
            .parse()
            .map_err(|e| AppError::BadRequest(format!("format: {e}")))?;
        let trial = self
            .trial
            .map(|t| {
                t.parse::<i64>().map_err(|_| {
                    AppError::BadRequest(format!(
                        "trial: {:?} is not a trial id; allowed: a whole number, a trial_id of the trials export",
                        t.chars().take(40).collect::<String>()
                    ))
                })
            })
            .transpose()?;
        Ok(ExportRequest {
            kind,
            format,
            cut: SampleCut::from_options(self.subject, trial)?,
        })
    }
}

/// An export as CSV or Parquet (`?format=`): `trials`, `samples` (all, `?subject=S01` or
/// `?trial=ID`), `subjects`, `codebook`, `summary`, `stats` or `notes`, optionally with
/// `.csv` or `.parquet`; streamed: the response starts at once and is written as rows are
/// read.
#[utoipa::path(get, path = "/api/studies/{id}/export/{kind}", tag = "results",
    params(("id" = i64, Path), ("kind" = String, Path, description = "trials, samples, subjects, codebook, summary, stats or notes"), ExportQuery),
    responses((status = 200, description = "the table as CSV (`format=csv`, the default) or Parquet (`format=parquet`)",
            content((String = "text/csv"), ("application/vnd.apache.parquet"))),
        (status = 422, description = "a kind, format or cut that is not allowed, named with what is")))]
async fn download(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath((id, kind)): AppPath<(i64, String)>,
    AppQuery(q): AppQuery<ExportQuery>,
) -> Result<Response, AppError> {
    let req = q.request(&kind)?;
    if !req.kind.per_study() {
        return Err(AppError::BadRequest(
            "kind: the audit log is not one study's; it is at /api/audit/export".into(),
        ));
    }
    let study = store::studies::get(&s.pool, id).await?;
    export::check(&s.pool, id, &req).await?;
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit("export", Some(format!("study:{id}")), req.audited())
        .await?;
    let filename = req.file_name(study.id, study.protocol_hash.as_deref());
    let format = req.format;
    Ok(attachment(stream(&s, id, req), format, &filename))
}

/// The study as a BIDS dataset (motion, beh, events, participants, with sidecars) in a zip,
/// streamed as it is made; refused with 422 when the study has no recorded test.
#[utoipa::path(get, path = "/api/studies/{id}/bids.zip", tag = "results",
    params(("id" = i64, Path)),
    responses((status = 200, description = "the BIDS dataset as a zip", content_type = "application/zip"),
        (status = 422, description = "the study has no recorded test to export")))]
async fn bids_zip(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> Result<Response, AppError> {
    let study = store::studies::get(&s.pool, id).await?;
    bids::check(&s.pool, id).await?;
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit(
            "export",
            Some(format!("study:{id}")),
            ExportedAll { kind: "bids" },
        )
        .await?;
    let hash = study.protocol_hash.as_deref().and_then(|h| h.get(..8));
    let root = format!("bdft-study{id}-bids-{}", hash.unwrap_or("unlocked"));
    let (w, r) = tokio::io::duplex(1 << 16);
    let pool = s.pool.clone();
    let folder = root.clone();
    tokio::spawn(async move {
        let mut zip = bids::ZipSink::new(w, &folder);
        let done = match bids::write(&pool, id, &mut zip).await {
            Ok(_) => zip.finish().await,
            Err(e) => Err(e),
        };
        if let Err(e) = done {
            tracing::error!("BIDS export of study {id} failed mid-stream: {e}");
        }
    });
    Ok((
        [
            (header::CONTENT_TYPE, "application/zip".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{root}.zip\""),
            ),
        ],
        Body::from_stream(tokio_util::io::ReaderStream::new(r)),
    )
        .into_response())
}

/// The export written into the response as it is read (`study_id` unused for `audit`).
fn stream(s: &AppState, study_id: i64, req: ExportRequest) -> Body {
    let (w, r) = tokio::io::duplex(1 << 16);
    let pool = s.pool.clone();
    tokio::spawn(async move {
        if let Err(e) = export::write(&pool, study_id, &req, w).await {
            tracing::error!("export {req:?} (study {study_id}) failed mid-stream: {e}");
        }
    });
    Body::from_stream(tokio_util::io::ReaderStream::new(r))
}

fn attachment(body: Body, format: ExportFormat, filename: &str) -> Response {
    (
        [
            (header::CONTENT_TYPE, format.mime().to_string()),
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
    responses((status = 200, description = "CSV", body = String, content_type = "text/csv")))]
async fn audit_export(State(s): State<AppState>, who: Experimenter) -> Result<Response, AppError> {
    Change::begin(&s.pool, who.username.as_str())
        .await?
        .commit(
            "export",
            None,
            ExportedAll {
                kind: ExportKind::Audit.name(),
            },
        )
        .await?;
    let body = stream(&s, 0, ExportRequest::new(ExportKind::Audit));
    Ok(attachment(body, ExportFormat::Csv, "bdft-audit.csv"))
}

/// Whether the audit log is intact: its hash chain and signed checkpoints, checked against
/// this server's key (`bdft-server audit verify` does the same on a file).
#[utoipa::path(get, path = "/api/audit/verify", tag = "results",
    responses((status = 200, body = AuditVerifyReport)))]
async fn audit_verify(
    State(s): State<AppState>,
    _who: Experimenter,
) -> ApiResult<AuditVerifyReport> {
    // One read transaction: the log, the chain and the checkpoints of one moment.
    let mut tx = s.pool.begin().await?;
    let verdict = audit_chain::verify(&mut tx, s.audit_public.as_ref()).await?;
    Ok(AppJson(AuditVerifyReport {
        report: verdict.to_string(),
        verdict,
    }))
}

/// What `/api/audit/verify` found, and the sentence `bdft-server audit verify` prints for it.
#[derive(Debug, Serialize, utoipa::ToSchema)]
struct AuditVerifyReport {
    #[serde(flatten)]
    verdict: Verdict,
    /// "intact: N entries, head H, last checkpoint at entry K", or the first entry that
    /// fails and why.
    report: String,
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
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
    AppQuery(q): AppQuery<AuditQuery>,
) -> ApiResult<Vec<AuditEntry>> {
    let limit = q.limit.unwrap_or(200).clamp(1, 10_000);
    Ok(AppJson(store::audit::newest(&s.pool, limit).await?))
}
