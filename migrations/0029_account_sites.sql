-- Per-site roles (issue 37): an account may be limited to some of the sites one server
-- serves (`serve --site`). A limited account starts, aborts and resets the E-stop of, and
-- runs the bench on, the machines of its sites only; any account still presses any E-stop.
-- An account with no row here is limited to no site: it may drive every site's machine, as
-- every account did before this migration (so existing accounts keep working). Names are
-- those `serve --site` gave when an admin set them; a name the server no longer serves
-- allows nothing. Admins set them (`experimenter.sites` in the audit log).
CREATE TABLE experimenter_sites (
    experimenter_id INTEGER NOT NULL REFERENCES experimenters(id),
    site            TEXT    NOT NULL,
    PRIMARY KEY (experimenter_id, site)
);
