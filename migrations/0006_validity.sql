-- Validity per test and nothing skipped (server/src/engine/validity.rs, store/trials.rs).
--
-- * status may be 'invalid': a person's test stopped because the station's display was
--   hidden or stalled beyond the study's limits (max_hidden_ms, max_frame_gap_ms). It never
--   counts. SQLite cannot change a CHECK constraint, so the table is rebuilt, and with it
--   the tables whose foreign keys name it (trial_records, surveys, notes): dropping a
--   parent table that still has children fails the foreign keys, and migrations run in a
--   transaction, where they cannot be switched off. Each new child table names the new
--   trials table, and the renames carry the names over.
-- * invalid_reason: set while the test still runs, the moment the server decides it is
--   invalid (before the controller's result arrives); the result is then filed invalid
--   with it, whatever the outcome, so an invalid test is never filed complete.
-- * queue_order: the order tests run in within their block (`slot` is the schedule). A test
--   that failed (aborted, incomplete or invalid) is re-queued as a new attempt at the end of
--   its block. Existing rows keep the schedule order.
-- * accepted_reason: the experimenter accepted this attempt's test as incomplete (it is
--   not re-queued again and counts as missing with this reason).
CREATE TABLE trials_new (
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
                       CHECK (status IN ('scheduled', 'running', 'complete', 'aborted', 'incomplete', 'invalid')),
    status_reason      TEXT,
    protocol_hash      TEXT,
    started_at         INTEGER,
    finished_at        INTEGER,
    mse_tracking_mm2   REAL,
    ms_cab_accel       REAL,
    timing_json        TEXT,
    client_timing_json TEXT,
    queue_order        INTEGER NOT NULL,
    invalid_reason     TEXT,
    accepted_reason    TEXT,
    UNIQUE (subject_id, slot, attempt)
);

INSERT INTO trials_new (id, subject_id, slot, attempt, practice, station, block, position, controller,
    blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json,
    target_mean_mm, target_std_mm, status, status_reason, protocol_hash, started_at, finished_at,
    mse_tracking_mm2, ms_cab_accel, timing_json, client_timing_json, queue_order)
SELECT id, subject_id, slot, attempt, practice, station, block, position, controller,
    blinded_label, compensator_json, k_bf, duration_s, target_seed, target_levels_json,
    target_mean_mm, target_std_mm, status, status_reason, protocol_hash, started_at, finished_at,
    mse_tracking_mm2, ms_cab_accel, timing_json, client_timing_json, slot
FROM trials;

CREATE TABLE trial_records_new (
    trial_id        INTEGER PRIMARY KEY REFERENCES trials_new(id),
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
INSERT INTO trial_records_new SELECT trial_id, dt, samples, target_mm, hand_mm, feedthrough_mm,
    cyl_ref_mm, valve_cmd, cyl_pos_mm, cab_accel_mm_s2, device_mm, tick_latency_us FROM trial_records;

CREATE TABLE surveys_new (
    trial_id        INTEGER PRIMARY KEY REFERENCES trials_new(id),
    accuracy        INTEGER NOT NULL,
    speed           INTEGER NOT NULL,
    smoothness      INTEGER NOT NULL,
    controllability INTEGER NOT NULL,
    comment         TEXT    NOT NULL DEFAULT '',
    submitted_at    INTEGER NOT NULL
);
INSERT INTO surveys_new SELECT trial_id, accuracy, speed, smoothness, controllability, comment,
    submitted_at FROM surveys;

CREATE TABLE notes_new (
    id         INTEGER PRIMARY KEY,
    subject_id INTEGER NOT NULL REFERENCES subjects(id),
    trial_id   INTEGER REFERENCES trials_new(id),
    text       TEXT    NOT NULL,
    author     TEXT    NOT NULL,
    created_at INTEGER NOT NULL
);
INSERT INTO notes_new SELECT id, subject_id, trial_id, text, author, created_at FROM notes;

-- Children first: then nothing refers to the old trials table when it goes.
DROP TABLE trial_records;
DROP TABLE surveys;
DROP TABLE notes;
DROP TABLE trials;
ALTER TABLE trials_new RENAME TO trials;
ALTER TABLE trial_records_new RENAME TO trial_records;
ALTER TABLE surveys_new RENAME TO surveys;
ALTER TABLE notes_new RENAME TO notes;
CREATE INDEX trials_by_status ON trials(status);
CREATE INDEX trials_by_queue ON trials(subject_id, block, queue_order);
