-- Erasure on request (issue 23; server/src/engine/operations/erasure.rs, store/erasure.rs).
-- An admin erases a subject: their trials, records, surveys and notes are deleted, the
-- subject's row keeps only what stops its id, code and enrolment index from being handed to
-- someone else (id, study, code, enrolment index, starting seat — a function of the index —,
-- synthetic flag), and the audit log keeps that the erasure happened, when, by whom, why,
-- and the code. The erasure is one transaction, in this order: its audit row
-- (`subject.erase`, target `subject:ID`), the subject's row marked erased, the details of
-- the older audit rows about the subject replaced by a redaction marker, the data deleted.

-- When the subject was erased (the time of its `subject.erase` audit row).
ALTER TABLE subjects ADD COLUMN erased_at INTEGER;

-- A subject is marked erased only when its erasure is in the audit log: no erasure goes
-- unrecorded.
CREATE TRIGGER subjects_erasure_is_audited BEFORE UPDATE OF erased_at ON subjects
WHEN NEW.erased_at IS NOT NULL AND NOT EXISTS (
    SELECT 1 FROM audit_log WHERE action = 'subject.erase' AND target = 'subject:' || NEW.id)
BEGIN SELECT RAISE(ABORT, 'a subject is erased only together with its subject.erase audit row'); END;

-- An erased subject never changes again (no consent, withdrawal or un-erasing), and gets no
-- new tests.
CREATE TRIGGER subjects_erased_is_final BEFORE UPDATE ON subjects
WHEN OLD.erased_at IS NOT NULL
BEGIN SELECT RAISE(ABORT, 'the subject''s data were erased; an erased subject does not change'); END;
CREATE TRIGGER trials_not_of_erased BEFORE INSERT ON trials
WHEN (SELECT erased_at FROM subjects WHERE id = NEW.subject_id) IS NOT NULL
BEGIN SELECT RAISE(ABORT, 'the subject''s data were erased; an erased subject gets no tests'); END;

-- The audit log stays append-only with one narrow exception: the details (`detail_json`,
-- and nothing else of the row) of a row about an erased subject may be replaced by the
-- marker {"erasure": E, "redacted": "subject.erase"}, where E is the id of that subject's
-- `subject.erase` row, and only for rows older than it. A row is about the subject when its
-- target is the subject or one of the subject's trials (which still exist at that point of
-- the erasure), or its details name the subject's id (`station.assign`). The erasure row
-- itself is never redacted, and rows are still never deleted (audit_log_no_delete). Every
-- comparison is NULL-safe and an unknown outcome refuses (COALESCE … 0): a NULL can never
-- open the exception.
DROP TRIGGER audit_log_no_update;
CREATE TRIGGER audit_log_no_update BEFORE UPDATE ON audit_log
WHEN NOT COALESCE((
    NEW.id IS OLD.id AND NEW.at IS OLD.at AND NEW.actor IS OLD.actor
    AND NEW.actor_id IS OLD.actor_id AND NEW.action IS OLD.action AND NEW.target IS OLD.target
    AND OLD.action IS NOT 'subject.erase'
    AND EXISTS (
        SELECT 1 FROM audit_log e JOIN subjects s ON e.target = 'subject:' || s.id
        WHERE e.action = 'subject.erase' AND e.id > OLD.id AND s.erased_at IS NOT NULL
          AND NEW.detail_json = json_object('erasure', e.id, 'redacted', 'subject.erase')
          AND (OLD.target = e.target
               OR OLD.target IN (SELECT 'trial:' || t.id FROM trials t WHERE t.subject_id = s.id)
               OR json_extract(OLD.detail_json, '$.subject_id') = s.id)
    )
), 0)
BEGIN SELECT RAISE(ABORT, 'audit_log is append-only (only an erasure redacts the details of the rows about its subject)'); END;
