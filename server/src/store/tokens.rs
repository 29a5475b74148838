//! Secrets: session, station and subject tokens, and study seeds. The database keeps only
//! [`token_hash`] of a token, never the token.

/// 32 random bytes as hex: session, station and subject tokens, pairing secrets.
pub fn random_token() -> String {
    let mut b = [0u8; 32];
    getrandom::fill(&mut b).expect("the OS random source works");
    bdft_protocol::hex::encode(&b)
}

/// A random u64 (study seeds when none is given).
pub fn random_seed() -> u64 {
    let mut b = [0u8; 8];
    getrandom::fill(&mut b).expect("the OS random source works");
    // Kept below 2^53 so the seed survives JSON and JavaScript unchanged.
    u64::from_le_bytes(b) >> 11
}

/// SHA-256 hex of a token: what the database stores instead of the token.
pub fn token_hash(token: &str) -> String {
    bdft_protocol::hex::sha256(token.as_bytes())
}
