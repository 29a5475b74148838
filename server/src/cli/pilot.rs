//! `bdft-server pilot`: the whole protocol for synthetic subjects, into the database.

use std::path::PathBuf;

use super::{newest_study, open_store, read_params};
use bdft_protocol::params::MachineCondition;
use bdft_protocol::study::{CancellationArm, CancellationParams, ModelError, StudyParams};

use crate::config::DbConfig;
use crate::engine::dry_runs::pilot;
use crate::engine::study::stability::StabilityCache;
use crate::engine::study::{dry_run, studies};
use crate::store;

#[derive(Debug, clap::Args)]
pub struct Args {
    #[command(flatten)]
    db: DbConfig,
    /// Study to add the subjects to [default: the newest; a default study if none].
    #[arg(long)]
    study: Option<i64>,
    /// Number of synthetic subjects.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=500))]
    subjects: u32,
    /// Seed of a study created for the pilot.
    #[arg(long)]
    seed: Option<u64>,
    /// Parameters of the study created for the pilot (JSON, as `GET /api/defaults` gives
    /// them; e.g. another population) [default: the default study's]; only into a
    /// database with no study yet.
    #[arg(long, conflicts_with = "study")]
    params: Option<PathBuf>,
    /// Add an identification test (the default multisine, hold-still) to the study the
    /// pilot creates, at the start of each subject's block on the machine; a study given
    /// with --study must have one in its parameters already.
    #[arg(long)]
    identification: bool,
    /// As --identification, with the study's LQR designs tuned to each subject's fitted
    /// body (`identification.personalized`).
    #[arg(long)]
    personalized: bool,
    /// As --identification, with model-based cancellation crossed with the compensators on
    /// the machine: the cancelling arms, comma-separated (personal, generic, wrong).
    #[arg(long, value_delimiter = ',', value_parser = parse_arm)]
    cancellation: Vec<CancellationArm>,
    /// The wrong arm's gain over the subject's body [default: 1.3].
    #[arg(long)]
    wrong_gain: Option<f64>,
    /// The wrong arm's phase lag at 2 Hz (degrees) [default: 0].
    #[arg(long)]
    wrong_phase_lag_deg: Option<f64>,
    /// The machine's condition of the study the pilot creates (stilts, tires, outriggers,
    /// loaded[:FILL], stick, joined by '+'; docs/machine-conditions.md); a study given with
    /// --study keeps its own.
    #[arg(long)]
    condition: Option<MachineCondition>,
    /// Run the pilot although a design is unstable with the body (in simulation only),
    /// acknowledged on the study it runs in with this reason (audited), as the study page's
    /// acknowledgement does.
    #[arg(long, value_name = "REASON")]
    acknowledge_instability: Option<String>,
}

fn parse_arm(s: &str) -> Result<CancellationArm, String> {
    match CancellationArm::parse(s) {
        Some(CancellationArm::Off) | None => Err(format!(
            "{s:?} is not a cancelling arm; allowed: personal, generic, wrong"
        )),
        Some(arm) => Ok(arm),
    }
}

pub async fn run(args: Args) -> anyhow::Result<()> {
    let Args {
        db,
        study,
        subjects,
        seed,
        params,
        identification,
        personalized,
        cancellation,
        wrong_gain,
        wrong_phase_lag_deg,
        condition,
        acknowledge_instability,
    } = args;
    let pool = open_store(&db).await?;
    let identification = identification || personalized || !cancellation.is_empty();
    let wrong = cancellation
        .contains(&CancellationArm::Wrong)
        .then(|| ModelError {
            gain: wrong_gain.unwrap_or(1.3),
            phase_lag_deg: wrong_phase_lag_deg.unwrap_or(0.0),
            phase_ref_hz: 2.0,
        });
    if wrong.is_none() && (wrong_gain.is_some() || wrong_phase_lag_deg.is_some()) {
        anyhow::bail!("--wrong-gain and --wrong-phase-lag-deg go with --cancellation ...,wrong");
    }
    if condition.is_some() && study.is_some() {
        anyhow::bail!(
            "--condition: study {} keeps its own condition; give --condition to a pilot that creates its study",
            study.unwrap_or_default()
        );
    }
    // The study the pilot creates, with what the flags add to it.
    let prepared = |mut p: StudyParams| {
        if let Some(c) = condition {
            p.condition = c;
        }
        if identification && p.identification.is_none() {
            p.identification = Some(Default::default());
        }
        if let Some(id) = p.identification.as_mut() {
            id.personalized |= personalized;
        }
        if !cancellation.is_empty() {
            p.cancellation = Some(CancellationParams {
                arms: cancellation.clone(),
                wrong,
                ..Default::default()
            });
        }
        p
    };
    let study = match (params, study) {
        (Some(path), _) => {
            Some(pilot::new_study(&pool, &prepared(read_params(&path)?), seed).await?)
        }
        (None, None)
            if (identification || condition.is_some())
                && store::studies::all(&pool).await?.is_empty() =>
        {
            Some(
                pilot::new_study(
                    &pool,
                    &prepared(crate::engine::study::schedule::default_params()),
                    seed,
                )
                .await?,
            )
        }
        (None, study) => {
            if identification {
                let s = newest_study(&pool, study).await?;
                let params = store::studies::get(&pool, s).await?.params;
                if params.identification.is_none() {
                    anyhow::bail!(
                        "--identification: study {s} has no identification test; add \"identification\" to its parameters"
                    );
                }
                if !cancellation.is_empty() && params.cancellation.is_none() {
                    anyhow::bail!(
                        "--cancellation: study {s} has no cancellation factor; add \"cancellation\" to its parameters"
                    );
                }
                if personalized && !params.identification.is_some_and(|id| id.personalized) {
                    anyhow::bail!(
                        "--personalized: study {s} does not personalize its designs; set \"identification\": {{\"personalized\": true}} in its parameters"
                    );
                }
            }
            study
        }
    };
    if let Some(reason) = acknowledge_instability {
        let target = newest_study(&pool, study).await?;
        let runs_in = dry_run::for_pilot(&pool, pilot::COMMAND_LINE, target).await?;
        studies::acknowledge_instability(
            &pool,
            &StabilityCache::default(),
            pilot::COMMAND_LINE,
            runs_in,
            &reason,
        )
        .await?;
    }
    let started = std::time::Instant::now();
    let report = pilot::run(&pool, study, subjects, seed).await?;
    println!("{}", serde_json::to_string(&report)?);
    tracing::info!(
        elapsed_s = started.elapsed().as_secs_f64(),
        "pilot finished"
    );
    Ok(())
}
