-- A `bdft-server serve` process working on this database. It beats (`beat_at`) every second
-- while it serves and ends its row when it stops; a row that stopped beating without ending
-- was a server that was killed. `bdft-server restore` refuses to replace a database that a
-- server (or a pilot process, `pilot_runs`) has beaten on within the last few seconds.
CREATE TABLE server_runs (
    id         INTEGER PRIMARY KEY,
    pid        INTEGER NOT NULL,
    listen     TEXT NOT NULL,
    started_at INTEGER NOT NULL,
    beat_at    INTEGER NOT NULL,
    ended_at   INTEGER
);
