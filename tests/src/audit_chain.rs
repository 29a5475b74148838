//! The audit chain's formats (server/src/store/audit_chain.rs) written out again from their
//! documentation, independently of the server's code: the tamper tests rewrite a chain with
//! them, and the verify bench writes a keyed log with them.

use sha2::{Digest, Sha256};

/// Lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Bytes from hex (panics on bad input: a test's own data).
pub fn unhex(text: &str) -> Vec<u8> {
    (0..text.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&text[i..i + 2], 16).unwrap())
        .collect()
}

pub fn sha_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// HMAC-SHA256 as RFC 2104 defines it.
pub fn hmac_sha256(key: &[u8], message: &[u8]) -> [u8; 32] {
    let mut block = [0u8; 64];
    if key.len() > 64 {
        block[..32].copy_from_slice(&Sha256::digest(key));
    } else {
        block[..key.len()].copy_from_slice(key);
    }
    let pad = |byte: u8| block.iter().map(|k| k ^ byte).collect::<Vec<u8>>();
    let inner = Sha256::new()
        .chain_update(pad(0x36))
        .chain_update(message)
        .finalize();
    Sha256::new()
        .chain_update(pad(0x5c))
        .chain_update(inner)
        .finalize()
        .into()
}

/// The chain key of the audit key file's text (the Ed25519 seed in hex).
pub fn chain_key(key_file_text: &str) -> [u8; 32] {
    hmac_sha256(&unhex(key_file_text.trim()), b"bdft-lab audit chain key v1")
}

/// An audit row as the chain hashes it.
#[derive(Debug, Clone)]
pub struct Row {
    pub id: i64,
    pub at: i64,
    pub actor: String,
    pub actor_id: Option<i64>,
    pub action: String,
    pub target: Option<String>,
    pub detail: Option<String>,
}

/// The row's (detail_hash, hash) after `prev` in `format` (0 as migration 0023, 1 salted,
/// 2 salted and keyed with `key`), with its `salt` for formats 1 and 2.
pub fn hashes(row: &Row, format: i64, prev: &str, salt: &[u8], key: &[u8; 32]) -> (String, String) {
    let detail = row.detail.as_deref().unwrap_or("");
    if format == 0 {
        let detail_hash = sha_hex(detail.as_bytes());
        let content = serde_json::to_string(&serde_json::json!([
            row.id,
            row.at,
            row.actor,
            row.actor_id,
            row.action,
            row.target,
            detail_hash
        ]))
        .unwrap();
        let hash = sha_hex(format!("{prev}\n{content}").as_bytes());
        return (detail_hash, hash);
    }
    let mut salted = salt.to_vec();
    salted.extend_from_slice(detail.as_bytes());
    let detail_hash = sha_hex(&salted);
    let mut m = b"bdft-lab audit entry\n".to_vec();
    m.extend_from_slice(prev.as_bytes());
    m.push(format as u8);
    m.extend_from_slice(&row.id.to_le_bytes());
    m.extend_from_slice(&row.at.to_le_bytes());
    match row.actor_id {
        Some(a) => {
            m.push(1);
            m.extend_from_slice(&a.to_le_bytes());
        }
        None => m.extend_from_slice(&[0; 9]),
    }
    for t in [Some(&row.actor), Some(&row.action), row.target.as_ref()] {
        match t {
            Some(t) => {
                m.push(1);
                m.extend_from_slice(&(t.len() as u64).to_le_bytes());
                m.extend_from_slice(t.as_bytes());
            }
            None => m.push(0),
        }
    }
    m.extend_from_slice(detail_hash.as_bytes());
    let hash = if format == 2 {
        hex(&hmac_sha256(key, &m))
    } else {
        sha_hex(&m)
    };
    (detail_hash, hash)
}
