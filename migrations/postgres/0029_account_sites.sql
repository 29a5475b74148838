-- Per-site roles: as migrations/0029_account_sites.sql (SQLite), in PostgreSQL's types.
CREATE TABLE experimenter_sites (
    experimenter_id BIGINT NOT NULL REFERENCES experimenters(id),
    site            TEXT   NOT NULL,
    PRIMARY KEY (experimenter_id, site)
);
