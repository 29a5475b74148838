-- Sites (issue 23): one server serves several labs, each with its own controller (`serve
-- --site NAME[=ADDRESS,KEY_FILE]`). A station belongs to one site, chosen when it is paired
-- (NULL: paired before sites existed, so the server's first site). A trial records the site
-- whose machine ran it when it starts (NULL: never started, or started before sites), and so
-- does a bench run on the real rig (NULL: simulated in the server, or before sites).
-- Each site's E-stop latch is a row of `site_estop_latch`, set and reset by name; the one
-- row of `estop_latch` stays the latch of every site at once (the E-stop of all sites).
ALTER TABLE stations ADD COLUMN site TEXT;
ALTER TABLE trials ADD COLUMN site TEXT;
ALTER TABLE bench_runs ADD COLUMN site TEXT;
CREATE TABLE site_estop_latch (
    site       TEXT PRIMARY KEY,
    latched    INTEGER NOT NULL CHECK (latched IN (0, 1)),
    changed_at INTEGER NOT NULL
);
