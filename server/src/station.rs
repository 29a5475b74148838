//! The operator station's API (bearer token of a paired station, acting for the subject
//! assigned to it): pairing, what to show now, consent, surveys, timing figures, and the
//! WebSocket that carries operator input in and live samples out.

use std::time::Instant;

use axum::Router;
use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::HeaderMap;
use axum::response::Response;
use axum::routing::{get, post};
use bdft_protocol::server_to_controller::ServerToController;
use bdft_protocol::study::SurveyAnswer;
use serde::Deserialize;
use serde_json::{Value, json};
use sqlx::SqlitePool;

use crate::auth::{Experimenter, StationAuth, station_by_token};
use crate::controller_link::ControllerEvent;
use crate::error::{ApiResult, AppError, AppJson};
use crate::state::AppState;
use crate::store::{self, Trial};

pub fn router() -> Router<AppState> {
    Router::new()
        .route("/api/station/register", post(register))
        .route("/api/station/state", get(state))
        .route("/api/station/consent", post(consent))
        .route("/api/station/survey", post(survey))
        .route("/api/station/timing", post(timing))
        .route("/api/station/ws", get(station_ws))
        .route("/api/live", get(live_ws))
}

/// Letters and digits that cannot be mistaken for one another when read off a screen.
const CODE_ALPHABET: &[u8] = b"ABCDEFGHJKLMNPQRSTUVWXYZ23456789";

async fn register(State(s): State<AppState>) -> AppJson<Value> {
    let token = crate::db::random_token();
    let mut bytes = [0u8; 6];
    getrandom::fill(&mut bytes).expect("the OS random source works");
    // 32 symbols divide 256, so every symbol is equally likely.
    let code: String = bytes
        .iter()
        .map(|b| CODE_ALPHABET[usize::from(*b) % CODE_ALPHABET.len()] as char)
        .collect();
    s.inner
        .pending_stations
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .insert(code.clone(), (token.clone(), Instant::now()));
    AppJson(json!({ "token": token, "pairing_code": code }))
}

/// The first completed test of the subject whose survey is still missing.
pub async fn pending_survey(pool: &SqlitePool, subject_id: i64) -> Result<Option<Trial>, AppError> {
    Ok(sqlx::query_as(
        "SELECT t.* FROM trials t WHERE t.subject_id = ? AND t.practice = 0 AND t.status = 'complete' \
         AND NOT EXISTS (SELECT 1 FROM surveys v WHERE v.trial_id = t.id) \
         AND t.attempt = (SELECT MAX(attempt) FROM trials u WHERE u.subject_id = t.subject_id AND u.slot = t.slot) ORDER BY t.slot LIMIT 1",
    )
    .bind(subject_id)
    .fetch_optional(pool)
    .await?)
}

fn serves(station: &StationAuth, trial_station: &str) -> bool {
    station.role == "both" || station.role == trial_station
}

/// What the station should show now.
pub async fn station_state(s: &AppState, station: &StationAuth) -> Result<Value, AppError> {
    let base = json!({ "station": { "name": station.name, "role": station.role } });
    let with = |mut v: Value| {
        v["station"] = base["station"].clone();
        v
    };
    let Some(subject_id) = station.subject_id else {
        return Ok(with(json!({ "phase": "waiting" })));
    };
    let subject = store::subject(&s.pool, subject_id).await?;
    let study = store::study(&s.pool, subject.study_id).await?;
    let code = subject.code.clone();
    if subject.withdrawn_at.is_some() {
        return Ok(with(
            json!({ "phase": "done", "subject": code, "reason": "withdrawn" }),
        ));
    }
    match subject.consent_decision.as_deref() {
        None => {
            return Ok(with(
                json!({ "phase": "consent", "subject": code, "consent": study.params.consent }),
            ));
        }
        Some("declined") => {
            return Ok(with(
                json!({ "phase": "done", "subject": code, "reason": "declined" }),
            ));
        }
        _ => {}
    }
    if let Some(t) = pending_survey(&s.pool, subject_id).await? {
        // The survey is answered where the test was run; another station sends the
        // subject there.
        if !serves(station, &t.station) {
            return Ok(with(
                json!({ "phase": "move", "subject": code, "to": t.station }),
            ));
        }
        return Ok(with(
            json!({ "phase": "survey", "subject": code, "trial_id": t.id, "label": t.blinded_label, "survey": study.params.survey }),
        ));
    }
    let trials = store::trials_of(&s.pool, subject_id).await?;
    let total = crate::api::latest_attempts(&trials)
        .filter(|t| !t.practice)
        .count();
    let Some(t) = store::next_trial(&s.pool, subject_id).await? else {
        return Ok(with(
            json!({ "phase": "done", "subject": code, "reason": "finished" }),
        ));
    };
    if !serves(station, &t.station) {
        return Ok(with(
            json!({ "phase": "move", "subject": code, "to": t.station }),
        ));
    }
    let test = json!({
        "trial_id": t.id,
        "label": t.blinded_label,
        "practice": t.practice,
        "number": t.slot,
        "of": total,
        "duration_s": t.duration_s,
        "station": t.station,
        "shake_gain": if t.station == "on" { study.params.display_shake_gain } else { 0.0 },
        "target_range_mm": study.params.target_range_mm,
        "k_bf": t.k_bf,
        "started_at": t.started_at,
    });
    let phase = if t.status == "running" {
        "running"
    } else {
        "ready"
    };
    Ok(with(
        json!({ "phase": phase, "subject": code, "test": test }),
    ))
}

async fn state(State(s): State<AppState>, station: StationAuth) -> ApiResult<Value> {
    Ok(AppJson(station_state(&s, &station).await?))
}

/// A test of the station's subject (a station never touches another subject's data).
async fn own_trial(
    s: &AppState,
    station: &StationAuth,
    trial_id: i64,
) -> Result<(i64, Trial), AppError> {
    let subject_id = subject_of(station)?;
    let trial = store::trial(&s.pool, trial_id).await?;
    if trial.subject_id != subject_id {
        return Err(AppError::Forbidden(
            "this test belongs to another subject".into(),
        ));
    }
    Ok((subject_id, trial))
}

fn subject_of(station: &StationAuth) -> Result<i64, AppError> {
    station
        .subject_id
        .ok_or_else(|| AppError::Conflict("no subject is assigned to this station".into()))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ConsentBody {
    decision: String,
}

async fn consent(
    State(s): State<AppState>,
    station: StationAuth,
    AppJson(b): AppJson<ConsentBody>,
) -> ApiResult<Value> {
    let subject_id = subject_of(&station)?;
    if !["agreed", "declined"].contains(&b.decision.as_str()) {
        return Err(AppError::BadRequest("decision: agreed or declined".into()));
    }
    let subject = store::subject(&s.pool, subject_id).await?;
    let study = store::study(&s.pool, subject.study_id).await?;
    let done = sqlx::query("UPDATE subjects SET consent_version = ?, consent_decision = ?, consent_at = ? WHERE id = ? AND consent_decision IS NULL")
        .bind(&study.params.consent.version)
        .bind(&b.decision)
        .bind(crate::db::now_ms())
        .bind(subject_id)
        .execute(&s.pool)
        .await?;
    if done.rows_affected() == 0 {
        return Err(AppError::Conflict(
            "consent has already been recorded".into(),
        ));
    }
    store::audit(&s.pool, &format!("subject:{}", subject.code), "consent", Some(format!("subject:{subject_id}")), json!({ "decision": b.decision, "version": study.params.consent.version, "station": station.name })).await?;
    Ok(AppJson(station_state(&s, &station).await?))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SurveyBody {
    trial_id: i64,
    #[serde(flatten)]
    answer: SurveyAnswer,
}

async fn survey(
    State(s): State<AppState>,
    station: StationAuth,
    AppJson(b): AppJson<SurveyBody>,
) -> ApiResult<Value> {
    let (subject_id, trial) = own_trial(&s, &station, b.trial_id).await?;
    if trial.practice || trial.status != "complete" {
        return Err(AppError::Conflict(
            "only a completed test has a survey".into(),
        ));
    }
    let subject = store::subject(&s.pool, subject_id).await?;
    let study = store::study(&s.pool, subject.study_id).await?;
    let r = b
        .answer
        .validate(study.params.survey.scale_points)
        .map_err(AppError::Fields)?;
    let done = sqlx::query("INSERT OR IGNORE INTO surveys (trial_id, accuracy, speed, smoothness, controllability, comment, submitted_at) VALUES (?, ?, ?, ?, ?, ?, ?)")
        .bind(b.trial_id)
        .bind(i64::from(r[0]))
        .bind(i64::from(r[1]))
        .bind(i64::from(r[2]))
        .bind(i64::from(r[3]))
        .bind(&b.answer.comment)
        .bind(crate::db::now_ms())
        .execute(&s.pool)
        .await?;
    if done.rows_affected() == 0 {
        return Err(AppError::Conflict(
            "this test's survey has already been answered".into(),
        ));
    }
    Ok(AppJson(station_state(&s, &station).await?))
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TimingBody {
    trial_id: i64,
    frames: u64,
    long_frames: u64,
    rtt_ms: Percentiles,
}

#[derive(Debug, Deserialize, serde::Serialize)]
#[serde(deny_unknown_fields)]
struct Percentiles {
    p50: f64,
    p95: f64,
    max: f64,
}

async fn timing(
    State(s): State<AppState>,
    station: StationAuth,
    AppJson(b): AppJson<TimingBody>,
) -> ApiResult<Value> {
    own_trial(&s, &station, b.trial_id).await?;
    for (name, v) in [
        ("rtt_ms.p50", b.rtt_ms.p50),
        ("rtt_ms.p95", b.rtt_ms.p95),
        ("rtt_ms.max", b.rtt_ms.max),
    ] {
        if !v.is_finite() || !(0.0..=600_000.0).contains(&v) {
            return Err(AppError::BadRequest(format!(
                "{name}: a finite number of milliseconds from 0 to 600000"
            )));
        }
    }
    if b.long_frames > b.frames {
        return Err(AppError::BadRequest(
            "long_frames cannot exceed frames".into(),
        ));
    }
    let body = json!({ "frames": b.frames, "long_frames": b.long_frames, "rtt_ms": b.rtt_ms });
    sqlx::query("UPDATE trials SET client_timing_json = ? WHERE id = ?")
        .bind(body.to_string())
        .bind(b.trial_id)
        .execute(&s.pool)
        .await?;
    Ok(AppJson(json!({ "ok": true })))
}

#[derive(Debug, Deserialize)]
struct TokenQuery {
    token: String,
}

/// Operator input from the station page (JSON text messages).
#[derive(Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum StationMessage {
    Input {
        trial_id: i64,
        seq: u64,
        position_mm: f64,
    },
}

/// The station's socket: token in the query (browsers cannot set headers on WebSockets).
async fn station_ws(
    State(s): State<AppState>,
    Query(q): Query<TokenQuery>,
    ws: WebSocketUpgrade,
) -> Result<Response, AppError> {
    let station = station_by_token(&s.pool, &q.token)
        .await?
        .ok_or(AppError::Unauthorized)?;
    Ok(ws.on_upgrade(move |socket| station_socket(s, station.id, socket)))
}

async fn station_socket(s: AppState, station_id: i64, socket: WebSocket) {
    use futures_util::{SinkExt, StreamExt};
    let (mut sink, mut stream) = socket.split();
    // Sending runs in its own task behind a small queue: a slow browser must never delay
    // the operator input read below (stale input stops the machine after 100 ms).
    let (out, mut outgoing) = tokio::sync::mpsc::channel::<String>(256);
    let writer = tokio::spawn(async move {
        while let Some(text) = outgoing.recv().await {
            if sink.send(Message::Text(text.into())).await.is_err() {
                return;
            }
        }
    });
    let mut events = s.controller.subscribe();
    // The trial this station may feed: its subject's running test at this station.
    let current = |s: AppState| async move {
        let st: Option<StationAuth> = sqlx::query_as(
            "SELECT id, study_id, name, role, subject_id FROM stations WHERE id = ?",
        )
        .bind(station_id)
        .fetch_optional(&s.pool)
        .await
        .ok()?;
        let st = st?;
        let t = store::next_trial(&s.pool, st.subject_id?).await.ok()??;
        (t.status == "running" && serves(&st, &t.station)).then_some(t.id)
    };
    let changed = json!({ "type": "changed" }).to_string();
    let mut running = current(s.clone()).await;
    loop {
        tokio::select! {
            msg = stream.next() => {
                let Some(Ok(msg)) = msg else { break };
                let Message::Text(text) = msg else { continue };
                match serde_json::from_str::<StationMessage>(&text) {
                    Ok(StationMessage::Input { trial_id, seq, position_mm }) if Some(trial_id) == running && position_mm.is_finite() && position_mm.abs() <= 1000.0 => {
                        let _ = s.controller.send(&ServerToController::OperatorInput { trial_id: trial_id as u64, seq, position_mm });
                    }
                    // Input for a trial that is not this station's running one, or garbage: dropped.
                    _ => {}
                }
            }
            ev = events.recv() => match ev {
                Ok(ControllerEvent::Live(sample)) if Some(sample.trial_id as i64) == running => {
                    // A live sample that cannot be queued is dropped, never waited for.
                    let _ = out.try_send(json!({ "type": "live", "sample": sample }).to_string());
                }
                Ok(ControllerEvent::TrialChanged { .. } | ControllerEvent::Link { .. } | ControllerEvent::EStop { .. }) | Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => {
                    running = current(s.clone()).await;
                    if out.send(changed.clone()).await.is_err() { break; }
                }
                Ok(ControllerEvent::Live(_)) => {}
                Err(_) => break,
            },
            // A trial started by the experimenter: look again every half second.
            _ = tokio::time::sleep(std::time::Duration::from_millis(500)), if running.is_none() => {
                let now = current(s.clone()).await;
                if now != running {
                    running = now;
                    if out.send(changed.clone()).await.is_err() { break; }
                }
            }
        }
    }
    writer.abort();
}

/// The dashboard's live feed: every live sample and every trial change. Same-origin only
/// (a cookie-authenticated WebSocket is otherwise open to cross-site hijacking).
async fn live_ws(
    State(s): State<AppState>,
    _who: Experimenter,
    headers: HeaderMap,
    ws: WebSocketUpgrade,
) -> Result<Response, AppError> {
    if let (Some(origin), Some(host)) = (headers.get("origin"), headers.get("host")) {
        let origin = origin.to_str().unwrap_or("");
        let host = host.to_str().unwrap_or("");
        if origin.split("://").nth(1) != Some(host) {
            return Err(AppError::Forbidden("cross-origin WebSocket refused".into()));
        }
    }
    Ok(ws.on_upgrade(move |mut socket| async move {
        let mut events = s.controller.subscribe();
        loop {
            let text = match events.recv().await {
                Ok(ControllerEvent::Live(sample)) => json!({ "type": "live", "sample": sample }),
                Ok(ControllerEvent::TrialChanged { trial_id }) => {
                    json!({ "type": "trial", "trial_id": trial_id })
                }
                Ok(ControllerEvent::Link { connected }) => {
                    json!({ "type": "controller", "connected": connected })
                }
                Ok(ControllerEvent::EStop { latched }) => {
                    json!({ "type": "estop", "latched": latched })
                }
                Err(tokio::sync::broadcast::error::RecvError::Lagged(_)) => continue,
                Err(_) => return,
            };
            if socket
                .send(Message::Text(text.to_string().into()))
                .await
                .is_err()
            {
                return;
            }
        }
    }))
}
