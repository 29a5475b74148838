-- Versions of a study's synthetic population made by a calibration (server/src/engine/
-- dry_runs/calibration/): the fitted population (PopulationParams as JSON) and the report it came
-- from (target, fit, intervals, predictions). The newest version of a study — or, for a
-- dry-run copy, of the study it copies if that one is newer — is the population its pilots
-- and its planner draw from (store::studies overlays it on the stored parameters); older
-- versions stay for the audit. Version 1 is the first calibration; the study's own
-- parameters are version 0.
CREATE TABLE population_versions (
    id              INTEGER PRIMARY KEY,
    study_id        INTEGER NOT NULL REFERENCES studies(id),
    version         INTEGER NOT NULL,
    population_json TEXT NOT NULL,
    report_json     TEXT NOT NULL,
    created_by      TEXT NOT NULL,
    created_at      INTEGER NOT NULL,
    UNIQUE (study_id, version)
);
