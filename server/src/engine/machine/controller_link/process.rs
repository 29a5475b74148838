//! The controller this server starts: a child process on a free loopback port, handed the
//! link key through its environment and tied to this process by its standard input.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Duration;

use bdft_protocol::link_auth::{KEY_ENV, LinkKey};
use tokio::io::{AsyncBufReadExt, BufReader};

/// Starts the controller on a free loopback port and reads the port it announces.
pub(super) async fn spawn(
    bin: &PathBuf,
    args: &[String],
    key: &LinkKey,
) -> anyhow::Result<(SocketAddr, Supervised)> {
    let mut child = tokio::process::Command::new(bin)
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        // The controller exits when this pipe closes: if the server dies (even by SIGKILL),
        // no orphan keeps a machine's valve.
        .arg("--exit-with-stdin")
        // The key goes by environment, never on the command line (which every user of the
        // machine can read in /proc).
        .env(KEY_ENV, key.to_hex())
        // A key file meant for this server must not override the key handed over here.
        .env_remove("BDFT_CONTROLLER_KEY_FILE")
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .kill_on_drop(true)
        .spawn()?;
    let out = child
        .stdout
        .take()
        .ok_or_else(|| anyhow::anyhow!("no stdout"))?;
    let mut lines = BufReader::new(out).lines();
    let addr = tokio::time::timeout(Duration::from_secs(20), async {
        while let Some(line) = lines.next_line().await? {
            if let Some(a) = line.strip_prefix("listening on ") {
                return anyhow::Ok(a.trim().parse::<SocketAddr>()?);
            }
        }
        anyhow::bail!("the controller exited before announcing its address")
    })
    .await??;
    tokio::spawn(async move { while let Ok(Some(_)) = lines.next_line().await {} });
    tracing::info!(%addr, pid = child.id(), "controller started");
    let stdin = child.stdin.take();
    Ok((
        addr,
        Supervised {
            child,
            _stdin: stdin,
        },
    ))
}

/// A controller this server started. Holding its stdin open keeps it alive; when this
/// process dies, the pipe closes and the controller stops (`--exit-with-stdin`).
pub(super) struct Supervised {
    pub(super) child: tokio::process::Child,
    _stdin: Option<tokio::process::ChildStdin>,
}
