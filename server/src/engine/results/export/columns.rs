//! The column definitions of every export: one table of specs per export, which the header
//! writer, the cell formatter (a number column's resolution), the Parquet schema and the
//! codebook all read, so they cannot drift apart.

use std::borrow::Cow;

use bdft_protocol::study::{RATING_KEYS, SurveyParams};
use bdft_protocol::trial::{RECORD_CHANNELS, RECORD_TIME};

/// What a column holds, and how its cells are written.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ColumnType {
    Integer,
    /// 0 or 1.
    Flag,
    /// Written to this many decimals (resolution 10^-decimals) and at most 12 significant
    /// digits: `bdft_protocol::numbers::format_number`.
    Number {
        decimals: u8,
    },
    Text,
    /// RFC 3339, UTC, milliseconds.
    Time,
}

impl ColumnType {
    /// The type's name in the codebook.
    pub fn name(self) -> &'static str {
        match self {
            Self::Integer => "integer",
            Self::Flag => "flag (0/1)",
            Self::Number { .. } => "number",
            Self::Text => "text",
            Self::Time => "time (RFC 3339, UTC)",
        }
    }

    /// The smallest step a number column shows (`None` for the other types).
    pub fn resolution(self) -> Option<f64> {
        match self {
            Self::Number { decimals } => Some(10f64.powi(-i32::from(decimals))),
            _ => None,
        }
    }
}

/// One column of an export: its header, unit (`1` dimensionless, empty for text), type and
/// meaning.
#[derive(Debug, Clone, PartialEq)]
pub struct Column {
    pub name: Cow<'static, str>,
    pub unit: Cow<'static, str>,
    pub ty: ColumnType,
    pub meaning: Cow<'static, str>,
}

const fn col(
    name: &'static str,
    unit: &'static str,
    ty: ColumnType,
    meaning: &'static str,
) -> Column {
    Column {
        name: Cow::Borrowed(name),
        unit: Cow::Borrowed(unit),
        ty,
        meaning: Cow::Borrowed(meaning),
    }
}

const INT: ColumnType = ColumnType::Integer;
const FLAG: ColumnType = ColumnType::Flag;
const TEXT: ColumnType = ColumnType::Text;
const TIME: ColumnType = ColumnType::Time;
const fn num(decimals: u8) -> ColumnType {
    ColumnType::Number { decimals }
}
/// Positions and their statistics: 1 nm, far below what a display or a cylinder shows, so
/// only float noise (4.7e-16 mm) is rounded away.
const MM: ColumnType = num(6);
/// Statistics (p-values, effect sizes): 12 decimals.
const STAT: ColumnType = num(12);

/// The keys that join the exports: the study and the subject's pseudonym.
const STUDY_ID: Column = col("study_id", "", INT, "the study's id");

/// The trials export's name of the mean-squared cab acceleration (with its unit).
const MS_CAB_ACCEL: &str = "ms_cab_accel_mm2_s4";

/// The trials export's name of rating `key` on a `points`-point scale.
fn rating_column(key: &str, points: u8) -> String {
    format!("rating_{key}_1to{points}")
}

/// The trials export's column a summary or statistics variable (`stats::SUMMARY_VARIABLES`,
/// or `log_` one of them) is computed from: the summary and stats exports name each
/// variable as the trials export names its column, unit included.
pub fn variable_column(variable: &str, survey: &SurveyParams) -> String {
    if let Some(inner) = variable.strip_prefix("log_") {
        return format!("log_{}", variable_column(inner, survey));
    }
    match variable.strip_prefix("rating_") {
        Some(key) => rating_column(key, survey.scale_points),
        None if variable == "ms_cab_accel" => MS_CAB_ACCEL.into(),
        None => variable.into(),
    }
}
const SUBJECT_CODE: Column = col("subject_code", "", TEXT, "the subject's pseudonym (S01, …)");
const SUBJECT_INDEX: Column = col(
    "subject_index",
    "",
    INT,
    "the subject's enrolment order, from 1",
);
const SYNTHETIC: Column = col(
    "synthetic",
    "",
    FLAG,
    "1 for a synthetic subject (pilot), 0 for a person",
);
const STARTING_SEAT: Column = col(
    "starting_seat",
    "",
    TEXT,
    "the seat the subject's tests began at (on/off); starting_station is its old name",
);
const STARTING_STATION: Column = col(
    "starting_station",
    "",
    TEXT,
    "old name of starting_seat (the same values), kept beside it for a release: the seat the subject's tests began at (on/off)",
);
const TRIAL_ID: Column = col(
    "trial_id",
    "",
    INT,
    "the test attempt's id (one per attempt)",
);
const PHASE: Column = col(
    "phase",
    "",
    TEXT,
    "practice (the unscored warm-up: no compensator, block or position of its own), test, or identification (the cab moved by a multisine while the subject held the device: unscored, no compensator of its own)",
);
/// The samples export's seat and compensator, under their old names only (a clear name
/// beside them would add two cells to every sample).
const STATION: Column = col(
    "station",
    "",
    TEXT,
    "the seat: on (on the machine, with feedthrough) or off (at the desk)",
);
const CONTROLLER: Column = col(
    "controller",
    "",
    TEXT,
    "the compensator (pid, pid-notch, pid-shaper, lqr, lqr-cabvel, lqr-cabacc, pid-notch-adaptive, pid-shaper-adaptive, lqr-cabvel-scheduled); empty for practice",
);
/// The seat and compensator under their clear names, and their old names kept beside them
/// for a release (the old column first, the clear one last in the export, so no column
/// moves): the codebook says which is which.
const SEAT: Column = col(
    "seat",
    "",
    TEXT,
    "the seat: on (on the machine, with feedthrough) or off (at the desk); station is its old name",
);
const STATION_ALIAS: Column = col(
    "station",
    "",
    TEXT,
    "old name of seat (the same values), kept beside it for a release: on (on the machine) or off (at the desk)",
);
const COMPENSATOR: Column = col(
    "compensator",
    "",
    TEXT,
    "the compensator (pid, pid-notch, pid-shaper, lqr, lqr-cabvel, lqr-cabacc, pid-notch-adaptive, pid-shaper-adaptive, lqr-cabvel-scheduled); empty for practice; controller is its old name",
);
const CONTROLLER_ALIAS: Column = col(
    "controller",
    "",
    TEXT,
    "old name of compensator (the same values), kept beside it for a release",
);
const ATTEMPT: Column = col(
    "attempt",
    "",
    INT,
    "attempt number of the test (1, then redos)",
);

/// The trials export (one row per test attempt), its ratings named with the study's scale.
pub fn trials(survey: &SurveyParams) -> Vec<Column> {
    let mut c = vec![
        STUDY_ID,
        TRIAL_ID,
        SUBJECT_CODE,
        SUBJECT_INDEX,
        SYNTHETIC,
        STARTING_STATION,
        PHASE,
        STATION_ALIAS,
        col(
            "block",
            "",
            INT,
            "block of the schedule (1: starting seat, 2: the other); empty for practice",
        ),
        col(
            "position",
            "",
            INT,
            "order of the test in the subject's schedule (1..); empty for practice",
        ),
        col(
            "slot",
            "",
            INT,
            "the schedule's slot (0 = practice); an attempt's test is (subject_code, slot)",
        ),
        ATTEMPT,
        col(
            "latest",
            "",
            FLAG,
            "1 on the latest attempt of its test (exactly one row per test)",
        ),
        col(
            "valid",
            "",
            FLAG,
            "1 when this attempt counts as a measurement: a test (not practice) that ran complete; the statistics use the rows with valid = 1 and latest = 1",
        ),
        CONTROLLER_ALIAS,
        col(
            "blinded_label",
            "",
            TEXT,
            "what the subject was told the compensator is (\"Controller k\"); empty for practice",
        ),
        col(
            "status",
            "",
            TEXT,
            "scheduled, running, complete, aborted, incomplete or invalid",
        ),
        col(
            "status_reason",
            "",
            TEXT,
            "why the attempt was filed with its status (a fault, the E-stop, …)",
        ),
        col("seed", "", INT, "seed of the attempt's target"),
        col(
            "target_mean_mm",
            "mm",
            MM,
            "mean of the target over the attempt",
        ),
        col(
            "target_std_mm",
            "mm",
            MM,
            "standard deviation of the target over the attempt",
        ),
        col(
            "target_ms_step_mm2",
            "mm²",
            MM,
            "mean-squared step change of the target, Σ(level[i] − level[i−1])²/n from 0 (equal across a difficulty-matched study; empty for tests scheduled before it was recorded)",
        ),
        col("k_bf", "1", num(6), "device-to-cylinder gain K_BF"),
        col("duration_s", "s", num(3), "planned length of the attempt"),
        col(
            "mse_tracking_mm2",
            "mm²",
            MM,
            "mean-squared tracking error, target − cylinder position",
        ),
        col(
            MS_CAB_ACCEL,
            "(mm/s²)²",
            num(3),
            "mean-squared measured cab acceleration",
        ),
        col(
            "cab_aw_m_s2",
            "m/s²",
            num(5),
            "ISO 2631-1 frequency-weighted r.m.s. a_w of the fore-aft cab acceleration (W_d: band limits 0.4–100 Hz, acceleration–velocity transition at 2 Hz, Q 0.63; discretized at the record's 1 kHz) over the attempt's record; empty for an attempt without a result or filed before release 0.2 (migration 0024)",
        ),
        col(
            "cab_vdv_m_s175",
            "m/s^1.75",
            num(5),
            "ISO 2631-1 vibration dose value (∫a_w⁴ dt)^¼ of the same W_d-weighted cab acceleration over the record; empty as cab_aw_m_s2",
        ),
    ];
    let points = survey.scale_points;
    for key in RATING_KEYS {
        let label = survey
            .items
            .iter()
            .find(|i| i.key == key)
            .map(|i| i.label.clone())
            .unwrap_or_default();
        c.push(Column {
            name: rating_column(key, points).into(),
            unit: format!("1–{points}").into(),
            ty: INT,
            meaning: format!("the subject's rating (ordinal, higher is better): {label}").into(),
        });
    }
    c.extend([
        col(
            "comment",
            "",
            TEXT,
            "the subject's answer to the open question",
        ),
        col(
            "protocol_hash",
            "",
            TEXT,
            "hash of the study protocol the attempt ran under",
        ),
        col("started_at", "", TIME, "when the attempt started"),
        col("finished_at", "", TIME, "when the attempt ended"),
        col(
            "consent_version",
            "",
            TEXT,
            "version of the consent form the subject agreed to",
        ),
        col(
            "display_frames",
            "",
            INT,
            "frames the station's display drew during the attempt",
        ),
        col(
            "display_longest_gap_ms",
            "ms",
            num(3),
            "longest time between two displayed frames",
        ),
        col(
            "display_hidden_ms",
            "ms",
            num(3),
            "time the station's page was hidden",
        ),
        col(
            "input_hz",
            "Hz",
            num(3),
            "rate of the station's input samples",
        ),
        col(
            "rtt_p50_ms",
            "ms",
            num(3),
            "median station ↔ server round-trip time",
        ),
        col(
            "rtt_p95_ms",
            "ms",
            num(3),
            "95th percentile station ↔ server round-trip time",
        ),
        col(
            "rtt_max_ms",
            "ms",
            num(3),
            "longest station ↔ server round-trip time",
        ),
        col(
            "controller_overruns",
            "",
            INT,
            "real-time ticks that missed their deadline",
        ),
        col(
            "controller_wake_p99_us",
            "µs",
            num(1),
            "99th percentile wake-up latency of the real-time tick",
        ),
        col(
            "accepted_reason",
            "",
            TEXT,
            "the experimenter's reason for accepting a failed attempt as incomplete",
        ),
        col(
            "config_version",
            "",
            TEXT,
            "the controller configuration version the trial ran (\"name vN\"; empty: a design not from a version)",
        ),
        col(
            "personalized",
            "",
            FLAG,
            "the design was tuned to the subject's identified body (a personalized study's LQR designs)",
        ),
        col(
            "design_alpha",
            "1",
            num(4),
            "the LQR design's tracking weight α as run (empty: not an LQR design)",
        ),
        col(
            "design_beta",
            "1",
            num(4),
            "the LQR design's cab-feedback weight β as run (empty: not an LQR design)",
        ),
        col(
            "site",
            "",
            TEXT,
            "the site whose machine ran the test (serve --site; empty: not started, a dry run's own controller, or started before sites)",
        ),
    ]);
    // The clear names, last: no column of an earlier release moves.
    c.extend([STARTING_SEAT, SEAT, COMPENSATOR]);
    c.push(col(
        "cancellation",
        "",
        TEXT,
        "what the test cancelled the feedthrough with (off, personal: the subject's identified body, generic: the population's median body, wrong: the subject's with the study's stated error; always off at the desk); a test whose cancellation the guard turned off has cancellation_off_at_s",
    ));
    c.push(col(
        "cancellation_off_at_s",
        "s",
        num(3),
        "when cancellation's guard turned it off for the rest of the test, which went on uncancelled (its output past the model's limit_mm); empty when it never did",
    ));
    c.push(col(
        "condition",
        "",
        TEXT,
        "the machine's condition the test ran under: stilts (the thesis's rig), or a ground (tires, outriggers), loaded or loaded:FILL (the bucket's fill of its rated load) and stick (the stick cylinder driven), joined by '+'; on the simulated rig the designs stay made for the study's rig and the rig is scaled by the rules of docs/machine-conditions.md; on a real rig it is what the lab declared",
    ));
    c.extend([
        col(
            "adapt_f_hz",
            "Hz",
            num(3),
            "an adaptive design's last estimate of the cab's first mode (empty: a fixed design, or no estimate by the test's end)",
        ),
        col(
            "adapt_confident_since_s",
            "s",
            num(3),
            "when the adaptive design's estimate was first trusted, s into the test (empty: never, or a fixed design)",
        ),
        col(
            "adapt_ratio",
            "1",
            num(3),
            "the mode-frequency ratio of the design running at the test's end (1 = the fixed design; empty: a fixed design)",
        ),
        col(
            "adapt_retunes",
            "",
            INT,
            "how often the adaptive design changed (each a crossfade to the design frozen at the estimate)",
        ),
        col(
            "adapt_fallbacks",
            "",
            INT,
            "retune decisions taken without a trusted estimate, each keeping or restoring the fixed design (also in the audit log's trial.finish)",
        ),
        col(
            "adapt_confident",
            "",
            FLAG,
            "1 when the adaptive design's estimate was trusted at the test's end",
        ),
    ]);
    c
}

/// The samples export: the join keys, then the record's columns (as `simulate --out`).
pub fn samples() -> Vec<Column> {
    let record = std::iter::once(&RECORD_TIME)
        .chain(&RECORD_CHANNELS)
        .map(|r| Column {
            name: r.name.into(),
            unit: r.unit.into(),
            ty: num(r.decimals),
            meaning: r.meaning.into(),
        });
    [
        STUDY_ID,
        SUBJECT_CODE,
        TRIAL_ID,
        PHASE,
        STATION,
        CONTROLLER,
        ATTEMPT,
    ]
    .into_iter()
    .chain(record)
    .collect()
}

/// Prefix of a subject's drawn parameters in the subjects export (`drawn.reaction_delay_s`).
pub const DRAWN_PREFIX: &str = "drawn.";

/// The subjects export: one row per subject, then one column per drawn parameter the
/// study's subjects have (`drawn_keys`, sorted).
pub fn subjects(drawn_keys: &[String]) -> Vec<Column> {
    let mut c = vec![
        STUDY_ID,
        SUBJECT_CODE,
        SUBJECT_INDEX,
        SYNTHETIC,
        STARTING_STATION,
        col(
            "consent_version",
            "",
            TEXT,
            "version of the consent form shown",
        ),
        col(
            "consent_decision",
            "",
            TEXT,
            "agreed or declined; empty before a decision",
        ),
        col("consent_at", "", TIME, "when the subject decided"),
        col(
            "consent_sha256",
            "",
            TEXT,
            "SHA-256 (hex) of the consent form's text the decision was made on: the text the protocol package prints with the same hash (empty before a decision, or for one recorded before migration 0030)",
        ),
        col(
            "withdrawn",
            "",
            FLAG,
            "1 when the subject withdrew (then left out of every other export)",
        ),
        col("withdrawn_at", "", TIME, "when the subject withdrew"),
        col(
            "order",
            "",
            TEXT,
            "the schedule's order: seat, then the compensators of the block in the order run (on: pid > lqr … | off: …)",
        ),
        col(
            "valid_tests",
            "",
            INT,
            "tests whose latest attempt is valid (those the statistics use)",
        ),
        col(
            "exposure_days",
            "",
            INT,
            "UTC days on which the subject rode the machine in a test (seat on, practice included when on the machine)",
        ),
        col(
            "a8_max_m_s2",
            "m/s²",
            num(5),
            "the highest daily vibration exposure A(8) = √(Σ a_w,i²·T_i / 8 h) over the subject's days (a day: the UTC date a test started; its tests on the machine at their cab_aw_m_s2 over their record); empty without a test on the machine, or when one of them has no measured figures (a test filed before release 0.2 or without a result: the budget counts it at its worst case, the interlock's limit held)",
        ),
        col(
            "vdv_day_max_m_s175",
            "m/s^1.75",
            num(5),
            "the highest daily vibration dose value (Σ VDV_i⁴)^¼ over the same days; empty as a8_max_m_s2",
        ),
    ];
    for (key, unit, meaning) in IDENTIFIED {
        for (suffix, what) in [
            ("", "fitted"),
            ("_lo", "lower 95 % bound of the fitted"),
            ("_hi", "upper 95 % bound of the fitted"),
        ] {
            c.push(Column {
                name: format!("identified.{key}{suffix}").into(),
                unit: unit.into(),
                ty: num(6),
                meaning: format!(
                    "{what} {meaning}, from the subject's latest identification test with a fit (the identification export has its points); empty without one, or when the data did not identify it (identified.{key}_status says why)"
                )
                .into(),
            });
        }
        c.push(Column {
            name: format!("identified.{key}_status").into(),
            unit: "".into(),
            ty: TEXT,
            meaning: format!(
                "whether the data identified the {meaning}: `identified`, or `not identified: ` and why as the fit gave it — the data carry no information on it; the fit ends at the edge of the plausible range; its 95 % interval spans more than a factor of 10; its resonance fitted with a damping below any body's (a mode of the machine); its resonance's other parameter was not identified; (k_h) a resonance the fit put where no body has one; or the seated body does not describe the measured feedthrough (its misfit) —; then identified.{key} and its bounds are empty; empty without a fit"
            )
            .into(),
        });
    }
    c.push(col(
        "identified.residual_rms",
        "",
        num(6),
        "RMS of that fit's residual, |ln(model / measured)| over its points",
    ));
    // The clear name after the fixed columns, before the study's own drawn ones.
    c.push(STARTING_SEAT);
    c.extend(drawn_keys.iter().map(|k| drawn_column(k)));
    c
}

/// The seated body's parameters an identification test fits, with unit and meaning, in
/// the subjects export's order.
pub const IDENTIFIED: [(&str, &str, &str); 5] = [
    (
        "k_h",
        "",
        "feedthrough gain k_h of the seated body (h = k_h·(1 − T·A)·x_c)",
    ),
    ("torso_f_hz", "Hz", "torso resonance frequency"),
    ("torso_zeta", "", "torso damping ratio"),
    (
        "arm_f_hz",
        "Hz",
        "arm resonance frequency, as gripped during the test",
    ),
    ("arm_zeta", "", "arm damping ratio"),
];

pub fn identification() -> Vec<Column> {
    let mag = |name, meaning| col(name, "mm/(m/s²)", num(6), meaning);
    let deg = |name, meaning| col(name, "deg", num(3), meaning);
    vec![
        STUDY_ID,
        SUBJECT_CODE,
        col("trial_id", "", INT, "the identification test's attempt"),
        col(
            "f_hz",
            "Hz",
            num(4),
            "an excited frequency of the multisine",
        ),
        mag(
            "magnitude",
            "|device position / cab acceleration| at f_hz, averaged over the test's periods",
        ),
        mag("magnitude_lo", "lower 95 % bound of magnitude"),
        mag("magnitude_hi", "upper 95 % bound of magnitude"),
        deg(
            "phase_deg",
            "phase of device position / cab acceleration at f_hz",
        ),
        deg("phase_lo_deg", "lower 95 % bound of phase_deg"),
        deg("phase_hi_deg", "upper 95 % bound of phase_deg"),
        col(
            "coherence",
            "",
            num(4),
            "squared coherence of cab acceleration and device position over the periods (0–1)",
        ),
    ]
}

/// A drawn parameter's column: its key carries the unit (`reaction_delay_s`).
fn drawn_column(key: &str) -> Column {
    Column {
        name: format!("{DRAWN_PREFIX}{key}").into(),
        unit: "as the name's suffix".into(),
        ty: num(9),
        meaning: "a synthetic subject's parameter drawn from the study's population at enrolment (operator, body, survey bias); empty for a person".into(),
    }
}

pub fn summary() -> Vec<Column> {
    let stat = |name, meaning| col(name, "of the variable", MM, meaning);
    vec![
        col(
            "controller",
            "",
            TEXT,
            "old name of compensator (the same values), kept beside it for a release",
        ),
        STATION_ALIAS,
        col(
            "variable",
            "",
            TEXT,
            "the trials export's column summarized (its name carries the unit)",
        ),
        col("n", "", INT, "subjects with a valid latest attempt"),
        stat("mean", "mean"),
        stat("median", "median"),
        stat("q1", "first quartile (linear interpolation)"),
        stat("q3", "third quartile (linear interpolation)"),
        stat("min", "smallest value"),
        stat("max", "largest value"),
        col(
            "compensator",
            "",
            TEXT,
            "the compensator; controller is its old name",
        ),
        SEAT,
        col(
            "cancellation",
            "",
            TEXT,
            "what the tests cancelled the feedthrough with (off, personal, generic, wrong: as the trials export's column)",
        ),
        col(
            "condition",
            "",
            TEXT,
            "the machine's condition of the subjects summarised (as the trials export's column): the study's, or one level of its condition factor, each level a row of its own",
        ),
    ]
}

pub fn stats() -> Vec<Column> {
    vec![
        col(
            "test",
            "",
            TEXT,
            "friedman, wilcoxon, wilcoxon_on_off, wilcoxon_cancellation (a compensator on the machine uncancelled, a, against cancelled, b: pid+personal), rm_anova, or kruskal_condition (a study's condition factor: its levels, a, compared between subjects)",
        ),
        col(
            "metric",
            "",
            TEXT,
            "the trials export's column analysed (log_: its logarithm)",
        ),
        col(
            "station",
            "",
            TEXT,
            "old name of seat (the same values), kept beside it for a release",
        ),
        col(
            "a",
            "",
            TEXT,
            "first compensator of a pair (the effect for rm_anova)",
        ),
        col("b", "", TEXT, "second compensator of a pair"),
        col("n", "", INT, "subjects in the analysis"),
        col(
            "statistic",
            "1",
            STAT,
            "χ² (Friedman), min(R⁺, R⁻) (Wilcoxon), F (ANOVA), H (Kruskal–Wallis)",
        ),
        col(
            "p_value",
            "1",
            STAT,
            "the test's p (ANOVA: Greenhouse–Geisser corrected)",
        ),
        col(
            "p_adjusted",
            "1",
            STAT,
            "Holm-adjusted p within the family; empty for omnibus tests",
        ),
        col(
            "effect_size",
            "1",
            STAT,
            "the effect size named in `effect`",
        ),
        col(
            "effect",
            "",
            TEXT,
            "kendall_w, rank_biserial (of a − b), eta_g2 or epsilon2 (Kruskal–Wallis: H / (n − 1))",
        ),
        col("median_diff", "of the metric", STAT, "median of a − b"),
        col(
            "ci_low",
            "of the metric",
            STAT,
            "95 % bootstrap interval of median_diff, low end",
        ),
        col(
            "ci_high",
            "of the metric",
            STAT,
            "95 % bootstrap interval of median_diff, high end",
        ),
        col("df1", "1", STAT, "degrees of freedom (ANOVA, corrected)"),
        col(
            "df2",
            "1",
            STAT,
            "error degrees of freedom (ANOVA, corrected)",
        ),
        col("eps", "1", STAT, "Greenhouse–Geisser ε"),
        col(
            "reachable",
            "",
            FLAG,
            "1 when the comparison can reach p < 0.05 after adjustment at this n",
        ),
        col(
            "note",
            "",
            TEXT,
            "why a comparison cannot reach significance, or other remarks",
        ),
        col(
            "seat",
            "",
            TEXT,
            "on, off, on-off (a seat comparison) or both (the ANOVA); station is its old name",
        ),
    ]
}

pub fn notes() -> Vec<Column> {
    vec![
        STUDY_ID,
        TRIAL_ID,
        SUBJECT_CODE,
        col("slot", "", INT, "the schedule's slot of the test"),
        ATTEMPT,
        col(
            "kind",
            "",
            TEXT,
            "note, redo, abort, accept_incomplete, start_failed, invalid or status",
        ),
        col("status", "", TEXT, "the attempt's status"),
        col("at", "", TIME, "when it was written"),
        col("by", "", TEXT, "who wrote it"),
        col("text", "", TEXT, "the note or reason"),
    ]
}

pub fn audit() -> Vec<Column> {
    vec![
        col("id", "", INT, "the audit row's id (increasing)"),
        col("at", "", TIME, "when the action happened"),
        col(
            "actor",
            "",
            TEXT,
            "who acted (an account, a station, system:…)",
        ),
        col("actor_id", "", INT, "the acting account's id"),
        col(
            "action",
            "",
            TEXT,
            "what was done (study.create, trial.redo, export, …)",
        ),
        col(
            "target",
            "",
            TEXT,
            "what it was done to (study:1, trial:7, …)",
        ),
        col("detail", "", TEXT, "details as JSON"),
    ]
}

pub fn codebook() -> Vec<Column> {
    vec![
        col("export", "", TEXT, "the export kind"),
        col("column", "", TEXT, "the column's header"),
        col(
            "type",
            "",
            TEXT,
            "integer, flag (0/1), number, text or time (RFC 3339, UTC)",
        ),
        col("unit", "", TEXT, "the unit (1: dimensionless; empty: none)"),
        col(
            "resolution",
            "of the column",
            num(12),
            "number columns: values are rounded to this step and to 12 significant digits; |x| below half of it is written 0",
        ),
        col("meaning", "", TEXT, "what the column holds"),
    ]
}
