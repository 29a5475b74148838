-- Identification tests (issue 22): a test of the schedule is now the practice, a scored test
-- or an identification test (the cab moved by a multisine while the person holds the device),
-- so the boolean `practice` becomes the test's `phase`.
ALTER TABLE trials ADD COLUMN phase TEXT NOT NULL DEFAULT 'test'
    CHECK (phase IN ('practice', 'test', 'identification'));
UPDATE trials SET phase = 'practice' WHERE practice = 1;
ALTER TABLE trials DROP COLUMN practice;

-- What a completed identification test measured: the feedthrough at each excited frequency
-- (`FrfPoint`s, JSON) and the seated body fitted to it (`BodyFit`, JSON), or why the fit
-- failed. One row per completed attempt; written with the trial's filing.
CREATE TABLE identifications (
    trial_id    INTEGER PRIMARY KEY REFERENCES trials(id),
    subject_id  INTEGER NOT NULL REFERENCES subjects(id),
    points_json TEXT    NOT NULL,
    fit_json    TEXT,
    fit_error   TEXT,
    created_at  INTEGER NOT NULL,
    CHECK ((fit_json IS NULL) <> (fit_error IS NULL))
);
CREATE INDEX identifications_by_subject ON identifications(subject_id);
