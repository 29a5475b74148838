-- The realized mean-squared step change of a test's target, Σ(level[i] − level[i−1])²/n with
-- the first step from 0 (mm²), beside its realized mean and standard deviation: what a
-- difficulty-matched study (`matched_targets`) holds equal across every target, recorded for
-- every study so targets can be compared. NULL for tests scheduled before it was recorded
-- (their levels are in target_levels_json).
ALTER TABLE trials ADD COLUMN target_ms_step_mm2 REAL;
