-- An audit log that cannot be extended or rewritten unseen (issue 37; store/audit_chain.rs).
--
-- `format` says how a chain row was made. 0: as migration 0023 made it (the SHA-256 of
-- the details, the chain SHA-256, nobody's key) — every row written before this migration.
-- 1: salted, unkeyed — the details' hash is the SHA-256 of a per-entry salt and the details,
-- the chain a SHA-256 of a fixed binary layout — written by a process that did not hold the
-- audit key; it counts only once a signed checkpoint covers it (the server signs within a
-- second of such a row). 2: salted and keyed — the chain an HMAC-SHA256 under a key derived
-- from the server's audit signing key, which lives in its keys directory, never here: whoever
-- holds only this database cannot make a row the next `audit verify` takes.
ALTER TABLE audit_chain ADD COLUMN format INTEGER NOT NULL DEFAULT 0 CHECK (format IN (0, 1, 2));

-- Each entry's salt (16 random bytes, hex), the details' hash of format 1 and 2 rows being
-- SHA-256(salt || details). An erasure that redacts an entry deletes its salt: the stored hash
-- can then no longer be tried against guessed details (a short note was once found by brute
-- force in under a second). Append-only but for that deletion.
CREATE TABLE audit_salts (
    entry_id INTEGER PRIMARY KEY,
    salt TEXT NOT NULL
);
CREATE TRIGGER audit_salts_no_update BEFORE UPDATE ON audit_salts
BEGIN SELECT RAISE(ABORT, 'audit_salts is append-only'); END;
CREATE TRIGGER audit_salts_only_redacted BEFORE DELETE ON audit_salts
WHEN NOT EXISTS (SELECT 1 FROM audit_log WHERE id = OLD.entry_id
                 AND detail_json LIKE '{"erasure":%,"redacted":"subject.erase"}')
BEGIN SELECT RAISE(ABORT, 'an audit entry''s salt is deleted only with its details, by an erasure'); END;

-- What each erasure redacted: the entry, the erasure, and an HMAC under the audit key of
-- both and of the entry's chain hash. `audit verify` takes a redaction marker only on an entry
-- its erasure recorded here (the marker itself, a constant, proves nothing).
CREATE TABLE audit_redactions (
    entry_id INTEGER PRIMARY KEY,
    erasure_id INTEGER NOT NULL,
    mac TEXT NOT NULL
);
CREATE TRIGGER audit_redactions_no_update BEFORE UPDATE ON audit_redactions
BEGIN SELECT RAISE(ABORT, 'audit_redactions is append-only'); END;
CREATE TRIGGER audit_redactions_no_delete BEFORE DELETE ON audit_redactions
BEGIN SELECT RAISE(ABORT, 'audit_redactions is append-only'); END;
