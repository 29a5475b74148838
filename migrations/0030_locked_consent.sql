-- The consent form as the lock rendered it (issue 39): its text, generated from the locked
-- protocol (`{procedure}`: every kind of test, its count and length, the shaking of the
-- seat, the exposure budget), and its SHA-256. Stations show this text from then on, so a
-- later release that words the description differently never changes what a running
-- study's subjects agree to. Each subject's decision records the hash of the text it was
-- made on. Studies locked before this migration have none: they are shown the form as
-- rendered now, and their subjects' decisions record its hash.
ALTER TABLE studies ADD COLUMN consent_text TEXT;
ALTER TABLE studies ADD COLUMN consent_sha256 TEXT;
ALTER TABLE subjects ADD COLUMN consent_sha256 TEXT;

-- Once written, the locked form never changes.
CREATE TRIGGER studies_locked_consent BEFORE UPDATE OF consent_text, consent_sha256 ON studies
WHEN OLD.consent_text IS NOT NULL
BEGIN SELECT RAISE(ABORT, 'the study''s consent form is locked'); END;
