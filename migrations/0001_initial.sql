-- bdft-lab schema, version 1. Append-only: later changes go in new migration files.
-- Times are Unix milliseconds (INTEGER); JSON columns hold protocol types (bdft_protocol).

-- Experimenters log in to the dashboard. Passwords as argon2id PHC strings.
CREATE TABLE experimenters (
    id            INTEGER PRIMARY KEY,
    username      TEXT    NOT NULL UNIQUE,
    password_hash TEXT    NOT NULL,
    created_at    INTEGER NOT NULL
);

-- Dashboard sessions: only a SHA-256 of the cookie token is stored, so a copied database
-- does not hand out sessions. `csrf` is the per-session token state-changing requests echo.
CREATE TABLE sessions (
    token_hash      TEXT    PRIMARY KEY,
    experimenter_id INTEGER NOT NULL REFERENCES experimenters(id),
    csrf            TEXT    NOT NULL,
    created_at      INTEGER NOT NULL,
    expires_at      INTEGER NOT NULL
);

-- One-time link printed at first start to create the first experimenter account.
CREATE TABLE setup_tokens (
    token_hash TEXT    PRIMARY KEY,
    created_at INTEGER NOT NULL,
    used_at    INTEGER
);

-- A study: the protocol parameters (StudyParams JSON). Locked when the first subject starts;
-- from then on params_json never changes and protocol_hash (SHA-256 of its canonical form)
-- is stamped on every trial and export.
CREATE TABLE studies (
    id            INTEGER PRIMARY KEY,
    name          TEXT    NOT NULL,
    params_json   TEXT    NOT NULL,
    seed          INTEGER NOT NULL,
    locked_at     INTEGER,
    protocol_hash TEXT,
    created_at    INTEGER NOT NULL
);

-- Subjects are pseudonymous: a code (S01, …), never a name. The schedule is a pure function
-- of (study seed, enrol_index, params), stored for display and reproducible on demand.
CREATE TABLE subjects (
    id               INTEGER PRIMARY KEY,
    study_id         INTEGER NOT NULL REFERENCES studies(id),
    code             TEXT    NOT NULL,
    enrol_index      INTEGER NOT NULL,
    synthetic        INTEGER NOT NULL DEFAULT 0,
    token_hash       TEXT    NOT NULL UNIQUE,
    starting_station TEXT    NOT NULL CHECK (starting_station IN ('on', 'off')),
    consent_version  TEXT,
    consent_decision TEXT CHECK (consent_decision IN ('agreed', 'declined')),
    consent_at       INTEGER,
    withdrawn_at     INTEGER,
    withdraw_reason  TEXT,
    created_at       INTEGER NOT NULL,
    UNIQUE (study_id, code),
    UNIQUE (study_id, enrol_index)
);

-- Operator stations: a browser registered by pairing code, serving the on-machine station,
-- the off-machine (desk) station, or both (one computer in simulation).
CREATE TABLE stations (
    id           INTEGER PRIMARY KEY,
    study_id     INTEGER NOT NULL REFERENCES studies(id),
    name         TEXT    NOT NULL,
    role         TEXT    NOT NULL CHECK (role IN ('on', 'off', 'both')),
    token_hash   TEXT    NOT NULL UNIQUE,
    pairing_code TEXT    NOT NULL,
    paired_at    INTEGER,
    subject_id   INTEGER REFERENCES subjects(id),
    created_at   INTEGER NOT NULL
);

-- One row per attempt at a scheduled test. `slot` 0 is the practice, 1..10 the tests in
-- schedule order; a redo adds a row with the next attempt number.
CREATE TABLE trials (
    id                 INTEGER PRIMARY KEY,
    subject_id         INTEGER NOT NULL REFERENCES subjects(id),
    slot               INTEGER NOT NULL,
    attempt            INTEGER NOT NULL DEFAULT 1,
    practice           INTEGER NOT NULL,
    station            TEXT    NOT NULL CHECK (station IN ('on', 'off')),
    block              INTEGER NOT NULL,
    position           INTEGER NOT NULL,
    controller         TEXT    NOT NULL,
    blinded_label      TEXT    NOT NULL,
    compensator_json   TEXT    NOT NULL,
    k_bf               REAL    NOT NULL,
    duration_s         REAL    NOT NULL,
    target_seed        INTEGER NOT NULL,
    target_levels_json TEXT    NOT NULL,
    target_mean_mm     REAL    NOT NULL,
    target_std_mm      REAL    NOT NULL,
    status             TEXT    NOT NULL DEFAULT 'scheduled'
                       CHECK (status IN ('scheduled', 'running', 'complete', 'aborted', 'incomplete')),
    status_reason      TEXT,
    protocol_hash      TEXT,
    started_at         INTEGER,
    finished_at        INTEGER,
    mse_tracking_mm2   REAL,
    ms_cab_accel       REAL,
    timing_json        TEXT,
    client_timing_json TEXT,
    UNIQUE (subject_id, slot, attempt)
);
CREATE INDEX trials_by_status ON trials(status);

-- The full-rate record of a trial: one little-endian f32 array per channel
-- (bdft_protocol::trial::RECORD_CHANNELS), written in the same transaction as the result.
CREATE TABLE trial_records (
    trial_id        INTEGER PRIMARY KEY REFERENCES trials(id),
    dt              REAL    NOT NULL,
    samples         INTEGER NOT NULL,
    target_mm       BLOB    NOT NULL,
    hand_mm         BLOB    NOT NULL,
    feedthrough_mm  BLOB    NOT NULL,
    cyl_ref_mm      BLOB    NOT NULL,
    valve_cmd       BLOB    NOT NULL,
    cyl_pos_mm      BLOB    NOT NULL,
    cab_accel_mm_s2 BLOB    NOT NULL,
    device_mm       BLOB    NOT NULL,
    tick_latency_us BLOB    NOT NULL
);

-- One survey per completed test, all ratings required.
CREATE TABLE surveys (
    trial_id        INTEGER PRIMARY KEY REFERENCES trials(id),
    accuracy        INTEGER NOT NULL,
    speed           INTEGER NOT NULL,
    smoothness      INTEGER NOT NULL,
    controllability INTEGER NOT NULL,
    comment         TEXT    NOT NULL DEFAULT '',
    submitted_at    INTEGER NOT NULL
);

-- Experimenter notes on a subject or trial.
CREATE TABLE notes (
    id         INTEGER PRIMARY KEY,
    subject_id INTEGER NOT NULL REFERENCES subjects(id),
    trial_id   INTEGER REFERENCES trials(id),
    text       TEXT    NOT NULL,
    author     TEXT    NOT NULL,
    created_at INTEGER NOT NULL
);

-- Every experimenter action (who, what, when). Append-only, enforced below.
CREATE TABLE audit_log (
    id          INTEGER PRIMARY KEY,
    at          INTEGER NOT NULL,
    actor       TEXT    NOT NULL,
    action      TEXT    NOT NULL,
    target      TEXT,
    detail_json TEXT
);
CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
BEGIN SELECT RAISE(ABORT, 'audit_log is append-only'); END;
CREATE TRIGGER audit_log_no_delete BEFORE DELETE ON audit_log
BEGIN SELECT RAISE(ABORT, 'audit_log is append-only'); END;

-- A locked study's parameters never change.
CREATE TRIGGER studies_locked_params BEFORE UPDATE OF params_json, seed ON studies
WHEN OLD.locked_at IS NOT NULL
BEGIN SELECT RAISE(ABORT, 'the study protocol is locked'); END;
