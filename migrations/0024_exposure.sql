-- ISO 2631-1 exposure of a test (issue 25): the W_d-weighted fore-aft cab acceleration's
-- r.m.s. a_w (m/s²) and vibration dose value (m/s^1.75) over the record, and the length of
-- the record they are over (s), as the controller's loop measured them. NULL for a test
-- filed before this release or without a result (a lost controller): such a test counts
-- towards its subject's day at its worst case (docs/exposure.md).
ALTER TABLE trials ADD COLUMN cab_aw_m_s2 REAL;
ALTER TABLE trials ADD COLUMN cab_vdv_m_s175 REAL;
ALTER TABLE trials ADD COLUMN exposure_s REAL;
