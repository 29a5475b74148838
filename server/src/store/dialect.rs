//! Which SQL a store speaks, where SQLite and PostgreSQL differ (locking, JSON, a backup).

use sqlx::{AnyConnection, AnyPool};

/// Which SQL a connection speaks, where the two differ (locking, an upsert, a backup).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dialect {
    Sqlite,
    Postgres,
}

impl Dialect {
    /// The dialect of an open connection.
    pub fn of(conn: &AnyConnection) -> Self {
        Self::named(conn.backend_name())
    }

    /// The dialect of a pool's connections.
    pub fn of_pool(pool: &AnyPool) -> Self {
        if pool
            .connect_options()
            .database_url
            .scheme()
            .starts_with("postgres")
        {
            Self::Postgres
        } else {
            Self::Sqlite
        }
    }

    fn named(backend: &str) -> Self {
        if backend == "PostgreSQL" {
            Self::Postgres
        } else {
            Self::Sqlite
        }
    }

    /// The statement that starts a change: it takes the store's one write lock at the
    /// start, so two changes racing wait for each other instead of one failing when it
    /// upgrades a read to a write (SQLite's `IMMEDIATE`; on PostgreSQL a transaction-scoped
    /// advisory lock, which every change takes, gives the same one-writer order).
    pub fn begin_write(self) -> &'static str {
        match self {
            Self::Sqlite => "BEGIN IMMEDIATE",
            Self::Postgres => "BEGIN",
        }
    }

    /// What runs right after [`Self::begin_write`] to complete the write lock, if anything.
    pub fn write_lock(self) -> Option<&'static str> {
        match self {
            Self::Sqlite => None,
            Self::Postgres => Some("SELECT pg_advisory_xact_lock(2026120401)"),
        }
    }
}
