//! The rows of each export, written through a `TableWriter` whose columns came from
//! `columns_of` (the same columns the codebook lists).

use std::collections::{BTreeMap, BTreeSet};

use bdft_protocol::identification::BodyFit;
use bdft_protocol::params::AdaptationStatus;
use bdft_protocol::records::TestPhase;
use bdft_protocol::study::SurveyParams;
use sqlx::AnyPool;
use tokio::io::AsyncWrite;

use super::columns::{self, Column, IDENTIFIED};
use super::sink::{Cell, TableWriter};
use super::{ExportError, ExportKind, ExportRequest, SampleCut};
use crate::engine::results::inference_table::study_table;
use crate::engine::results::stats::summary_stats;
use crate::engine::results::study_data::{counts, valid};
use crate::engine::study::exposure::{self, ExposureDay};
use crate::store;
use crate::store::db::rfc3339;
use crate::store::exports::{SubjectExportRow, TrialExportRow, Withdrawn};

/// What a study's columns depend on: its survey scale (the ratings' headers) and the names
/// of its subjects' drawn parameters.
#[derive(Debug, Default)]
pub struct StudyContext {
    survey: SurveyParams,
    drawn_keys: Vec<String>,
}

impl StudyContext {
    /// The context of a study with the survey `survey` whose subjects are people (no drawn
    /// parameters).
    pub fn of_people(survey: SurveyParams) -> Self {
        Self {
            survey,
            drawn_keys: Vec::new(),
        }
    }

    /// The study's context (none for the audit log, which is no study's).
    pub async fn load(
        pool: &AnyPool,
        study_id: i64,
        kind: ExportKind,
    ) -> Result<Self, ExportError> {
        if !kind.per_study() {
            return Ok(Self::default());
        }
        let study = store::studies::get(pool, study_id).await?;
        let subjects = store::exports::subject_rows(pool, study_id).await?;
        let keys: BTreeSet<String> = subjects.iter().flat_map(|s| drawn(s).into_keys()).collect();
        Ok(Self {
            survey: study.params.survey,
            drawn_keys: keys.into_iter().collect(),
        })
    }
}

/// A subject's drawn parameters (empty for a person, or a value that is no flat object).
fn drawn(s: &SubjectExportRow) -> BTreeMap<String, Option<f64>> {
    s.drawn_json
        .as_deref()
        .and_then(|j| serde_json::from_str::<serde_json::Map<String, serde_json::Value>>(j).ok())
        .map(|m| m.into_iter().map(|(k, v)| (k, v.as_f64())).collect())
        .unwrap_or_default()
}

/// The columns of `kind`: what its header, its Parquet schema and the codebook say.
pub fn columns_of(kind: ExportKind, cx: &StudyContext) -> Vec<Column> {
    match kind {
        ExportKind::Trials => columns::trials(&cx.survey),
        ExportKind::Samples => columns::samples(),
        ExportKind::Subjects => columns::subjects(&cx.drawn_keys),
        ExportKind::Codebook => columns::codebook(),
        ExportKind::Summary => columns::summary(),
        ExportKind::Stats => columns::stats(),
        ExportKind::Notes => columns::notes(),
        ExportKind::Identification => columns::identification(),
        ExportKind::Audit => columns::audit(),
    }
}

type Table<'w, W> = &'w mut TableWriter<W>;

pub async fn write_rows<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    req: &ExportRequest,
    cx: &StudyContext,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    match req.kind {
        ExportKind::Trials => trials(pool, study_id, t).await,
        ExportKind::Samples => samples(pool, study_id, &req.cut, t).await,
        ExportKind::Subjects => subjects(pool, study_id, t).await,
        ExportKind::Codebook => codebook(cx, t).await,
        ExportKind::Summary => summary(pool, study_id, &cx.survey, t).await,
        ExportKind::Stats => stats(pool, study_id, &cx.survey, t).await,
        ExportKind::Notes => notes(pool, study_id, t).await,
        ExportKind::Identification => identification(pool, study_id, t).await,
        ExportKind::Audit => audit(pool, t).await,
    }
}

fn opt_text(s: &Option<String>) -> Cell<'_> {
    Cell::Text(s.as_deref().map(Into::into))
}

fn time(ms: Option<i64>) -> Cell<'static> {
    Cell::Text(ms.map(|ms| rfc3339(ms).into()))
}

fn phase(p: TestPhase) -> Cell<'static> {
    Cell::text(p.as_str())
}

/// A test-only cell: empty for the practice and an identification test, so that neither
/// can be read as a test of its compensator.
fn test_only(p: TestPhase, cell: Cell<'_>) -> Cell<'_> {
    match (p.scored(), cell) {
        (true, c) => c,
        (false, Cell::Int(_)) => Cell::Int(None),
        (false, Cell::Num(_)) => Cell::Num(None),
        (false, Cell::Text(_)) => Cell::Text(None),
    }
}

async fn trials<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for r in store::exports::trial_rows(pool, study_id, Withdrawn::LeftOut).await? {
        t.row(&trial_cells(&r)).await?;
    }
    Ok(())
}

/// A trials export row: the cells of `columns::trials`, in its order.
pub fn trial_cells(r: &TrialExportRow) -> Vec<Cell<'_>> {
    let p = r.phase;
    let rating = |v: Option<i64>| Cell::Int(v);
    let mut cells = vec![
        Cell::Int(Some(r.study_id)),
        Cell::Int(Some(r.trial_id)),
        Cell::text(r.code.as_str()),
        Cell::Int(Some(r.enrol_index + 1)),
        Cell::flag(r.synthetic),
        Cell::text(r.starting_station.as_str()),
        phase(p),
        Cell::text(r.station.as_str()),
        test_only(p, Cell::Int(Some(r.block))),
        test_only(p, Cell::Int(Some(r.position))),
        Cell::Int(Some(r.slot)),
        Cell::Int(Some(r.attempt)),
        Cell::flag(r.latest),
        Cell::flag(valid(r)),
        test_only(p, Cell::text(r.controller.name())),
        test_only(p, Cell::text(r.blinded_label.as_str())),
        Cell::text(r.status.as_str()),
        opt_text(&r.status_reason),
        Cell::Int(Some(r.target_seed)),
        Cell::Num(Some(r.target_mean_mm)),
        Cell::Num(Some(r.target_std_mm)),
        Cell::Num(r.target_ms_step_mm2),
        Cell::Num(Some(r.k_bf)),
        Cell::Num(Some(r.duration_s)),
        Cell::Num(r.mse_tracking_mm2),
        Cell::Num(r.ms_cab_accel),
        Cell::Num(r.cab_aw_m_s2),
        Cell::Num(r.cab_vdv_m_s175),
        rating(r.accuracy),
        rating(r.speed),
        rating(r.smoothness),
        rating(r.controllability),
        opt_text(&r.comment),
        opt_text(&r.protocol_hash),
        time(r.started_at),
        time(r.finished_at),
        opt_text(&r.consent_version),
    ];
    cells.extend(validity_cells(r));
    cells.push(opt_text(&r.config_version));
    cells.extend(design_cells(r));
    cells.push(opt_text(&r.site));
    // The clear names of starting_station, station and controller (`columns::trials`).
    cells.extend([
        Cell::text(r.starting_station.as_str()),
        Cell::text(r.station.as_str()),
        test_only(p, Cell::text(r.controller.name())),
    ]);
    cells.push(test_only(p, Cell::text(r.cancellation.as_str())));
    cells.push(Cell::Num(r.cancellation_off_at_s));
    cells.push(Cell::text(r.condition.as_str()));
    cells.extend(adaptation_cells(r));
    cells
}

/// What an adaptive design did over the test (`columns::trials`' adapt_ columns); empty for
/// a fixed design.
fn adaptation_cells(r: &TrialExportRow) -> [Cell<'static>; 6] {
    // Written by the store from the controller's result: a row it cannot read is one this
    // server did not write, and it exports empty rather than failing the whole export.
    let a = r
        .adaptation_json
        .as_deref()
        .and_then(|j| serde_json::from_str::<AdaptationStatus>(j).ok());
    [
        Cell::Num(a.and_then(|a| a.f_hz)),
        Cell::Num(a.and_then(|a| a.confident_since_s)),
        Cell::Num(a.map(|a| a.ratio)),
        Cell::Int(a.map(|a| i64::from(a.retunes))),
        Cell::Int(a.map(|a| i64::from(a.fallbacks))),
        Cell::Int(a.map(|a| i64::from(a.confident))),
    ]
}

/// Whether the trial's design was the subject's own, and its LQR weights as run.
fn design_cells(r: &TrialExportRow) -> [Cell<'_>; 3] {
    use bdft_protocol::params::CompensatorSpec;
    let lqr = match serde_json::from_str(&r.compensator_json) {
        Ok(
            CompensatorSpec::Lqr { lqr }
            | CompensatorSpec::LqrCabvel { lqr }
            | CompensatorSpec::LqrCabacc { lqr }
            // The scheduled LQR's weights are those of each of its designs.
            | CompensatorSpec::LqrCabvelScheduled { lqr, .. },
        ) => Some(lqr),
        _ => None,
    };
    [
        Cell::flag(r.personalized),
        Cell::Num(lqr.as_ref().map(|l| l.alpha)),
        Cell::Num(lqr.as_ref().map(|l| l.beta)),
    ]
}

/// How the test ran (validity): the station's display and input, the controller's timing,
/// and the experimenter's acceptance of a failed test as incomplete; empty where a figure
/// is missing (a test that never ran, a station that sent none).
fn validity_cells(r: &TrialExportRow) -> [Cell<'_>; 10] {
    let parse = |j: &Option<String>| {
        j.as_deref()
            .and_then(|j| serde_json::from_str::<serde_json::Value>(j).ok())
            .unwrap_or_default()
    };
    let (station, controller) = (parse(&r.client_timing_json), parse(&r.timing_json));
    let int = |v: &serde_json::Value| Cell::Int(v.as_i64());
    let num = |v: &serde_json::Value| Cell::Num(v.as_f64());
    [
        int(&station["frames"]),
        num(&station["longest_gap_ms"]),
        num(&station["hidden_ms"]),
        num(&station["input_hz"]),
        num(&station["rtt_ms"]["p50"]),
        num(&station["rtt_ms"]["p95"]),
        num(&station["rtt_ms"]["max"]),
        int(&controller["overruns"]),
        num(&controller["wake_latency_us"]["p99"]),
        opt_text(&r.accepted_reason),
    ]
}

/// Join keys before the record's columns in every samples row.
const SAMPLE_KEYS: usize = 7;

async fn samples<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    cut: &SampleCut,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    let (code, trial) = match cut {
        SampleCut::All => (None, None),
        SampleCut::Subject(code) => (Some(code.as_str()), None),
        SampleCut::Trial(id) => (None, Some(*id)),
    };
    let width = t.columns().len();
    for r in store::exports::recorded_trials(pool, study_id, code, trial).await? {
        // One trial's record in memory at a time (about 5 MB for 140 s).
        let store::records::Record { dt, channels } = store::records::get(pool, r.trial_id).await?;
        let p = r.phase;
        let mut cells = vec![
            Cell::Int(Some(study_id)),
            Cell::text(r.code.as_str()),
            Cell::Int(Some(r.trial_id)),
            phase(p),
            Cell::text(r.seat.as_str()),
            test_only(p, Cell::text(r.compensator.as_str())),
            Cell::Int(Some(r.attempt)),
        ];
        cells.resize(width, Cell::Num(None));
        debug_assert_eq!(width, SAMPLE_KEYS + 1 + channels.len());
        for k in 0..channels.first().map_or(0, Vec::len) {
            cells[SAMPLE_KEYS] = Cell::Num(Some(k as f64 * dt));
            for (cell, c) in cells[SAMPLE_KEYS + 1..].iter_mut().zip(&channels) {
                *cell = Cell::Num(Some(f64::from(c[k])));
            }
            t.row(&cells).await?;
        }
    }
    Ok(())
}

async fn subjects<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    let trials = store::exports::trial_rows(pool, study_id, Withdrawn::Included).await?;
    let drawn_columns: Vec<String> = t.columns()[columns::subjects(&[]).len()..]
        .iter()
        .map(|c| c.name[columns::DRAWN_PREFIX.len()..].to_string())
        .collect();
    let study = store::studies::get(pool, study_id).await?;
    for s in store::exports::subject_rows(pool, study_id).await? {
        let own: Vec<&TrialExportRow> = trials.iter().filter(|r| r.code == s.code).collect();
        let values = drawn(&s);
        let mut cells = vec![
            Cell::Int(Some(study_id)),
            Cell::text(s.code.as_str()),
            Cell::Int(Some(s.enrol_index + 1)),
            Cell::flag(s.synthetic),
            Cell::text(s.starting_seat.as_str()),
            opt_text(&s.consent_version),
            opt_text(&s.consent_decision),
            time(s.consent_at),
            opt_text(&s.consent_sha256),
            Cell::flag(s.withdrawn_at.is_some()),
            time(s.withdrawn_at),
            Cell::text(order_summary(&own)),
            Cell::Int(Some(own.iter().filter(|r| counts(r)).count() as i64)),
        ];
        let days = exposure::days(&mut *pool.acquire().await?, &study.params, s.id)
            .await?
            .days;
        // A day with a test the loop did not measure has only a bound (the budget counts
        // it at its worst case): no figure rather than a bound read as a measurement.
        let measured = days.iter().all(|d| d.worst_case_tests == 0);
        let most =
            |f: fn(&ExposureDay) -> f64| days.iter().map(f).reduce(f64::max).filter(|_| measured);
        cells.extend([
            Cell::Int(Some(days.len() as i64)),
            Cell::Num(most(|d| d.a8_m_s2)),
            Cell::Num(most(|d| d.vdv_m_s175)),
        ]);
        // The body fitted by the subject's latest identification test that has a fit.
        let fit = store::identifications::of_subject(pool, s.id)
            .await?
            .into_iter()
            .rev()
            .find_map(|i| i.fit);
        // A parameter the data did not identify has no value or interval, and says why.
        match fit.as_ref().map(BodyFit::reported) {
            Some(reported) => {
                for r in reported {
                    cells.extend([
                        Cell::Num(r.value),
                        Cell::Num(r.lo),
                        Cell::Num(r.hi),
                        Cell::text(r.status()),
                    ]);
                }
            }
            None => cells.extend((0..IDENTIFIED.len()).flat_map(|_| {
                [
                    Cell::Num(None),
                    Cell::Num(None),
                    Cell::Num(None),
                    Cell::Text(None),
                ]
            })),
        }
        cells.push(Cell::Num(fit.as_ref().map(|f| f.residual_rms)));
        // starting_station's clear name.
        cells.push(Cell::text(s.starting_seat.as_str()));
        cells.extend(
            drawn_columns
                .iter()
                .map(|k| Cell::Num(values.get(k).copied().flatten())),
        );
        t.row(&cells).await?;
    }
    Ok(())
}

async fn identification<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for (code, i) in store::identifications::of_study(pool, study_id).await? {
        for p in &i.points {
            t.row(&[
                Cell::Int(Some(study_id)),
                Cell::text(code.as_str()),
                Cell::Int(Some(i.trial_id)),
                Cell::Num(Some(p.f_hz)),
                Cell::Num(Some(p.magnitude)),
                Cell::Num(Some(p.magnitude_lo)),
                Cell::Num(Some(p.magnitude_hi)),
                Cell::Num(Some(p.phase_deg)),
                Cell::Num(Some(p.phase_lo_deg)),
                Cell::Num(Some(p.phase_hi_deg)),
                Cell::Num(Some(p.coherence)),
            ])
            .await?;
        }
    }
    Ok(())
}

/// The schedule's order: each seat's compensators in schedule (slot) order, from the first
/// attempts (`on: pid > lqr > … | off: …`).
fn order_summary(trials: &[&TrialExportRow]) -> String {
    let mut tests: Vec<&&TrialExportRow> = trials
        .iter()
        .filter(|r| r.phase.scored() && r.attempt == 1)
        .collect();
    tests.sort_by_key(|r| r.slot);
    let mut blocks: Vec<(&str, Vec<&str>)> = Vec::new();
    for r in tests {
        match blocks.last_mut() {
            Some((seat, names)) if *seat == r.station.as_str() => names.push(r.controller.name()),
            _ => blocks.push((r.station.as_str(), vec![r.controller.name()])),
        }
    }
    blocks
        .iter()
        .map(|(seat, names)| format!("{seat}: {}", names.join(" > ")))
        .collect::<Vec<_>>()
        .join(" | ")
}

/// One row per column of every export (of this study: its rating scale, its drawn
/// parameters), from the same definitions the exports write.
async fn codebook<W: AsyncWrite + Unpin>(
    cx: &StudyContext,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for kind in ExportKind::ALL {
        for c in columns_of(kind, cx) {
            t.row(&[
                Cell::text(kind.name()),
                Cell::text(c.name),
                Cell::text(c.ty.name()),
                Cell::text(c.unit),
                Cell::Num(c.ty.resolution()),
                Cell::text(c.meaning),
            ])
            .await?;
        }
    }
    Ok(())
}

async fn summary<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    survey: &SurveyParams,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for s in summary_stats(pool, study_id).await? {
        t.row(&[
            Cell::text(s.compensator.clone()),
            Cell::text(s.seat.clone()),
            Cell::text(columns::variable_column(&s.variable, survey)),
            Cell::Int(Some(s.n as i64)),
            Cell::Num(Some(s.mean)),
            Cell::Num(Some(s.median)),
            Cell::Num(Some(s.q1)),
            Cell::Num(Some(s.q3)),
            Cell::Num(Some(s.min)),
            Cell::Num(Some(s.max)),
            // controller's and station's clear names.
            Cell::text(s.compensator),
            Cell::text(s.seat),
            Cell::text(s.cancellation),
            Cell::text(s.condition),
        ])
        .await?;
    }
    Ok(())
}

async fn stats<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    survey: &SurveyParams,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for r in study_table(pool, study_id).await? {
        t.row(&[
            Cell::text(r.test),
            Cell::text(columns::variable_column(&r.metric, survey)),
            Cell::text(r.seat.clone()),
            Cell::text(r.a),
            Cell::text(r.b),
            Cell::Int(Some(r.n as i64)),
            Cell::Num(Some(r.statistic)),
            Cell::Num(Some(r.p_value)),
            Cell::Num(r.p_adjusted),
            Cell::Num(Some(r.effect_size)),
            Cell::text(r.effect),
            Cell::Num(r.median_diff),
            Cell::Num(r.ci_low),
            Cell::Num(r.ci_high),
            Cell::Num(r.df1),
            Cell::Num(r.df2),
            Cell::Num(r.eps),
            Cell::flag(r.reachable),
            Cell::text(r.note),
            // station's clear name.
            Cell::text(r.seat),
        ])
        .await?;
    }
    Ok(())
}

async fn notes<W: AsyncWrite + Unpin>(
    pool: &AnyPool,
    study_id: i64,
    t: Table<'_, W>,
) -> Result<(), ExportError> {
    for r in store::exports::note_rows(pool, study_id).await? {
        t.row(&[
            Cell::Int(Some(r.study_id)),
            Cell::Int(r.trial_id),
            Cell::text(r.code),
            Cell::Int(r.slot),
            Cell::Int(r.attempt),
            Cell::text(r.kind),
            Cell::Text(r.status.map(Into::into)),
            time(r.at),
            Cell::text(r.author),
            Cell::text(r.text),
        ])
        .await?;
    }
    Ok(())
}

/// Rows of the audit log read at a time.
const AUDIT_PAGE: i64 = 2000;

async fn audit<W: AsyncWrite + Unpin>(pool: &AnyPool, t: Table<'_, W>) -> Result<(), ExportError> {
    let mut after = 0;
    loop {
        let rows = store::audit::page(pool, after, AUDIT_PAGE).await?;
        let Some(last) = rows.last() else {
            return Ok(());
        };
        after = last.0;
        for (id, at, actor, actor_id, action, target, detail) in rows {
            t.row(&[
                Cell::Int(Some(id)),
                time(Some(at)),
                Cell::text(actor),
                Cell::Int(actor_id),
                Cell::text(action),
                Cell::Text(target.map(Into::into)),
                Cell::Text(detail.map(Into::into)),
            ])
            .await?;
        }
    }
}
