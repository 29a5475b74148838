-- The keyed audit chain: as migrations/0028_keyed_audit_chain.sql (SQLite), in PostgreSQL's
-- types; the triggers as the base schema writes them (`refuse()`, a function per rule).
ALTER TABLE audit_chain ADD COLUMN format BIGINT NOT NULL DEFAULT 0 CHECK (format IN (0, 1, 2));

CREATE TABLE audit_salts (
    entry_id BIGINT PRIMARY KEY,
    salt     TEXT   NOT NULL
);
CREATE TRIGGER audit_salts_no_update BEFORE UPDATE ON audit_salts
FOR EACH ROW EXECUTE FUNCTION refuse('audit_salts is append-only');

CREATE FUNCTION audit_salts_only_redacted() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    IF NOT EXISTS (SELECT 1 FROM audit_log WHERE id = OLD.entry_id
                   AND detail_json LIKE '{"erasure":%,"redacted":"subject.erase"}') THEN
        RAISE EXCEPTION 'an audit entry''s salt is deleted only with its details, by an erasure';
    END IF;
    RETURN OLD;
END;
$$;
CREATE TRIGGER audit_salts_only_redacted BEFORE DELETE ON audit_salts
FOR EACH ROW EXECUTE FUNCTION audit_salts_only_redacted();

CREATE TABLE audit_redactions (
    entry_id   BIGINT PRIMARY KEY,
    erasure_id BIGINT NOT NULL,
    mac        TEXT   NOT NULL
);
CREATE TRIGGER audit_redactions_no_update BEFORE UPDATE ON audit_redactions
FOR EACH ROW EXECUTE FUNCTION refuse('audit_redactions is append-only');
CREATE TRIGGER audit_redactions_no_delete BEFORE DELETE ON audit_redactions
FOR EACH ROW EXECUTE FUNCTION refuse('audit_redactions is append-only');
