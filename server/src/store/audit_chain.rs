//! The audit log's hash chain and its signed checkpoints (migration 0023): what makes an
//! edit, a deletion, a reordering or a truncation of the log show, even by someone who holds
//! the file and drops its triggers.
//!
//! Each audit row's chain row holds `detail_hash` = SHA-256 of its details and `hash` =
//! SHA-256 of the previous row's hash, a newline and the row's canonical content: the JSON
//! array `[id, at, actor, actor_id, action, target, detail_hash]`. The content is taken
//! through the details' hash so that an erasure, which may replace the details of rows about
//! the erased subject with its redaction marker, leaves the chain whole. A checkpoint signs
//! (Ed25519) the head at a moment: a chain alone cannot show a cut-off tail or a rewrite of
//! every hash.

use bdft_protocol::hex;
use ed25519_dalek::{Signature, Signer, SigningKey, Verifier, VerifyingKey};
use serde::Serialize;
use std::collections::{HashMap, HashSet};

use futures_util::TryStreamExt;
use sqlx::AnyConnection;

use crate::error::{AppError, Result};

/// The hash before the first entry.
pub const GENESIS: &str = "0000000000000000000000000000000000000000000000000000000000000000";

/// The SHA-256 of a row's details (an absent detail hashes as the empty text, which no
/// stored detail is).
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

impl Entry {
    /// The entry's hash after `prev`, with its details' hash `detail_hash`.
    pub fn hash(&self, prev: &str, detail_hash: &str) -> String {
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
        hex::sha256(format!("{prev}\n{content}").as_bytes())
    }
}

async fn head(db: &mut AnyConnection) -> Result<Option<(i64, String)>> {
    Ok(
        sqlx::query_as("SELECT entry_id, hash FROM audit_chain ORDER BY entry_id DESC LIMIT 1")
            .fetch_optional(db)
            .await?,
    )
}

async fn link(db: &mut AnyConnection, entry: &Entry, prev: &str, late: bool) -> Result<String> {
    let detail_hash = detail_hash(entry.detail_json.as_deref());
    let hash = entry.hash(prev, &detail_hash);
    sqlx::query(
        "INSERT INTO audit_chain (entry_id, prev_hash, detail_hash, hash, chained_late) VALUES ($1, $2, $3, $4, $5)",
    )
    .bind(entry.id)
    .bind(prev)
    .bind(&detail_hash)
    .bind(&hash)
    .bind(i64::from(late))
    .execute(db)
    .await?;
    Ok(hash)
}

/// Chains the row just appended (on the appending transaction's connection).
pub(super) async fn chain(db: &mut AnyConnection, entry: &Entry) -> Result<()> {
    let prev = head(db)
        .await?
        .map_or_else(|| GENESIS.to_string(), |(_, h)| h);
    link(db, entry, &prev, false).await?;
    Ok(())
}

/// Chains the rows written before the chain existed (a database of an earlier release), in
/// order, marked as chained late; returns how many. Run at every open, before anything is
/// appended.
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
            prev = link(db, e, &prev, true).await?;
        }
        chained += rows.len() as u64;
        if (rows.len() as i64) < BATCH {
            return Ok(chained);
        }
    }
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

/// What `audit verify` found.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, utoipa::ToSchema)]
pub struct Verdict {
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
        if self.redacted > 0 {
            write!(f, " ({} entries redacted by erasures)", self.redacted)?;
        }
        Ok(())
    }
}

/// An entry with its chain row (none: the entry was never chained).
struct Row {
    entry: Entry,
    prev_hash: Option<String>,
    detail_hash: Option<String>,
    hash: Option<String>,
    chained_late: Option<bool>,
}

/// How many entries [`page`] reads at a time.
const PAGE: i64 = 2000;

/// The (at most [`PAGE`]) entries after entry `after`, in order, with their chain rows.
///
/// SQLite hands them over as one JSON text per page: row by row, sqlx's worker thread
/// would copy every value and switch threads once a row, several times the cost of the
/// hashing (a million entries must verify in seconds). JSON carries the texts unchanged.
async fn page(db: &mut AnyConnection, after: i64) -> Result<Vec<Row>> {
    type Fields = (
        AuditRow,
        Option<String>,
        Option<String>,
        Option<String>,
        Option<i64>,
    );
    let sql = match super::dialect::Dialect::of(db) {
        super::dialect::Dialect::Sqlite => {
            "SELECT json_group_array(json_array(json_array(id, at, actor, actor_id, action, target, detail_json), prev_hash, detail_hash, hash, chained_late)) \
             FROM (SELECT a.id, a.at, a.actor, a.actor_id, a.action, a.target, a.detail_json, c.prev_hash, c.detail_hash, c.hash, c.chained_late \
                   FROM audit_log a LEFT JOIN audit_chain c ON c.entry_id = a.id WHERE a.id > $1 ORDER BY a.id LIMIT $2) p"
        }
        // The same array from PostgreSQL's JSON functions (an empty page is NULL there).
        super::dialect::Dialect::Postgres => {
            "SELECT COALESCE(json_agg(json_build_array(json_build_array(id, at, actor, actor_id, action, target, detail_json), prev_hash, detail_hash, hash, chained_late) ORDER BY id), '[]')::text \
             FROM (SELECT a.id, a.at, a.actor, a.actor_id, a.action, a.target, a.detail_json, c.prev_hash, c.detail_hash, c.hash, c.chained_late \
                   FROM audit_log a LEFT JOIN audit_chain c ON c.entry_id = a.id WHERE a.id > $1 ORDER BY a.id LIMIT $2) p"
        }
    };
    let text: String = sqlx::query_scalar(sql)
        .bind(after)
        .bind(PAGE)
        .fetch_one(&mut *db)
        .await?;
    let fields: Vec<Fields> = serde_json::from_str(&text)
        .map_err(|e| AppError::Internal(anyhow::anyhow!("reading the audit log: {e}")))?;
    Ok(fields
        .into_iter()
        .map(|(e, prev_hash, detail_hash, hash, late)| Row {
            entry: Entry {
                id: e.0,
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
            chained_late: late.map(|l| l != 0),
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

/// Whether `detail` is an erasure's redaction marker left by an erasure after `entry`.
fn redacted_by_erasure(detail: Option<&str>, entry: i64, erasures: &[i64]) -> bool {
    let Some(v) = detail.and_then(|d| serde_json::from_str::<serde_json::Value>(d).ok()) else {
        return false;
    };
    let by = v["erasure"].as_i64();
    v.as_object().is_some_and(|o| o.len() == 2)
        && v["redacted"] == "subject.erase"
        && by.is_some_and(|e| e > entry && erasures.contains(&e))
}

/// The other place in the chain where `e`'s content (its details hashing to `detail_hash`)
/// belongs, if any: a row moved rather than edited. Searched only once something failed,
/// by a second pass over the chain (streamed, like the first).
async fn moved_from(db: &mut AnyConnection, e: &Entry, detail_hash: &str) -> Result<Option<i64>> {
    let mut chain = sqlx::query_as::<_, (i64, String, String)>(
        "SELECT entry_id, prev_hash, hash FROM audit_chain ORDER BY entry_id",
    )
    .fetch(&mut *db);
    while let Some((id, prev, hash)) = chain.try_next().await? {
        let there = Entry { id, ..e.clone() };
        if id != e.id && there.hash(&prev, detail_hash) == hash {
            return Ok(Some(id));
        }
    }
    Ok(None)
}

/// Records the first failure (the ones after it follow from it).
fn fail(verdict: &mut Verdict, entry: i64, why: String) {
    if verdict.failure.is_none() {
        verdict.intact = false;
        verdict.failure = Some(Failure { entry, why });
    }
}

/// Checks the whole log against its chain and its checkpoints, the checkpoints against
/// `trusted` (the server's public key; none: the key each checkpoint names).
pub async fn verify(db: &mut AnyConnection, trusted: Option<&VerifyingKey>) -> Result<Verdict> {
    let erasures: Vec<i64> =
        sqlx::query_scalar("SELECT id FROM audit_log WHERE action = 'subject.erase'")
            .fetch_all(&mut *db)
            .await?;
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
    let mut verdict = Verdict {
        intact: true,
        entries,
        head: None,
        last_checkpoint: checkpoints.last().map(|c| c.entry_id),
        chained_late: 0,
        redacted: 0,
        failure: None,
    };
    // The hashes of the entries checkpoints signed: the only ones kept past their turn, so
    // memory stays bounded however long the log.
    let signed: HashSet<i64> = checkpoints.iter().map(|c| c.entry_id).collect();
    let mut hashes: HashMap<i64, String> = HashMap::new();
    let mut prev = (0i64, GENESIS.to_string());
    // The first entry whose content fails to hash, looked up elsewhere in the chain after the
    // pass (the pass holds the connection).
    let mut misfit: Option<(Entry, String, bool)> = None;
    'pages: loop {
        let rows = page(db, prev.0).await?;
        if rows.is_empty() {
            break 'pages;
        }
        for r in rows {
            let e = &r.entry;
            let (Some(prev_hash), Some(stored_detail), Some(hash)) =
                (&r.prev_hash, &r.detail_hash, &r.hash)
            else {
                fail(
                    &mut verdict,
                    e.id,
                    "inserted behind the server's back: it has no place in the chain".into(),
                );
                break 'pages;
            };
            if e.id != prev.0 + 1 {
                let gap = if e.id == prev.0 + 2 {
                    format!("entry {} was deleted", prev.0 + 1)
                } else {
                    format!("entries {} to {} were deleted", prev.0 + 1, e.id - 1)
                };
                fail(
                    &mut verdict,
                    e.id,
                    format!("{gap} (the ids jump from {} to {})", prev.0, e.id),
                );
                break 'pages;
            }
            if *prev_hash != prev.1 {
                fail(
                    &mut verdict,
                    e.id,
                    format!(
                        "its chain does not follow entry {}: an entry before it was deleted, replaced or moved",
                        prev.0
                    ),
                );
                break 'pages;
            }
            let detail_now = detail_hash(e.detail_json.as_deref());
            let redacted = detail_now != *stored_detail
                && redacted_by_erasure(e.detail_json.as_deref(), e.id, &erasures);
            let details_hold = detail_now == *stored_detail || redacted;
            if !details_hold || e.hash(prev_hash, stored_detail) != *hash {
                misfit = Some((e.clone(), detail_now, details_hold));
                break 'pages;
            }
            if redacted {
                verdict.redacted += 1;
            }
            if r.chained_late == Some(true) {
                verdict.chained_late += 1;
            }
            if signed.contains(&e.id) {
                hashes.insert(e.id, hash.clone());
            }
            prev = (e.id, hash.clone());
        }
    }
    if let Some((e, detail_now, details_hold)) = misfit {
        let why = match moved_from(db, &e, &detail_now).await? {
            Some(j) => format!(
                "reordered: it holds what entry {j} held (its content hashes to entry {j}'s place in the chain)"
            ),
            None if !details_hold => "edited: its details do not match their hash".into(),
            None => {
                "edited: its id, time, actor, action or target no longer hash to its chain".into()
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
    Ok(verdict)
}
