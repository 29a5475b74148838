-- The E-stop latch as the server keeps it (server/src/engine/controller_link.rs): one row,
-- set by an E-stop and cleared only by an experimenter's reset, re-sent to every new
-- controller connection (a controller starts latched and waits for it). Kept in the database
-- so that a server restart after an E-stop does not release the machine.
CREATE TABLE estop_latch (
    id         INTEGER PRIMARY KEY CHECK (id = 1),
    latched    INTEGER NOT NULL,
    changed_at INTEGER NOT NULL
);
INSERT INTO estop_latch (id, latched, changed_at) VALUES (1, 0, 0);
