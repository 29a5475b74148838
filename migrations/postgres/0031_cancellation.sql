-- Model-based cancellation: as migrations/0031_cancellation.sql (SQLite), in PostgreSQL's
-- dialect.
ALTER TABLE trials ADD COLUMN cancellation TEXT NOT NULL DEFAULT 'off'
    CHECK (cancellation IN ('off', 'personal', 'generic', 'wrong'));
ALTER TABLE trials ADD COLUMN cancellation_json TEXT;

ALTER TABLE trial_records ADD COLUMN cancellation_mm BYTEA;
