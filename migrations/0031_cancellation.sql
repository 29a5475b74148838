-- Model-based cancellation as a factor on the machine (issue 38): each test's arm (off,
-- personal, generic, wrong) and the model it cancels with, set when the subject's
-- identification test is filed and the model has passed the check against their body.
-- Tests scheduled before this migration are uncancelled.
ALTER TABLE trials ADD COLUMN cancellation TEXT NOT NULL DEFAULT 'off'
    CHECK (cancellation IN ('off', 'personal', 'generic', 'wrong'));
ALTER TABLE trials ADD COLUMN cancellation_json TEXT;

-- The record's channel of what cancellation subtracted from the device reading (f32 blob,
-- as the others); NULL in a record filed before it, read as zeros (nothing was cancelled).
ALTER TABLE trial_records ADD COLUMN cancellation_mm BLOB;

-- When (s into the test) cancellation's guard turned it off for the rest of the test, which
-- went on uncancelled; NULL when it never did.
ALTER TABLE trials ADD COLUMN cancellation_off_at_s REAL;
