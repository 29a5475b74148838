-- A tamper-evident audit log (issue 25; store/audit_chain.rs). Every audit row has a chain
-- row: the SHA-256 of its details (`detail_hash`), and its `hash` = SHA-256 of the previous
-- chain row's hash and the row's canonical content (id, time, actor, account, action,
-- target, detail_hash). The chain is kept beside the log rather than in it, so the log's
-- rows are never updated for it; an erasure that redacts a row's details leaves its
-- detail_hash, and the chain still verifies. Rows that existed before this migration are
-- chained at the next start (`chained_late` = 1): their history before that is as good as
-- the triggers that guarded it.
CREATE TABLE audit_chain (
    entry_id INTEGER PRIMARY KEY,
    prev_hash TEXT NOT NULL,
    detail_hash TEXT NOT NULL,
    hash TEXT NOT NULL,
    chained_late INTEGER NOT NULL DEFAULT 0 CHECK (chained_late IN (0, 1))
);
CREATE TRIGGER audit_chain_no_update BEFORE UPDATE ON audit_chain
BEGIN SELECT RAISE(ABORT, 'audit_chain is append-only'); END;
CREATE TRIGGER audit_chain_no_delete BEFORE DELETE ON audit_chain
BEGIN SELECT RAISE(ABORT, 'audit_chain is append-only'); END;

-- Signed checkpoints: the chain's head at a moment, signed with the server's Ed25519 key
-- (kept beside the database). A chain alone cannot show a truncated tail or a rewrite of
-- every hash; a checkpoint's signature can.
CREATE TABLE audit_checkpoints (
    id INTEGER PRIMARY KEY,
    entry_id INTEGER NOT NULL,
    head_hash TEXT NOT NULL,
    at INTEGER NOT NULL,
    public_key TEXT NOT NULL,
    signature TEXT NOT NULL
);
CREATE TRIGGER audit_checkpoints_no_update BEFORE UPDATE ON audit_checkpoints
BEGIN SELECT RAISE(ABORT, 'audit_checkpoints is append-only'); END;
CREATE TRIGGER audit_checkpoints_no_delete BEFORE DELETE ON audit_checkpoints
BEGIN SELECT RAISE(ABORT, 'audit_checkpoints is append-only'); END;
