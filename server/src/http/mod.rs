//! The HTTP surface: one module per area, each a router of its handlers; `app` puts them
//! together by who may call them and generates the OpenAPI document from the same routers,
//! so the document cannot drift from what is served.
//!
//! *Invariants:* an area module imports only the infrastructure beside it (`error`,
//! `extract`, `bodies`, `page`), never another area; the experimenter router carries the
//! authentication layer, so a route added there is protected by default; every API route
//! is registered with `routes!`, so it is in the document.
//!
//! `app` groups the area routers by caller (anyone, bearer token, experimenter), the experimenter
//! group under the `require_experimenter` layer, and splits the OpenAPI document out of the same
//! routers (`utoipa-axum`), served at `/api/openapi.json` with every operation's security and error
//! answers filled in; every answer names its media types (JSON with its schema, CSV and SVG as
//! text, PNG and Parquet by media type alone; a WebSocket upgrade has no body).
//!
//! Areas: `session` (login, logout, first account), `accounts` (admin-only account management),
//! `erasure` (admin-only: erase a subject, the erasures with the backups still holding their data),
//! `protocol_package` (a study's ethics-board page, with the pages' headers), `studies`, `subjects`
//! (and the subject's own page's API: progress, withdrawal), `stations` (pairing, assignment,
//! monitor view), `station_client` (the station's own API), `trials`, `controller` (health, E-stop,
//! link status), `live` (the station and dashboard WebSockets: size caps, pings, the station's read
//! budget and opening limit, the E-stop latch pushed to the station; each socket reads its peer all
//! the time, so a closed one releases its task and descriptor), `pilot`, `calibration`, `backups`
//! (admin-only: the backup directory's listing and "back up now"), `configs` (configuration
//! versions, a study's picks), `bench` (bench runs, their views and CSV; a 4 MiB body for an
//! uploaded reference), `results` (summary, plots, exports, audit log, the power planner),
//! `workbench` (read-only analysis of a study's designs: frequency, Nyquist, poles, robustness),
//! `pages` (`web/`, embedded with `include_dir` or served from `--web-dir`, strict CSP). Shared
//! infrastructure: `error` (status codes, `AppJson`), `extract` (session layer, CSRF, the role
//! check, `Experimenter::may_drive` — the per-site check the handlers that start, abort or reset a
//! machine or run the bench on one call before acting —, bearer extractors, `AppPath` and
//! `AppQuery`, whose rejections are the JSON error), `bodies`, `page` (every page's content type,
//! no-cache and security headers: the strict CSP).
//!
//! More invariants: an `Experimenter` extractor used outside the experimenter router fails closed;
//! the layer refuses analysts every state-changing route but the E-stop (and logging out), and
//! everyone but admins `/api/accounts…`, `/api/backups…` and the erasure routes (one table,
//! `ADMIN_ONLY`), so a new route fails closed; every API route's request and response schemas are
//! documented, so they cannot drift; path and query parameters are read through
//! `AppPath`/`AppQuery` (or `query`), never axum's own extractors, whose rejections are plain text;
//! an account limited to sites drives only those sites' machines, and the E-stop handler never
//! checks sites.

pub mod bodies;
pub mod error;
pub mod extract;
pub mod page;

mod accounts;
mod backups;
mod bench;
mod calibration;
mod configs;
mod controller;
mod erasure;
mod live;
mod pages;
mod pilot;
mod protocol_package;
mod results;
mod session;
mod station_client;
mod stations;
mod studies;
mod subjects;
mod trials;
mod workbench;

use std::sync::Arc;

use axum::extract::DefaultBodyLimit;
use axum::routing::get;
use axum::{Json, Router, middleware};
use utoipa::OpenApi;
use utoipa::openapi::path::{Operation, PathItem};
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityRequirement, SecurityScheme};
use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};
use utoipa_axum::router::OpenApiRouter;

use crate::state::AppState;

/// Largest request body accepted (study parameters are a few kB).
const MAX_BODY: usize = 256 * 1024;

/// Who may call a group of routes, as the document names it.
#[derive(Debug, Clone, Copy)]
enum Caller {
    Anyone,
    /// `session`: the experimenter's cookie (and the CSRF header on changes).
    Experimenter,
    /// `bearer`: a station's or a subject's token.
    Bearer,
}

#[derive(OpenApi)]
#[openapi(
    info(
        title = "bdft-lab experiment server",
        description = "Studies, subjects, stations, trials, surveys, results and exports of biodynamic-feedthrough experiments. Errors are JSON `{\"error\": ..., \"fields\": [...]}`: 4xx for what a user got wrong, 500 only for bugs."
    ),
    components(schemas(error::ErrorBody))
)]
struct ApiDoc;

/// The whole HTTP surface.
pub fn app(state: AppState) -> Router {
    let experimenter = OpenApiRouter::new()
        .merge(session::experimenter())
        .merge(accounts::routes())
        .merge(backups::routes())
        .merge(studies::routes())
        .merge(subjects::experimenter())
        .merge(erasure::routes())
        .merge(protocol_package::routes())
        .merge(stations::routes())
        .merge(trials::routes())
        .merge(controller::experimenter())
        .merge(pilot::routes())
        .merge(calibration::routes())
        .merge(bench::routes())
        .merge(configs::routes())
        .merge(results::routes())
        .merge(workbench::routes())
        .merge(live::experimenter())
        .route_layer(middleware::from_fn_with_state(
            state.clone(),
            extract::require_experimenter,
        ));
    let groups = [
        (Caller::Anyone, session::public()),
        (Caller::Anyone, controller::public()),
        (Caller::Anyone, station_client::public()),
        // The station socket takes its token in the query.
        (Caller::Bearer, live::station()),
        (Caller::Bearer, station_client::station()),
        (Caller::Bearer, subjects::subject()),
        (Caller::Experimenter, experimenter),
    ];
    let mut doc = ApiDoc::openapi();
    let mut router = Router::new();
    for (caller, group) in groups {
        let (r, mut api) = group.split_for_parts();
        describe(&mut api, caller);
        doc.merge(api);
        router = router.merge(r);
    }
    add_security_schemes(&mut doc);
    let doc = Arc::new(doc);
    let https = state.https;
    let router = router
        .route(
            "/api/openapi.json",
            get(move || async move { Json(doc.as_ref().clone()) }),
        )
        .merge(pages::routes())
        .layer(DefaultBodyLimit::max(MAX_BODY))
        .with_state(state);
    if https {
        router.layer(middleware::map_response(strict_transport_security))
    } else {
        router
    }
}

/// HSTS on every answer of an HTTPS server: a browser that has seen it once never falls
/// back to plain HTTP for this host (a year, the usual value).
async fn strict_transport_security(mut r: axum::response::Response) -> axum::response::Response {
    r.headers_mut().insert(
        axum::http::header::STRICT_TRANSPORT_SECURITY,
        axum::http::HeaderValue::from_static("max-age=31536000"),
    );
    r
}

fn operations(item: &mut PathItem) -> impl Iterator<Item = &mut Operation> {
    [
        &mut item.get,
        &mut item.put,
        &mut item.post,
        &mut item.delete,
        &mut item.patch,
        &mut item.head,
        &mut item.options,
        &mut item.trace,
    ]
    .into_iter()
    .flatten()
}

/// Marks who may call each operation of `api` and adds the error answers they share.
fn describe(api: &mut utoipa::openapi::OpenApi, caller: Caller) {
    let errors: &[(&str, &str)] = &[
        ("401", "not logged in, or no valid token"),
        (
            "403",
            "forbidden: wrong CSRF token, the account's role may not do it, the account is limited to other sites than the machine's it would drive, or another subject's data",
        ),
        ("404", "not found"),
        (
            "409",
            "not allowed in the current state, or another user changed it first",
        ),
        ("413", "the request body is too large"),
        (
            "422",
            "invalid input: `error` says what, `fields` lists bad form fields",
        ),
        ("503", "the controller or the database cannot serve it now"),
    ];
    for item in api.paths.paths.values_mut() {
        for op in operations(item) {
            op.security = Some(match caller {
                Caller::Anyone => vec![SecurityRequirement::default()],
                Caller::Experimenter => {
                    vec![SecurityRequirement::new("session", Vec::<String>::new())]
                }
                Caller::Bearer => vec![SecurityRequirement::new("bearer", Vec::<String>::new())],
            });
            for (code, what) in errors {
                op.responses
                    .responses
                    .entry((*code).to_string())
                    .or_insert_with(|| {
                        ResponseBuilder::new()
                            .description(*what)
                            .content(
                                "application/json",
                                ContentBuilder::new()
                                    .schema(Some(Ref::from_schema_name("ErrorBody")))
                                    .build(),
                            )
                            .build()
                            .into()
                    });
            }
        }
    }
}

fn add_security_schemes(doc: &mut utoipa::openapi::OpenApi) {
    let components = doc.components.get_or_insert_with(Default::default);
    components.add_security_scheme(
        "session",
        SecurityScheme::ApiKey(utoipa::openapi::security::ApiKey::Cookie(
            utoipa::openapi::security::ApiKeyValue::with_description(
                extract::SESSION_COOKIE,
                "the experimenter's session (POST /api/login); changes also need the X-CSRF-Token header",
            ),
        )),
    );
    components.add_security_scheme(
        "bearer",
        SecurityScheme::Http(
            HttpBuilder::new()
                .scheme(HttpAuthScheme::Bearer)
                .description(Some("a station's token (POST /api/station/register, then paired) or a subject's page token"))
                .build(),
        ),
    );
}
