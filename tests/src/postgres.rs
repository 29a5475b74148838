//! Databases on the test command's PostgreSQL server (`scripts/test.sh` starts one for the
//! run and names it in `BDFT_TEST_POSTGRES`, a Unix socket): each test makes one of its own.
//! `BDFT_TEST_STORE=postgres` runs every server the tests start on one of them instead of a
//! SQLite file.

use sqlx::postgres::PgConnectOptions;
use sqlx::{ConnectOptions, Connection};

/// Whether this run's servers use PostgreSQL (`BDFT_TEST_STORE=postgres`) rather than
/// SQLite files (unset, or `sqlite`); any other value is a mistake, not a default.
pub fn servers_on_postgres() -> bool {
    match std::env::var("BDFT_TEST_STORE").as_deref() {
        Err(_) | Ok("sqlite") => false,
        Ok("postgres") => true,
        Ok(other) => panic!("BDFT_TEST_STORE={other}: sqlite or postgres"),
    }
}

/// A database of its own on the test command's PostgreSQL server, dropped with this value.
#[derive(Debug)]
pub struct PgDatabase {
    server: PgConnectOptions,
    pub name: String,
}

impl PgDatabase {
    pub async fn new(tag: &str) -> Self {
        Self::created(tag, None).await
    }

    /// A copy of `self` (which nothing may be connected to), as `CREATE DATABASE … TEMPLATE`
    /// makes it.
    pub fn blocking_copy(&self, tag: &str) -> Self {
        runtime().block_on(Self::created(tag, Some(&self.name)))
    }

    async fn created(tag: &str, template: Option<&str>) -> Self {
        let url = std::env::var("BDFT_TEST_POSTGRES").expect(
            "BDFT_TEST_POSTGRES is not set: run the tests with scripts/test.sh, which starts a \
             PostgreSQL server for them (or set it to a postgres:// URL of a server whose user \
             may create databases)",
        );
        let server: PgConnectOptions = url.parse().expect("BDFT_TEST_POSTGRES is a postgres URL");
        let name = format!(
            "bdft_{tag}_{}_{}",
            std::process::id(),
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_nanos())
        )
        .replace(|c: char| !c.is_ascii_alphanumeric() && c != '_', "_");
        let mut admin = server.connect().await.expect("connecting to PostgreSQL");
        let from = template.map_or(String::new(), |t| format!(" TEMPLATE {t}"));
        sqlx::raw_sql(&format!("CREATE DATABASE {name}{from}"))
            .execute(&mut admin)
            .await
            .unwrap();
        admin.close().await.unwrap();
        Self { server, name }
    }

    /// [`Self::new`] outside a runtime.
    pub fn blocking_new(tag: &str) -> Self {
        runtime().block_on(Self::new(tag))
    }

    /// A pool on this database with the PostgreSQL migrations applied.
    pub async fn migrated(&self) -> sqlx::PgPool {
        let pool = sqlx::PgPool::connect_with(self.options()).await.unwrap();
        sqlx::migrate!("../migrations/postgres")
            .run(&pool)
            .await
            .expect("the PostgreSQL migrations apply to an empty database");
        pool
    }

    /// How to connect to this database.
    pub fn options(&self) -> PgConnectOptions {
        self.server.clone().database(&self.name)
    }

    /// This database's `postgres://` URL, as the server's `--db` takes it.
    pub fn url(&self) -> String {
        self.options().to_url_lossy().to_string()
    }
}

impl Drop for PgDatabase {
    /// Drops the database (closing what is still connected to it). On a thread of its own:
    /// the value may be dropped inside a test's runtime, which cannot block on another.
    fn drop(&mut self) {
        let server = self.server.clone();
        let name = std::mem::take(&mut self.name);
        let dropped = std::thread::spawn(move || {
            runtime().block_on(async {
                let mut admin = server.connect().await?;
                sqlx::raw_sql(&format!("DROP DATABASE IF EXISTS {name} WITH (FORCE)"))
                    .execute(&mut admin)
                    .await?;
                admin.close().await
            })
        })
        .join();
        if !std::thread::panicking() {
            dropped
                .expect("dropping a test database")
                .expect("dropping a test database");
        }
    }
}

fn runtime() -> tokio::runtime::Runtime {
    tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap()
}
