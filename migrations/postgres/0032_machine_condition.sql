-- Machine conditions: as migrations/0032_machine_condition.sql (SQLite), in PostgreSQL's
-- dialect (the same).
ALTER TABLE trials ADD COLUMN condition TEXT NOT NULL DEFAULT 'stilts';
ALTER TABLE bench_runs ADD COLUMN condition TEXT NOT NULL DEFAULT 'stilts';
