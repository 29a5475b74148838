//! The audit log's hash chain, its signed checkpoints and its redaction records (migrations
//! 0023 and 0028): what makes an edit, a deletion, a reordering, an insertion, an appended
//! entry, a forged redaction or a truncation of the log show, even by someone who holds the
//! database and drops its triggers.
//!
//! Each audit row has a chain row holding `detail_hash`, the hash of its details, and
//! `hash`, the hash of the previous row's hash and the row's content (id, time, actor,
//! account, action, target, detail_hash). The content is taken through the details' hash so
//! that an erasure, which replaces the details of the rows about the erased subject by its
//! redaction marker, leaves the chain whole. How the hashes are made is the row's `format`:
//!
//! - [`Format::Keyed`] (every row this release writes with the audit key): `detail_hash` =
//!   SHA-256(salt ‖ details), the salt 16 random bytes of the entry's own in `audit_salts`;
//!   `hash` = HMAC-SHA256 under the chain key ([`ChainKey`], derived from the server's audit
//!   signing key in its keys directory, never in the database) of a fixed binary layout
//!   ([`Entry::message`]). Whoever holds only the database cannot make a row that verifies.
//! - [`Format::Salted`] (a process without the key, e.g. `pilot --db postgres://…` without
//!   `--keys-dir`): the same, with SHA-256 in place of the HMAC. Anybody could have made such
//!   a row, so it counts only once a signed checkpoint covers it; the server signs within a
//!   second of one (`engine::operations::audit_signing`).
//! - [`Format::Legacy`] (rows written before 0028): `detail_hash` = SHA-256(details), `hash`
//!   = SHA-256 of the previous hash, a newline and the JSON array `[id, at, actor, actor_id,
//!   action, target, detail_hash]`; covered by the checkpoints the server signed since.
//!
//! A checkpoint signs (Ed25519) the head at a moment: a chain alone cannot show a cut-off
//! tail or a rewrite of every unkeyed hash. An erasure records each entry it redacts in
//! `audit_redactions` with an HMAC of the entry, the erasure and the entry's hash, and
//! deletes the entry's salt; a redaction marker anywhere else is a forgery.

use bdft_protocol::hex;
use ed25519_dalek::{Signature, Signer, SigningKey, Verifier, VerifyingKey};
use hmac::{Hmac, Mac};
use serde::Serialize;
use sha2::{Digest, Sha256};
use std::collections::{HashMap, HashSet};
use std::sync::OnceLock;

use futures_util::TryStreamExt;
use sqlx::AnyConnection;

use crate::error::{AppError, Result};

/// The hash before the first entry.
pub const GENESIS: &str = "0000000000000000000000000000000000000000000000000000000000000000";

/// How a chain row's hashes were made (migration 0028's `format` column).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// Before 0028: unsalted details, SHA-256 of the JSON content.
    Legacy,
    /// Salted details, SHA-256 of the binary content: written without the audit key.
    Salted,
    /// Salted details, HMAC-SHA256 of the binary content under the chain key.
    Keyed,
}

impl Format {
    pub fn of(code: i64) -> Option<Self> {
        match code {
            0 => Some(Self::Legacy),
            1 => Some(Self::Salted),
            2 => Some(Self::Keyed),
            _ => None,
        }
    }

    pub fn code(self) -> i64 {
        match self {
            Self::Legacy => 0,
            Self::Salted => 1,
            Self::Keyed => 2,
        }
    }
}

/// The key of the chain's HMACs: HMAC-SHA256(the audit signing key's 32 secret bytes,
/// "bdft-lab audit chain key v1"), so it lives where that key lives (the keys directory, or
/// beside the SQLite file) and is backed up with it.
#[derive(Clone)]
pub struct ChainKey(Hmac<Sha256>);

impl std::fmt::Debug for ChainKey {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("ChainKey(…)")
    }
}

fn hmac_of(key: &[u8]) -> Hmac<Sha256> {
    match <Hmac<Sha256> as Mac>::new_from_slice(key) {
        Ok(mac) => mac,
        // HMAC takes a key of any length.
        Err(_) => unreachable!("HMAC-SHA256 takes any key"),
    }
}

impl ChainKey {
    pub fn from_signing_key(key: &SigningKey) -> Self {
        let mut derive = hmac_of(&key.to_bytes());
        derive.update(b"bdft-lab audit chain key v1");
        Self(hmac_of(&derive.finalize().into_bytes()))
    }

    fn mac(&self, message: &[u8]) -> [u8; 32] {
        // The keyed state is cloned: the key's pads are not hashed again for every entry.
        let mut mac = self.0.clone();
        mac.update(message);
        mac.finalize().into_bytes().into()
    }
}

/// The chain key of this process, set once when its keys are loaded (`serve`, or a command
/// that finds the key file): appends are keyed only with it.
static CHAIN_KEY: OnceLock<ChainKey> = OnceLock::new();

/// Makes `key` this process's chain key (a second, different key is refused: one process
/// serves one store).
pub fn use_key(key: ChainKey) -> Result<()> {
    let same = CHAIN_KEY.get_or_init(|| key.clone());
    if same.mac(b"probe") != key.mac(b"probe") {
        return Err(AppError::Internal(anyhow::anyhow!(
            "a second audit key in one process"
        )));
    }
    Ok(())
}

/// This process's chain key, if it has one.
pub fn key() -> Option<&'static ChainKey> {
    CHAIN_KEY.get()
}

/// Lower-case hex of 32 bytes, on the stack (compared with stored hashes as bytes).
fn hex32(bytes: &[u8; 32]) -> [u8; 64] {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut out = [0u8; 64];
    for (i, b) in bytes.iter().enumerate() {
        out[2 * i] = DIGITS[usize::from(b >> 4)];
        out[2 * i + 1] = DIGITS[usize::from(b & 15)];
    }
    out
}

/// 16 bytes from 32 hex digits (lower or upper case), or none: a salt, read once per entry
/// (`hex::decode` parses each byte through `from_str_radix`: 3.6 % of a profiled pass).
fn salt_of(hex: &str) -> Option<[u8; 16]> {
    fn nibble(c: u8) -> Option<u8> {
        match c {
            b'0'..=b'9' => Some(c - b'0'),
            b'a'..=b'f' => Some(c - b'a' + 10),
            b'A'..=b'F' => Some(c - b'A' + 10),
            _ => None,
        }
    }
    let hex = hex.as_bytes();
    if hex.len() != 32 {
        return None;
    }
    let mut out = [0u8; 16];
    for (i, b) in out.iter_mut().enumerate() {
        *b = (nibble(hex[2 * i])? << 4) | nibble(hex[2 * i + 1])?;
    }
    Some(out)
}

fn hex_text(hex: [u8; 64]) -> String {
    hex.iter().map(|&b| char::from(b)).collect()
}

/// The hash of a row's details in `format`, with the entry's salt for the salted formats
/// (none: cannot be computed, the salt was deleted). An absent detail hashes as the empty
/// text, which no stored detail is.
fn detail_digest(
    format: Format,
    salt: Option<&[u8; 16]>,
    detail: Option<&str>,
) -> Option<[u8; 64]> {
    let detail = detail.unwrap_or("").as_bytes();
    let mut h = Sha256::new();
    match format {
        Format::Legacy => {}
        Format::Salted | Format::Keyed => h.update(salt?),
    }
    h.update(detail);
    Some(hex32(&h.finalize().into()))
}

/// The SHA-256 of a row's details as migration 0023 made it (unsalted).
pub fn detail_hash(detail: Option<&str>) -> String {
    hex::sha256(detail.unwrap_or("").as_bytes())
}

/// An audit row's columns: id, at, actor, actor_id, action, target, detail_json (the
/// chain's pages and the log's export read them so).
pub type AuditRow = (
    i64,
    i64,
    String,
    Option<i64>,
    String,
    Option<String>,
    Option<String>,
);

/// An audit row as the chain reads it.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct Entry {
    pub id: i64,
    pub at: i64,
    pub actor: String,
    pub actor_id: Option<i64>,
    pub action: String,
    pub target: Option<String>,
    pub detail_json: Option<String>,
}

fn put_text(out: &mut Vec<u8>, text: Option<&str>) {
    match text {
        None => out.push(0),
        Some(t) => {
            out.push(1);
            out.extend_from_slice(&(t.len() as u64).to_le_bytes());
            out.extend_from_slice(t.as_bytes());
        }
    }
}

impl Entry {
    /// The message a salted or keyed chain row hashes, into `out` (cleared): a label, the
    /// previous hash (hex), the format, the id, time and account (8 bytes little-endian
    /// each, the account after a presence byte), actor, action and target (a presence byte,
    /// an 8-byte length and the UTF-8), and the details' hash (hex). Every field has a fixed
    /// size or a length, so no two contents give one message.
    pub fn message(&self, out: &mut Vec<u8>, format: Format, prev: &str, detail_hash: &str) {
        out.clear();
        out.extend_from_slice(b"bdft-lab audit entry\n");
        out.extend_from_slice(prev.as_bytes());
        out.push(format.code() as u8);
        out.extend_from_slice(&self.id.to_le_bytes());
        out.extend_from_slice(&self.at.to_le_bytes());
        match self.actor_id {
            None => out.extend_from_slice(&[0; 9]),
            Some(a) => {
                out.push(1);
                out.extend_from_slice(&a.to_le_bytes());
            }
        }
        put_text(out, Some(&self.actor));
        put_text(out, Some(&self.action));
        put_text(out, self.target.as_deref());
        out.extend_from_slice(detail_hash.as_bytes());
    }

    /// The entry's hash after `prev` in `format`, with its details' hash `detail_hash`
    /// (none: a keyed row and no key). `buf` is reused between entries.
    fn digest(
        &self,
        format: Format,
        key: Option<&ChainKey>,
        prev: &str,
        detail_hash: &str,
        buf: &mut Vec<u8>,
    ) -> Option<[u8; 64]> {
        let bytes: [u8; 32] = match format {
            Format::Legacy => {
                let content = (
                    self.id,
                    self.at,
                    &self.actor,
                    self.actor_id,
                    &self.action,
                    &self.target,
                    detail_hash,
                );
                let content = serde_json::to_string(&content).unwrap_or_default();
                let mut h = Sha256::new();
                h.update(prev.as_bytes());
                h.update(b"\n");
                h.update(content.as_bytes());
                h.finalize().into()
            }
            Format::Salted => {
                self.message(buf, format, prev, detail_hash);
                Sha256::digest(&buf[..]).into()
            }
            Format::Keyed => {
                self.message(buf, format, prev, detail_hash);
                key?.mac(&buf[..])
            }
        };
        Some(hex32(&bytes))
    }

    /// The entry's hash after `prev` as migration 0023 made it.
    pub fn hash(&self, prev: &str, detail_hash: &str) -> String {
        self.digest(Format::Legacy, None, prev, detail_hash, &mut Vec::new())
            .map(hex_text)
            .unwrap_or_default()
    }
}

async fn head(db: &mut AnyConnection) -> Result<Option<(i64, String)>> {
    Ok(
        sqlx::query_as("SELECT entry_id, hash FROM audit_chain ORDER BY entry_id DESC LIMIT 1")
            .fetch_optional(db)
            .await?,
    )
}

/// Chains `entry` after `prev` as migration 0023 did (rows an earlier release wrote).
async fn link_legacy(db: &mut AnyConnection, entry: &Entry, prev: &str) -> Result<String> {
    let detail_hash = detail_hash(entry.detail_json.as_deref());
    let hash = entry.hash(prev, &detail_hash);
    sqlx::query(
        "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash, chained_late, format) VALUES ($1, $2, $3, $4, 1, 0)",
    )
    .bind(entry.id)
    .bind(prev)
    .bind(&detail_hash)
    .bind(&hash)
    .execute(db)
    .await?;
    Ok(hash)
}

/// Chains the row just appended (on the appending transaction's connection): salted, and
/// keyed when this process holds the chain key.
pub(super) async fn chain(db: &mut AnyConnection, entry: &Entry) -> Result<()> {
    let prev = head(db)
        .await?
        .map_or_else(|| GENESIS.to_string(), |(_, h)| h);
    let key = key();
    let format = if key.is_some() {
        Format::Keyed
    } else {
        Format::Salted
    };
    let mut salt = [0u8; 16];
    getrandom::fill(&mut salt)
        .map_err(|e| AppError::Internal(anyhow::anyhow!("an audit entry's salt: {e}")))?;
    let detail = detail_digest(format, Some(&salt), entry.detail_json.as_deref())
        .map(hex_text)
        .unwrap_or_default();
    let hash = entry
        .digest(format, key, &prev, &detail, &mut Vec::new())
        .map(hex_text)
        .unwrap_or_default();
    sqlx::query(
        "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash, chained_late, format) VALUES ($1, $2, $3, $4, 0, $5)",
    )
    .bind(entry.id)
    .bind(&prev)
    .bind(&detail)
    .bind(&hash)
    .bind(format.code())
    .execute(&mut *db)
    .await?;
    sqlx::query("INSERT INTO audit_salts (entry_id, salt) VALUES ($1, $2)")
        .bind(entry.id)
        .bind(hex::encode(&salt))
        .execute(db)
        .await?;
    Ok(())
}

/// Chains the rows written before the chain existed (a database of a release before
/// migration 0023), in order, as that migration's chain did, marked as chained late;
/// returns how many. Run at every open, before anything is appended.
pub async fn chain_late(db: &mut AnyConnection) -> Result<u64> {
    // In batches, so a long log from an earlier release is chained in bounded memory.
    const BATCH: i64 = 10_000;
    let mut chained = 0;
    loop {
        let (last, mut prev) = head(db)
            .await?
            .map_or_else(|| (0, GENESIS.to_string()), |(id, h)| (id, h));
        let rows: Vec<Entry> = sqlx::query_as(
            "SELECT id, at, actor, actor_id, action, target, detail_json FROM audit_log WHERE id > $1 ORDER BY id LIMIT $2",
        )
        .bind(last)
        .bind(BATCH)
        .fetch_all(&mut *db)
        .await?;
        for e in &rows {
            prev = link_legacy(db, e, &prev).await?;
        }
        chained += rows.len() as u64;
        if (rows.len() as i64) < BATCH {
            return Ok(chained);
        }
    }
}

/// What a redaction record's HMAC covers.
fn redaction_message(entry_id: i64, erasure_id: i64, entry_hash: &str) -> String {
    format!("bdft-lab audit redaction\n{entry_id}\n{erasure_id}\n{entry_hash}")
}

/// Records that erasure `erasure_id` redacted entry `entry_id` (whose details it has just
/// replaced by its marker, in this transaction) and deletes the entry's salt. Needs the
/// chain key: an erasure runs in the server, which holds it.
pub(super) async fn record_redaction(
    db: &mut AnyConnection,
    entry_id: i64,
    erasure_id: i64,
) -> Result<()> {
    let Some(key) = key() else {
        return Err(AppError::Internal(anyhow::anyhow!(
            "an erasure needs the audit key (the server's keys directory)"
        )));
    };
    let hash: String = sqlx::query_scalar("SELECT hash FROM audit_chain WHERE entry_id = $1")
        .bind(entry_id)
        .fetch_one(&mut *db)
        .await?;
    let mac = hex::encode(&key.mac(redaction_message(entry_id, erasure_id, &hash).as_bytes()));
    sqlx::query("INSERT INTO audit_redactions (entry_id, erasure_id, mac) VALUES ($1, $2, $3)")
        .bind(entry_id)
        .bind(erasure_id)
        .bind(mac)
        .execute(&mut *db)
        .await?;
    sqlx::query("DELETE FROM audit_salts WHERE entry_id = $1")
        .bind(entry_id)
        .execute(db)
        .await?;
    Ok(())
}

/// What a checkpoint signs.
fn checkpoint_message(entry_id: i64, head_hash: &str, at: i64) -> String {
    format!("bdft-lab audit checkpoint\n{entry_id}\n{head_hash}\n{at}")
}

pub fn public_key_hex(key: &VerifyingKey) -> String {
    hex::encode(key.as_bytes())
}

/// Signs the chain's head with `key` unless the newest checkpoint already holds it; returns
/// the entry it signed.
pub async fn checkpoint(db: &mut AnyConnection, key: &SigningKey, at: i64) -> Result<Option<i64>> {
    let Some((entry_id, hash)) = head(db).await? else {
        return Ok(None);
    };
    let last: Option<i64> =
        sqlx::query_scalar("SELECT entry_id FROM audit_checkpoints ORDER BY id DESC LIMIT 1")
            .fetch_optional(&mut *db)
            .await?;
    if last == Some(entry_id) {
        return Ok(None);
    }
    let signature = key.sign(checkpoint_message(entry_id, &hash, at).as_bytes());
    let signature = hex::encode(&signature.to_bytes());
    sqlx::query(
        "INSERT INTO audit_checkpoints (entry_id, head_hash, at, public_key, signature) VALUES ($1, $2, $3, $4, $5)",
    )
    .bind(entry_id)
    .bind(&hash)
    .bind(at)
    .bind(public_key_hex(&key.verifying_key()))
    .bind(signature)
    .execute(db)
    .await?;
    Ok(Some(entry_id))
}

/// Whether an entry written without the key (format 0 or 1) follows the newest checkpoint:
/// then the head needs signing now, not in minutes.
pub async fn unkeyed_after_checkpoint(db: &mut AnyConnection) -> Result<bool> {
    let found: Option<i64> = sqlx::query_scalar(
        // The newest checkpoint by its key (it signed the highest entry: the head only
        // grows), not MAX(entry_id), which would read every checkpoint once a second.
        "SELECT entry_id FROM audit_chain WHERE format < 2 AND entry_id > \
         COALESCE((SELECT entry_id FROM audit_checkpoints ORDER BY id DESC LIMIT 1), 0) LIMIT 1",
    )
    .fetch_optional(db)
    .await?;
    Ok(found.is_some())
}

/// What `audit verify` found.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Verdict {
    /// Every entry checked and none failed.
    pub intact: bool,
    pub entries: i64,
    /// The newest entry's hash.
    pub head: Option<String>,
    /// The newest checkpoint: the entry it signed.
    pub last_checkpoint: Option<i64>,
    /// Entries written before the chain existed, chained when this release first opened
    /// the database.
    pub chained_late: i64,
    /// Entries whose details an erasure redacted (their details' hash still chains).
    pub redacted: i64,
    /// Entries with keyed hashes.
    pub keyed: i64,
    /// Entries written without the audit key (by a command without the keys directory),
    /// each covered by a signed checkpoint.
    pub unkeyed: i64,
    /// Entries of the format before keyed hashes (migration 0028), checked as then.
    pub legacy: i64,
    /// Keyed entries that could not be checked: the audit key was not at hand.
    pub unchecked: i64,
    /// The first entry that fails, and why (none when intact).
    pub failure: Option<Failure>,
}

#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Failure {
    pub entry: i64,
    pub why: String,
}

impl std::fmt::Display for Verdict {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.failure {
            None if self.unchecked > 0 => write!(
                f,
                "NOT checked: {} of {} entries have keyed hashes and the audit key is not at hand \
                 (the key file beside the database or in --keys-dir): checked are only the links \
                 between entries, the signed checkpoints and the unkeyed entries, not whether a \
                 keyed entry was edited or appended",
                self.unchecked, self.entries
            )?,
            None => write!(
                f,
                "intact: {} entries, head {}, last checkpoint {}",
                self.entries,
                self.head.as_deref().unwrap_or("none"),
                self.last_checkpoint
                    .map_or_else(|| "none".to_string(), |k| format!("at entry {k}")),
            )?,
            Some(x) => write!(f, "NOT intact: entry {}: {}", x.entry, x.why)?,
        }
        if self.chained_late > 0 {
            write!(f, " ({} entries chained late", self.chained_late)?;
            write!(f, ", at the upgrade that brought the chain)")?;
        }
        if self.legacy > 0 {
            write!(
                f,
                " ({} entries from before keyed hashes, checked unkeyed up to the signed checkpoints)",
                self.legacy
            )?;
        }
        if self.unkeyed > 0 {
            write!(
                f,
                " ({} entries written without the audit key, each covered by a signed checkpoint)",
                self.unkeyed
            )?;
        }
        if self.redacted > 0 {
            write!(f, " ({} entries redacted by erasures)", self.redacted)?;
        }
        Ok(())
    }
}

/// An entry with its chain row (none: the entry was never chained), its salt and its
/// redaction record.
struct Row {
    entry: Entry,
    prev_hash: Option<String>,
    detail_hash: Option<String>,
    hash: Option<String>,
    chained_late: Option<bool>,
    format: Option<i64>,
    salt: Option<String>,
    redaction: Option<(i64, String)>,
}

/// How many entries [`page`] reads at a time.
const PAGE: i64 = 5000;

/// The rows of `query` (which selects `columns` and keeps the order it names) as one JSON
/// text, read as `T`s.
///
/// SQLite hands a page over as one JSON text: row by row, sqlx's worker thread would copy
/// every value and switch threads once a row, several times the cost of the hashing (a
/// million entries must verify in a second). JSON carries the texts unchanged.
async fn json_rows<T: serde::de::DeserializeOwned>(
    db: &mut AnyConnection,
    columns: &str,
    query: &str,
    order: &str,
    from: i64,
    to: i64,
) -> Result<Vec<T>> {
    let sql = match super::dialect::Dialect::of(db) {
        super::dialect::Dialect::Sqlite => {
            format!("SELECT json_group_array(json_array({columns})) FROM ({query}) p")
        }
        // The same array from PostgreSQL's JSON functions (an empty page is NULL there).
        super::dialect::Dialect::Postgres => format!(
            "SELECT COALESCE(json_agg(json_build_array({columns}) ORDER BY {order}), '[]')::text FROM ({query}) p"
        ),
    };
    let text: String = sqlx::query_scalar(&sql)
        .bind(from)
        .bind(to)
        .fetch_one(&mut *db)
        .await?;
    serde_json::from_str(&text)
        .map_err(|e| AppError::Internal(anyhow::anyhow!("reading the audit log: {e}")))
}

/// The (at most [`PAGE`]) entries after entry `after`, in order, with their chain rows,
/// salts and redaction records. Each table is read apart over the page's range of ids
/// (ordered scans of their keys) and joined here, which costs SQLite far less than a join
/// looking up three tables for every entry.
async fn page(db: &mut AnyConnection, after: i64) -> Result<Vec<Row>> {
    let log: Vec<AuditRow> = json_rows(
        db,
        "id, at, actor, actor_id, action, target, detail_json",
        "SELECT id, at, actor, actor_id, action, target, detail_json FROM audit_log \
         WHERE id > $1 ORDER BY id LIMIT $2",
        "id",
        after,
        PAGE,
    )
    .await?;
    let Some(last) = log.last().map(|e| e.0) else {
        return Ok(Vec::new());
    };
    type Link = (i64, String, String, String, i64, i64);
    let links: Vec<Link> = json_rows(
        db,
        "entry_id, prev_hash, detail_hash, hash, chained_late, format",
        "SELECT entry_id, prev_hash, detail_hash, hash, chained_late, format FROM audit_chain \
         WHERE entry_id > $1 AND entry_id <= $2 ORDER BY entry_id",
        "entry_id",
        after,
        last,
    )
    .await?;
    let salts: Vec<(i64, String)> = json_rows(
        db,
        "entry_id, salt",
        "SELECT entry_id, salt FROM audit_salts WHERE entry_id > $1 AND entry_id <= $2 ORDER BY entry_id",
        "entry_id",
        after,
        last,
    )
    .await?;
    let redactions: Vec<(i64, i64, String)> = json_rows(
        db,
        "entry_id, erasure_id, mac",
        "SELECT entry_id, erasure_id, mac FROM audit_redactions WHERE entry_id > $1 AND entry_id <= $2 ORDER BY entry_id",
        "entry_id",
        after,
        last,
    )
    .await?;
    let mut links = links.into_iter().peekable();
    let mut salts = salts.into_iter().peekable();
    let mut redactions = redactions.into_iter().peekable();
    Ok(log
        .into_iter()
        .map(|e| {
            let id = e.0;
            // Each list is ordered by id: past the rows of no entry (a chain row whose entry
            // was deleted), the entry's row is next, or there is none.
            while links.next_if(|l| l.0 < id).is_some() {}
            let link = links.next_if(|l| l.0 == id);
            while salts.next_if(|s| s.0 < id).is_some() {}
            let salt = salts.next_if(|s| s.0 == id);
            while redactions.next_if(|r| r.0 < id).is_some() {}
            let redaction = redactions.next_if(|r| r.0 == id);
            let (prev_hash, detail_hash, hash, late, format) = match link {
                Some((_, p, d, h, l, f)) => (Some(p), Some(d), Some(h), Some(l != 0), Some(f)),
                None => (None, None, None, None, None),
            };
            Row {
                entry: Entry {
                    id,
                    at: e.1,
                    actor: e.2,
                    actor_id: e.3,
                    action: e.4,
                    target: e.5,
                    detail_json: e.6,
                },
                prev_hash,
                detail_hash,
                hash,
                chained_late: late,
                format,
                salt: salt.map(|s| s.1),
                redaction: redaction.map(|r| (r.1, r.2)),
            }
        })
        .collect())
}

#[derive(sqlx::FromRow)]
struct CheckpointRow {
    id: i64,
    entry_id: i64,
    head_hash: String,
    at: i64,
    public_key: String,
    signature: String,
}

/// The erasure `detail` names when it is an erasure's redaction marker
/// (`{"erasure": E, "redacted": "subject.erase"}`, nothing else).
fn marker_of(detail: Option<&str>) -> Option<i64> {
    let detail = detail?;
    // Cheap refusal first: most details are no marker.
    if !detail.contains("\"redacted\"") {
        return None;
    }
    let v = serde_json::from_str::<serde_json::Value>(detail).ok()?;
    (v.as_object().is_some_and(|o| o.len() == 2) && v["redacted"] == "subject.erase")
        .then(|| v["erasure"].as_i64())
        .flatten()
}

/// An erasure entry: its target and its format.
struct Erasure {
    target: Option<String>,
    format: Option<i64>,
}

/// Why a redaction marker on entry `e` (naming erasure `by`, with the redaction record
/// `record`) is no erasure's redaction; none when it is.
fn forged_redaction(
    e: &Entry,
    hash: &str,
    by: i64,
    record: Option<&(i64, String)>,
    erasures: &HashMap<i64, Erasure>,
    key: Option<&ChainKey>,
) -> Option<String> {
    let Some(erasure) = erasures.get(&by).filter(|_| by > e.id) else {
        return Some(format!(
            "redacted, but not by an erasure: its details name erasure {by}, which is no erasure after it"
        ));
    };
    match record {
        Some((recorded_by, mac)) => {
            if *recorded_by != by {
                return Some(format!(
                    "redacted, but not by an erasure: its details name erasure {by}, erasure {recorded_by} recorded redacting it"
                ));
            }
            let good = key.is_none_or(|k| {
                hex32(&k.mac(redaction_message(e.id, by, hash).as_bytes())) == mac.as_bytes()
            });
            (!good).then(|| {
                format!(
                    "redacted, but not by an erasure: its redaction record by erasure {by} was forged (its HMAC does not verify)"
                )
            })
        }
        // An erasure from before redaction records (0028) is taken as then: an entry about
        // another subject is refused where its target shows it.
        None if erasure.format == Some(0) => {
            let other_subject = e
                .target
                .as_deref()
                .is_some_and(|t| t.starts_with("subject:") && Some(t) != erasure.target.as_deref());
            other_subject.then(|| {
                format!("redacted, but not by an erasure: erasure {by} erased another subject")
            })
        }
        None => Some(format!(
            "redacted, but not by an erasure: erasure {by} did not redact it (it recorded no such redaction)"
        )),
    }
}

/// The other place in the chain where `e`'s content belongs, if any: a row moved rather
/// than edited. Searched only once something failed, by a second pass over the chain
/// (streamed, like the first), each place's details hashed with that place's salt.
async fn moved_from(
    db: &mut AnyConnection,
    e: &Entry,
    key: Option<&ChainKey>,
) -> Result<Option<i64>> {
    type Place = (i64, String, String, String, i64, Option<String>);
    let mut chain = sqlx::query_as::<_, Place>(
        "SELECT c.entry_id, c.prev_hash, c.detail_hash, c.hash, c.format, s.salt FROM audit_chain c \
         LEFT JOIN audit_salts s ON s.entry_id = c.entry_id ORDER BY c.entry_id",
    )
    .fetch(&mut *db);
    let mut buf = Vec::new();
    while let Some((id, prev, detail_hash, hash, format, salt)) = chain.try_next().await? {
        let Some(format) = Format::of(format) else {
            continue;
        };
        let salt = salt.as_deref().and_then(salt_of);
        let Some(detail) = detail_digest(format, salt.as_ref(), e.detail_json.as_deref()) else {
            continue;
        };
        if id == e.id || detail != detail_hash.as_bytes() {
            continue;
        }
        let there = Entry { id, ..e.clone() };
        if there
            .digest(format, key, &prev, &detail_hash, &mut buf)
            .is_some_and(|h| h == hash.as_bytes())
        {
            return Ok(Some(id));
        }
    }
    Ok(None)
}

/// One pass over the log: what it has seen so far.
struct Pass<'k> {
    /// The newest entry a checkpoint signed: an unkeyed entry after it counts for nothing.
    covered: i64,
    /// The entries checkpoints signed, and their hashes once passed: the only hashes kept
    /// past their turn, so memory stays bounded however long the log.
    signed: HashSet<i64>,
    hashes: HashMap<i64, String>,
    /// The last entry passed and its hash.
    prev: (i64, String),
    buf: Vec<u8>,
    /// The first entry whose content fails to hash, looked up elsewhere in the chain after
    /// the pass (the pass holds the connection), and whether its details held.
    misfit: Option<(Entry, bool)>,
    erasures: HashMap<i64, Erasure>,
    key: Option<&'k ChainKey>,
    verdict: Verdict,
}

impl Pass<'_> {
    /// Checks the page's entries in order; false once one failed (the pass stops).
    fn take(&mut self, rows: Vec<Row>) -> bool {
        for r in rows {
            let e = &r.entry;
            let (Some(prev_hash), Some(stored_detail), Some(hash)) =
                (&r.prev_hash, &r.detail_hash, &r.hash)
            else {
                fail(
                    &mut self.verdict,
                    e.id,
                    "inserted behind the server's back: it has no place in the chain".into(),
                );
                return false;
            };
            if e.id != self.prev.0 + 1 {
                let gap = if e.id == self.prev.0 + 2 {
                    format!("entry {} was deleted", self.prev.0 + 1)
                } else {
                    format!("entries {} to {} were deleted", self.prev.0 + 1, e.id - 1)
                };
                fail(
                    &mut self.verdict,
                    e.id,
                    format!("{gap} (the ids jump from {} to {})", self.prev.0, e.id),
                );
                return false;
            }
            if *prev_hash != self.prev.1 {
                fail(
                    &mut self.verdict,
                    e.id,
                    format!(
                        "its chain does not follow entry {}: an entry before it was deleted, replaced or moved",
                        self.prev.0
                    ),
                );
                return false;
            }
            let Some(format) = r.format.and_then(Format::of) else {
                fail(
                    &mut self.verdict,
                    e.id,
                    "its chain row names no known format".into(),
                );
                return false;
            };
            if format != Format::Keyed && e.id > self.covered {
                fail(
                    &mut self.verdict,
                    e.id,
                    format!(
                        "appended after the last checkpoint without the audit key: its hash is not keyed and no signed checkpoint covers it (forged, or written by a command without the keys directory that no server has signed since{})",
                        if self.covered > 0 {
                            format!("; the last checkpoint signed entry {}", self.covered)
                        } else {
                            String::new()
                        }
                    ),
                );
                return false;
            }
            let salt = match r.salt.as_deref() {
                None => None,
                Some(s) => match salt_of(s) {
                    Some(s) => Some(s),
                    None => {
                        fail(
                            &mut self.verdict,
                            e.id,
                            "its salt is no salt (32 hex digits)".into(),
                        );
                        return false;
                    }
                },
            };
            let details_hold = detail_digest(format, salt.as_ref(), e.detail_json.as_deref())
                .is_some_and(|d| d == stored_detail.as_bytes());
            let mut redacted = false;
            if !details_hold {
                match marker_of(e.detail_json.as_deref()) {
                    Some(by) => {
                        if let Some(why) = forged_redaction(
                            e,
                            hash,
                            by,
                            r.redaction.as_ref(),
                            &self.erasures,
                            self.key,
                        ) {
                            fail(&mut self.verdict, e.id, why);
                            return false;
                        }
                        redacted = true;
                    }
                    None if format != Format::Legacy && salt.is_none() => {
                        fail(
                            &mut self.verdict,
                            e.id,
                            "edited: its salt was deleted, but no erasure redacted its details"
                                .into(),
                        );
                        return false;
                    }
                    None => {
                        self.misfit = Some((e.clone(), false));
                        return false;
                    }
                }
            }
            match e.digest(format, self.key, prev_hash, stored_detail, &mut self.buf) {
                Some(h) if h == hash.as_bytes() => {}
                Some(_) => {
                    self.misfit = Some((e.clone(), true));
                    return false;
                }
                None => self.verdict.unchecked += 1,
            }
            match format {
                Format::Keyed => self.verdict.keyed += 1,
                Format::Salted => self.verdict.unkeyed += 1,
                Format::Legacy => self.verdict.legacy += 1,
            }
            if redacted {
                self.verdict.redacted += 1;
            }
            if r.chained_late == Some(true) {
                self.verdict.chained_late += 1;
            }
            if self.signed.contains(&e.id) {
                self.hashes.insert(e.id, hash.clone());
            }
            self.prev = (e.id, hash.clone());
        }
        true
    }
}

/// Records the first failure (the ones after it follow from it).
fn fail(verdict: &mut Verdict, entry: i64, why: String) {
    if verdict.failure.is_none() {
        verdict.intact = false;
        verdict.failure = Some(Failure { entry, why });
    }
}

/// Checks the whole log against its chain and its checkpoints with this process's chain key
/// ([`key`]), the checkpoints against `trusted` (the server's public key; none: the key
/// each checkpoint names).
pub async fn verify(db: &mut AnyConnection, trusted: Option<&VerifyingKey>) -> Result<Verdict> {
    verify_with(db, trusted, key()).await
}

/// [`verify`] with the chain key `key` (none: keyed entries cannot be checked, and the
/// verdict says so).
pub async fn verify_with(
    db: &mut AnyConnection,
    trusted: Option<&VerifyingKey>,
    key: Option<&ChainKey>,
) -> Result<Verdict> {
    let erasures: Vec<(i64, Option<String>, Option<i64>)> = sqlx::query_as(
        "SELECT a.id, a.target, c.format FROM audit_log a LEFT JOIN audit_chain c ON c.entry_id = a.id \
         WHERE a.action = 'subject.erase'",
    )
    .fetch_all(&mut *db)
    .await?;
    let erasures: HashMap<i64, Erasure> = erasures
        .into_iter()
        .map(|(id, target, format)| (id, Erasure { target, format }))
        .collect();
    let orphan: Option<i64> = sqlx::query_scalar(
        "SELECT entry_id FROM audit_chain WHERE entry_id NOT IN (SELECT id FROM audit_log) ORDER BY entry_id LIMIT 1",
    )
    .fetch_optional(&mut *db)
    .await?;
    let checkpoints: Vec<CheckpointRow> = sqlx::query_as(
        "SELECT id, entry_id, head_hash, at, public_key, signature FROM audit_checkpoints ORDER BY id",
    )
    .fetch_all(&mut *db)
    .await?;

    let entries: i64 = sqlx::query_scalar("SELECT COUNT(*) FROM audit_log")
        .fetch_one(&mut *db)
        .await?;
    let verdict = Verdict {
        intact: true,
        entries,
        head: None,
        last_checkpoint: checkpoints.last().map(|c| c.entry_id),
        chained_late: 0,
        redacted: 0,
        keyed: 0,
        unkeyed: 0,
        legacy: 0,
        unchecked: 0,
        failure: None,
    };
    let mut pass = Pass {
        // The entries an unkeyed hash may have: those a checkpoint signed (each checkpoint
        // is itself checked below).
        covered: checkpoints.iter().map(|c| c.entry_id).max().unwrap_or(0),
        signed: checkpoints.iter().map(|c| c.entry_id).collect(),
        hashes: HashMap::new(),
        prev: (0, GENESIS.to_string()),
        buf: Vec::with_capacity(512),
        misfit: None,
        erasures,
        key,
        verdict,
    };
    // The next page is read while this one is hashed: SQLite's work runs on sqlx's worker
    // thread meanwhile, so the two cores share the pass.
    let mut rows = page(db, 0).await?;
    while let Some(last) = rows.last().map(|r| r.entry.id) {
        let (next, go_on) = tokio::join!(page(db, last), async { pass.take(rows) });
        if !go_on {
            break;
        }
        rows = next?;
    }
    let Pass {
        hashes,
        prev,
        misfit,
        mut verdict,
        ..
    } = pass;
    if let Some((e, details_hold)) = misfit {
        let why = match moved_from(db, &e, key).await? {
            Some(j) => format!(
                "reordered: it holds what entry {j} held (its content hashes to entry {j}'s place in the chain)"
            ),
            None if !details_hold => "edited: its details do not match their hash".into(),
            None => {
                "edited: its id, time, actor, action or target no longer hash to its chain (or its hash was not made with the audit key)".into()
            }
        };
        fail(&mut verdict, e.id, why);
    }
    if verdict.intact
        && let Some(id) = orphan
    {
        fail(
            &mut verdict,
            id,
            "deleted: its chain row remains, the entry does not".into(),
        );
    }
    verdict.head = (prev.0 > 0).then(|| prev.1.clone());
    if !verdict.intact {
        return Ok(verdict);
    }
    for c in &checkpoints {
        let signed_by =
            hex::decode::<32>(&c.public_key).and_then(|k| VerifyingKey::from_bytes(&k).ok());
        let Some(signed_by) = signed_by else {
            fail(
                &mut verdict,
                c.entry_id,
                format!("checkpoint {}: its public key is no Ed25519 key", c.id),
            );
            break;
        };
        if trusted.is_some_and(|t| *t != signed_by) {
            fail(
                &mut verdict,
                c.entry_id,
                format!(
                    "checkpoint {} is signed by another key than this server's",
                    c.id
                ),
            );
            break;
        }
        let signature = hex::decode::<64>(&c.signature).map(|s| Signature::from_bytes(&s));
        let message = checkpoint_message(c.entry_id, &c.head_hash, c.at);
        if signature.is_none_or(|s| signed_by.verify(message.as_bytes(), &s).is_err()) {
            fail(
                &mut verdict,
                c.entry_id,
                format!(
                    "checkpoint {}: its signature does not verify (the checkpoint was forged or edited)",
                    c.id
                ),
            );
            break;
        }
        match hashes.get(&c.entry_id) {
            None => {
                fail(
                    &mut verdict,
                    c.entry_id,
                    format!(
                        "truncated after checkpoint {}: it signed entry {}, the log ends at entry {}",
                        c.id, c.entry_id, prev.0
                    ),
                );
                break;
            }
            Some(h) if *h != c.head_hash => {
                fail(
                    &mut verdict,
                    c.entry_id,
                    format!(
                        "rewritten: its hash is not the one checkpoint {} signed",
                        c.id
                    ),
                );
                break;
            }
            Some(_) => {}
        }
    }
    if verdict.unchecked > 0 {
        verdict.intact = false;
    }
    Ok(verdict)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry() -> Entry {
        Entry {
            id: 7,
            at: 1_700_000_000_000,
            actor: "admin".into(),
            actor_id: Some(1),
            action: "trial.note".into(),
            target: Some("trial:3".into()),
            detail_json: Some(r#"{"note":1,"text":"ABCD"}"#.into()),
        }
    }

    #[test]
    fn the_audit_chain_message_is_the_documented_layout() {
        let e = entry();
        let mut m = Vec::new();
        e.message(&mut m, Format::Keyed, GENESIS, &"d".repeat(64));
        let mut want = b"bdft-lab audit entry\n".to_vec();
        want.extend_from_slice(GENESIS.as_bytes());
        want.push(2);
        want.extend_from_slice(&7i64.to_le_bytes());
        want.extend_from_slice(&1_700_000_000_000i64.to_le_bytes());
        want.push(1);
        want.extend_from_slice(&1i64.to_le_bytes());
        for t in ["admin", "trial.note", "trial:3"] {
            want.push(1);
            want.extend_from_slice(&(t.len() as u64).to_le_bytes());
            want.extend_from_slice(t.as_bytes());
        }
        want.extend_from_slice("d".repeat(64).as_bytes());
        assert_eq!(m, want);
        // A target moved into the action cannot give the same message.
        let moved = Entry {
            action: "trial.notetrial:3".into(),
            target: None,
            ..e
        };
        let mut n = Vec::new();
        moved.message(&mut n, Format::Keyed, GENESIS, &"d".repeat(64));
        assert_ne!(m, n);
    }

    #[test]
    fn audit_keyed_hashes_need_the_key_and_salted_details_the_salt() {
        let e = entry();
        let key = ChainKey::from_signing_key(&SigningKey::from_bytes(&[7; 32]));
        let other = ChainKey::from_signing_key(&SigningKey::from_bytes(&[8; 32]));
        let mut buf = Vec::new();
        let d = hex_text(
            detail_digest(Format::Keyed, Some(&[1; 16]), e.detail_json.as_deref()).unwrap(),
        );
        let keyed = e
            .digest(Format::Keyed, Some(&key), GENESIS, &d, &mut buf)
            .unwrap();
        let by_other = e
            .digest(Format::Keyed, Some(&other), GENESIS, &d, &mut buf)
            .unwrap();
        let unkeyed = e
            .digest(Format::Salted, None, GENESIS, &d, &mut buf)
            .unwrap();
        assert_ne!(keyed, by_other);
        assert_ne!(keyed, unkeyed);
        assert_eq!(e.digest(Format::Keyed, None, GENESIS, &d, &mut buf), None);
        // The salted hash is neither the plain SHA-256 nor computable without the salt.
        assert_ne!(d, detail_hash(e.detail_json.as_deref()));
        assert_eq!(
            detail_digest(Format::Keyed, None, e.detail_json.as_deref()),
            None
        );
        // HMAC-SHA256 as RFC 4231 defines it (test case 2), through the reused keyed state.
        let rfc = ChainKey(hmac_of(b"Jefe"));
        assert_eq!(
            hex::encode(&rfc.mac(b"what do ya want for nothing?")),
            "5bdcc146bf60754e6a042426089575c75a003f089d2739839dec58b964ec3843"
        );
    }

    #[test]
    fn audit_markers_are_read_exactly() {
        assert_eq!(
            marker_of(Some(r#"{"erasure":12,"redacted":"subject.erase"}"#)),
            Some(12)
        );
        assert_eq!(marker_of(Some(r#"{"erasure":12,"redacted":"x"}"#)), None);
        assert_eq!(
            marker_of(Some(r#"{"erasure":12,"redacted":"subject.erase","x":1}"#)),
            None
        );
        assert_eq!(marker_of(Some("not json \"redacted\"")), None);
        assert_eq!(marker_of(None), None);
    }

    #[test]
    fn audit_salts_are_read_as_hex_says() {
        let salt = [
            0x00, 0x0f, 0xa5, 0xff, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12,
        ];
        assert_eq!(salt_of(&hex::encode(&salt)), Some(salt));
        assert_eq!(salt_of(&hex::encode(&salt).to_uppercase()), Some(salt));
        assert_eq!(salt_of("00"), None);
        assert_eq!(salt_of(&"g".repeat(32)), None);
        assert_eq!(salt_of(&"é".repeat(16)), None);
    }
}
