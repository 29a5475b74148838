//! Subjects: enrolment, the experimenter's view of each, withdrawal, and the subject's own
//! page data (bearer token of the subject).

use axum::extract::State;
use serde::{Deserialize, Serialize};
use utoipa::ToSchema;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::bodies::ReasonBody;
use super::error::{ApiResult, AppJson, Done, optional_json};
use super::extract::{AppPath, AppQuery, Experimenter, SubjectAuth};
use crate::engine::procedure::enrolment::enrol;
use crate::engine::procedure::subjects::{self, OwnProgress, SubjectDetail, SubjectProgress};
use crate::engine::results::identification::{self, IdentificationView, SubjectStability};
use crate::state::AppState;
use crate::store;
use crate::store::subjects::Subject;

pub fn experimenter() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(list_subjects, enrol_subject))
        .routes(routes!(get_subject))
        .routes(routes!(get_identification))
        .routes(routes!(get_subject_stability))
        .routes(routes!(withdraw))
}

/// The routes of a subject's own page (bearer token of the subject).
pub fn subject() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(own_progress))
        .routes(routes!(withdraw_own))
}

/// The study's subjects with their progress.
#[utoipa::path(get, path = "/api/studies/{id}/subjects", tag = "subjects", params(("id" = i64, Path)),
    responses((status = 200, body = Vec<SubjectProgress>)))]
async fn list_subjects(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<Vec<SubjectProgress>> {
    Ok(AppJson(subjects::progress_of_study(&s.pool, id).await?))
}

#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct EnrolBody {
    /// A simulated subject: the synthetic operator drives its tests (dry runs); flagged in
    /// every export.
    #[serde(default)]
    synthetic: bool,
}

#[derive(Debug, Serialize, ToSchema)]
pub struct Enrolled {
    pub subject: Subject,
    /// The token of the subject's own page (shown once; only its hash is stored).
    pub subject_token: String,
    pub protocol_hash: Option<String>,
}

/// Enrol the next subject (an empty body enrols a person). The first enrolment locks the
/// protocol.
#[utoipa::path(post, path = "/api/studies/{id}/subjects", tag = "subjects", params(("id" = i64, Path)),
    request_body(content = Option<EnrolBody>, description = "optional"), responses((status = 200, body = Enrolled)))]
async fn enrol_subject(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    body: axum::body::Bytes,
) -> ApiResult<Enrolled> {
    let b: EnrolBody = optional_json(&body, "enrolment")?;
    let (subject, subject_token) =
        enrol(&s.pool, &s.stability, &who.username, id, b.synthetic).await?;
    let study = store::studies::get(&s.pool, id).await?;
    Ok(AppJson(Enrolled {
        subject,
        subject_token,
        protocol_hash: study.protocol_hash,
    }))
}

/// One subject with every attempt, survey and note (real compensator names).
#[utoipa::path(get, path = "/api/subjects/{id}", tag = "subjects", params(("id" = i64, Path)),
    responses((status = 200, body = SubjectDetail)))]
async fn get_subject(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<SubjectDetail> {
    Ok(AppJson(subjects::detail(&s.pool, id).await?))
}

/// The subject's identification tests: the measured feedthrough, the fitted body and the
/// study population's band (the subject page's Bode plot).
#[utoipa::path(get, path = "/api/subjects/{id}/identification", tag = "subjects", params(("id" = i64, Path)),
    responses((status = 200, body = IdentificationView)))]
async fn get_identification(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
) -> ApiResult<IdentificationView> {
    Ok(AppJson(identification::view(&s.pool, id).await?))
}

#[derive(Debug, Deserialize, utoipa::IntoParams)]
#[into_params(parameter_in = Query)]
struct StabilityQuery {
    /// The feedthrough gain to check at [default: the study's].
    k_bf: Option<f64>,
}

/// Every design of the study checked against the subject's identified body: stable on and
/// off the machine at K_BF, and the largest stable K_BF for this subject.
#[utoipa::path(get, path = "/api/subjects/{id}/stability", tag = "subjects",
    params(("id" = i64, Path), StabilityQuery),
    responses((status = 200, body = SubjectStability)))]
async fn get_subject_stability(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppQuery(q): AppQuery<StabilityQuery>,
) -> ApiResult<SubjectStability> {
    Ok(AppJson(
        identification::subject_stability(&s.pool, &s.stability, id, q.k_bf).await?,
    ))
}

/// Record that the subject withdraws (their data leave every export).
#[utoipa::path(post, path = "/api/subjects/{id}/withdraw", tag = "subjects", params(("id" = i64, Path)),
    request_body = ReasonBody, responses((status = 200, body = Done)))]
async fn withdraw(
    State(s): State<AppState>,
    who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Done> {
    subjects::withdraw(&s.pool, &s.sites, &who.username, id, &b.reason).await?;
    Ok(Done::ok())
}

/// The subject's own progress, blinded (bearer token of the subject's page).
#[utoipa::path(get, path = "/api/subject", tag = "subjects", responses((status = 200, body = OwnProgress)))]
async fn own_progress(
    State(s): State<AppState>,
    SubjectAuth(me): SubjectAuth,
) -> ApiResult<OwnProgress> {
    Ok(AppJson(subjects::own_progress(&s.pool, me).await?))
}

#[derive(Debug, Default, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct OwnWithdrawal {
    /// Optional, at most 500 characters: a subject owes no reason.
    #[serde(default)]
    reason: Option<String>,
}

/// The subject withdraws (bearer token of the subject's page): a running test of theirs
/// stops at once, nothing more is run, and their data leave every export and result. An
/// empty body is a withdrawal without a reason.
#[utoipa::path(post, path = "/api/subject/withdraw", tag = "subjects",
    request_body(content = Option<OwnWithdrawal>, description = "optional"),
    responses((status = 200, body = OwnProgress), (status = 409, body = super::error::ErrorBody, description = "already withdrawn")))]
async fn withdraw_own(
    State(s): State<AppState>,
    SubjectAuth(me): SubjectAuth,
    body: axum::body::Bytes,
) -> ApiResult<OwnProgress> {
    let b: OwnWithdrawal = optional_json(&body, "withdrawal")?;
    subjects::withdraw_own(&s.pool, &s.sites, &me, b.reason.as_deref()).await?;
    let me = store::subjects::get(&s.pool, me.id).await?;
    Ok(AppJson(subjects::own_progress(&s.pool, me).await?))
}
