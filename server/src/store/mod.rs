//! The only SQL of the server: one module per table group. Reads take any executor (the
//! pool, or a transaction's connection); every change runs inside a [`Change`], which
//! commits the change and its audit row in one immediate transaction, so nothing is ever
//! half-stored and no change goes unaudited.
//!
//! *Invariant:* no module outside `store` writes SQL; only hashes of tokens are stored.

pub mod accounts;
pub mod audit;
pub mod backups;
pub mod bench;
pub mod configs;
pub mod db;
pub mod dry_runs;
pub mod exports;
pub mod latch;
pub mod pilot_runs;
pub mod populations;
pub mod records;
pub mod server_runs;
pub mod stations;
pub mod studies;
pub mod subjects;
pub mod tokens;
pub mod trials;

use anyhow::Context;
use serde::Serialize;
use sqlx::{Sqlite, SqliteConnection, SqlitePool, Transaction};

use crate::error::Result;

/// One change to the data and the audit row that records it, committed together.
///
/// The transaction is `BEGIN IMMEDIATE`: it takes SQLite's write lock at the start, so two
/// changes racing wait for each other (up to the busy timeout) instead of one failing with
/// "database is locked" when it upgrades a read to a write.
#[derive(Debug)]
pub struct Change {
    tx: Transaction<'static, Sqlite>,
    actor: String,
}

impl Change {
    /// Starts a change made by `actor`: a username, or a non-person actor as `audit` lists
    /// them (`subject:S01`, `station:NAME`, `system:WHAT`, `pilot (by NAME)`).
    pub async fn begin(pool: &SqlitePool, actor: impl Into<String>) -> Result<Self> {
        Ok(Self {
            tx: pool.begin_with("BEGIN IMMEDIATE").await?,
            actor: actor.into(),
        })
    }

    /// The connection the change's statements run on.
    pub fn db(&mut self) -> &mut SqliteConnection {
        &mut self.tx
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
        let detail = json_text(&detail)?;
        audit::append(&mut self.tx, &self.actor, action, target, &detail).await?;
        self.tx.commit().await?;
        Ok(())
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
