//! The live sockets: the station's (operator input in, live samples of its own running test
//! out) and the dashboard's monitor feed (every live sample and every change).

use axum::extract::ws::{Message, WebSocket, WebSocketUpgrade};
use axum::extract::{Query, State};
use axum::http::HeaderMap;
use axum::response::Response;
use bdft_protocol::browser_to_server::StationMessage;
use bdft_protocol::server_to_browser::{MonitorEvent, StationEvent};
use serde::Deserialize;
use tokio::sync::broadcast::error::RecvError;
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::AppError;
use super::extract::Experimenter;
use crate::engine::controller_link::ControllerEvent;
use crate::engine::stations::running_trial;
use crate::state::AppState;
use crate::store;

/// The station's socket (it authenticates with the token in the query).
pub fn station() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(station_ws))
}

pub fn experimenter() -> OpenApiRouter<AppState> {
    OpenApiRouter::new().routes(routes!(live_ws))
}

#[derive(Debug, Deserialize, IntoParams)]
struct TokenQuery {
    /// The station's bearer token (browsers cannot set headers on WebSockets).
    token: String,
}

/// Largest operator position accepted (mm of device travel).
const MAX_POSITION_MM: f64 = 1000.0;

/// WebSocket of a paired station: `input` messages in, `live` samples of its running test
/// and `changed` notices out.
#[utoipa::path(get, path = "/api/station/ws", tag = "station", params(TokenQuery),
    responses((status = 101, description = "WebSocket: StationMessage in, StationEvent out")))]
async fn station_ws(
    State(s): State<AppState>,
    Query(q): Query<TokenQuery>,
    ws: WebSocketUpgrade,
) -> Result<Response, AppError> {
    let station = store::stations::by_token(&s.pool, &q.token)
        .await?
        .ok_or(AppError::Unauthorized)?;
    Ok(ws.on_upgrade(move |socket| station_socket(s, station.id, socket)))
}

fn text(event: &impl serde::Serialize) -> String {
    serde_json::to_string(event).expect("browser messages serialize")
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
    // The trial this station may feed: its subject's running test at a seat it serves.
    let current =
        |s: AppState| async move { running_trial(&s.pool, station_id).await.ok().flatten() };
    let changed = text(&StationEvent::Changed);
    let mut running = current(s.clone()).await;
    loop {
        tokio::select! {
            msg = stream.next() => {
                let Some(Ok(msg)) = msg else { break };
                let Message::Text(body) = msg else { continue };
                match serde_json::from_str::<StationMessage>(&body) {
                    Ok(StationMessage::Input { trial_id, seq, position_mm })
                        if Some(trial_id) == running
                            && position_mm.is_finite()
                            && position_mm.abs() <= MAX_POSITION_MM =>
                    {
                        s.controller.send_input(trial_id as u64, seq, position_mm);
                    }
                    // Input for a trial that is not this station's running one, or garbage: dropped.
                    _ => {}
                }
            }
            ev = events.recv() => match ev {
                Ok(ControllerEvent::Live(sample)) if Some(sample.trial_id as i64) == running => {
                    // A live sample that cannot be queued is dropped, never waited for.
                    let _ = out.try_send(text(&StationEvent::Live { sample }));
                }
                Ok(ControllerEvent::TrialChanged { .. } | ControllerEvent::Link { .. } | ControllerEvent::EStop { .. }) | Err(RecvError::Lagged(_)) => {
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

/// The dashboard's live feed: every live sample and every change (MonitorEvent messages).
/// Same-origin only: a cookie-authenticated WebSocket is otherwise open to cross-site
/// hijacking.
#[utoipa::path(get, path = "/api/live", tag = "monitor",
    responses((status = 101, description = "WebSocket: MonitorEvent out")))]
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
            let event = match events.recv().await {
                Ok(ControllerEvent::Live(sample)) => MonitorEvent::Live { sample },
                Ok(ControllerEvent::TrialChanged { trial_id }) => MonitorEvent::Trial { trial_id },
                Ok(ControllerEvent::Link { connected }) => MonitorEvent::Controller { connected },
                Ok(ControllerEvent::EStop { latched }) => MonitorEvent::EStop { latched },
                Err(RecvError::Lagged(_)) => continue,
                Err(_) => return,
            };
            if socket
                .send(Message::Text(text(&event).into()))
                .await
                .is_err()
            {
                return;
            }
        }
    }))
}
