//! HTTPS for a lab network: without it the session cookie and the subjects' answers cross
//! the wire in clear text. Either the lab's own certificate and key (PEM files), or a
//! self-signed certificate this server makes at its first start for the machine's names and
//! keeps beside the database, so the stations can pin its fingerprint once (it is printed at
//! every start) and a restart does not make them check a new one.

use std::path::{Path, PathBuf};
use std::sync::Arc;

use anyhow::Context;
use sha2::{Digest, Sha256};
use tokio_rustls::TlsAcceptor;
use tokio_rustls::rustls::ServerConfig;
use tokio_rustls::rustls::crypto::ring::default_provider;
use tokio_rustls::rustls::pki_types::pem::PemObject;
use tokio_rustls::rustls::pki_types::{CertificateDer, PrivateKeyDer};

/// A loaded certificate, ready to accept connections.
#[derive(Clone)]
pub struct Tls {
    pub acceptor: TlsAcceptor,
    /// SHA-256 of the certificate (DER), as browsers show it: `AB:CD:…`.
    pub fingerprint: String,
}

impl std::fmt::Debug for Tls {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tls")
            .field("fingerprint", &self.fingerprint)
            .finish_non_exhaustive()
    }
}

/// The lab's certificate chain and private key, PEM files.
pub fn from_files(cert: &Path, key: &Path) -> anyhow::Result<Tls> {
    let chain: Vec<CertificateDer<'static>> = CertificateDer::pem_file_iter(cert)
        .with_context(|| format!("--tls-cert {}: not readable", cert.display()))?
        .collect::<Result<_, _>>()
        .with_context(|| format!("--tls-cert {}: not a PEM certificate", cert.display()))?;
    if chain.is_empty() {
        anyhow::bail!(
            "--tls-cert {}: no certificate in the file (PEM `BEGIN CERTIFICATE` expected)",
            cert.display()
        );
    }
    let key = PrivateKeyDer::from_pem_file(key).with_context(|| {
        format!(
            "--tls-key {}: no PEM private key in the file (PKCS#8, PKCS#1 or SEC1)",
            key.display()
        )
    })?;
    build(chain, key)
}

/// Where a self-signed certificate is kept: beside the database, named after it.
pub fn self_signed_paths(db: &Path) -> (PathBuf, PathBuf) {
    (
        db.with_extension("tls-cert.pem"),
        db.with_extension("tls-key.pem"),
    )
}

/// The self-signed certificate kept beside the database, made for `names` (DNS names or IP
/// addresses) the first time. The key file is readable by its owner only.
///
/// A certificate already there is used as it is, whatever its subject (those of earlier
/// releases say "rcgen self signed cert"): the stations have pinned its fingerprint, and a new
/// one would make every station check the server again.
pub fn self_signed(db: &Path, names: &[String]) -> anyhow::Result<Tls> {
    let (cert, key) = self_signed_paths(db);
    if !(cert.exists() && key.exists()) {
        let signing_key = rcgen::KeyPair::generate().context("making a TLS key")?;
        let made = certificate_params(names)?
            .self_signed(&signing_key)
            .context("making a self-signed certificate")?;
        write_private(&key, signing_key.serialize_pem().as_bytes())?;
        std::fs::write(&cert, made.pem()).with_context(|| format!("writing {}", cert.display()))?;
        tracing::info!(cert = %cert.display(), ?names, "made a self-signed certificate");
    }
    from_files(&cert, &key)
}

/// Who a self-signed certificate names as its subject (and, being self-signed, its issuer):
/// what a browser shows when asked to trust it, so it says whose server it is.
fn certificate_params(names: &[String]) -> anyhow::Result<rcgen::CertificateParams> {
    let mut params = rcgen::CertificateParams::new(names.to_vec())
        .context("the names of a self-signed certificate")?;
    let mut subject = rcgen::DistinguishedName::new();
    subject.push(
        rcgen::DnType::CommonName,
        format!("bdft-lab server {}", server_name(names)),
    );
    subject.push(rcgen::DnType::OrganizationName, "bdft-lab");
    params.distinguished_name = subject;
    Ok(params)
}

/// The name that tells this server from another lab's: the first of `names` that is not a
/// loopback one (the host name, or the address it listens on), else the first.
fn server_name(names: &[String]) -> &str {
    let loopback = |n: &str| {
        n == "localhost"
            || n.parse::<std::net::IpAddr>()
                .is_ok_and(|ip| ip.is_loopback())
    };
    names
        .iter()
        .find(|n| !loopback(n))
        .or(names.first())
        .map_or("", String::as_str)
}

/// The names a self-signed certificate covers: loopback, the machine's host name, and the
/// address the server listens on when it is a specific one.
pub fn machine_names(listen: std::net::SocketAddr) -> Vec<String> {
    let mut names = vec!["localhost".to_string(), "127.0.0.1".into(), "::1".into()];
    if let Ok(host) = std::fs::read_to_string("/proc/sys/kernel/hostname") {
        let host = host.trim();
        if !host.is_empty() {
            names.push(host.to_string());
        }
    }
    let ip = listen.ip();
    if !ip.is_unspecified() && !ip.is_loopback() {
        names.push(ip.to_string());
    }
    names.dedup();
    names
}

fn write_private(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    use std::io::Write;
    let mut f = crate::files::new_private()
        .open(path)
        .with_context(|| format!("creating {}", path.display()))?;
    f.write_all(bytes)
        .with_context(|| format!("writing {}", path.display()))
}

fn build(chain: Vec<CertificateDer<'static>>, key: PrivateKeyDer<'static>) -> anyhow::Result<Tls> {
    let fingerprint = fingerprint(&chain[0]);
    let mut config = ServerConfig::builder_with_provider(Arc::new(default_provider()))
        .with_safe_default_protocol_versions()
        .context("TLS protocol versions")?
        .with_no_client_auth()
        .with_single_cert(chain, key)
        .context("the TLS key does not match the certificate")?;
    config.alpn_protocols = vec![b"http/1.1".to_vec()];
    Ok(Tls {
        acceptor: TlsAcceptor::from(Arc::new(config)),
        fingerprint,
    })
}

/// SHA-256 of a certificate, upper-case hex bytes joined by colons.
pub fn fingerprint(cert: &CertificateDer<'_>) -> String {
    Sha256::digest(cert.as_ref())
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(":")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_self_signed_certificate_is_kept_and_reused() {
        let dir = std::env::temp_dir().join(format!("bdft-tls-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let db = dir.join("lab.db");
        let first = self_signed(&db, &["localhost".into()]).unwrap();
        let again = self_signed(&db, &["localhost".into()]).unwrap();
        assert_eq!(first.fingerprint, again.fingerprint);
        assert_eq!(first.fingerprint.len(), 32 * 3 - 1);
        let (_, key) = self_signed_paths(&db);
        use std::os::unix::fs::PermissionsExt;
        let mode = std::fs::metadata(&key).unwrap().permissions().mode();
        assert_eq!(mode & 0o777, 0o600, "the key is its owner's only");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_new_certificate_names_the_lab_server_by_its_host() {
        let names = |n: &[&str]| n.iter().map(|s| s.to_string()).collect::<Vec<_>>();
        assert_eq!(
            server_name(&names(&[
                "localhost",
                "127.0.0.1",
                "::1",
                "rig-pc",
                "10.0.0.2"
            ])),
            "rig-pc"
        );
        assert_eq!(server_name(&names(&["localhost", "::1"])), "localhost");
        let params = certificate_params(&names(&["localhost", "rig-pc"])).unwrap();
        let subject = &params.distinguished_name;
        let text = |ty| match subject.get(&ty) {
            Some(rcgen::DnValue::Utf8String(s)) => s.clone(),
            other => panic!("{ty:?}: {other:?}"),
        };
        assert_eq!(text(rcgen::DnType::CommonName), "bdft-lab server rig-pc");
        assert_eq!(text(rcgen::DnType::OrganizationName), "bdft-lab");

        // An earlier release's certificate, with rcgen's default subject, is kept: its
        // fingerprint is the one the stations pinned.
        let dir = std::env::temp_dir().join(format!("bdft-tls-old-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let db = dir.join("lab.db");
        let (cert, key) = self_signed_paths(&db);
        let old = rcgen::generate_simple_self_signed(vec!["localhost".into()]).unwrap();
        std::fs::write(&cert, old.cert.pem()).unwrap();
        write_private(&key, old.signing_key.serialize_pem().as_bytes()).unwrap();
        let kept = self_signed(&db, &names(&["localhost", "rig-pc"])).unwrap();
        assert_eq!(kept.fingerprint, fingerprint(old.cert.der()));
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_files_are_refused_with_the_flag_named() {
        let dir = std::env::temp_dir().join(format!("bdft-tls-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let junk = dir.join("junk.pem");
        std::fs::write(&junk, "not a certificate").unwrap();
        let err = format!("{:#}", from_files(&junk, &junk).unwrap_err());
        assert!(err.contains("--tls-cert"), "{err}");
        let err = format!(
            "{:#}",
            from_files(&dir.join("missing.pem"), &junk).unwrap_err()
        );
        assert!(err.contains("not readable"), "{err}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
