//! Lower-case hex, the one text form of every hash, key, token and signature the platform
//! stores or prints (the server's tokens and hashes, the link key, the audit chain).

use sha2::{Digest, Sha256};

/// `bytes` as lower-case hex, without a formatter per byte (verifying a million audit
/// entries encodes two million hashes).
pub fn encode(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut out = String::with_capacity(2 * bytes.len());
    for b in bytes {
        out.push(char::from(DIGITS[usize::from(b >> 4)]));
        out.push(char::from(DIGITS[usize::from(b & 15)]));
    }
    out
}

/// Exactly `N` bytes from `2 N` hex digits (either case), or `None`.
pub fn decode<const N: usize>(hex: &str) -> Option<[u8; N]> {
    if hex.len() != 2 * N || !hex.bytes().all(|c| c.is_ascii_hexdigit()) {
        return None;
    }
    let mut out = [0u8; N];
    for (i, b) in out.iter_mut().enumerate() {
        *b = u8::from_str_radix(&hex[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

/// The SHA-256 of `bytes`, in hex.
pub fn sha256(bytes: &[u8]) -> String {
    encode(&Sha256::digest(bytes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encodes_and_decodes_as_the_standard_test_vectors_say() {
        // FIPS 180-2, appendix B.1: SHA-256("abc").
        assert_eq!(
            sha256(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(encode(&[0x00, 0x0f, 0xa5, 0xff]), "000fa5ff");
        assert_eq!(decode::<4>("000FA5ff"), Some([0x00, 0x0f, 0xa5, 0xff]));
        assert_eq!(decode::<4>("000fa5f"), None);
        assert_eq!(decode::<2>("0g00"), None);
        assert_eq!(decode::<1>("+f"), None, "from_str_radix would take a sign");
    }
}
