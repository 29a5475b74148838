-- Sites: as migrations/0027_sites.sql (SQLite), in PostgreSQL's types.
ALTER TABLE stations ADD COLUMN site TEXT;
ALTER TABLE trials ADD COLUMN site TEXT;
ALTER TABLE bench_runs ADD COLUMN site TEXT;
CREATE TABLE site_estop_latch (
    site       TEXT PRIMARY KEY,
    latched    BIGINT NOT NULL CHECK (latched IN (0, 1)),
    changed_at BIGINT NOT NULL
);
