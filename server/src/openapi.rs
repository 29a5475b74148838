//! The API described as OpenAPI 3.1, served at /api/openapi.json. Written out by hand from
//! the routers (a test checks every documented path is routed).

use serde_json::{Value, json};

fn op(summary: &str, auth: &str) -> Value {
    let security = match auth {
        "experimenter" => json!([{ "session": [] }]),
        "station" | "subject" => json!([{ "bearer": [] }]),
        _ => json!([]),
    };
    json!({
        "summary": summary,
        "security": security,
        "responses": {
            "200": { "description": "OK (JSON)" },
            "401": { "description": "not logged in / no valid token", "content": { "application/json": { "schema": { "$ref": "#/components/schemas/Error" } } } },
            "403": { "description": "forbidden (wrong CSRF token, wrong scope)" },
            "404": { "description": "not found" },
            "409": { "description": "not allowed in the current state" },
            "422": { "description": "invalid input; `error` says what, `fields` lists bad fields" }
        }
    })
}

/// (method, path, summary, auth)
pub const ROUTES: &[(&str, &str, &str, &str)] = &[
    ("get", "/api/health", "liveness and controller link", "none"),
    ("get", "/api/openapi.json", "this document", "none"),
    (
        "get",
        "/api/setup",
        "whether the first experimenter account must still be created",
        "none",
    ),
    (
        "post",
        "/api/setup",
        "create the first experimenter with the one-time set-up token",
        "none",
    ),
    (
        "post",
        "/api/login",
        "log in (sets an HttpOnly session cookie, returns the CSRF token)",
        "none",
    ),
    ("post", "/api/logout", "log out", "experimenter"),
    (
        "get",
        "/api/me",
        "the logged-in experimenter and CSRF token",
        "experimenter",
    ),
    (
        "get",
        "/api/defaults",
        "default study parameters (the published protocol)",
        "experimenter",
    ),
    ("get", "/api/studies", "list studies", "experimenter"),
    (
        "post",
        "/api/studies",
        "create a study {name, params?, seed?}",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}",
        "a study, with lock time and protocol hash",
        "experimenter",
    ),
    (
        "put",
        "/api/studies/{id}",
        "edit a study's name and parameters (refused once locked)",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}/subjects",
        "subjects with progress",
        "experimenter",
    ),
    (
        "post",
        "/api/studies/{id}/subjects",
        "enrol the next subject (locks the protocol); returns the subject token",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}/stations",
        "paired stations",
        "experimenter",
    ),
    (
        "post",
        "/api/studies/{id}/stations",
        "pair a station by its code {pairing_code, name, role}",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}/summary",
        "statistics per controller × station",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}/export/{kind}",
        "CSV export, kind = trials | samples | summary (streamed)",
        "experimenter",
    ),
    (
        "get",
        "/api/subjects/{id}",
        "a subject's schedule with real controller names, surveys, notes",
        "experimenter",
    ),
    (
        "post",
        "/api/subjects/{id}/withdraw",
        "withdraw a subject {reason} (excluded from exports)",
        "experimenter",
    ),
    (
        "post",
        "/api/stations/{id}/assign",
        "assign a subject to a station {subject_id}",
        "experimenter",
    ),
    (
        "get",
        "/api/stations/{id}/state",
        "what a station shows now, with the real controller name",
        "experimenter",
    ),
    (
        "get",
        "/api/studies/{id}/plots/{file}",
        "box plot of a variable per controller × station: {variable}.svg or {variable}.png",
        "experimenter",
    ),
    (
        "post",
        "/api/trials/{id}/start",
        "start a scheduled test on the controller",
        "experimenter",
    ),
    (
        "post",
        "/api/trials/{id}/abort",
        "abort a running test {reason}",
        "experimenter",
    ),
    (
        "post",
        "/api/trials/{id}/redo",
        "schedule a new attempt of a finished test",
        "experimenter",
    ),
    (
        "post",
        "/api/trials/{id}/incomplete",
        "mark a test incomplete {reason}",
        "experimenter",
    ),
    (
        "post",
        "/api/trials/{id}/note",
        "add a note {text}",
        "experimenter",
    ),
    (
        "post",
        "/api/studies/{id}/pilot",
        "dry-run the protocol with synthetic subjects in the background {subjects}",
        "experimenter",
    ),
    (
        "get",
        "/api/pilot",
        "progress of the pilot run",
        "experimenter",
    ),
    (
        "post",
        "/api/estop",
        "emergency stop: every valve to zero, latched",
        "experimenter",
    ),
    (
        "post",
        "/api/estop/reset",
        "clear the e-stop latch",
        "experimenter",
    ),
    (
        "get",
        "/api/controller",
        "controller link status",
        "experimenter",
    ),
    (
        "get",
        "/api/audit",
        "the audit log, newest first (?limit=)",
        "experimenter",
    ),
    (
        "get",
        "/api/live",
        "WebSocket: every live sample and trial change",
        "experimenter",
    ),
    (
        "post",
        "/api/station/register",
        "a new station: token and pairing code to show",
        "none",
    ),
    (
        "get",
        "/api/station/state",
        "what the station shows now (phase)",
        "station",
    ),
    (
        "post",
        "/api/station/consent",
        "the assigned subject's consent {decision: agreed|declined}",
        "station",
    ),
    (
        "post",
        "/api/station/survey",
        "the survey of a completed test",
        "station",
    ),
    (
        "post",
        "/api/station/timing",
        "display timing of a test (frames, long frames, input round trip)",
        "station",
    ),
    (
        "get",
        "/api/station/ws",
        "WebSocket (?token=): operator input in, live samples out",
        "station",
    ),
    (
        "get",
        "/api/subject",
        "the subject's own progress (blinded)",
        "subject",
    ),
];

pub fn document() -> Value {
    let mut paths = serde_json::Map::new();
    for (method, path, summary, auth) in ROUTES {
        let entry = paths
            .entry((*path).to_string())
            .or_insert_with(|| json!({}));
        entry[*method] = op(summary, auth);
    }
    json!({
        "openapi": "3.1.0",
        "info": { "title": "bdft-lab experiment server", "version": env!("CARGO_PKG_VERSION") },
        "paths": paths,
        "components": {
            "securitySchemes": {
                "session": { "type": "apiKey", "in": "cookie", "name": crate::auth::SESSION_COOKIE, "description": "state-changing requests also send X-CSRF-Token" },
                "bearer": { "type": "http", "scheme": "bearer", "description": "station or subject token" }
            },
            "schemas": { "Error": { "type": "object", "properties": { "error": { "type": "string" }, "fields": { "type": "array" } }, "required": ["error"] } }
        }
    })
}
