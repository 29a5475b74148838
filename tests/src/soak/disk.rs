//! The soak's disk: the server runs with its database capped at `cap` pages
//! (`--db-max-pages`, SQLite's `max_page_count`), and the soak keeps the room under the cap
//! small with ballast rows of its own in the same file, as other files on a small disk would.
//! Outside a fault it keeps about `reserve` pages free (deleting ballast as the study's data
//! grow); a disk-full fault fills the rest, so that every write the server makes that needs
//! a new page fails ("database or disk is full"), and frees it again afterwards.
//!
//! The ballast is a table `soak_ballast` the product never reads; it is dropped at the end,
//! before the database's integrity is checked and the exports are read.

use std::path::Path;
use std::str::FromStr;
use std::time::Duration;

use sqlx::sqlite::{SqliteConnectOptions, SqlitePoolOptions};
use sqlx::{Row, SqlitePool};

/// Pages of one ballast row at most (1 MiB of 4 KiB pages).
const ROW_PAGES: i64 = 256;

/// The ballast of one database.
#[derive(Debug)]
pub struct Ballast {
    rt: tokio::runtime::Runtime,
    pool: SqlitePool,
    cap: i64,
    reserve: i64,
    page_size: i64,
}

impl Ballast {
    /// Opens `db` (made by the server, whose cap is `cap` pages) beside the server.
    pub fn open(db: &Path, cap: u32, reserve: u32) -> Result<Self, String> {
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .map_err(|e| e.to_string())?;
        let pool = rt.block_on(async {
            let opts = SqliteConnectOptions::from_str(&format!("sqlite://{}", db.display()))?
                .busy_timeout(Duration::from_secs(30));
            let pool = SqlitePoolOptions::new()
                .max_connections(1)
                .connect_with(opts)
                .await?;
            sqlx::query(
                "CREATE TABLE IF NOT EXISTS soak_ballast (id INTEGER PRIMARY KEY, kind TEXT NOT NULL, fill BLOB NOT NULL)",
            )
            .execute(&pool)
            .await?;
            Ok::<_, sqlx::Error>(pool)
        });
        let pool = pool.map_err(|e| format!("opening {} for the ballast: {e}", db.display()))?;
        let mut b = Self {
            rt,
            pool,
            cap: i64::from(cap),
            reserve: i64::from(reserve),
            page_size: 4096,
        };
        b.page_size = b.pragma("page_size")?;
        Ok(b)
    }

    fn pragma(&self, name: &str) -> Result<i64, String> {
        self.rt
            .block_on(sqlx::query(&format!("PRAGMA {name}")).fetch_one(&self.pool))
            .and_then(|r| r.try_get::<i64, _>(0))
            .map_err(|e| format!("PRAGMA {name}: {e}"))
    }

    /// Pages the server may still take: below the cap, and free inside the file.
    pub fn room(&self) -> Result<i64, String> {
        Ok(self.cap - self.pragma("page_count")? + self.pragma("freelist_count")?)
    }

    /// Pages the ballast holds.
    pub fn pages(&self) -> Result<i64, String> {
        let bytes: i64 = self
            .rt
            .block_on(
                sqlx::query("SELECT COALESCE(SUM(length(fill)), 0) FROM soak_ballast")
                    .fetch_one(&self.pool),
            )
            .and_then(|r| r.try_get(0))
            .map_err(|e| e.to_string())?;
        Ok(bytes / self.page_size)
    }

    fn insert(&self, kind: &str, pages: i64) -> Result<(), String> {
        // An overflow page holds its size less a 4-byte link.
        let bytes = pages * (self.page_size - 4);
        self.rt
            .block_on(
                sqlx::query("INSERT INTO soak_ballast (kind, fill) VALUES (?, zeroblob(?))")
                    .bind(kind)
                    .bind(bytes)
                    .execute(&self.pool),
            )
            .map(|_| ())
            .map_err(|e| format!("adding ballast: {e}"))
    }

    /// Outside a fault: about `reserve` pages of room (ballast added while there is more
    /// than twice as much, removed while there is less than half). `Err` when the ballast
    /// is gone and the room still runs out: the run outgrew the cap it was given.
    pub fn keep_room(&self) -> Result<(), String> {
        let mut room = self.room()?;
        while room > 2 * self.reserve {
            self.insert("room", (room - self.reserve).min(ROW_PAGES))?;
            room = self.room()?;
        }
        while room < self.reserve / 2 {
            let deleted = self
                .rt
                .block_on(
                    sqlx::query(
                        "DELETE FROM soak_ballast WHERE id = (SELECT MIN(id) FROM soak_ballast WHERE kind = 'room')",
                    )
                    .execute(&self.pool),
                )
                .map_err(|e| format!("removing ballast: {e}"))?
                .rows_affected();
            if deleted == 0 {
                return Err(format!(
                    "the database outgrew its cap of {} pages: {room} pages of room left and no ballast to remove (the soak sized the cap too small)",
                    self.cap
                ));
            }
            room = self.room()?;
        }
        Ok(())
    }

    /// The disk fills: ballast until no page is left below the cap (nor free in the file).
    pub fn fill(&self) -> Result<(), String> {
        let mut room = self.room()?;
        while room >= 0 {
            self.insert("fill", (room + 1).min(ROW_PAGES))?;
            room = self.room()?;
        }
        Ok(())
    }

    /// The disk has room again: the fill is removed.
    pub fn release(&self) -> Result<(), String> {
        self.rt
            .block_on(
                sqlx::query("DELETE FROM soak_ballast WHERE kind = 'fill'").execute(&self.pool),
            )
            .map(|_| ())
            .map_err(|e| format!("removing the fill: {e}"))
    }

    /// Removes the ballast table (the database as the server left it).
    pub fn remove(self) -> Result<(), String> {
        self.rt
            .block_on(async {
                sqlx::query("DROP TABLE IF EXISTS soak_ballast")
                    .execute(&self.pool)
                    .await?;
                self.pool.close().await;
                Ok::<_, sqlx::Error>(())
            })
            .map_err(|e| format!("dropping the ballast: {e}"))
    }
}

/// `PRAGMA integrity_check` and `PRAGMA foreign_key_check` of `db`: what they reported
/// beyond "ok" (nothing when the database is sound).
pub fn integrity(db: &Path) -> Result<Vec<String>, String> {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .map_err(|e| e.to_string())?;
    rt.block_on(async {
        let opts =
            SqliteConnectOptions::from_str(&format!("sqlite://{}", db.display()))?.read_only(true);
        let pool = SqlitePoolOptions::new()
            .max_connections(1)
            .connect_with(opts)
            .await?;
        let mut problems = Vec::new();
        for row in sqlx::query("PRAGMA integrity_check")
            .fetch_all(&pool)
            .await?
        {
            let line: String = row.try_get(0)?;
            if line != "ok" {
                problems.push(format!("integrity_check: {line}"));
            }
        }
        for row in sqlx::query("PRAGMA foreign_key_check")
            .fetch_all(&pool)
            .await?
        {
            let table: String = row.try_get(0)?;
            let rowid: Option<i64> = row.try_get(1)?;
            problems.push(format!("foreign_key_check: {table} row {rowid:?}"));
        }
        pool.close().await;
        Ok::<_, sqlx::Error>(problems)
    })
    .map_err(|e| format!("checking {}: {e}", db.display()))
}
