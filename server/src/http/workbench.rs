//! The workbench's analysis of a study's designs: frequency responses, Nyquist views and pole
//! tables, and robustness maps. Read-only (GET), so analysts may use them; the numbers behind
//! every plot are the JSON answered here, the dashboard draws them.

use axum::extract::State;
use serde::Deserialize;
use utoipa::IntoParams;
use utoipa_axum::router::OpenApiRouter;
use utoipa_axum::routes;

use super::error::{ApiResult, AppJson};
use super::extract::{AppPath, AppQuery, Experimenter};
use crate::engine::machine::workbench_analysis::{
    ConditionTable, ConditionsQuery, FrequencyReport, RobustnessQuery, RobustnessReport,
    conditions_report, frequency_report, robustness_report,
};
use crate::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
        .routes(routes!(frequency))
        .routes(routes!(robustness))
        .routes(routes!(conditions))
}

#[derive(Debug, Deserialize, IntoParams)]
#[into_params(parameter_in = Query)]
struct FrequencyQuery {
    /// K_BF at which the loops are closed and the Nyquist curve drawn, 0–20 [default: the
    /// study's].
    kbf: Option<f64>,
    /// A subject of the study whose identified body (their latest identification test's
    /// fit) replaces the study's [default: none].
    subject: Option<i64>,
}

/// Bode data of the rig's parts, the body, each compensator and each closed loop (on and off
/// the machine); the Nyquist curve of each design with the feedthrough loop opened
/// (encirclements of −1, verdict, largest stable K_BF); the closed-loop poles in the design
/// and implemented views with the cause of each difference. As `bdft-controller frequency
/// --json` prints it.
#[utoipa::path(get, path = "/api/studies/{id}/workbench/frequency", tag = "workbench",
    params(("id" = i64, Path), FrequencyQuery),
    responses((status = 200, body = Object, description = "the frequency report (bdft-controller frequency --json)")))]
async fn frequency(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppQuery(q): AppQuery<FrequencyQuery>,
) -> ApiResult<FrequencyReport> {
    let r = frequency_report(&s.pool, id, q.kbf, q.subject).await?;
    Ok(AppJson(FrequencyReport::clone(&r)))
}

/// The largest stable K_BF of one design over a K_H × structure-frequency map, and the
/// Monte-Carlo pass rate at K_BF with K_H, both structure frequencies and dampings and the
/// valve parameters drawn within the ranges (as `bdft-controller robustness … --json`).
#[utoipa::path(get, path = "/api/studies/{id}/workbench/robustness", tag = "workbench",
    params(("id" = i64, Path), RobustnessQuery),
    responses((status = 200, body = Object, description = "the robustness report (bdft-controller robustness --json, one design)")))]
async fn robustness(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppQuery(q): AppQuery<RobustnessQuery>,
) -> ApiResult<RobustnessReport> {
    Ok(AppJson(robustness_report(&s.pool, id, q).await?))
}

/// Each of the study's designs, made for its rig, on the machine under each condition (on
/// tires, outriggers down, a loaded bucket, the stick driven, …): its swept-sine bench
/// cab-acceleration reduction against its twin and its largest stable K_BF with the body (as
/// `bdft-controller conditions --json`).
#[utoipa::path(get, path = "/api/studies/{id}/workbench/conditions", tag = "workbench",
    params(("id" = i64, Path), ConditionsQuery),
    responses((status = 200, body = Object, description = "the conditions table (bdft-controller conditions --json)")))]
async fn conditions(
    State(s): State<AppState>,
    _who: Experimenter,
    AppPath(id): AppPath<i64>,
    AppQuery(q): AppQuery<ConditionsQuery>,
) -> ApiResult<ConditionTable> {
    Ok(AppJson(conditions_report(&s.pool, id, q).await?))
}
