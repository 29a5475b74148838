-- Personalized designs (issue 22): a study may tune its LQR designs to each subject's body
-- as their identification test fitted it. A trial records whether the design it runs
-- (`compensator_json`) is the subject's own; an identification records the designs tuned
-- from it, or why a design could not be (`PersonalDesign`s, JSON; NULL in a study that does
-- not personalize).
ALTER TABLE trials ADD COLUMN personalized INTEGER NOT NULL DEFAULT 0
    CHECK (personalized IN (0, 1));
ALTER TABLE identifications ADD COLUMN designs_json TEXT;
