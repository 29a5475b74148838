//! What a population's subjects answer in the surveys, cell by cell: each subject's scored
//! test run in full with its record (the trial a pilot runs, `runtime::local::run`), then
//! perceived and answered as a pilot's subject answers (`perception::perceive`, `answers`).
//! The batch simulator keeps no records to perceive, so this costs a pilot's time per test:
//! for pilots of a few subjects.

use std::sync::atomic::{AtomicBool, Ordering};

use bdft_controller::perception;
use bdft_protocol::study::StudyParams;
use bdft_protocol::trial::Outcome;
use serde::Serialize;

use super::findings::median;
use super::sim::{Cell, DT, SubjectRef, on_every_core, trial};
use crate::engine::dry_runs::job::Progress;
use crate::engine::study::synthetic;
use crate::error::{AppError, Result};

#[derive(Debug, Clone, Serialize, utoipa::ToSchema)]
pub struct SurveyCell {
    /// The compensator (key `controller`, as the report has always named it).
    #[serde(rename = "controller")]
    pub compensator: String,
    /// The seat (key `station`).
    #[serde(rename = "station")]
    pub seat: String,
    /// Subjects whose test completed (and who answered).
    pub n: usize,
    /// Mean over subjects of accuracy, speed, smoothness and controllability (the scale's
    /// points): with eight subjects a mean separates cells a median of 7-point answers
    /// rounds together.
    pub mean_ratings: [f64; 4],
    /// Their standard deviations over subjects.
    pub sd_ratings: [f64; 4],
    /// Medians of what was perceived (`perception::Perception`): RMS tracking error (mm),
    /// response lag (s), felt cab acceleration (m/s²) and seen shake (mm) — what
    /// `perception::MIDDLING` is set from.
    pub median_error_mm: f64,
    pub median_response_s: f64,
    pub median_felt_m_s2: f64,
    pub median_seen_shake_mm: f64,
}

/// One answered test: its cell, ratings and what was perceived.
type Answered = (usize, [u8; 4], perception::Perception);

/// Every `subjects`' answers in every one of `cells`, on every core. `progress` counts the
/// tests run; `cancel` stops them (409).
pub fn surveys(
    params: &StudyParams,
    subjects: &[SubjectRef],
    cells: &[Cell],
    progress: &Progress,
    cancel: &AtomicBool,
) -> Result<Vec<SurveyCell>> {
    let items = subjects.len() * cells.len();
    progress.total.fetch_add(items, Ordering::Relaxed);
    let one = |item: usize| -> Result<Option<Answered>> {
        let (subject, c) = (subjects[item / cells.len()], item % cells.len());
        let cell = cells[c];
        let (start, target_seed) = trial(
            params,
            subject,
            cell.seat,
            &params.compensators[cell.compensator],
        )?;
        let (result, channels) = bdft_controller::runtime::local::run(&start, DT)
            .map_err(|e| AppError::BadRequest(format!("a simulated trial: {e}")))?;
        if result.outcome != Outcome::Complete {
            return Ok(None);
        }
        let perceived = perception::perceive_record(&channels, cell.seat, DT);
        let (ratings, _) = perception::answer_test(
            &synthetic::draw(params, subject.seed, subject.index),
            &perceived,
            cell.seat,
            params.survey.scale_points,
            target_seed,
        );
        Ok(Some((c, ratings, perceived)))
    };
    let answered = on_every_core(items, cancel, |item| {
        let answered = one(item)?;
        progress.add(1);
        Ok(answered.into_iter().collect())
    })?;
    Ok(cells
        .iter()
        .enumerate()
        .map(|(c, cell)| {
            let mine: Vec<&Answered> = answered.iter().filter(|a| a.0 == c).collect();
            let n = mine.len();
            let mean_sd = |i: usize| {
                let v: Vec<f64> = mine.iter().map(|a| f64::from(a.1[i])).collect();
                super::target::mean_sd(&v)
            };
            let items = [mean_sd(0), mean_sd(1), mean_sd(2), mean_sd(3)];
            SurveyCell {
                compensator: params.compensators[cell.compensator]
                    .kind()
                    .name()
                    .to_string(),
                seat: cell.seat.as_str().to_string(),
                n,
                mean_ratings: items.map(|m| m.0),
                sd_ratings: items.map(|m| m.1),
                median_error_mm: median(mine.iter().map(|a| a.2.rms_error_mm).collect()),
                median_response_s: median(mine.iter().map(|a| a.2.response_time_s).collect()),
                median_felt_m_s2: median(mine.iter().map(|a| a.2.felt_rms_m_s2).collect()),
                median_seen_shake_mm: median(mine.iter().map(|a| a.2.seen_shake_mm).collect()),
            }
        })
        .collect())
}

/// The survey answers of the first `subjects` of `params` (enrolled as a study seeded `seed`
/// would enrol them) as a Markdown table: `bdft-server findings`.
pub fn table(params: &StudyParams, subjects: u32, seed: u64) -> Result<String> {
    let cells = super::sim::all_cells(params);
    let answers = surveys(
        params,
        &super::sim::enrolled(seed, subjects),
        &cells,
        &Progress::default(),
        &AtomicBool::new(false),
    )?;
    let mut out = format!(
        "\nSurveys of the first {subjects} subjects (mean rating; {}-point scale, higher is better)\n\n| controller | station | accuracy | speed | smoothness | controllability | median error (mm) | median response (s) | median felt (m/s²) | median seen shake (mm) |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n",
        params.survey.scale_points
    );
    for c in &answers {
        let [a, sp, sm, co] = c.mean_ratings;
        out += &format!(
            "| {} | {} | {a:.2} | {sp:.2} | {sm:.2} | {co:.2} | {:.1} | {:.2} | {:.2} | {:.2} |\n",
            c.compensator,
            c.seat,
            c.median_error_mm,
            c.median_response_s,
            c.median_felt_m_s2,
            c.median_seen_shake_mm
        );
    }
    Ok(out)
}
