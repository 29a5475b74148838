//! Tidy CSV exports for R or pandas, streamed row by row (memory stays constant however large
//! the study): `trials` (one row per test attempt), `samples` (the 1 kHz records, long
//! format), `summary` (statistics per compensator × seat), `stats` (the inferential
//! statistics: `inference_table`), `notes` (every note and reason about a test), and `audit` (the whole audit log, not one study's). Withdrawn subjects are
//! left out. Text cells are neutralized against spreadsheet formula injection.

use sqlx::SqlitePool;
use tokio::io::{AsyncWrite, AsyncWriteExt, BufWriter};

use bdft_protocol::trial::RECORD_CHANNELS;

use super::stats::summary_stats;
use crate::error::AppError;
use crate::store;
use crate::store::db::rfc3339;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ExportKind {
    Trials,
    Samples,
    Summary,
    Stats,
    Notes,
    Audit,
}

impl ExportKind {
    /// Every kind but `audit` is one study's.
    pub fn per_study(self) -> bool {
        self != Self::Audit
    }
}

impl std::str::FromStr for ExportKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "trials" => Ok(Self::Trials),
            "samples" => Ok(Self::Samples),
            "summary" => Ok(Self::Summary),
            "stats" => Ok(Self::Stats),
            "notes" => Ok(Self::Notes),
            "audit" => Ok(Self::Audit),
            _ => Err(format!(
                "unknown export {s:?}; valid: trials, samples, summary, stats, notes, audit"
            )),
        }
    }
}

/// Characters a spreadsheet reads as the start of a formula.
const FORMULA_STARTERS: [char; 6] = ['=', '+', '-', '@', '\t', '\r'];

/// Whether a spreadsheet would read `s` as a formula: its first character, or its first
/// after any leading whitespace (spreadsheets trim spaces, U+00A0, U+FEFF, U+3000 … before
/// they look), is a formula starter.
fn reads_as_formula(s: &str) -> bool {
    if s.starts_with(FORMULA_STARTERS) {
        return true;
    }
    // U+FEFF is not White_Space in Unicode, but a byte-order mark is dropped on import.
    s.trim_start_matches(|c: char| c.is_whitespace() || c == '\u{feff}')
        .starts_with(FORMULA_STARTERS)
}

/// A text cell: quoted when needed, and prefixed with an apostrophe when a spreadsheet would
/// read it as a formula (`reads_as_formula`).
pub fn text_cell(s: &str) -> String {
    let neutral = if reads_as_formula(s) {
        format!("'{s}")
    } else {
        s.to_string()
    };
    if neutral.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", neutral.replace('"', "\"\""))
    } else {
        neutral
    }
}

fn num(v: Option<f64>) -> String {
    v.map(|x| x.to_string()).unwrap_or_default()
}

pub const TRIAL_COLUMNS: [&str; 43] = [
    "study_id",
    "trial_id",
    "subject_code",
    "subject_index",
    "synthetic",
    "starting_station",
    "station",
    "block",
    "position",
    "slot",
    "attempt",
    "controller",
    "blinded_label",
    "practice",
    "status",
    "status_reason",
    "seed",
    "target_mean_mm",
    "target_std_mm",
    "k_bf",
    "duration_s",
    "mse_tracking_mm2",
    "ms_cab_accel",
    "rating_accuracy",
    "rating_speed",
    "rating_smoothness",
    "rating_controllability",
    "comment",
    "protocol_hash",
    "started_at",
    "finished_at",
    "consent_version",
    // How the test ran (validity): the station's display and input, the controller's
    // timing, and the experimenter's acceptance of a failed test as incomplete.
    "display_frames",
    "display_longest_gap_ms",
    "display_hidden_ms",
    "input_hz",
    "rtt_p50_ms",
    "rtt_p95_ms",
    "rtt_max_ms",
    "controller_overruns",
    "controller_wake_p99_us",
    "accepted_reason",
    // The configuration version the trial ran (empty: a design not from a version).
    "config_version",
];

/// The validity cells of a trial row, in `TRIAL_COLUMNS` order: empty where a figure is
/// missing (a test that never ran, a station that sent none).
fn validity_cells(r: &store::exports::TrialExportRow) -> [String; 10] {
    let parse = |j: &Option<String>| {
        j.as_deref()
            .and_then(|j| serde_json::from_str::<serde_json::Value>(j).ok())
            .unwrap_or_default()
    };
    let (station, controller) = (parse(&r.client_timing_json), parse(&r.timing_json));
    let cell = |v: &serde_json::Value| match v {
        serde_json::Value::Number(n) => n.to_string(),
        _ => String::new(),
    };
    [
        cell(&station["frames"]),
        cell(&station["longest_gap_ms"]),
        cell(&station["hidden_ms"]),
        cell(&station["input_hz"]),
        cell(&station["rtt_ms"]["p50"]),
        cell(&station["rtt_ms"]["p95"]),
        cell(&station["rtt_ms"]["max"]),
        cell(&controller["overruns"]),
        cell(&controller["wake_latency_us"]["p99"]),
        text_cell(r.accepted_reason.as_deref().unwrap_or("")),
    ]
}

/// Writes the export of `kind` for `study_id` to `out` (`audit`: the whole log, whatever
/// the study).
pub async fn write(
    pool: &SqlitePool,
    study_id: i64,
    kind: ExportKind,
    out: impl AsyncWrite + Unpin,
) -> Result<(), ExportError> {
    if kind.per_study() {
        store::studies::get(pool, study_id).await?;
    }
    let mut w = BufWriter::with_capacity(1 << 16, out);
    match kind {
        ExportKind::Trials => trials(pool, study_id, &mut w).await?,
        ExportKind::Samples => samples(pool, study_id, &mut w).await?,
        ExportKind::Summary => summary(pool, study_id, &mut w).await?,
        ExportKind::Stats => stats(pool, study_id, &mut w).await?,
        ExportKind::Notes => notes(pool, study_id, &mut w).await?,
        ExportKind::Audit => audit(pool, &mut w).await?,
    }
    w.flush().await?;
    Ok(())
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Data(#[from] AppError),
    #[error("writing the export: {0}")]
    Io(#[from] std::io::Error),
}

impl From<sqlx::Error> for ExportError {
    fn from(e: sqlx::Error) -> Self {
        Self::Data(e.into())
    }
}

async fn trials(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(format!("{}\n", TRIAL_COLUMNS.join(",")).as_bytes())
        .await?;
    for r in store::exports::trial_rows(pool, study_id).await? {
        let rating = |v: Option<i64>| v.map(|x| x.to_string()).unwrap_or_default();
        let validity = validity_cells(&r);
        let cells = [
            r.study_id.to_string(),
            r.trial_id.to_string(),
            text_cell(&r.code),
            (r.enrol_index + 1).to_string(),
            u8::from(r.synthetic).to_string(),
            r.starting_station.as_str().to_string(),
            r.station.as_str().to_string(),
            r.block.to_string(),
            r.position.to_string(),
            r.slot.to_string(),
            r.attempt.to_string(),
            r.controller.name().to_string(),
            text_cell(&r.blinded_label),
            u8::from(r.practice).to_string(),
            r.status.as_str().to_string(),
            text_cell(r.status_reason.as_deref().unwrap_or("")),
            r.target_seed.to_string(),
            r.target_mean_mm.to_string(),
            r.target_std_mm.to_string(),
            r.k_bf.to_string(),
            r.duration_s.to_string(),
            num(r.mse_tracking_mm2),
            num(r.ms_cab_accel),
            rating(r.accuracy),
            rating(r.speed),
            rating(r.smoothness),
            rating(r.controllability),
            text_cell(r.comment.as_deref().unwrap_or("")),
            r.protocol_hash.unwrap_or_default(),
            r.started_at.map(rfc3339).unwrap_or_default(),
            r.finished_at.map(rfc3339).unwrap_or_default(),
            text_cell(r.consent_version.as_deref().unwrap_or("")),
        ];
        w.write_all(cells.join(",").as_bytes()).await?;
        w.write_all(b",").await?;
        w.write_all(validity.join(",").as_bytes()).await?;
        w.write_all(b",").await?;
        w.write_all(text_cell(r.config_version.as_deref().unwrap_or("")).as_bytes())
            .await?;
        w.write_all(b"\n").await?;
    }
    Ok(())
}

async fn samples(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    let header: Vec<&str> = [
        "study_id",
        "trial_id",
        "subject_code",
        "station",
        "controller",
        "practice",
        "t_s",
    ]
    .into_iter()
    .chain(RECORD_CHANNELS)
    .collect();
    w.write_all(format!("{}\n", header.join(",")).as_bytes())
        .await?;
    let mut line = String::with_capacity(256);
    for (trial_id, code, station, controller, practice) in
        store::exports::recorded_trials(pool, study_id).await?
    {
        // One trial's record in memory at a time (about 5 MB for 140 s).
        let store::records::Record { dt, channels: cols } =
            store::records::get(pool, trial_id).await?;
        let prefix = format!(
            "{study_id},{trial_id},{},{station},{controller},{},",
            text_cell(&code),
            u8::from(practice)
        );
        for k in 0..cols[0].len() {
            line.clear();
            line.push_str(&prefix);
            line.push_str(&format!("{:.3}", k as f64 * dt));
            for c in &cols {
                line.push(',');
                line.push_str(&c[k].to_string());
            }
            line.push('\n');
            w.write_all(line.as_bytes()).await?;
        }
    }
    Ok(())
}

async fn summary(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(b"controller,station,variable,n,mean,median,q1,q3,min,max\n")
        .await?;
    for s in summary_stats(pool, study_id).await? {
        let line = format!(
            "{},{},{},{},{},{},{},{},{},{}\n",
            s.controller, s.station, s.variable, s.n, s.mean, s.median, s.q1, s.q3, s.min, s.max
        );
        w.write_all(line.as_bytes()).await?;
    }
    Ok(())
}

pub const STATS_COLUMNS: [&str; 19] = [
    "test",
    "metric",
    "station",
    "a",
    "b",
    "n",
    "statistic",
    "p_value",
    "p_adjusted",
    "effect_size",
    "effect",
    "median_diff",
    "ci_low",
    "ci_high",
    "df1",
    "df2",
    "eps",
    "reachable",
    "note",
];

async fn stats(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(format!("{}\n", STATS_COLUMNS.join(",")).as_bytes())
        .await?;
    let opt = |v: Option<f64>| v.map(|x| x.to_string()).unwrap_or_default();
    for r in super::inference_table::study_table(pool, study_id).await? {
        let cells = [
            r.test,
            r.metric,
            r.station,
            r.a,
            r.b,
            r.n.to_string(),
            r.statistic.to_string(),
            r.p_value.to_string(),
            opt(r.p_adjusted),
            r.effect_size.to_string(),
            r.effect,
            opt(r.median_diff),
            opt(r.ci_low),
            opt(r.ci_high),
            opt(r.df1),
            opt(r.df2),
            opt(r.eps),
            u8::from(r.reachable).to_string(),
            text_cell(&r.note),
        ];
        w.write_all(cells.join(",").as_bytes()).await?;
        w.write_all(b"\n").await?;
    }
    Ok(())
}

pub const NOTE_COLUMNS: [&str; 10] = [
    "study_id",
    "trial_id",
    "subject_code",
    "slot",
    "attempt",
    "kind",
    "status",
    "at",
    "by",
    "text",
];

async fn notes(
    pool: &SqlitePool,
    study_id: i64,
    w: &mut (impl AsyncWrite + Unpin),
) -> Result<(), ExportError> {
    w.write_all(format!("{}\n", NOTE_COLUMNS.join(",")).as_bytes())
        .await?;
    let int = |v: Option<i64>| v.map(|x| x.to_string()).unwrap_or_default();
    for r in store::exports::note_rows(pool, study_id).await? {
        let cells = [
            r.study_id.to_string(),
            int(r.trial_id),
            text_cell(&r.code),
            int(r.slot),
            int(r.attempt),
            r.kind,
            r.status.unwrap_or_default(),
            r.at.map(rfc3339).unwrap_or_default(),
            text_cell(&r.author),
            text_cell(&r.text),
        ];
        w.write_all(cells.join(",").as_bytes()).await?;
        w.write_all(b"\n").await?;
    }
    Ok(())
}

/// Rows of the audit log read at a time.
const AUDIT_PAGE: i64 = 2000;

async fn audit(pool: &SqlitePool, w: &mut (impl AsyncWrite + Unpin)) -> Result<(), ExportError> {
    w.write_all(b"id,at,actor,actor_id,action,target,detail\n")
        .await?;
    let mut after = 0;
    loop {
        let rows = store::audit::page(pool, after, AUDIT_PAGE).await?;
        let Some(last) = rows.last() else {
            return Ok(());
        };
        after = last.0;
        for (id, at, actor, actor_id, action, target, detail) in rows {
            let line = format!(
                "{id},{},{},{},{},{},{}\n",
                rfc3339(at),
                text_cell(&actor),
                actor_id.map(|i| i.to_string()).unwrap_or_default(),
                text_cell(&action),
                text_cell(target.as_deref().unwrap_or("")),
                text_cell(detail.as_deref().unwrap_or("")),
            );
            w.write_all(line.as_bytes()).await?;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn formula_cells_are_neutralized_and_quoted() {
        assert_eq!(text_cell("S01"), "S01");
        assert_eq!(text_cell("=HYPERLINK(\"x\")"), "\"'=HYPERLINK(\"\"x\"\")\"");
        assert_eq!(text_cell("+1"), "'+1");
        assert_eq!(text_cell("-2"), "'-2");
        assert_eq!(text_cell("@SUM(A1)"), "'@SUM(A1)");
        assert_eq!(text_cell("a,b"), "\"a,b\"");
        assert_eq!(text_cell("line\nbreak"), "\"line\nbreak\"");
    }

    #[test]
    fn formulas_behind_leading_whitespace_are_neutralized() {
        for cell in [
            " =1",
            "\u{a0}=1",
            "\u{feff}=1",
            "\u{3000}=1",
            "\u{2003}+1",
            "  \u{a0}-2",
            "\n@SUM(A1)",
        ] {
            let out = text_cell(cell);
            let unquoted = out.trim_start_matches('"');
            assert!(unquoted.starts_with('\''), "{cell:?} → {out:?}");
        }
        // Text that only contains a starter later on is left alone.
        assert_eq!(text_cell(" a=1"), " a=1");
        assert_eq!(text_cell("\u{a0}ok"), "\u{a0}ok");
        assert_eq!(text_cell(""), "");
    }
}
