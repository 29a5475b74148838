-- The stability gate (server/src/engine/stability.rs): a simulated study whose design is
-- unstable on the machine may be locked only after an experimenter acknowledged it. The
-- acknowledgement ({"by", "at", "reason"}) belongs to the parameters it was given for:
-- editing the study clears it. (Also in the audit log, as study.acknowledge_instability.)
ALTER TABLE studies ADD COLUMN instability_ack_json TEXT;
