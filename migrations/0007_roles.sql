-- Accounts with roles (issue 10). `admin` manages accounts and does everything an
-- experimenter does; `experimenter` runs studies; `analyst` only reads (results, exports,
-- the audit log) and may press the E-stop. The first account of an existing database was
-- made by the set-up link or --admin-password and becomes the admin; the others keep doing
-- what they did.
ALTER TABLE experimenters ADD COLUMN role TEXT NOT NULL DEFAULT 'experimenter'
    CHECK (role IN ('admin', 'experimenter', 'analyst'));
UPDATE experimenters SET role = 'admin' WHERE id = (SELECT MIN(id) FROM experimenters);

-- Accounts are disabled, never deleted: audit rows keep naming a real person.
ALTER TABLE experimenters ADD COLUMN disabled_at INTEGER;

-- The account an audit row was made by (NULL for the non-person actors: `subject:S01`,
-- `station:NAME`, `system:…`, `pilot (by alice)`, `anonymous:…`).
ALTER TABLE audit_log ADD COLUMN actor_id INTEGER REFERENCES experimenters(id);

-- Every new row names a real person, or a non-person actor that says what it is. Non-person
-- actors contain ':' or ' ', which usernames never do, so no actor can pass for an account
-- and no account can be named by a bare word such as "system".
CREATE TRIGGER audit_log_names_actor BEFORE INSERT ON audit_log
WHEN NEW.actor_id IS NULL AND instr(NEW.actor, ':') = 0 AND instr(NEW.actor, ' ') = 0
BEGIN SELECT RAISE(ABORT, 'audit actor is neither an account nor a described non-person actor'); END;
