//! Mutual authentication of the server ↔ controller link. Whoever reaches the controller's
//! TCP port could otherwise start trials (move a machine) or reset someone's E-stop, and a
//! rogue "controller" could feed the server invented results.
//!
//! Both ends hold one 32-byte [`LinkKey`]. On a new connection the controller speaks first:
//! `challenge` with a fresh random nonce. The server answers `hello` with its own fresh nonce
//! and `HMAC-SHA256(key, "bdft-link v1 server" ‖ role ‖ challenge ‖ nonce)`; the controller
//! checks it in constant time and only then reads anything else, answering `hello_ack` with
//! `HMAC-SHA256(key, "bdft-link v1 controller" ‖ role ‖ challenge ‖ nonce)`, which the
//! server checks in turn. Fresh nonces on both sides make a recorded handshake worthless;
//! the labels keep the two proofs apart, so one side's proof never serves as the other's.
//!
//! This authenticates the peers when the connection opens; it does not encrypt or sign the
//! messages after it. Across an untrusted network, put the link on its own cable or VLAN or
//! inside a tunnel (WireGuard, SSH) — see the README's deployment section.

use std::fmt;
use std::path::Path;

use hmac::{Hmac, Mac};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use sha2::Sha256;
use thiserror::Error;

/// Largest frame read before a connection is authenticated: a hello is about 300 bytes, so
/// an unauthenticated peer can never make either end buffer more than this.
pub const MAX_UNAUTHENTICATED_FRAME: usize = 1024;

/// The environment variable that hands a controller its key as 64 hex digits (what the
/// server does for the controller it starts: unlike the command line, a process's
/// environment is readable only by its own user).
pub const KEY_ENV: &str = "BDFT_CONTROLLER_KEY";

/// What a connection is for. The E-stop path is a connection of its own, so an E-stop
/// never waits behind operator input or records on the control connection; it carries
/// only `e_stop`, `status` and `heartbeat`, so it can stop the machine but never move it
/// or clear a latch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum LinkRole {
    Control,
    EStop,
}

impl LinkRole {
    fn label(self) -> u8 {
        match self {
            LinkRole::Control => b'c',
            LinkRole::EStop => b'e',
        }
    }
}

/// 32 bytes on the wire as 64 lowercase hex digits: nonces and proofs.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Bytes32(pub [u8; 32]);

impl Bytes32 {
    /// 32 bytes from the operating system's random source.
    pub fn random() -> Result<Self, KeyError> {
        let mut b = [0u8; 32];
        getrandom::fill(&mut b).map_err(|e| KeyError::Random(e.to_string()))?;
        Ok(Self(b))
    }

    pub fn to_hex(&self) -> String {
        crate::hex::encode(&self.0)
    }

    pub fn from_hex(s: &str) -> Result<Self, KeyError> {
        crate::hex::decode(s.trim())
            .map(Self)
            .ok_or(KeyError::Format)
    }
}

impl fmt::Debug for Bytes32 {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.to_hex())
    }
}

impl Serialize for Bytes32 {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.serialize_str(&self.to_hex())
    }
}

impl<'de> Deserialize<'de> for Bytes32 {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        let s = String::deserialize(d)?;
        Self::from_hex(&s).map_err(|_| serde::de::Error::custom("expected 64 hex digits"))
    }
}

#[derive(Debug, Error)]
pub enum KeyError {
    #[error("a link key is 64 hex digits (32 bytes); make one with `bdft-controller keygen FILE`")]
    Format,
    #[error("reading the key file {path}: {error}")]
    Read { path: String, error: String },
    #[error("the key file {path} can be read by other users (mode {mode:o}); `chmod 600 {path}`")]
    Exposed { path: String, mode: u32 },
    #[error("writing the key file {path}: {error}")]
    Write { path: String, error: String },
    #[error("the operating system's random source failed: {0}")]
    Random(String),
}

/// The shared secret of a server and its controller.
#[derive(Clone)]
pub struct LinkKey(Bytes32);

/// Never printed: a key in a log line is a key given away.
impl fmt::Debug for LinkKey {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str("LinkKey(…)")
    }
}

impl LinkKey {
    pub fn generate() -> Result<Self, KeyError> {
        Bytes32::random().map(Self)
    }

    pub fn from_hex(s: &str) -> Result<Self, KeyError> {
        Bytes32::from_hex(s).map(Self)
    }

    pub fn to_hex(&self) -> String {
        self.0.to_hex()
    }

    /// Reads a key file (64 hex digits), refusing one that other users can read.
    pub fn load(path: &Path) -> Result<Self, KeyError> {
        let shown = path.display().to_string();
        #[cfg(unix)]
        {
            use std::os::unix::fs::PermissionsExt;
            let meta = std::fs::metadata(path).map_err(|e| KeyError::Read {
                path: shown.clone(),
                error: e.to_string(),
            })?;
            let mode = meta.permissions().mode() & 0o777;
            if mode & 0o077 != 0 {
                return Err(KeyError::Exposed { path: shown, mode });
            }
        }
        let text = std::fs::read_to_string(path).map_err(|e| KeyError::Read {
            path: shown,
            error: e.to_string(),
        })?;
        Self::from_hex(&text)
    }

    /// Makes a new key and writes it to a new file only its owner can read (an existing
    /// file is never overwritten: that would silently lock out the other end).
    pub fn create_file(path: &Path) -> Result<Self, KeyError> {
        use std::io::Write;
        let key = Self::generate()?;
        let write_err = |e: std::io::Error| KeyError::Write {
            path: path.display().to_string(),
            error: e.to_string(),
        };
        let mut open = std::fs::OpenOptions::new();
        open.write(true).create_new(true);
        #[cfg(unix)]
        {
            use std::os::unix::fs::OpenOptionsExt;
            open.mode(0o600);
        }
        let mut file = open.open(path).map_err(write_err)?;
        writeln!(file, "{}", key.to_hex()).map_err(write_err)?;
        file.sync_all().map_err(write_err)?;
        Ok(key)
    }

    fn mac(
        &self,
        label: &[u8],
        role: LinkRole,
        challenge: &Bytes32,
        nonce: &Bytes32,
    ) -> Hmac<Sha256> {
        let mut mac = Hmac::<Sha256>::new_from_slice(&self.0.0).expect("HMAC takes any key length");
        mac.update(label);
        mac.update(&[role.label()]);
        mac.update(&challenge.0);
        mac.update(&nonce.0);
        mac
    }

    /// The server's proof, sent in `hello`.
    pub fn server_proof(&self, role: LinkRole, challenge: &Bytes32, nonce: &Bytes32) -> Bytes32 {
        Bytes32(
            self.mac(SERVER, role, challenge, nonce)
                .finalize()
                .into_bytes()
                .into(),
        )
    }

    /// The controller's proof, sent in `hello_ack`.
    pub fn controller_proof(
        &self,
        role: LinkRole,
        challenge: &Bytes32,
        nonce: &Bytes32,
    ) -> Bytes32 {
        Bytes32(
            self.mac(CONTROLLER, role, challenge, nonce)
                .finalize()
                .into_bytes()
                .into(),
        )
    }

    /// Checks the server's proof in constant time.
    pub fn verify_server(
        &self,
        role: LinkRole,
        challenge: &Bytes32,
        nonce: &Bytes32,
        proof: &Bytes32,
    ) -> bool {
        self.mac(SERVER, role, challenge, nonce)
            .verify_slice(&proof.0)
            .is_ok()
    }

    /// Checks the controller's proof in constant time.
    pub fn verify_controller(
        &self,
        role: LinkRole,
        challenge: &Bytes32,
        nonce: &Bytes32,
        proof: &Bytes32,
    ) -> bool {
        self.mac(CONTROLLER, role, challenge, nonce)
            .verify_slice(&proof.0)
            .is_ok()
    }
}

const SERVER: &[u8] = b"bdft-link v1 server";
const CONTROLLER: &[u8] = b"bdft-link v1 controller";

#[cfg(test)]
mod tests {
    use super::*;

    fn key(byte: u8) -> LinkKey {
        LinkKey(Bytes32([byte; 32]))
    }

    /// Pinned against Python's hmac module:
    /// `hmac.new(bytes([7]*32), b"bdft-link v1 server" + b"c" + bytes([1]*32) + bytes([2]*32), "sha256").hexdigest()`
    #[test]
    fn server_proof_is_hmac_sha256_of_label_role_and_nonces() {
        let p = key(7).server_proof(LinkRole::Control, &Bytes32([1; 32]), &Bytes32([2; 32]));
        assert_eq!(p.to_hex(), SERVER_PROOF_FIXTURE);
    }

    const SERVER_PROOF_FIXTURE: &str =
        "4ba5d0d1cd0dca76b71771e75139c39984b83122dbc87b8ef0c0b707d2182232";

    #[test]
    fn proofs_bind_key_role_nonces_and_side() {
        let (c, n) = (Bytes32([1; 32]), Bytes32([2; 32]));
        let k = key(7);
        let p = k.server_proof(LinkRole::Control, &c, &n);
        assert!(k.verify_server(LinkRole::Control, &c, &n, &p));
        assert!(
            !key(8).verify_server(LinkRole::Control, &c, &n, &p),
            "another key"
        );
        assert!(
            !k.verify_server(LinkRole::EStop, &c, &n, &p),
            "another role"
        );
        assert!(
            !k.verify_server(LinkRole::Control, &Bytes32([3; 32]), &n, &p),
            "another challenge"
        );
        assert!(
            !k.verify_server(LinkRole::Control, &c, &Bytes32([3; 32]), &p),
            "another nonce"
        );
        assert!(
            !k.verify_controller(LinkRole::Control, &c, &n, &p),
            "the server's proof is not the controller's"
        );
    }

    #[test]
    fn hex_round_trips_and_bad_keys_are_refused() {
        let k = LinkKey::generate().unwrap();
        assert_eq!(LinkKey::from_hex(&k.to_hex()).unwrap().to_hex(), k.to_hex());
        assert!(LinkKey::from_hex("abc").is_err());
        assert!(LinkKey::from_hex(&"g".repeat(64)).is_err());
        assert!(
            format!("{k:?}").find(&k.to_hex()).is_none(),
            "Debug never shows the key"
        );
    }

    #[cfg(unix)]
    #[test]
    fn key_files_are_private_and_never_overwritten() {
        use std::os::unix::fs::PermissionsExt;
        let dir = std::env::temp_dir().join(format!("bdft-key-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("link.key");
        let _ = std::fs::remove_file(&path);
        let made = LinkKey::create_file(&path).unwrap();
        assert_eq!(
            std::fs::metadata(&path).unwrap().permissions().mode() & 0o777,
            0o600
        );
        assert_eq!(LinkKey::load(&path).unwrap().to_hex(), made.to_hex());
        assert!(matches!(
            LinkKey::create_file(&path),
            Err(KeyError::Write { .. })
        ));
        std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o644)).unwrap();
        assert!(matches!(
            LinkKey::load(&path),
            Err(KeyError::Exposed { mode: 0o644, .. })
        ));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
