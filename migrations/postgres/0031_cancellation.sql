-- Model-based cancellation: as migrations/0031_cancellation.sql (SQLite), in PostgreSQL's
-- dialect.
ALTER TABLE trials ADD COLUMN cancellation TEXT NOT NULL DEFAULT 'off'
    CHECK (cancellation IN ('off', 'personal', 'generic', 'wrong'));
ALTER TABLE trials ADD COLUMN cancellation_json TEXT;

ALTER TABLE trial_records ADD COLUMN cancellation_mm BYTEA;

-- When (s into the test) cancellation's guard turned it off for the rest of the test, which
-- went on uncancelled; NULL when it never did.
ALTER TABLE trials ADD COLUMN cancellation_off_at_s DOUBLE PRECISION;
