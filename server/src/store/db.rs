//! The SQLite database: one file, WAL mode, deleted content overwritten (`secure_delete`),
//! created if missing, migrations applied at start; the time unit of every column.

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use anyhow::Context;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::{ConnectOptions, Connection, SqliteConnection, SqlitePool};

/// Opens (creating if needed) the database at `path` and brings its schema up to date.
pub async fn open(path: &Path) -> anyhow::Result<SqlitePool> {
    open_with(path, 8, None).await
}

/// [`open`], every connection refusing to grow the file beyond `max_pages` pages when given
/// (SQLite's `max_page_count`: a write that needs another page fails with "database or disk
/// is full", as on a full disk; the soak test's full disk).
pub async fn open_capped(path: &Path, max_pages: Option<u32>) -> anyhow::Result<SqlitePool> {
    open_with(path, 8, max_pages).await
}

/// As [`open`], with one connection: a database only this process works on (a restore's
/// copy), whose journal mode [`leave_wal`] can then change.
pub async fn open_alone(path: &Path) -> anyhow::Result<SqlitePool> {
    open_with(path, 1, None).await
}

async fn open_with(
    path: &Path,
    connections: u32,
    max_pages: Option<u32>,
) -> anyhow::Result<SqlitePool> {
    let url = format!("sqlite://{}", path.display());
    let opts = SqliteConnectOptions::from_str(&url)
        .with_context(|| format!("database path {}", path.display()))?
        .create_if_missing(true)
        .journal_mode(SqliteJournalMode::Wal)
        // NORMAL in WAL mode: a power cut may lose the last transactions but never corrupts.
        .synchronous(SqliteSynchronous::Normal)
        .foreign_keys(true)
        // Deleted rows are overwritten with zeros, not left in free pages: an erased
        // subject's data must not stay readable in the file (`erasure`).
        .pragma("secure_delete", "on")
        .busy_timeout(Duration::from_secs(10));
    let opts = match max_pages {
        Some(n) => opts.pragma("max_page_count", n.to_string()),
        None => opts,
    };
    let pool = SqlitePoolOptions::new()
        .max_connections(connections)
        .connect_with(opts)
        .await
        .with_context(|| format!("opening the database {}", path.display()))?;
    MIGRATOR.run(&pool).await.context("applying migrations")?;
    // Rows an earlier release wrote join the audit chain before anything is appended.
    let mut tx = pool.begin_with("BEGIN IMMEDIATE").await?;
    super::audit_chain::chain_late(&mut tx)
        .await
        .map_err(|e| anyhow::anyhow!(e.describe()))
        .context("chaining the audit log")?;
    tx.commit().await?;
    Ok(pool)
}

/// The migrations this program knows (embedded at build time).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// How many rows a connection's worker reads ahead of its reader.
const READ_BATCH_ROWS: usize = 4096;

/// One read-only connection to the database file at `path`, as it is: nothing created,
/// nothing migrated (a backup being checked, or a database a restore would replace).
pub async fn open_read_only(path: &Path) -> anyhow::Result<SqliteConnection> {
    if !path.is_file() {
        anyhow::bail!("no such file");
    }
    SqliteConnectOptions::new()
        .filename(path)
        .read_only(true)
        .busy_timeout(Duration::from_secs(10))
        // Whole tables are read through it (a backup's checks, the audit chain's
        // verification): rows handed over in large batches, not one thread switch each.
        .row_buffer_size(READ_BATCH_ROWS)
        .connect()
        .await
        .context("opening it read-only")
}

/// Folds the write-ahead log of a database opened with [`open_alone`] into its file and
/// leaves it in rollback-journal mode: one file, whole, once the pool is closed.
pub async fn leave_wal(pool: &SqlitePool) -> anyhow::Result<()> {
    let (mode,): (String,) = sqlx::query_as("PRAGMA journal_mode = DELETE")
        .fetch_one(pool)
        .await?;
    anyhow::ensure!(mode == "delete", "the journal mode stayed {mode}");
    Ok(())
}

/// Folds the database's write-ahead log into its file and leaves it in rollback-journal
/// mode, one file that can be renamed whole (the server turns WAL back on when it opens it).
/// Nobody else may have it open.
pub async fn fold_into_one_file(path: &Path) -> anyhow::Result<()> {
    let conn = SqliteConnectOptions::new()
        .filename(path)
        .journal_mode(SqliteJournalMode::Delete)
        .busy_timeout(Duration::from_secs(10))
        .connect()
        .await
        .context("folding its write-ahead log in")?;
    conn.close().await?;
    let mut wal = path.as_os_str().to_os_string();
    wal.push("-wal");
    if Path::new(&wal).exists() {
        anyhow::bail!(
            "its write-ahead log {} is still there: another process has the database open",
            Path::new(&wal).display()
        );
    }
    Ok(())
}

/// Milliseconds since the Unix epoch, the unit of every time column.
pub fn now_ms() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as i64)
}

/// RFC 3339 UTC text of a time column, always with milliseconds (so the text sorts as the
/// time does): `2026-11-22T07:03:24.650Z`.
pub fn rfc3339(ms: i64) -> String {
    match time::OffsetDateTime::from_unix_timestamp_nanos(i128::from(ms) * 1_000_000) {
        Ok(t) => format!(
            "{:04}-{:02}-{:02}T{:02}:{:02}:{:02}.{:03}Z",
            t.year(),
            u8::from(t.month()),
            t.day(),
            t.hour(),
            t.minute(),
            t.second(),
            t.millisecond()
        ),
        Err(_) => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use crate::error::{AppError, DISK_FULL};

    /// A database capped at 1024 pages (4 MiB) takes 3 MiB, then refuses the next 3 MiB
    /// with the full disk's answer; what fits after a delete is taken again.
    #[tokio::test]
    async fn a_capped_database_refuses_to_grow_as_a_full_disk_does() {
        let path = std::env::temp_dir().join(format!("bdft-capped-{}.db", std::process::id()));
        let pool = super::open_capped(&path, Some(1024)).await.unwrap();
        sqlx::query("CREATE TABLE fill (b BLOB)")
            .execute(&pool)
            .await
            .unwrap();
        let insert = |mib: i64| {
            sqlx::query("INSERT INTO fill VALUES (zeroblob(?))")
                .bind(mib * 1024 * 1024)
                .execute(&pool)
        };
        insert(3).await.unwrap();
        let full = AppError::from(insert(3).await.unwrap_err());
        assert!(
            matches!(&full, AppError::Unavailable(m) if m == DISK_FULL),
            "{full:?}"
        );
        sqlx::query("DELETE FROM fill")
            .execute(&pool)
            .await
            .unwrap();
        insert(3).await.unwrap();
        pool.close().await;
        for suffix in ["", "-wal", "-shm"] {
            let _ = std::fs::remove_file(format!("{}{suffix}", path.display()));
        }
    }

    #[test]
    fn times_have_fixed_width_and_sort_as_text() {
        assert_eq!(super::rfc3339(0), "1970-01-01T00:00:00.000Z");
        // Unix time 10⁹ s is 2001-09-09T01:46:40Z.
        assert_eq!(
            super::rfc3339(1_000_000_000_700),
            "2001-09-09T01:46:40.700Z"
        );
        assert!(super::rfc3339(1_000_000_000_700) < super::rfc3339(1_000_000_000_746));
    }
}
