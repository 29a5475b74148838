//! The experimenter's JSON API (every route needs a logged-in experimenter; every change is
//! written to the audit log).

use axum::Router;
use axum::body::Body;
use axum::extract::{Path, Query, State};
use axum::http::header;
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::study::StudyParams;
use serde::Deserialize;
use serde_json::{Value, json};

use crate::auth::Experimenter;
use crate::error::{ApiResult, AppError, AppJson};
use crate::export::ExportKind;
use crate::orchestrator::{Operator, start_message};
use crate::state::AppState;
use crate::store::{self, Trial};
use crate::study::default_params;

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/api/me", get(crate::auth::me))
        .route("/api/logout", post(crate::auth::logout))
        .route("/api/defaults", get(defaults))
        .route("/api/studies", get(list_studies).post(create_study))
        .route("/api/studies/{id}", get(get_study).put(update_study))
        .route("/api/studies/{id}/subjects", get(list_subjects).post(enrol))
        .route(
            "/api/studies/{id}/stations",
            get(list_stations).post(pair_station),
        )
        .route("/api/studies/{id}/summary", get(summary))
        .route("/api/studies/{id}/plots/{file}", get(plot))
        .route("/api/studies/{id}/export/{kind}", get(export))
        .route("/api/subjects/{id}", get(get_subject))
        .route("/api/subjects/{id}/withdraw", post(withdraw))
        .route("/api/stations/{id}/assign", post(assign_station))
        .route("/api/stations/{id}/state", get(station_state))
        .route("/api/trials/{id}/start", post(start_trial))
        .route("/api/trials/{id}/abort", post(abort_trial))
        .route("/api/trials/{id}/redo", post(redo_trial))
        .route("/api/trials/{id}/incomplete", post(mark_incomplete))
        .route("/api/trials/{id}/note", post(add_note))
        .route("/api/studies/{id}/pilot", post(start_pilot))
        .route("/api/pilot", get(pilot_status))
        .route("/api/estop", post(estop))
        .route("/api/estop/reset", post(estop_reset))
        .route("/api/controller", get(controller_status))
        .route("/api/audit", get(audit_log))
}

async fn audit(
    state: &AppState,
    who: &Experimenter,
    action: &str,
    target: String,
    detail: Value,
) -> Result<(), AppError> {
    Ok(store::audit(&state.pool, &who.username, action, Some(target), detail).await?)
}

async fn defaults(_who: Experimenter) -> AppJson<StudyParams> {
    AppJson(default_params())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct StudyBody {
    name: String,
    params: Option<StudyParams>,
    seed: Option<u64>,
}

fn check_name(name: &str) -> Result<(), AppError> {
    if name.trim().is_empty() || name.len() > 200 {
        return Err(AppError::BadRequest("name: 1 to 200 characters".into()));
    }
    Ok(())
}

async fn list_studies(
    State(s): State<AppState>,
    _who: Experimenter,
) -> ApiResult<Vec<store::Study>> {
    Ok(AppJson(store::studies(&s.pool).await?))
}

async fn create_study(
    State(s): State<AppState>,
    who: Experimenter,
    AppJson(b): AppJson<StudyBody>,
) -> ApiResult<store::Study> {
    check_name(&b.name)?;
    let params = b.params.unwrap_or_else(default_params);
    if let Some(seed) = b.seed {
        if seed >= 1 << 53 {
            return Err(AppError::BadRequest(
                "seed: a whole number below 2^53".into(),
            ));
        }
    }
    let seed = b.seed.unwrap_or_else(crate::db::random_seed);
    let id = store::create_study(&s.pool, &b.name, &params, seed).await?;
    audit(
        &s,
        &who,
        "study.create",
        format!("study:{id}"),
        json!({ "name": b.name, "seed": seed }),
    )
    .await?;
    Ok(AppJson(store::study(&s.pool, id).await?))
}

async fn get_study(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<store::Study> {
    Ok(AppJson(store::study(&s.pool, id).await?))
}

async fn update_study(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<StudyBody>,
) -> ApiResult<store::Study> {
    check_name(&b.name)?;
    let params = b
        .params
        .ok_or_else(|| AppError::BadRequest("params: required".into()))?;
    if b.seed.is_some() {
        return Err(AppError::BadRequest(
            "seed: fixed when the study is created".into(),
        ));
    }
    store::update_study(&s.pool, id, &b.name, &params).await?;
    audit(
        &s,
        &who,
        "study.update",
        format!("study:{id}"),
        json!({ "name": b.name, "params": params }),
    )
    .await?;
    Ok(AppJson(store::study(&s.pool, id).await?))
}

async fn list_subjects(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Vec<Value>> {
    store::study(&s.pool, id).await?;
    let mut out = Vec::new();
    for subj in store::subjects(&s.pool, id).await? {
        let trials = store::trials_of(&s.pool, subj.id).await?;
        let done = latest_attempts(&trials)
            .filter(|t| !t.practice && t.status == "complete")
            .count();
        let tests = latest_attempts(&trials).filter(|t| !t.practice).count();
        out.push(json!({ "subject": subj, "tests_complete": done, "tests": tests }));
    }
    Ok(AppJson(out))
}

/// The latest attempt of each slot.
pub fn latest_attempts(trials: &[Trial]) -> impl Iterator<Item = &Trial> {
    trials.iter().filter(move |t| {
        !trials
            .iter()
            .any(|u| u.slot == t.slot && u.attempt > t.attempt)
    })
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct EnrolBody {
    /// A simulated subject: the synthetic operator drives its tests (dry runs); flagged in
    /// every export.
    #[serde(default)]
    synthetic: bool,
}

async fn enrol(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    body: axum::body::Bytes,
) -> ApiResult<Value> {
    // The body is optional: an empty POST enrols a person.
    let b: EnrolBody = crate::error::optional_json(&body, "enrolment")?;
    let (subject, token) = store::enrol(&s.pool, id, b.synthetic).await?;
    audit(
        &s,
        &who,
        "subject.enrol",
        format!("subject:{}", subject.id),
        json!({ "code": subject.code }),
    )
    .await?;
    let study = store::study(&s.pool, id).await?;
    Ok(AppJson(
        json!({ "subject": subject, "subject_token": token, "protocol_hash": study.protocol_hash }),
    ))
}

async fn get_subject(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Value> {
    let subject = store::subject(&s.pool, id).await?;
    let trials = store::trials_of(&s.pool, id).await?;
    let surveys: Vec<(i64, i64, i64, i64, i64, String)> = sqlx::query_as(
        "SELECT v.trial_id, v.accuracy, v.speed, v.smoothness, v.controllability, v.comment FROM surveys v JOIN trials t ON t.id = v.trial_id WHERE t.subject_id = ?",
    )
    .bind(id)
    .fetch_all(&s.pool)
    .await?;
    let notes: Vec<(i64, Option<i64>, String, String, i64)> = sqlx::query_as(
        "SELECT id, trial_id, text, author, created_at FROM notes WHERE subject_id = ? ORDER BY id",
    )
    .bind(id)
    .fetch_all(&s.pool)
    .await?;
    Ok(AppJson(json!({
        "subject": subject,
        "trials": trials.iter().map(|t| {
            let survey = surveys.iter().find(|v| v.0 == t.id).map(|v| json!({ "accuracy": v.1, "speed": v.2, "smoothness": v.3, "controllability": v.4, "comment": v.5 }));
            json!({ "trial": t, "survey": survey })
        }).collect::<Vec<_>>(),
        "notes": notes.iter().map(|n| json!({ "id": n.0, "trial_id": n.1, "text": n.2, "author": n.3, "created_at": n.4 })).collect::<Vec<_>>(),
    })))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ReasonBody {
    reason: String,
}

fn check_reason(r: &str) -> Result<(), AppError> {
    if r.trim().is_empty() || r.chars().count() > 500 {
        return Err(AppError::BadRequest("reason: 1 to 500 characters".into()));
    }
    Ok(())
}

async fn withdraw(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Value> {
    check_reason(&b.reason)?;
    store::subject(&s.pool, id).await?;
    let done = sqlx::query("UPDATE subjects SET withdrawn_at = ?, withdraw_reason = ? WHERE id = ? AND withdrawn_at IS NULL")
        .bind(crate::db::now_ms())
        .bind(&b.reason)
        .bind(id)
        .execute(&s.pool)
        .await?;
    if done.rows_affected() == 0 {
        return Err(AppError::Conflict(
            "the subject has already withdrawn".into(),
        ));
    }
    audit(
        &s,
        &who,
        "subject.withdraw",
        format!("subject:{id}"),
        json!({ "reason": b.reason }),
    )
    .await?;
    Ok(AppJson(json!({ "ok": true })))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PairBody {
    pairing_code: String,
    name: String,
    role: String,
}

async fn pair_station(
    State(s): State<AppState>,
    who: Experimenter,
    Path(study_id): Path<i64>,
    AppJson(b): AppJson<PairBody>,
) -> ApiResult<Value> {
    store::study(&s.pool, study_id).await?;
    check_name(&b.name)?;
    if !["on", "off", "both"].contains(&b.role.as_str()) {
        return Err(AppError::BadRequest("role: on, off or both".into()));
    }
    let code = b.pairing_code.trim().to_uppercase();
    let token = {
        let mut pending = s
            .inner
            .pending_stations
            .lock()
            .unwrap_or_else(|p| p.into_inner());
        pending.retain(|_, (_, at)| at.elapsed() < std::time::Duration::from_secs(3600));
        pending.remove(&code).map(|(t, _)| t)
    };
    let token = token.ok_or_else(|| {
        AppError::BadRequest(format!(
            "pairing code {code:?} is not shown by any station (codes expire after an hour)"
        ))
    })?;
    let id = sqlx::query("INSERT INTO stations (study_id, name, role, token_hash, pairing_code, paired_at, created_at) VALUES (?, ?, ?, ?, ?, ?, ?)")
        .bind(study_id)
        .bind(&b.name)
        .bind(&b.role)
        .bind(crate::db::token_hash(&token))
        .bind(&code)
        .bind(crate::db::now_ms())
        .bind(crate::db::now_ms())
        .execute(&s.pool)
        .await?
        .last_insert_rowid();
    audit(
        &s,
        &who,
        "station.pair",
        format!("station:{id}"),
        json!({ "name": b.name, "role": b.role }),
    )
    .await?;
    Ok(AppJson(json!({ "id": id, "name": b.name, "role": b.role })))
}

async fn list_stations(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(study_id): Path<i64>,
) -> ApiResult<Vec<crate::auth::StationAuth>> {
    Ok(AppJson(sqlx::query_as("SELECT id, study_id, name, role, subject_id FROM stations WHERE study_id = ? ORDER BY id").bind(study_id).fetch_all(&s.pool).await?))
}

/// What a station shows now, for the experimenter's live monitor (with the real controller
/// name of the test at hand).
async fn station_state(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Value> {
    let station: crate::auth::StationAuth =
        sqlx::query_as("SELECT id, study_id, name, role, subject_id FROM stations WHERE id = ?")
            .bind(id)
            .fetch_optional(&s.pool)
            .await?
            .ok_or(AppError::NotFound("station"))?;
    let mut state = crate::station::station_state(&s, &station).await?;
    if let Some(t) = state["test"]["trial_id"].as_i64() {
        state["test"]["controller"] = json!(store::trial(&s.pool, t).await?.controller);
    }
    state["station"]["id"] = json!(station.id);
    state["station"]["subject_id"] = json!(station.subject_id);
    Ok(AppJson(state))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct AssignBody {
    subject_id: Option<i64>,
}

async fn assign_station(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<AssignBody>,
) -> ApiResult<Value> {
    let station: Option<(i64,)> = sqlx::query_as("SELECT study_id FROM stations WHERE id = ?")
        .bind(id)
        .fetch_optional(&s.pool)
        .await?;
    let (study_id,) = station.ok_or(AppError::NotFound("station"))?;
    if let Some(subject_id) = b.subject_id {
        let subj = store::subject(&s.pool, subject_id).await?;
        if subj.study_id != study_id {
            return Err(AppError::BadRequest(
                "the subject belongs to another study".into(),
            ));
        }
    }
    sqlx::query("UPDATE stations SET subject_id = ? WHERE id = ?")
        .bind(b.subject_id)
        .bind(id)
        .execute(&s.pool)
        .await?;
    audit(
        &s,
        &who,
        "station.assign",
        format!("station:{id}"),
        json!({ "subject_id": b.subject_id }),
    )
    .await?;
    Ok(AppJson(json!({ "ok": true })))
}

/// Checks that `trial` may start now and starts it on the controller.
pub async fn start(s: &AppState, trial: &Trial) -> Result<(), AppError> {
    let subject = store::subject(&s.pool, trial.subject_id).await?;
    if subject.withdrawn_at.is_some() {
        return Err(AppError::Conflict(format!(
            "{} has withdrawn",
            subject.code
        )));
    }
    if subject.consent_decision.as_deref() != Some("agreed") {
        return Err(AppError::Conflict(format!(
            "{} has not consented; nothing runs without consent",
            subject.code
        )));
    }
    let next = store::next_trial(&s.pool, subject.id).await?;
    if next.as_ref().map(|t| t.id) != Some(trial.id) {
        return Err(AppError::Conflict(format!(
            "trial {} is not {}'s next test",
            trial.id, subject.code
        )));
    }
    // A synthetic subject's surveys may be answered (to try the pages) but never hold up a
    // dry run; a person's must be answered before the next test.
    let pending = if subject.synthetic {
        None
    } else {
        crate::station::pending_survey(&s.pool, subject.id).await?
    };
    if let Some(pending) = pending {
        return Err(AppError::Conflict(format!(
            "the survey of trial {} is still to be answered",
            pending.id
        )));
    }
    if !s.controller.is_connected() {
        return Err(AppError::Unavailable(
            "the controller is not connected".into(),
        ));
    }
    let study = store::study(&s.pool, subject.study_id).await?;
    // A study run on the real machine must never go to a simulating controller, nor the
    // reverse: the data would silently mean something else.
    let want = match study.params.rig {
        bdft_protocol::study::RigKind::Simulated => "sim",
        bdft_protocol::study::RigKind::Real => "udp",
    };
    if s.controller.rig().as_deref() != Some(want) {
        return Err(AppError::Conflict(format!(
            "the study runs on the {} rig but the controller's rig is {}",
            if want == "sim" { "simulated" } else { "real" },
            s.controller.rig().unwrap_or_else(|| "unknown".into())
        )));
    }
    let operator = if subject.synthetic {
        Operator::Synthetic
    } else {
        Operator::Person
    };
    let msg = start_message(&study, trial, operator)?;
    store::mark_running(&s.pool, trial.id).await?;
    if let Err(reason) = s.controller.start_trial(&msg).await {
        store::unmark_running(&s.pool, trial.id).await?;
        return Err(AppError::Unavailable(format!(
            "the controller did not start the trial: {reason}"
        )));
    }
    // The station's socket starts forwarding operator input at once.
    s.controller
        .emit(crate::controller_link::ControllerEvent::TrialChanged { trial_id: trial.id });
    Ok(())
}

async fn start_trial(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Trial> {
    let trial = store::trial(&s.pool, id).await?;
    start(&s, &trial).await?;
    audit(
        &s,
        &who,
        "trial.start",
        format!("trial:{id}"),
        json!({ "controller": trial.controller, "station": trial.station }),
    )
    .await?;
    Ok(AppJson(store::trial(&s.pool, id).await?))
}

async fn abort_trial(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Value> {
    check_reason(&b.reason)?;
    let trial = store::trial(&s.pool, id).await?;
    if trial.status != "running" {
        return Err(AppError::Conflict(format!(
            "trial {id} is {}, not running",
            trial.status
        )));
    }
    s.controller
        .send(&ServerToController::AbortTrial {
            trial_id: id as u64,
            reason: b.reason.clone(),
        })
        .map_err(AppError::Unavailable)?;
    audit(
        &s,
        &who,
        "trial.abort",
        format!("trial:{id}"),
        json!({ "reason": b.reason }),
    )
    .await?;
    Ok(AppJson(json!({ "ok": true })))
}

#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct RedoBody {
    #[serde(default)]
    reason: String,
}

async fn redo_trial(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    body: axum::body::Bytes,
) -> ApiResult<Trial> {
    // The reason is optional (an empty POST redoes without one) but goes to the audit log.
    let b: RedoBody = crate::error::optional_json(&body, "redo")?;
    if b.reason.chars().count() > 500 {
        return Err(AppError::BadRequest(
            "reason: at most 500 characters".into(),
        ));
    }
    let t = store::trial(&s.pool, id).await?;
    let (latest,): (i64,) =
        sqlx::query_as("SELECT MAX(attempt) FROM trials WHERE subject_id = ? AND slot = ?")
            .bind(t.subject_id)
            .bind(t.slot)
            .fetch_one(&s.pool)
            .await?;
    if latest != t.attempt || !["complete", "aborted", "incomplete"].contains(&t.status.as_str()) {
        return Err(AppError::Conflict(
            "only the latest attempt of a finished test can be redone".into(),
        ));
    }
    let new_id = sqlx::query(
        "INSERT INTO trials (subject_id, slot, attempt, practice, station, block, position, controller, blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, protocol_hash) \
         SELECT subject_id, slot, attempt + 1, practice, station, block, position, controller, blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json, target_mean_mm, target_std_mm, protocol_hash FROM trials WHERE id = ?",
    )
    .bind(id)
    .execute(&s.pool)
    .await?
    .last_insert_rowid();
    audit(
        &s,
        &who,
        "trial.redo",
        format!("trial:{id}"),
        json!({ "new_trial": new_id, "reason": b.reason }),
    )
    .await?;
    Ok(AppJson(store::trial(&s.pool, new_id).await?))
}

async fn mark_incomplete(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<ReasonBody>,
) -> ApiResult<Trial> {
    check_reason(&b.reason)?;
    let done = sqlx::query("UPDATE trials SET status = 'incomplete', status_reason = ? WHERE id = ? AND status IN ('complete', 'scheduled')")
        .bind(&b.reason)
        .bind(id)
        .execute(&s.pool)
        .await?;
    if done.rows_affected() == 0 {
        store::trial(&s.pool, id).await?;
        return Err(AppError::Conflict(
            "only a scheduled or complete test can be marked incomplete".into(),
        ));
    }
    audit(
        &s,
        &who,
        "trial.mark_incomplete",
        format!("trial:{id}"),
        json!({ "reason": b.reason }),
    )
    .await?;
    Ok(AppJson(store::trial(&s.pool, id).await?))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoteBody {
    text: String,
}

async fn add_note(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<NoteBody>,
) -> ApiResult<Value> {
    if b.text.trim().is_empty() || b.text.chars().count() > 2000 {
        return Err(AppError::BadRequest("text: 1 to 2000 characters".into()));
    }
    let t = store::trial(&s.pool, id).await?;
    let note = sqlx::query(
        "INSERT INTO notes (subject_id, trial_id, text, author, created_at) VALUES (?, ?, ?, ?, ?)",
    )
    .bind(t.subject_id)
    .bind(id)
    .bind(&b.text)
    .bind(&who.username)
    .bind(crate::db::now_ms())
    .execute(&s.pool)
    .await?
    .last_insert_rowid();
    audit(
        &s,
        &who,
        "trial.note",
        format!("trial:{id}"),
        json!({ "note": note }),
    )
    .await?;
    Ok(AppJson(json!({ "id": note })))
}

async fn estop(State(s): State<AppState>, who: Experimenter) -> ApiResult<Value> {
    // Log first: the stop itself must not wait for anything that could fail.
    let sent = s.controller.send(&ServerToController::EStop);
    audit(
        &s,
        &who,
        "estop",
        "controller".into(),
        json!({ "delivered": sent.is_ok() }),
    )
    .await?;
    sent.map_err(AppError::Unavailable)?;
    Ok(AppJson(json!({ "ok": true })))
}

async fn estop_reset(State(s): State<AppState>, who: Experimenter) -> ApiResult<Value> {
    s.controller
        .send(&ServerToController::ResetEStop)
        .map_err(AppError::Unavailable)?;
    // The controller's status confirms the cleared latch.
    let _ = s.controller.send(&ServerToController::Status);
    audit(&s, &who, "estop.reset", "controller".into(), json!({})).await?;
    Ok(AppJson(json!({ "ok": true })))
}

async fn controller_status(State(s): State<AppState>, _who: Experimenter) -> AppJson<Value> {
    AppJson(
        json!({ "connected": s.controller.is_connected(), "pid": s.controller.pid(), "rig": s.controller.rig(), "estop_latched": s.controller.estop_latched() }),
    )
}

/// id, at, actor, action, target, detail_json
type AuditRow = (i64, i64, String, String, Option<String>, Option<String>);

#[derive(Debug, Deserialize)]
struct AuditQuery {
    limit: Option<i64>,
}

async fn audit_log(
    State(s): State<AppState>,
    _who: Experimenter,
    Query(q): Query<AuditQuery>,
) -> ApiResult<Vec<Value>> {
    let limit = q.limit.unwrap_or(200).clamp(1, 10_000);
    let rows: Vec<AuditRow> = sqlx::query_as(
        "SELECT id, at, actor, action, target, detail_json FROM audit_log ORDER BY id DESC LIMIT ?",
    )
    .bind(limit)
    .fetch_all(&s.pool)
    .await?;
    Ok(AppJson(
        rows.into_iter()
            .map(|r| json!({ "id": r.0, "at": crate::db::rfc3339(r.1), "actor": r.2, "action": r.3, "target": r.4, "detail": r.5.and_then(|d| serde_json::from_str::<Value>(&d).ok()) }))
            .collect(),
    ))
}

async fn summary(
    State(s): State<AppState>,
    _who: Experimenter,
    Path(id): Path<i64>,
) -> ApiResult<Vec<crate::export::Stats>> {
    store::study(&s.pool, id).await?;
    Ok(AppJson(
        crate::export::summary_stats(&s.pool, id)
            .await
            .map_err(|e| AppError::Internal(e.into()))?,
    ))
}

/// Streams a CSV export: the response starts at once and is written as rows are read.
async fn export(
    State(s): State<AppState>,
    who: Experimenter,
    Path((id, kind)): Path<(i64, String)>,
) -> Result<Response, AppError> {
    let kind_name = kind.trim_end_matches(".csv").to_string();
    let kind: ExportKind = kind_name.parse().map_err(AppError::BadRequest)?;
    let study = store::study(&s.pool, id).await?;
    audit(
        &s,
        &who,
        "export",
        format!("study:{id}"),
        json!({ "kind": kind_name }),
    )
    .await?;
    let (w, r) = tokio::io::duplex(1 << 16);
    let pool = s.pool.clone();
    tokio::spawn(async move {
        if let Err(e) = crate::export::write(&pool, id, kind, w).await {
            tracing::error!("export of study {id} failed mid-stream: {e}");
        }
    });
    let body = Body::from_stream(tokio_util::io::ReaderStream::new(r));
    let filename = format!(
        "bdft-study{}-{kind_name}-{}.csv",
        study.id,
        &study
            .protocol_hash
            .unwrap_or_default()
            .get(..8)
            .unwrap_or("unlocked")
    );
    Ok((
        [
            (header::CONTENT_TYPE, "text/csv; charset=utf-8".to_string()),
            (
                header::CONTENT_DISPOSITION,
                format!("attachment; filename=\"{filename}\""),
            ),
        ],
        body,
    )
        .into_response())
}

/// GET /api/studies/{id}/plots/{variable}.svg|png
async fn plot(
    State(s): State<AppState>,
    _who: Experimenter,
    Path((id, file)): Path<(i64, String)>,
) -> Result<Response, AppError> {
    use crate::export::SUMMARY_VARIABLES;
    let (variable, ext) = file
        .rsplit_once('.')
        .ok_or_else(|| AppError::BadRequest("plot: name.svg or name.png".into()))?;
    let index = SUMMARY_VARIABLES
        .iter()
        .position(|v| *v == variable)
        .ok_or_else(|| {
            AppError::BadRequest(format!(
                "plot: unknown variable {variable:?}; valid: {}",
                SUMMARY_VARIABLES.join(", ")
            ))
        })?;
    if ext != "svg" && ext != "png" {
        return Err(AppError::BadRequest("plot: .svg or .png".into()));
    }
    let study = store::study(&s.pool, id).await?;
    let groups: Vec<crate::plots::Group> = crate::export::group_values(&s.pool, id)
        .await
        .map_err(|e| AppError::Internal(e.into()))?
        .into_iter()
        .map(|((c, st), vals)| (c, st, vals.iter().filter_map(|v| v[index]).collect()))
        .collect();
    let controllers: Vec<String> = study
        .params
        .controllers
        .iter()
        .map(|c| c.kind().name().to_string())
        .collect();
    let scale = f64::from(study.params.survey.scale_points);
    let (title, unit, range) = match variable {
        "mse_tracking_mm2" => ("Tracking error (mean square)", "MSE (mm²)", None),
        "ms_cab_accel" => (
            "Cab acceleration (mean square)",
            "mean-square acceleration ((mm/s²)²)",
            None,
        ),
        "rating_accuracy" => (
            "Rating: accuracy",
            "rating (higher is better)",
            Some((0.5, scale + 0.5)),
        ),
        "rating_speed" => (
            "Rating: speed of response",
            "rating (higher is better)",
            Some((0.5, scale + 0.5)),
        ),
        "rating_smoothness" => (
            "Rating: smoothness",
            "rating (higher is better)",
            Some((0.5, scale + 0.5)),
        ),
        _ => (
            "Rating: overall controllability",
            "rating (higher is better)",
            Some((0.5, scale + 0.5)),
        ),
    };
    let svg = crate::plots::box_plot_svg(
        &format!("{title} — study {}", study.name),
        unit,
        &controllers,
        &groups,
        range,
    );
    let (body, mime) = if ext == "svg" {
        (svg.into_bytes(), "image/svg+xml")
    } else {
        (
            tokio::task::spawn_blocking(move || crate::plots::png(&svg))
                .await
                .map_err(anyhow::Error::from)??,
            "image/png",
        )
    };
    Ok((
        [
            (header::CONTENT_TYPE, mime),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response())
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct PilotBody {
    subjects: u32,
}

/// POST /api/studies/{id}/pilot: dry-runs the protocol with synthetic subjects in the
/// background (progress at GET /api/pilot).
async fn start_pilot(
    State(s): State<AppState>,
    who: Experimenter,
    Path(id): Path<i64>,
    AppJson(b): AppJson<PilotBody>,
) -> ApiResult<Value> {
    if !(1..=50).contains(&b.subjects) {
        return Err(AppError::BadRequest("subjects: 1 to 50".into()));
    }
    store::study(&s.pool, id).await?;
    let progress = std::sync::Arc::new(crate::pilot::Progress::default());
    {
        let mut slot = s.inner.pilot.lock().unwrap_or_else(|p| p.into_inner());
        if slot.as_ref().is_some_and(|r| r.outcome.is_none()) {
            return Err(AppError::Conflict(
                "a pilot run is already in progress".into(),
            ));
        }
        *slot = Some(crate::state::PilotRun {
            study_id: id,
            progress: progress.clone(),
            outcome: None,
        });
    }
    audit(
        &s,
        &who,
        "pilot.start",
        format!("study:{id}"),
        json!({ "subjects": b.subjects }),
    )
    .await?;
    let state = s.clone();
    tokio::spawn(async move {
        let r = crate::pilot::run_with_progress(&state.pool, Some(id), b.subjects, None, progress)
            .await;
        let outcome = r
            .map(|rep| serde_json::to_value(rep).unwrap_or_default())
            .map_err(|e| format!("{e:#}"));
        if let Some(run) = state
            .inner
            .pilot
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .as_mut()
        {
            run.outcome = Some(outcome);
        }
    });
    Ok(AppJson(json!({ "started": true })))
}

async fn pilot_status(State(s): State<AppState>, _who: Experimenter) -> AppJson<Value> {
    use std::sync::atomic::Ordering;
    let run = s
        .inner
        .pilot
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone();
    AppJson(match run {
        None => json!({ "running": false }),
        Some(r) => json!({
            "study_id": r.study_id,
            "running": r.outcome.is_none(),
            "done": r.progress.done.load(Ordering::Relaxed),
            "total": r.progress.total.load(Ordering::Relaxed),
            "report": r.outcome.as_ref().and_then(|o| o.as_ref().ok()),
            "error": r.outcome.as_ref().and_then(|o| o.as_ref().err()),
        }),
    })
}
