-- A synthetic subject's own parameters, drawn at enrolment from the study's population
-- (operator: delay, neuromuscular dynamics, gains, remnant, learning, fatigue; body:
-- transmissibility and arm admittance; survey bias). A flat JSON object of
-- column name → number, the names carrying their unit (`reaction_delay_s`), so an export can
-- lay them out as columns. NULL for a person: nothing about a person is drawn.
ALTER TABLE subjects ADD COLUMN drawn_json TEXT;
