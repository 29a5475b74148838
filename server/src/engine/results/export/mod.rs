//! Tidy exports for R or pandas, as CSV or Parquet, streamed (memory stays bounded however
//! large the study): `trials` (one row per test attempt, with `valid` and `latest`),
//! `samples` (the 1 kHz records, long format, with join keys; all, or one subject's, or one
//! test's), `subjects` (one row per subject with their drawn parameters), `codebook` (every
//! column of every export: meaning, unit, type, resolution), `summary` (statistics per
//! compensator × seat), `stats` (the inferential statistics: `inference_table`), `notes`
//! (every note and reason about a test), and `audit` (the whole audit log, not one study's).
//! Withdrawn subjects are left out of all but `subjects`. Columns are defined once
//! (`columns`), numbers written by one formatter at each column's resolution
//! (`bdft_protocol::numbers`), text cells neutralized against spreadsheet formula injection.

pub mod bench;
pub mod bids;
mod columns;
mod sink;
mod tables;

use bdft_protocol::study::SurveyParams;
use serde::Serialize;
use sqlx::AnyPool;
use tokio::io::{AsyncWrite, BufWriter};

pub use columns::{Column, ColumnType};
pub use sink::ExportFormat;

use crate::error::AppError;
use crate::store;
use sink::TableWriter;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ExportKind {
    Trials,
    Samples,
    Subjects,
    Codebook,
    Summary,
    Stats,
    Notes,
    Identification,
    Audit,
}

impl ExportKind {
    /// Every kind, in the codebook's order.
    pub const ALL: [Self; 9] = [
        Self::Trials,
        Self::Samples,
        Self::Subjects,
        Self::Codebook,
        Self::Summary,
        Self::Stats,
        Self::Notes,
        Self::Identification,
        Self::Audit,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Self::Trials => "trials",
            Self::Samples => "samples",
            Self::Subjects => "subjects",
            Self::Codebook => "codebook",
            Self::Summary => "summary",
            Self::Stats => "stats",
            Self::Notes => "notes",
            Self::Identification => "identification",
            Self::Audit => "audit",
        }
    }

    /// Every kind but `audit` is one study's.
    pub fn per_study(self) -> bool {
        self != Self::Audit
    }
}

impl std::str::FromStr for ExportKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| {
                let all: Vec<&str> = Self::ALL.iter().map(|k| k.name()).collect();
                format!("unknown export {s:?}; allowed: {}", all.join(", "))
            })
    }
}

/// Which samples to export: all, one subject's (by code) or one test attempt's.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub enum SampleCut {
    #[default]
    All,
    Subject(String),
    Trial(i64),
}

impl SampleCut {
    /// The cut a subject code or a trial id names (at most one of them).
    pub fn from_options(subject: Option<String>, trial: Option<i64>) -> Result<Self, AppError> {
        match (subject, trial) {
            (None, None) => Ok(Self::All),
            (Some(code), None) => Ok(Self::Subject(code)),
            (None, Some(id)) => Ok(Self::Trial(id)),
            (Some(_), Some(_)) => Err(AppError::BadRequest(
                "subject, trial: give one of them (one subject's samples or one test's), not both"
                    .into(),
            )),
        }
    }
}

/// What the `export` audit row of a study's export records: its kind, format and cut
/// (null: every sample).
#[derive(Debug, Serialize)]
pub struct Exported<'a> {
    kind: &'static str,
    format: &'static str,
    cut: Option<Cut<'a>>,
}

/// The samples an export was cut to, as its audit row names them: `{"subject":"S01"}` or
/// `{"trial":12}`.
#[derive(Debug, Serialize)]
#[serde(rename_all = "lowercase")]
enum Cut<'a> {
    Subject(&'a str),
    Trial(i64),
}

/// What the `export` audit row of a file that is all of its kind records (the audit log, a
/// bench run): `{"kind":"audit"}`.
#[derive(Debug, Serialize)]
pub struct ExportedAll {
    pub kind: &'static str,
}

/// What to export and how.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExportRequest {
    pub kind: ExportKind,
    pub format: ExportFormat,
    pub cut: SampleCut,
}

impl ExportRequest {
    pub fn new(kind: ExportKind) -> Self {
        Self {
            kind,
            format: ExportFormat::Csv,
            cut: SampleCut::All,
        }
    }

    /// What its audit row records.
    pub fn audited(&self) -> Exported<'_> {
        Exported {
            kind: self.kind.name(),
            format: self.format.extension(),
            cut: match &self.cut {
                SampleCut::All => None,
                SampleCut::Subject(code) => Some(Cut::Subject(code)),
                SampleCut::Trial(id) => Some(Cut::Trial(*id)),
            },
        }
    }

    /// The file name: `bdft-study3-samples-S01-1a2b3c4d.parquet`.
    pub fn file_name(&self, study_id: i64, protocol_hash: Option<&str>) -> String {
        let cut = match &self.cut {
            SampleCut::All => String::new(),
            SampleCut::Subject(code) => format!("-{code}"),
            SampleCut::Trial(id) => format!("-trial{id}"),
        };
        let hash = protocol_hash.and_then(|h| h.get(..8)).unwrap_or("unlocked");
        format!(
            "bdft-study{study_id}-{}{cut}-{hash}.{}",
            self.kind.name(),
            self.format.extension()
        )
    }
}

/// Longest subject code a cut may name, and how many codes an error lists.
const MAX_CODE_LEN: usize = 64;
const CODES_LISTED: usize = 20;

/// Checks a request against the study before anything is written: the study exists, and a
/// cut is of the samples and names one of its remaining subjects or recorded tests.
pub async fn check(pool: &AnyPool, study_id: i64, req: &ExportRequest) -> Result<(), AppError> {
    if req.kind.per_study() {
        store::studies::get(pool, study_id).await?;
    }
    if req.cut != SampleCut::All && req.kind != ExportKind::Samples {
        return Err(AppError::BadRequest(format!(
            "subject, trial: only the samples export is cut per subject or test, not {}",
            req.kind.name()
        )));
    }
    match &req.cut {
        SampleCut::All => Ok(()),
        SampleCut::Subject(code) => {
            let codes = store::exports::subject_codes(pool, study_id).await?;
            if code.len() <= MAX_CODE_LEN && codes.iter().any(|c| c == code) {
                return Ok(());
            }
            let mut listed: Vec<&str> = codes
                .iter()
                .take(CODES_LISTED)
                .map(String::as_str)
                .collect();
            if codes.len() > CODES_LISTED {
                listed.push("…");
            }
            let shown: String = code.chars().take(MAX_CODE_LEN).collect();
            Err(AppError::BadRequest(format!(
                "subject: {shown:?} is not a subject of study {study_id} who has not withdrawn; allowed: {}",
                if listed.is_empty() {
                    "none yet".to_string()
                } else {
                    listed.join(", ")
                }
            )))
        }
        SampleCut::Trial(id) => {
            if store::exports::recorded_trials(pool, study_id, None, Some(*id))
                .await?
                .is_empty()
            {
                Err(AppError::BadRequest(format!(
                    "trial: {id} is not a recorded test attempt of study {study_id} (a trial_id of its trials export with a record)"
                )))
            } else {
                Ok(())
            }
        }
    }
}

/// Writes the export `req` of `study_id` to `out` (`audit`: the whole log, whatever the
/// study), after `check`.
pub async fn write(
    pool: &AnyPool,
    study_id: i64,
    req: &ExportRequest,
    out: impl AsyncWrite + Unpin,
) -> Result<(), ExportError> {
    check(pool, study_id, req).await?;
    let cx = tables::StudyContext::load(pool, study_id, req.kind).await?;
    let out = BufWriter::with_capacity(1 << 16, out);
    let mut t = TableWriter::start(tables::columns_of(req.kind, &cx), req.format, out).await?;
    tables::write_rows(pool, study_id, req, &cx, &mut t).await?;
    t.finish().await
}

/// Every export's columns for a study of people with the survey `survey`: what its
/// codebook lists (the ethics board's package shows it as the data kept).
pub fn data_kept(survey: &SurveyParams) -> Vec<(ExportKind, Vec<Column>)> {
    let cx = tables::StudyContext::of_people(survey.clone());
    ExportKind::ALL
        .into_iter()
        .map(|kind| (kind, tables::columns_of(kind, &cx)))
        .collect()
}

#[derive(Debug, thiserror::Error)]
pub enum ExportError {
    #[error(transparent)]
    Data(#[from] AppError),
    #[error("writing the export: {0}")]
    Io(#[from] std::io::Error),
    #[error("writing Parquet: {0}")]
    Parquet(#[from] parquet::errors::ParquetError),
}

impl From<sqlx::Error> for ExportError {
    fn from(e: sqlx::Error) -> Self {
        Self::Data(e.into())
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
