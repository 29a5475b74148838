-- The locked consent form: as migrations/0030_locked_consent.sql (SQLite), in PostgreSQL's
-- dialect.
ALTER TABLE studies ADD COLUMN consent_text TEXT;
ALTER TABLE studies ADD COLUMN consent_sha256 TEXT;
ALTER TABLE subjects ADD COLUMN consent_sha256 TEXT;

CREATE TRIGGER studies_locked_consent BEFORE UPDATE OF consent_text, consent_sha256 ON studies
FOR EACH ROW WHEN (OLD.consent_text IS NOT NULL)
EXECUTE FUNCTION refuse('the study''s consent form is locked');
