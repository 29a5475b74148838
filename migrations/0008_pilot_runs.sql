-- A `bdft-server pilot` process working on this database. It beats (`beat_at`) every second
-- while it runs; a run that stopped beating without ending was killed, and the server (or
-- the next pilot) files the trials it left running as incomplete.
CREATE TABLE pilot_runs (
    id         INTEGER PRIMARY KEY,
    pid        INTEGER NOT NULL,
    started_at INTEGER NOT NULL,
    beat_at    INTEGER NOT NULL,
    ended_at   INTEGER
);

-- The trials a pilot run started (one run per trial).
CREATE TABLE pilot_trials (
    trial_id INTEGER PRIMARY KEY REFERENCES trials(id),
    run_id   INTEGER NOT NULL REFERENCES pilot_runs(id)
);
CREATE INDEX pilot_trials_by_run ON pilot_trials(run_id);
