-- Machine conditions (issue 41): the condition the machine ran under (stilts, tires,
-- outriggers, loaded[:fill], stick, joined by '+'; `MachineCondition`) — every test of a
-- study, and every bench run. Rows from before it ran on the thesis's rig.
ALTER TABLE trials ADD COLUMN condition TEXT NOT NULL DEFAULT 'stilts';
ALTER TABLE bench_runs ADD COLUMN condition TEXT NOT NULL DEFAULT 'stilts';
