//! The only SQL of the server: one module per table group. Reads take any executor (the
//! pool, or a transaction's connection); every change runs inside a [`Change`], which
//! commits the change and its audit row in one immediate transaction, so nothing is ever
//! half-stored and no change goes unaudited.
//!
//! *Invariant:* no module outside `store` writes SQL; only hashes of tokens are stored.
//!
//! Modules: `studies` (a study with its newest population version overlaid), `subjects` (with
//! notes), `trials` (with surveys), `records`, `exposure` (a subject's tests on the machine with
//! their figures), `identifications`, `stations`, `accounts` (with the sites an account is limited
//! to, `experimenter_sites`), `audit` (the log and the non-person actors it accepts), `audit_chain`
//! (each entry's hash chained to the one before — an HMAC under the chain key, never stored in the
//! database; the details hashed with a salt of the entry's own; rows from before 0028 in their
//! unkeyed format —, the signed checkpoints, the erasures' redaction records, and `verify`, which
//! pages through the log in bounded memory and names the first entry that fails), `exports`,
//! `configs` (configuration versions and a study's picks), `erasure` (one erasure's statements and
//! the erasures so far), `bench` (bench runs and results), `latch` (the E-stop latches as the store
//! records them beside each press's and reset's audit row — every site's at once, and each site's
//! own; the server's own latch is `machine::estop_latch`), `pilot_runs` (pilot processes, their
//! heartbeats and trials), `populations` (calibrated population versions), `dry_runs` (which
//! studies are dry runs and what each copies), `server_runs` (serving processes and their
//! heartbeats) and `process_runs` (what it shares with `pilot_runs`), `backups` (`VACUUM INTO`, the
//! integrity check, row counts and the migrations a file holds), `dialect` (`Dialect`: which SQL a
//! connection speaks where the two differ — the write lock, the audit page's JSON, a vacuum; its
//! own module so `audit_chain` reads it without importing `db`), `db` (open: every connection
//! through sqlx's `Any` driver, so each query is written once for both stores — `$N` placeholders,
//! `RETURNING id`, flags as integers read through `db::Flag` —; a `Location`, a SQLite file or a
//! `postgres://` URL; a file's path made absolute — its directory canonicalized — before it becomes
//! a `sqlite://` URL, which would shorten a leading `../..`; on SQLite WAL, foreign keys,
//! `secure_delete` so deleted content is overwritten, set on each connection; migrations —
//! `MIGRATOR`, and `POSTGRES_MIGRATOR` for PostgreSQL —; the write lock per dialect; a file opened
//! read-only as it is; folding the WAL in; the optional page cap; the time unit), `tokens`, and
//! `error_mapping_tests` (how database errors map to `AppError`). Rows map to the protocol's enums
//! (`TrialStatus`, `Seat`, `StationRole`, `ConsentDecision`, `CompensatorKind`).
//!
//! Migrations (`migrations/`): embedded, append-only, commented SQL (SQLite: the default store).
//! `migrations/postgres/` holds the same schema in PostgreSQL's dialect for the multi-site store
//! (its first migration, 0026, is the whole schema after SQLite's 0001–0026; every later migration
//! comes in both dialects under one number); the integration test `store_dialects` applies both and
//! compares them, and what their triggers refuse, against the PostgreSQL server the test command
//! starts; `the_servers_store_runs_on_postgres` runs the server's own store code there (migrate,
//! chain, a change, reopen). `serve` does not take a `postgres://` `--db` yet. Bench runs left
//! running by a stopped server are failed at start-up.
//!
//! More invariants:
//!
//! - A [`Change`] holds the store's one write lock from its start (SQLite's `BEGIN IMMEDIATE`; on
//!   PostgreSQL a transaction-scoped advisory lock every change takes, the same one-writer order);
//!   its audit row names a real account (with its id) or a non-person actor that says what it is
//!   (`audit` lists them; a trigger refuses a bare word); racing writers wait for the lock; a
//!   unique-constraint clash is a 409; a change dropped uncommitted closes its connection, so no
//!   connection goes back to the pool inside a transaction — not even one SQLite rolled back by
//!   itself on a full disk.
//! - An audit row's detail is a type of the module that commits it (shapes several actions share
//!   are one type: `audit::NoDetail`, `audit::Reason`), stored by `json_text` with its keys in
//!   sorted order, as the log has always held them.
//! - An audit entry without a keyed hash counts only up to the newest signed checkpoint, a
//!   redaction marker only where its erasure recorded it.
//! - A trial takes a result only while `running`; a trial marked invalid while it runs
//!   (`invalid_reason`) is filed invalid whatever the outcome, never complete; `next` follows the
//!   queue (block, then `queue_order`), not the schedule's `slot`.
//! - The audit log is append-only (SQL triggers refuse UPDATE and DELETE; the one exception, 0021,
//!   lets an erasure replace only the details of the rows older than it about its subject by the
//!   redaction marker naming it); an erased subject never changes again and gets no tests; a
//!   subject is marked erased only with its erasure's audit row; a locked study's parameters cannot
//!   change (trigger).
//! - The audit chain and its checkpoints are append-only too (0023), and so are the entries' salts
//!   and the redaction records (0028; a salt is deleted only once its entry's details are the
//!   redaction marker); every audit row is chained and salted in the transaction that appends it.
//! - A study's `version` goes up with every edit, and an edit names the version it was based on (a
//!   stale one is a 409 with the current study).
//! - A configuration version is immutable (triggers); a trial's `config_id` is set by a trigger at
//!   insertion from the picks of its study (or of the study a dry run copies), only when its design
//!   is the picked version's design to the byte.

pub mod accounts;
pub mod audit;
pub mod audit_chain;
pub mod backups;
pub mod bench;
pub mod configs;
pub mod db;
pub mod dialect;
pub mod dry_runs;
pub mod erasure;
#[cfg(test)]
mod error_mapping_tests;
pub mod exports;
pub mod exposure;
pub mod identifications;
pub mod latch;
pub mod pilot_runs;
pub mod populations;
mod process_runs;
pub mod records;
pub mod server_runs;
pub mod stations;
pub mod studies;
pub mod subjects;
pub mod tokens;
pub mod trials;

use anyhow::Context;
use serde::Serialize;
use sqlx::pool::PoolConnection;
use sqlx::{Any, AnyConnection, AnyPool};

use crate::error::Result;

/// One change to the data and the audit row that records it, committed together.
///
/// The transaction takes the store's write lock at the start ([`db::begin_write`]: SQLite's
/// `BEGIN IMMEDIATE`), so two changes racing wait for each other (up to the busy timeout)
/// instead of one failing with "database is locked" when it upgrades a read to a write.
///
/// A change dropped before it committed (a refusal, an error on the way) is rolled back by
/// closing its connection rather than handing it back to the pool: after some errors (a
/// full disk, an I/O error) SQLite rolls the transaction back by itself, and a connection
/// whose transaction sqlx's own bookkeeping still counted open would refuse every later
/// change ("non-zero transaction depth") until it was recycled.
#[derive(Debug)]
pub struct Change {
    conn: PoolConnection<Any>,
    actor: String,
    committed: bool,
}

impl Change {
    /// Starts a change made by `actor`: a username, or a non-person actor as `audit` lists
    /// them (`subject:S01`, `station:NAME`, `system:WHAT`, `pilot (by NAME)`).
    pub async fn begin(pool: &AnyPool, actor: impl Into<String>) -> Result<Self> {
        let mut conn = pool.acquire().await?;
        db::begin_write(&mut conn).await?;
        Ok(Self {
            conn,
            actor: actor.into(),
            committed: false,
        })
    }

    /// The connection the change's statements run on.
    pub fn db(&mut self) -> &mut AnyConnection {
        &mut self.conn
    }

    /// Writes the audit row and commits everything. `detail` is what the action records (a
    /// type of the module that commits it, or one of `audit`'s shared ones), stored as JSON
    /// text by [`json_text`].
    pub async fn commit(
        mut self,
        action: &str,
        target: Option<String>,
        detail: impl Serialize,
    ) -> Result<()> {
        self.audit_also(action, target, detail).await?;
        self.finish().await
    }

    /// Writes an audit row for an event the change brings about besides itself (a test's
    /// filing taking its subject's exposure to an action value), in the same transaction;
    /// the change's own row is still written by `commit`.
    pub async fn audit_also(
        &mut self,
        action: &str,
        target: Option<String>,
        detail: impl Serialize,
    ) -> Result<()> {
        let detail = json_text(&detail)?;
        audit::append(&mut self.conn, &self.actor, action, target, &detail).await?;
        Ok(())
    }

    /// Commits the transaction as it stands.
    async fn finish(mut self) -> Result<()> {
        sqlx::query("COMMIT").execute(&mut *self.conn).await?;
        self.committed = true;
        Ok(())
    }

    /// Writes the audit row first, for a change whose statements need it to exist (an
    /// erasure: the SQL triggers let only a recorded erasure mark its subject erased and
    /// redact the subject's older rows, naming the erasure's row); the rest of the change
    /// then runs on the returned [`Audited`], which commits without another row.
    pub async fn audit_first(
        mut self,
        action: &str,
        target: Option<String>,
        detail: impl Serialize,
    ) -> Result<Audited> {
        let detail = json_text(&detail)?;
        let audit_id = audit::append(&mut self.conn, &self.actor, action, target, &detail).await?;
        Ok(Audited {
            change: self,
            audit_id,
        })
    }
}

/// A change whose audit row is already written ([`Change::audit_first`]).
#[derive(Debug)]
pub struct Audited {
    change: Change,
    /// The id of the change's audit row.
    pub audit_id: i64,
}

impl Audited {
    /// The connection the change's statements run on.
    pub fn db(&mut self) -> &mut AnyConnection {
        self.change.db()
    }

    /// Commits everything, the audit row with it.
    pub async fn commit(self) -> Result<()> {
        self.change.finish().await
    }
}

/// The JSON text of a detail the server stores (an audit row's, a station's timing figures):
/// through `serde_json::Value`, so every object's keys are in sorted order whatever the order
/// of its type's fields — the text these columns have held since they were written from
/// untyped JSON objects.
pub fn json_text(detail: &impl Serialize) -> Result<String> {
    Ok(serde_json::to_value(detail)
        .context("a detail to store as JSON")?
        .to_string())
}

impl Drop for Change {
    fn drop(&mut self) {
        if !self.committed {
            // Closing the connection rolls back whatever is left of the transaction.
            self.conn.close_on_drop();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::Change;

    /// A change that fails on a full disk (SQLite may roll the whole transaction back by
    /// itself then) leaves no connection behind in a transaction: the next changes work.
    #[tokio::test]
    async fn a_change_that_failed_on_a_full_disk_leaves_the_pool_usable() {
        let path = std::env::temp_dir().join(format!("bdft-change-{}.db", std::process::id()));
        let pool = super::db::open_capped(&path, Some(1024)).await.unwrap();
        sqlx::query("CREATE TABLE fill (b BLOB)")
            .execute(&pool)
            .await
            .unwrap();
        for _ in 0..3 {
            let mut change = Change::begin(&pool, "system:test").await.unwrap();
            let full = sqlx::query("INSERT INTO fill VALUES (zeroblob(8388608))")
                .execute(change.db())
                .await;
            assert!(full.is_err(), "8 MiB do not fit under a 4 MiB cap");
        }
        let mut change = Change::begin(&pool, "system:test").await.unwrap();
        sqlx::query("INSERT INTO fill VALUES (zeroblob(1024))")
            .execute(change.db())
            .await
            .unwrap();
        change
            .commit("test.fill", None, super::audit::NoDetail {})
            .await
            .unwrap();
        pool.close().await;
        for suffix in ["", "-wal", "-shm"] {
            let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
        }
    }
}
