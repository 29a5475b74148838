//! Password hashing with bounded memory: argon2id with the crate's default parameters
//! (19 MiB, 2 passes, 1 lane — the hashes stored since the first release), computed by at
//! most [`AT_ONCE`] blocking threads at a time, each in one of [`AT_ONCE`] working buffers
//! allocated once and reused.
//!
//! Why not `Argon2::default().verify_password` on `spawn_blocking`: each call allocates
//! 19 MiB on whichever blocking thread runs it; glibc keeps that in the thread's arena after
//! the free (the chunk is under its mmap threshold once one such chunk was freed), so a
//! burst of logins left 19 MiB resident per blocking thread — 780 MB after three bursts,
//! never returned. With the buffers here the process holds at most `AT_ONCE` × 19 MiB for
//! passwords, whatever the load.

use std::sync::{LazyLock, Mutex};

use argon2::password_hash::{Output, ParamsString, PasswordHash, SaltString};
use argon2::{Algorithm, Argon2, Block, Params, Version};
use tokio::sync::Semaphore;

/// Password computations running at once (each holds one working buffer).
pub const AT_ONCE: usize = 2;

/// The parameters of every hash this server makes: the argon2 crate's defaults, which are
/// also what every stored hash was made with.
fn params() -> Params {
    Params::DEFAULT
}

/// The process's one set of working buffers. One per process, not per `AppState`: what it
/// bounds is the process's memory.
static WORKERS: LazyLock<Workers> = LazyLock::new(|| Workers {
    permits: Semaphore::new(AT_ONCE),
    buffers: Mutex::new(Vec::new()),
});

#[derive(Debug)]
struct Workers {
    permits: Semaphore,
    /// Buffers not in use; a holder of a permit takes one (or makes one: at most `AT_ONCE`
    /// ever exist, since at most `AT_ONCE` permits are held).
    buffers: Mutex<Vec<Vec<Block>>>,
}

impl Workers {
    /// Runs `work` on a blocking thread with a working buffer, waiting for a permit.
    async fn run<T: Send + 'static>(
        &'static self,
        work: impl FnOnce(&mut [Block]) -> T + Send + 'static,
    ) -> anyhow::Result<T> {
        let _permit = self.permits.acquire().await?;
        let pool = &self.buffers;
        let mut buffer = pool
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .pop()
            .unwrap_or_default();
        let (buffer, out) = tokio::task::spawn_blocking(move || {
            let blocks = params().block_count();
            if buffer.len() < blocks {
                buffer = vec![Block::new(); blocks];
            }
            let out = work(&mut buffer);
            (buffer, out)
        })
        .await?;
        pool.lock().unwrap_or_else(|p| p.into_inner()).push(buffer);
        Ok(out)
    }
}

/// A new argon2id PHC string of `password` (random salt).
pub async fn hash(password: &str) -> anyhow::Result<String> {
    let mut salt = [0u8; 16];
    getrandom::fill(&mut salt).map_err(|e| anyhow::anyhow!("random salt: {e}"))?;
    let pw = password.to_string();
    WORKERS
        .run(move |memory| hash_with(&pw, &salt, memory))
        .await?
}

/// Whether `password` matches the PHC string `phc` (false for a malformed string too).
pub async fn verify(password: &str, phc: &str) -> anyhow::Result<bool> {
    let (pw, phc) = (password.to_string(), phc.to_string());
    WORKERS
        .run(move |memory| verify_with(&pw, &phc, memory))
        .await
}

fn hash_with(password: &str, salt: &[u8], memory: &mut [Block]) -> anyhow::Result<String> {
    let e = |e: &dyn std::fmt::Display| anyhow::anyhow!("argon2: {e}");
    let params = params();
    let salt = SaltString::encode_b64(salt).map_err(|x| e(&x))?;
    let mut raw_salt = [0u8; 64];
    let raw_salt = salt.decode_b64(&mut raw_salt).map_err(|x| e(&x))?;
    let argon = Argon2::new(Algorithm::Argon2id, Version::V0x13, params.clone());
    let output = Output::init_with(Params::DEFAULT_OUTPUT_LEN, |out| {
        argon
            .hash_password_into_with_memory(password.as_bytes(), raw_salt, out, &mut *memory)
            .map_err(Into::into)
    })
    .map_err(|x| e(&x))?;
    let phc = PasswordHash {
        algorithm: Algorithm::Argon2id.ident(),
        version: Some(Version::V0x13.into()),
        params: ParamsString::try_from(&params).map_err(|x| e(&x))?,
        salt: Some(salt.as_salt()),
        hash: Some(output),
    };
    Ok(phc.to_string())
}

fn verify_with(password: &str, phc: &str, memory: &mut [Block]) -> bool {
    let Ok(hash) = PasswordHash::new(phc) else {
        return false;
    };
    let (Some(salt), Some(expected)) = (hash.salt, hash.hash) else {
        return false;
    };
    let (Ok(algorithm), Ok(params)) =
        (Algorithm::try_from(hash.algorithm), Params::try_from(&hash))
    else {
        return false;
    };
    let version = match hash.version.map(Version::try_from).transpose() {
        Ok(v) => v.unwrap_or_default(),
        Err(_) => return false,
    };
    if params.block_count() > memory.len() {
        // Not a hash this server made: refusing it keeps memory bounded.
        tracing::error!(
            m_cost = params.m_cost(),
            "a stored password hash needs more memory than the server allows"
        );
        return false;
    }
    let mut raw_salt = [0u8; 64];
    let Ok(raw_salt) = salt.decode_b64(&mut raw_salt) else {
        return false;
    };
    let argon = Argon2::new(algorithm, version, params);
    Output::init_with(expected.len(), |out| {
        argon
            .hash_password_into_with_memory(password.as_bytes(), raw_salt, out, &mut *memory)
            .map_err(Into::into)
    })
    // `Output`'s equality is constant-time.
    .is_ok_and(|computed| computed == expected)
}

#[cfg(test)]
mod tests {
    use argon2::password_hash::{PasswordHasher, PasswordVerifier, SaltString};

    #[tokio::test]
    async fn hashes_are_those_of_the_argon2_crate_both_ways() {
        // Ours verifies with the crate's own verifier, so every stored hash stays valid…
        let ours = super::hash("correct horse battery").await.unwrap();
        assert!(
            ours.starts_with("$argon2id$v=19$m=19456,t=2,p=1$"),
            "{ours}"
        );
        let parsed = argon2::PasswordHash::new(&ours).unwrap();
        assert!(
            argon2::Argon2::default()
                .verify_password(b"correct horse battery", &parsed)
                .is_ok()
        );
        // …and a hash the crate made (as the server did before) verifies here.
        let salt = SaltString::encode_b64(b"sixteen byte salt").unwrap();
        let theirs = argon2::Argon2::default()
            .hash_password(b"correct horse battery", &salt)
            .unwrap()
            .to_string();
        assert!(
            super::verify("correct horse battery", &theirs)
                .await
                .unwrap()
        );
        assert!(!super::verify("wrong horse battery", &theirs).await.unwrap());
        assert!(
            !super::verify("correct horse battery", "not a hash")
                .await
                .unwrap()
        );
    }

    #[tokio::test]
    async fn a_hash_asking_for_more_memory_is_refused() {
        let params = argon2::Params::new(64 * 1024, 1, 1, None).unwrap();
        let salt = SaltString::encode_b64(b"sixteen byte salt").unwrap();
        let big = argon2::Argon2::new(argon2::Algorithm::Argon2id, argon2::Version::V0x13, params)
            .hash_password(b"pw", &salt)
            .unwrap()
            .to_string();
        assert!(!super::verify("pw", &big).await.unwrap());
    }
}
