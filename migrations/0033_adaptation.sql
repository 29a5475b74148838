-- Adaptive compensation (issue 41): what an adaptive design's estimator and schedule did
-- over a test (`AdaptationStatus` as JSON: its last estimate of the cab mode, when it first
-- trusted it, its retunes and its fallbacks to the fixed design). NULL for a fixed design and
-- for rows from before it.
ALTER TABLE trials ADD COLUMN adaptation_json TEXT;
