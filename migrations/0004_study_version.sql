-- Optimistic concurrency on study edits (server/src/engine/studies.rs): an edit of a study's
-- name or parameters names the version it was based on and makes the next one; an edit based
-- on an older version is refused with a 409 that carries the current study, so of two
-- experimenters editing one study the second cannot silently overwrite the first.
-- Existing studies start at version 1.
ALTER TABLE studies ADD COLUMN version INTEGER NOT NULL DEFAULT 1;
