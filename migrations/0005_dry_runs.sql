-- A dry run is a study that holds only synthetic subjects: pilots run there, never in a
-- study with people, so synthetic data can never be pooled with a real subject's.
-- `of_study` links a dry-run copy to the study it copies (same parameters and seed); a
-- stand-alone pilot study has none. A study has at most one dry-run copy.
CREATE TABLE dry_runs (
    study_id   INTEGER PRIMARY KEY REFERENCES studies(id),
    of_study   INTEGER UNIQUE REFERENCES studies(id),
    created_at INTEGER NOT NULL
);
