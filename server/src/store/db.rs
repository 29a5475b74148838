//! The database: by default one SQLite file (WAL mode, deleted content overwritten by
//! `secure_delete`, created if missing); or a PostgreSQL database shared by several labs
//! (`--db postgres://…`). Both through sqlx's `Any` driver, so every query is written once;
//! each dialect has its own migrations (`migrations/`, `migrations/postgres/`), applied at
//! start. Also the time unit of every column.

use std::path::Path;
use std::time::Duration;

use anyhow::Context;
use sqlx::any::{AnyConnectOptions, AnyPoolOptions};
use sqlx::{AnyConnection, AnyPool, ConnectOptions, Connection, Executor};

pub use super::dialect::Dialect;

/// Starts a write transaction on `conn` holding the store's write lock ([`Dialect::begin_write`]).
pub async fn begin_write(conn: &mut AnyConnection) -> sqlx::Result<()> {
    let dialect = Dialect::of(conn);
    conn.execute(dialect.begin_write()).await?;
    if let Some(lock) = dialect.write_lock() {
        conn.execute(lock).await?;
    }
    Ok(())
}

/// A transaction on `pool` holding the store's write lock ([`Dialect::begin_write`]).
pub async fn write_transaction(
    pool: &AnyPool,
) -> sqlx::Result<sqlx::Transaction<'static, sqlx::Any>> {
    let dialect = Dialect::of_pool(pool);
    let mut tx = pool.begin_with(dialect.begin_write()).await?;
    if let Some(lock) = dialect.write_lock() {
        tx.execute(lock).await?;
    }
    Ok(tx)
}

/// Makes sqlx's `Any` driver know SQLite and PostgreSQL (idempotent).
pub(crate) fn drivers() {
    sqlx::any::install_default_drivers();
}

/// Where the data live: a SQLite file, or a PostgreSQL database's URL (`postgres://…`).
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Location {
    File(std::path::PathBuf),
    Postgres(String),
}

impl std::str::FromStr for Location {
    type Err = std::convert::Infallible;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(
            if s.starts_with("postgres://") || s.starts_with("postgresql://") {
                Self::Postgres(s.to_string())
            } else {
                Self::File(s.into())
            },
        )
    }
}

impl std::fmt::Display for Location {
    /// The file's path, or the URL without its password (it goes into messages and logs).
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::File(path) => write!(f, "{}", path.display()),
            Self::Postgres(url) => f.write_str(&without_password(url)),
        }
    }
}

/// `url` with the password of its `user:password@` part, if any, written as `***`.
fn without_password(url: &str) -> String {
    let Some(scheme_end) = url.find("://").map(|i| i + 3) else {
        return url.to_string();
    };
    let authority_end = url[scheme_end..]
        .find(['/', '?', '#'])
        .map_or(url.len(), |i| scheme_end + i);
    let authority = &url[scheme_end..authority_end];
    match authority
        .rfind('@')
        .and_then(|at| Some((at, authority[..at].find(':')?)))
    {
        Some((at, colon)) => format!(
            "{}{}***{}",
            &url[..scheme_end],
            &authority[..=colon],
            &url[scheme_end + at..]
        ),
        None => url.to_string(),
    }
}

impl Location {
    /// The SQLite file, or an error naming `what` cannot be done on a PostgreSQL store
    /// (a file copy, a restore) and what to use there instead.
    pub fn file(&self, what: &str) -> anyhow::Result<&Path> {
        match self {
            Self::File(path) => Ok(path),
            Self::Postgres(_) => anyhow::bail!("--db {self}: {what} {ONLY_SQLITE_BACKUPS}"),
        }
    }

    /// Opens the store as [`open_location`] does, without a size cap.
    pub async fn open(&self) -> anyhow::Result<AnyPool> {
        open_location(self, None).await
    }
}

/// Why a backup or a restore is refused on a PostgreSQL store, and what to use there.
pub const ONLY_SQLITE_BACKUPS: &str = "works on a SQLite file; a PostgreSQL store is backed up and restored with PostgreSQL's own tools (pg_dump and pg_restore, or continuous archiving)";

/// Opens (creating if needed) the database at `path` and brings its schema up to date.
pub async fn open(path: &Path) -> anyhow::Result<AnyPool> {
    open_with(path, 8, None).await
}

/// Opens the store at `location` (a SQLite file as [`open_capped`] does, or a PostgreSQL
/// database) and brings its schema up to date.
pub async fn open_location(location: &Location, max_pages: Option<u32>) -> anyhow::Result<AnyPool> {
    match location {
        Location::File(path) => open_with(path, 8, max_pages).await,
        Location::Postgres(url) => open_postgres(url).await,
    }
}

/// [`open`], every connection refusing to grow the file beyond `max_pages` pages when given
/// (SQLite's `max_page_count`: a write that needs another page fails with "database or disk
/// is full", as on a full disk; the soak test's full disk).
pub async fn open_capped(path: &Path, max_pages: Option<u32>) -> anyhow::Result<AnyPool> {
    open_with(path, 8, max_pages).await
}

/// As [`open`], with one connection: a database only this process works on (a restore's
/// copy), whose journal mode [`leave_wal`] can then change.
pub async fn open_alone(path: &Path) -> anyhow::Result<AnyPool> {
    open_with(path, 1, None).await
}

/// The `sqlite://` URL of a file: the path made absolute first ([`resolved`]), then its
/// bytes outside the unreserved set and `/` percent-encoded (sqlx decodes them back), so a
/// `?`, `#` or `%` in a path stays a path.
fn sqlite_url(path: &Path, mode: &str) -> String {
    let path = resolved(path);
    let mut url = String::from("sqlite://");
    for b in path.as_os_str().as_encoded_bytes() {
        match b {
            b'A'..=b'Z' | b'a'..=b'z' | b'0'..=b'9' | b'-' | b'.' | b'_' | b'~' | b'/' => {
                url.push(char::from(*b));
            }
            _ => url.push_str(&format!("%{b:02X}")),
        }
    }
    url.push_str("?mode=");
    url.push_str(mode);
    url
}

/// `path` as an absolute path without `.` or `..` components, as the kernel resolves it:
/// its directory canonicalized (symbolic links followed, so `link/..` means what it means to
/// the kernel), its file name joined. A URL cannot carry a relative path: sqlx's `Any`
/// driver parses `sqlite://../../x` as the host `..` and the path `/../x`, which URL
/// parsing shortens to `/x` — the file `../x`, one level off — and it would shorten `a/..`
/// lexically too. A directory that cannot be canonicalized (it does not exist) leaves the
/// path made absolute against the working directory, for the open to fail naming it.
fn resolved(path: &Path) -> std::path::PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    match (absolute.parent(), absolute.file_name()) {
        (Some(dir), Some(name)) => match dir.canonicalize() {
            Ok(dir) => dir.join(name),
            Err(_) => absolute,
        },
        _ => absolute,
    }
}

/// How long a statement waits for another connection's write lock before "busy".
const BUSY_TIMEOUT: Duration = Duration::from_secs(10);

async fn open_with(
    path: &Path,
    connections: u32,
    max_pages: Option<u32>,
) -> anyhow::Result<AnyPool> {
    drivers();
    crate::files::create_database_file(path)
        .with_context(|| format!("creating the database {}", path.display()))?;
    let opts: AnyConnectOptions = sqlite_url(path, "rwc")
        .parse()
        .with_context(|| format!("database path {}", path.display()))?;
    let mut pragmas = vec![
        "PRAGMA journal_mode = WAL".to_string(),
        // NORMAL in WAL mode: a power cut may lose the last transactions but never corrupts.
        "PRAGMA synchronous = NORMAL".into(),
        "PRAGMA foreign_keys = ON".into(),
        // Deleted rows are overwritten with zeros, not left in free pages: an erased
        // subject's data must not stay readable in the file (`erasure`).
        "PRAGMA secure_delete = ON".into(),
        format!("PRAGMA busy_timeout = {}", BUSY_TIMEOUT.as_millis()),
    ];
    if let Some(n) = max_pages {
        pragmas.push(format!("PRAGMA max_page_count = {n}"));
    }
    let pool = AnyPoolOptions::new()
        .max_connections(connections)
        .after_connect(move |conn, _| {
            let pragmas = pragmas.clone();
            Box::pin(async move {
                for pragma in &pragmas {
                    conn.execute(pragma.as_str()).await?;
                }
                Ok(())
            })
        })
        .connect_with(opts)
        .await
        .with_context(|| format!("opening the database {}", path.display()))?;
    migrate(&pool, &MIGRATOR).await?;
    Ok(pool)
}

/// Opens the PostgreSQL database at `url` (which must exist) and migrates it.
async fn open_postgres(url: &str) -> anyhow::Result<AnyPool> {
    drivers();
    let opts: AnyConnectOptions = url.parse().context("the PostgreSQL URL")?;
    let pool = AnyPoolOptions::new()
        .max_connections(8)
        .acquire_timeout(BUSY_TIMEOUT)
        .connect_with(opts)
        .await
        .context("connecting to PostgreSQL")?;
    migrate(&pool, &POSTGRES_MIGRATOR).await?;
    Ok(pool)
}

async fn migrate(pool: &AnyPool, migrator: &sqlx::migrate::Migrator) -> anyhow::Result<()> {
    migrator.run(pool).await.context("applying migrations")?;
    // Rows an earlier release wrote join the audit chain before anything is appended.
    let mut tx = write_transaction(pool).await?;
    super::audit_chain::chain_late(&mut tx)
        .await
        .map_err(|e| anyhow::anyhow!(e.describe()))
        .context("chaining the audit log")?;
    tx.commit().await?;
    Ok(())
}

/// The migrations this program knows (embedded at build time), SQLite's.
pub static MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations");

/// The same schema in PostgreSQL's dialect: its first migration is SQLite's schema at
/// version 26 in one file; every later one exists in both.
pub static POSTGRES_MIGRATOR: sqlx::migrate::Migrator = sqlx::migrate!("../migrations/postgres");

/// One read-only connection to the database file at `path`, as it is: nothing created,
/// nothing migrated (a backup being checked, or a database a restore would replace).
pub async fn open_read_only(path: &Path) -> anyhow::Result<AnyConnection> {
    if !path.is_file() {
        anyhow::bail!("no such file");
    }
    drivers();
    let opts: AnyConnectOptions = sqlite_url(path, "ro").parse()?;
    let mut conn = opts.connect().await.context("opening it read-only")?;
    conn.execute(format!("PRAGMA busy_timeout = {}", BUSY_TIMEOUT.as_millis()).as_str())
        .await
        .context("opening it read-only")?;
    Ok(conn)
}

/// One read-only connection to the store at `location`, nothing created or migrated: the
/// file as [`open_read_only`] opens it, or a PostgreSQL session whose transactions are all
/// read-only.
pub async fn connect_read_only(location: &Location) -> anyhow::Result<AnyConnection> {
    match location {
        Location::File(path) => open_read_only(path).await,
        Location::Postgres(url) => {
            drivers();
            let opts: AnyConnectOptions = url.parse().context("the PostgreSQL URL")?;
            let mut conn = opts.connect().await.context("connecting to PostgreSQL")?;
            conn.execute("SET default_transaction_read_only = on")
                .await?;
            Ok(conn)
        }
    }
}

/// Which of `names` are tables of the connection's database (its schema on PostgreSQL).
pub async fn tables_named(conn: &mut AnyConnection, names: &[&str]) -> sqlx::Result<Vec<String>> {
    let sql = match Dialect::of(conn) {
        Dialect::Sqlite => "SELECT name FROM sqlite_master WHERE type = 'table'",
        // information_schema's names are a domain over `name`, which the Any driver does
        // not decode: cast to text.
        Dialect::Postgres => {
            "SELECT table_name::text FROM information_schema.tables WHERE table_schema = current_schema()"
        }
    };
    let all: Vec<String> = sqlx::query_scalar(sql).fetch_all(&mut *conn).await?;
    Ok(all
        .into_iter()
        .filter(|t| names.contains(&t.as_str()))
        .collect())
}

/// Folds the write-ahead log of a database opened with [`open_alone`] into its file and
/// leaves it in rollback-journal mode: one file, whole, once the pool is closed.
pub async fn leave_wal(pool: &AnyPool) -> anyhow::Result<()> {
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
    drivers();
    let opts: AnyConnectOptions = sqlite_url(path, "rw").parse()?;
    let mut conn = opts
        .connect()
        .await
        .context("folding its write-ahead log in")?;
    conn.execute(format!("PRAGMA busy_timeout = {}", BUSY_TIMEOUT.as_millis()).as_str())
        .await?;
    conn.execute("PRAGMA journal_mode = DELETE")
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

/// A 0/1 flag column read as a `bool`. Both stores keep flags as integers (SQLite has no
/// boolean; the PostgreSQL schema mirrors it), and sqlx's `Any` driver decodes a `bool` only
/// from a boolean value: a row field is read as `#[sqlx(try_from = "Flag")] field: bool`,
/// a tuple's as `Flag` and then `.0`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Flag(pub bool);

impl From<Flag> for bool {
    fn from(f: Flag) -> Self {
        f.0
    }
}

impl sqlx::Type<sqlx::Any> for Flag {
    fn type_info() -> sqlx::any::AnyTypeInfo {
        <i64 as sqlx::Type<sqlx::Any>>::type_info()
    }

    fn compatible(ty: &sqlx::any::AnyTypeInfo) -> bool {
        <i64 as sqlx::Type<sqlx::Any>>::compatible(ty)
            || <bool as sqlx::Type<sqlx::Any>>::compatible(ty)
    }
}

impl<'r> sqlx::Decode<'r, sqlx::Any> for Flag {
    fn decode(value: sqlx::any::AnyValueRef<'r>) -> Result<Self, sqlx::error::BoxDynError> {
        if <bool as sqlx::Type<sqlx::Any>>::compatible(&sqlx::ValueRef::type_info(&value)) {
            return <bool as sqlx::Decode<sqlx::Any>>::decode(value).map(Flag);
        }
        <i64 as sqlx::Decode<sqlx::Any>>::decode(value).map(|v| Flag(v != 0))
    }
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
            sqlx::query("INSERT INTO fill VALUES (zeroblob($1))")
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
    fn a_postgres_location_is_shown_without_its_password() {
        let shown = |s: &str| s.parse::<super::Location>().unwrap().to_string();
        assert_eq!(
            shown("postgres://lab:s3cr:et@db.example:5432/bdft?sslmode=require"),
            "postgres://lab:***@db.example:5432/bdft?sslmode=require"
        );
        assert_eq!(
            shown("postgres:///bdft?host=/run/postgresql&user=lab"),
            "postgres:///bdft?host=/run/postgresql&user=lab"
        );
        assert_eq!(
            shown("postgresql://lab@db/bdft"),
            "postgresql://lab@db/bdft"
        );
        assert_eq!(shown("data/bdft-lab.db"), "data/bdft-lab.db");
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
