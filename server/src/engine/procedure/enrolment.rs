//! Enrolling a subject: the first enrolment locks the protocol (its hash goes on every
//! trial); the subject's schedule and every test's target are drawn from the study seed and
//! stored, all in one immediate transaction with the audit row.

use bdft_protocol::records::TestPhase;
use serde::Serialize;
use sqlx::AnyPool;

use super::stations::consent_form;
use crate::engine::study::schedule::{protocol_hash, schedule, starting_seat, target};
use crate::engine::study::stability::{StabilityCache, check_lockable};
use crate::error::{AppError, Result};
use crate::store::subjects::{NewSubject, Subject};
use crate::store::trials::NewTrial;
use crate::store::{self, Change};

/// What `subject.enrol` records: the subject's code, and whether it is synthetic.
#[derive(Debug, Serialize)]
struct Enrolled<'a> {
    code: &'a str,
    synthetic: bool,
}

/// Enrols the study's next subject; returns it and the token of its own page. The first
/// enrolment passes the stability gate before it locks the protocol.
pub async fn enrol(
    pool: &AnyPool,
    stability: &StabilityCache,
    actor: &str,
    study_id: i64,
    synthetic: bool,
) -> Result<(Subject, String)> {
    // The analysis takes seconds: it runs before the write transaction, never inside it.
    let before = store::studies::get(pool, study_id).await?;
    if before.locked_at.is_none() {
        let report = stability.report(&before.params).await?;
        check_lockable(&before.params, &report, before.instability_ack.is_some())?;
    }
    let mut change = Change::begin(pool, actor).await?;
    crate::engine::study::dry_run::check_enrolment(change.db(), study_id, synthetic).await?;
    let study = store::studies::get(change.db(), study_id).await?;
    if study.locked_at.is_none()
        && (study.params != before.params || study.instability_ack != before.instability_ack)
    {
        return Err(AppError::Conflict(
            "the study was edited meanwhile; try again".into(),
        ));
    }
    let hash = match &study.protocol_hash {
        Some(h) => h.clone(),
        None => {
            let h = protocol_hash(&study.params);
            // The form is kept as the lock renders it: what every subject agrees to.
            let form = consent_form(&study);
            let form_hash = bdft_protocol::hex::sha256(form.text.as_bytes());
            store::studies::lock(change.db(), study_id, &h, &form.text, &form_hash).await?;
            h
        }
    };
    let index = store::subjects::count_in_study(change.db(), study_id).await?;
    let code = format!("S{:02}", index + 1);
    let token = store::tokens::random_token();
    // A synthetic subject draws its own operator, body and survey habits; a person is
    // nobody's draw.
    let drawn =
        synthetic.then(|| crate::engine::study::synthetic::draw(&study.params, study.seed, index));
    let subject_id = store::subjects::insert(
        change.db(),
        &NewSubject {
            study_id,
            code: &code,
            enrol_index: index,
            synthetic,
            token: &token,
            starting_seat: starting_seat(index),
            drawn: drawn.as_ref(),
        },
    )
    .await?;
    for t in schedule(&study.params, study.seed, index) {
        // An identification test has no target to track: the multisine drawn from its seed
        // moves the cab (`orchestrator::start`).
        let (levels, mean_mm, std_mm, ms_step_mm2) = match t.phase {
            TestPhase::Identification => (Vec::new(), 0.0, 0.0, 0.0),
            _ => {
                let tg = target(&study.params, &t)?;
                (tg.levels_mm, tg.mean_mm, tg.std_mm, tg.ms_step_mm2)
            }
        };
        // The practice (and an identification test) runs the study's own design of its
        // compensator when the study has one, else that compensator's design for people.
        let spec = study
            .params
            .compensators
            .iter()
            .find(|c| c.kind() == t.compensator)
            .cloned()
            .or_else(|| {
                (t.phase != TestPhase::Test).then(|| {
                    bdft_controller::compensator::study_spec(t.compensator, &study.params.plant)
                })
            })
            .ok_or_else(|| {
                AppError::Internal(anyhow::anyhow!(
                    "scheduled {} is not in the study",
                    t.compensator
                ))
            })?;
        store::trials::insert(
            change.db(),
            &NewTrial {
                subject_id,
                test: &t,
                compensator_json: serde_json::to_string(&spec).expect("specs serialize"),
                k_bf: study.params.k_bf,
                target_levels_json: serde_json::to_string(&levels).expect("levels serialize"),
                target_mean_mm: mean_mm,
                target_std_mm: std_mm,
                target_ms_step_mm2: ms_step_mm2,
                protocol_hash: &hash,
                condition: study.params.condition_of(index).to_string(),
            },
        )
        .await?;
    }
    let subject = store::subjects::get(change.db(), subject_id).await?;
    change
        .commit(
            "subject.enrol",
            Some(format!("subject:{subject_id}")),
            Enrolled {
                code: &code,
                synthetic,
            },
        )
        .await?;
    Ok((subject, token))
}
