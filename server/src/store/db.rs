//! The SQLite database: one file, WAL mode, created if missing, migrations applied at start;
//! the time unit of every column.

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use anyhow::Context;
use sqlx::sqlite::{SqliteConnectOptions, SqliteJournalMode, SqlitePoolOptions, SqliteSynchronous};
use sqlx::{ConnectOptions, Connection, SqliteConnection, SqlitePool};

/// Opens (creating if needed) the database at `path` and brings its schema up to date.
pub async fn open(path: &Path) -> anyhow::Result<SqlitePool> {
    open_with(path, 8).await
}

/// As [`open`], with one connection: a database only this process works on (a restore's
/// copy), whose journal mode [`leave_wal`] can then change.
pub async fn open_alone(path: &Path) -> anyhow::Result<SqlitePool> {
    open_with(path, 1).await
}

async fn open_with(path: &Path, connections: u32) -> anyhow::Result<SqlitePool> {
    let url = format!("sqlite://{}", path.display());
    let opts = SqliteConnectOptions::from_str(&url)
        .with_context(|| format!("database path {}", path.display()))?
        .create_if_missing(true)
        .journal_mode(SqliteJournalMode::Wal)
        // NORMAL in WAL mode: a power cut may lose the last transactions but never corrupts.
        .synchronous(SqliteSynchronous::Normal)
        .foreign_keys(true)
        .busy_timeout(Duration::from_secs(10));
    let pool = SqlitePoolOptions::new()
        .max_connections(connections)
        .connect_with(opts)
        .await
        .with_context(|| format!("opening the database {}", path.display()))?;
    MIGRATOR.run(&pool).await.context("applying migrations")?;
    Ok(pool)
}

/// The migrations this program knows (embedded at build time).
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

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
