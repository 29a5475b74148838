//! The protocol's pure rules: default study parameters, the protocol hash, each subject's
//! schedule and each test's target. Everything here is a function of the study's
//! parameters and seeds, so a schedule can be regenerated on demand and checked.

use bdft_controller::compensator::study_spec;
use bdft_controller::rng::Rng;
use bdft_controller::signals::StepTarget;
use bdft_protocol::identification::MultisineSpec;
use bdft_protocol::params::{CompensatorKind, ParamError, PlantParams, Seat, StepParams};
use bdft_protocol::records::TestPhase;
use bdft_protocol::study::{
    CancellationArm, ConsentForm, OrderDesign, RigKind, StudyParams, StudyTexts, SurveyParams,
};
use bdft_protocol::trial::TargetSpec;

use super::williams;

/// K_BF of the human-subject study: about 30 % above the rig's nominal 0.6, so that the
/// feedthrough is clearly felt.
pub const STUDY_KBF: f64 = 0.78;

/// The published study's protocol with the identified rig, and the compensators tuned for
/// people on the machine (`study_spec`: the PID family slow, as the original study did).
pub fn default_params() -> StudyParams {
    let plant = PlantParams::default();
    StudyParams {
        compensators: CompensatorKind::STUDY
            .iter()
            .map(|&k| study_spec(k, &plant))
            .collect(),
        practice_compensator: CompensatorKind::Pid,
        seats: vec![Seat::On, Seat::Off],
        trial_s: 140.0,
        practice_s: 120.0,
        step_interval_s: 2.0,
        target_range_mm: 25.0,
        target_std_mm: 12.0,
        matched_targets: false,
        order_design: OrderDesign::Random,
        k_bf: STUDY_KBF,
        survey: SurveyParams::default(),
        consent: ConsentForm::default(),
        texts: StudyTexts::default(),
        rig: RigKind::Simulated,
        plant,
        body: Default::default(),
        display_shake_gain: 1.0,
        population: Default::default(),
        stale_input_ms: 100.0,
        max_cab_rms_mm_s2: bdft_protocol::server_to_controller::DEFAULT_MAX_CAB_RMS_MM_S2,
        max_hidden_ms: 500.0,
        max_frame_gap_ms: 1000.0,
        exposure_budget_a8_m_s2: bdft_protocol::exposure::ACTION_A8_M_S2,
        exposure_budget_vdv_m_s175: bdft_protocol::exposure::ACTION_VDV_M_S175,
        identification: None,
        cancellation: None,
        condition: Default::default(),
        conditions: Vec::new(),
    }
}

/// The parameters' canonical JSON (keys sorted, no whitespace): the text the protocol hash
/// is of, so the same protocol always hashes the same, whatever order a client sent the
/// fields in.
pub fn canonical_json(params: &StudyParams) -> String {
    // serde_json's Value keeps object keys in sorted order (no preserve_order feature).
    serde_json::to_value(params)
        .expect("params serialize")
        .to_string()
}

/// SHA-256 (hex) of the parameters' [`canonical_json`].
pub fn protocol_hash(params: &StudyParams) -> String {
    bdft_protocol::hex::sha256(canonical_json(params).as_bytes())
}

/// One entry of a subject's schedule: defined beside the store's `NewTrial`, which stores
/// it as it is.
pub use crate::store::trials::ScheduledTest;

/// Starting seat by enrolment order: on, off, on, … to balance learning effects.
pub fn starting_seat(enrol_index: u32) -> Seat {
    if enrol_index % 2 == 0 {
        Seat::On
    } else {
        Seat::Off
    }
}

fn other(s: Seat) -> Seat {
    match s {
        Seat::On => Seat::Off,
        Seat::Off => Seat::On,
    }
}

const SCHEDULE_STREAM: u64 = 0x5343_4845_4455_4c45;

fn shuffle<T>(items: &mut [T], rng: &mut Rng) {
    for i in (1..items.len()).rev() {
        let j = ((rng.next_f64() * (i + 1) as f64) as usize).min(i);
        items.swap(i, j);
    }
}

/// One cell of a seat's block: a compensator and what it cancels with.
type Cell = (CompensatorKind, CancellationArm);

/// The schedule of the subject enrolled `enrol_index`-th (from 0): practice off the machine,
/// then every cell once at the starting seat, then every cell once at the other seat in a
/// different order. A cell is a compensator at the desk, and a compensator with each of the
/// study's cancellation arms on the machine (off alone without the factor). The orders are
/// random (`OrderDesign::Random`, the original) or rows of the Williams design over the
/// seat's cells in the study's order (`OrderDesign::Williams`, `williams::seat_rows` says
/// which). Blinded labels ("Controller k", as the approved protocol words it for the
/// subject) are a random numbering of the machine's cells, fixed for the subject: a
/// compensator at the desk has its uncancelled label, and nothing tells the subject which
/// tests cancel.
pub fn schedule(params: &StudyParams, study_seed: u64, enrol_index: u32) -> Vec<ScheduledTest> {
    let mut rng = Rng::derive(
        Rng::derive(study_seed, SCHEDULE_STREAM).next_u64(),
        u64::from(enrol_index),
    );
    let kinds: Vec<CompensatorKind> = params.compensators.iter().map(|c| c.kind()).collect();
    let arms = params.machine_arms();
    let machine: Vec<Cell> = kinds
        .iter()
        .flat_map(|&k| arms.iter().map(move |&a| (k, a)))
        .collect();
    let desk: Vec<Cell> = kinds.iter().map(|&k| (k, CancellationArm::Off)).collect();
    let cells_at = |seat: Seat| match seat {
        Seat::On => &machine,
        Seat::Off => &desk,
    };
    let mut labels: Vec<usize> = (1..=machine.len()).collect();
    shuffle(&mut labels, &mut rng);
    let start = starting_seat(enrol_index);
    let (first, second) = match params.order_design {
        OrderDesign::Random => {
            let mut first = cells_at(start).clone();
            shuffle(&mut first, &mut rng);
            let mut second = cells_at(other(start)).clone();
            loop {
                shuffle(&mut second, &mut rng);
                if second != first || second.len() < 2 {
                    break;
                }
            }
            (first, second)
        }
        OrderDesign::Williams => {
            let order = |seat: Seat| {
                let cells = cells_at(seat);
                let (on, off) = williams::seat_rows(cells.len(), enrol_index);
                let row = if seat == Seat::On { on } else { off };
                williams::rows(cells.len())[row]
                    .iter()
                    .map(|&c| cells[c])
                    .collect::<Vec<_>>()
            };
            (order(start), order(other(start)))
        }
    };
    let label_of = |k: CompensatorKind, arm: CancellationArm| {
        let i = machine
            .iter()
            .position(|&c| c == (k, arm))
            .expect("a cell of the study");
        format!("Controller {}", labels[i])
    };
    let mut out = Vec::with_capacity(machine.len() + desk.len() + 2);
    if params.practice_s > 0.0 {
        out.push(ScheduledTest {
            slot: 0,
            phase: TestPhase::Practice,
            seat: Seat::Off,
            block: 0,
            position: 0,
            queue_order: 0,
            compensator: params.practice_compensator,
            cancellation: CancellationArm::Off,
            blinded_label: "Practice".into(),
            duration_s: params.practice_s,
            target_seed: rng.next_u64() >> 11,
        });
    }
    let mut slot = 0;
    for (block, (seat, order)) in [(start, &first), (other(start), &second)]
        .into_iter()
        .enumerate()
    {
        for (i, &(k, arm)) in order.iter().enumerate() {
            slot += 1;
            out.push(ScheduledTest {
                slot,
                phase: TestPhase::Test,
                seat,
                block: block as u32 + 1,
                position: i as u32 + 1,
                queue_order: slot,
                compensator: k,
                cancellation: arm,
                blinded_label: label_of(k, arm),
                duration_s: params.trial_s,
                target_seed: rng.next_u64() >> 11,
            });
        }
    }
    if let Some(id) = &params.identification {
        // Drawn after every other test's seed, so adding identification to a study leaves
        // its orders, labels and targets as they were.
        let seed = rng.next_u64() >> 11;
        // First in the block on the machine (so before every cancelling test); in a
        // personalized study first of all the scored tests, wherever the subject starts, so
        // every test of an LQR design runs the subject's own (desk tests too: the designs
        // compared must be the same on both seats).
        let block = if start == Seat::On || id.personalized {
            1
        } else {
            2
        };
        let first_slot = if block == 1 {
            1
        } else {
            first.len() as u32 + 1
        };
        out.push(ScheduledTest {
            slot: slot + 1,
            phase: TestPhase::Identification,
            seat: Seat::On,
            block,
            position: 0,
            // Before the block's first test: the queue orders by block, then this.
            queue_order: first_slot - 1,
            compensator: id.compensator_or(params.practice_compensator),
            cancellation: CancellationArm::Off,
            blinded_label: "Identification".into(),
            duration_s: id.excitation.duration_s(),
            target_seed: seed,
        });
    }
    out
}

/// What moves the cab in a study's identification test whose phases are drawn from `seed`
/// (the test's `target_seed`); none when the study has no identification test.
pub fn identification_target(params: &StudyParams, seed: u64) -> Option<TargetSpec> {
    params
        .identification
        .as_ref()
        .map(|id| TargetSpec::Identification {
            excitation: MultisineSpec {
                seed,
                ..id.excitation
            },
            task: id.task,
        })
}

/// The target of one test: steps every `step_interval_s`, within ±range, zero mean and the
/// study's standard deviation (exact up to rounding, so well inside ±1 mm and ±5 %); with
/// `matched_targets`, the study's one mean-squared step change as well.
pub fn target(params: &StudyParams, test: &ScheduledTest) -> Result<StepTarget, ParamError> {
    draw_target(params, test.duration_s, test.target_seed)
}

/// The target of a test lasting `duration_s` with `seed`, as `target` draws it (the
/// creation check draws them too).
pub fn draw_target(
    params: &StudyParams,
    duration_s: f64,
    seed: u64,
) -> Result<StepTarget, ParamError> {
    let steps = StepParams {
        interval_s: params.step_interval_s,
        range_mm: params.target_range_mm,
        std_mm: params.target_std_mm,
    };
    let duration_s = duration_s.max(2.0 * params.step_interval_s);
    if params.matched_targets {
        StepTarget::generate_matched(&steps, duration_s, seed)
    } else {
        StepTarget::generate(&steps, duration_s, seed)
    }
}

#[cfg(test)]
#[path = "schedule_tests.rs"]
mod tests;
