-- Versioned controller configurations and bench runs (issue 12).

-- A named version of a compensator's design. Editing a design makes a new version; a version
-- never changes once created (triggers below), so a trial that names it names exactly what
-- it ran. Who created it and when is in the audit log (`config.create`).
CREATE TABLE compensator_configs (
    id         INTEGER PRIMARY KEY,
    name       TEXT    NOT NULL,
    version    INTEGER NOT NULL CHECK (version >= 1),
    -- CompensatorKind's name, so a study can put the version in place of its design of
    -- that kind.
    kind       TEXT    NOT NULL,
    -- The CompensatorSpec as serde_json writes it: the same text a trial's
    -- compensator_json holds when it ran this version.
    spec_json  TEXT    NOT NULL,
    created_at INTEGER NOT NULL,
    UNIQUE (name, version)
);
CREATE TRIGGER compensator_configs_no_update BEFORE UPDATE ON compensator_configs
BEGIN SELECT RAISE(ABORT, 'a configuration version is immutable; create a new version'); END;
CREATE TRIGGER compensator_configs_no_delete BEFORE DELETE ON compensator_configs
BEGIN SELECT RAISE(ABORT, 'a configuration version is immutable; create a new version'); END;

-- The versions a study picked, one per compensator kind. The study's parameters hold the
-- resolved design (so the protocol hash and the controller messages stay what they were);
-- this table only remembers which version the design came from.
CREATE TABLE study_configs (
    study_id  INTEGER NOT NULL REFERENCES studies(id),
    kind      TEXT    NOT NULL,
    config_id INTEGER NOT NULL REFERENCES compensator_configs(id),
    PRIMARY KEY (study_id, kind)
);

-- The version each trial ran: NULL for a design not from a configuration.
ALTER TABLE trials ADD COLUMN config_id INTEGER REFERENCES compensator_configs(id);

-- Filled as the trial is scheduled (enrolment, redo) from the picks of the subject's study,
-- or of the study a dry run copies, only when the trial's design is the picked version's
-- design to the byte: a study edited by hand after picking (or a copy made before it) keeps
-- no stale version.
CREATE TRIGGER trials_config_version AFTER INSERT ON trials
WHEN NEW.config_id IS NULL
BEGIN
    UPDATE trials SET config_id = (
        SELECT c.id FROM subjects s
        JOIN study_configs sc ON sc.study_id = s.study_id
            OR sc.study_id = (SELECT d.of_study FROM dry_runs d WHERE d.study_id = s.study_id)
        JOIN compensator_configs c ON c.id = sc.config_id
        WHERE s.id = NEW.subject_id AND sc.kind = NEW.controller AND c.spec_json = NEW.compensator_json
        LIMIT 1
    ) WHERE id = NEW.id;
END;

-- A bench run: compensators driven by one reference signal, no operator. `signal_json` is
-- the TargetSpec, `rig` 'sim' (in-process, faster than real time) or 'real'.
CREATE TABLE bench_runs (
    id          INTEGER PRIMARY KEY,
    study_id    INTEGER REFERENCES studies(id),
    rig         TEXT    NOT NULL CHECK (rig IN ('sim', 'real')),
    signal_json TEXT    NOT NULL,
    duration_s  REAL    NOT NULL,
    seed        INTEGER NOT NULL,
    status      TEXT    NOT NULL DEFAULT 'running' CHECK (status IN ('running', 'done', 'failed')),
    error       TEXT,
    created_by  TEXT    NOT NULL,
    created_at  INTEGER NOT NULL,
    finished_at INTEGER
);

-- One compensator's run within a bench run, with the metrics of its full-rate (1 kHz)
-- record, and that record decimated for plots and export.
CREATE TABLE bench_results (
    id               INTEGER PRIMARY KEY,
    run_id           INTEGER NOT NULL REFERENCES bench_runs(id),
    position         INTEGER NOT NULL,
    label            TEXT    NOT NULL,
    kind             TEXT    NOT NULL,
    config_id        INTEGER REFERENCES compensator_configs(id),
    spec_json        TEXT    NOT NULL,
    outcome          TEXT    NOT NULL,
    ticks            INTEGER NOT NULL,
    mse_tracking_mm2 REAL    NOT NULL,
    ms_cab_accel     REAL    NOT NULL,
    -- Every `decimation`-th tick of target_mm, cyl_pos_mm and cab_accel_mm_s2 (point
    -- samples, no averaging), as JSON {"dt_s":…, "target_mm":[…], …}.
    decimation       INTEGER NOT NULL,
    trace_json       TEXT    NOT NULL,
    UNIQUE (run_id, position)
);
