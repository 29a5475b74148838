//! What the soak reads of the server's process from /proc: its memory, its open file
//! descriptors by kind, the TCP connections its clients hold, and whether a process lives.

use std::collections::BTreeMap;

/// Resident memory of `pid` (KiB), from /proc/PID/status.
pub fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    status
        .lines()
        .find_map(|l| l.strip_prefix("VmRSS:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
}

/// The open file descriptors of `pid` by kind: `socket`, `pipe`, `anon_inode:[…]`,
/// `database` (the SQLite file, its WAL and shared memory) and `file` (anything else).
pub fn fds(pid: u32) -> Result<BTreeMap<String, usize>, String> {
    let dir = format!("/proc/{pid}/fd");
    let mut kinds = BTreeMap::new();
    for entry in std::fs::read_dir(&dir).map_err(|e| format!("{dir}: {e}"))? {
        let Ok(entry) = entry else { continue };
        // A descriptor closed between the listing and the read is gone: not counted.
        let Ok(target) = std::fs::read_link(entry.path()) else {
            continue;
        };
        let t = target.to_string_lossy();
        let kind = if t.starts_with("socket:") {
            "socket".to_string()
        } else if t.starts_with("pipe:") {
            "pipe".to_string()
        } else if t.starts_with("anon_inode:") {
            t.into_owned()
        } else if t.contains(".db") {
            "database".to_string()
        } else {
            "file".to_string()
        };
        *kinds.entry(kind).or_insert(0) += 1;
    }
    Ok(kinds)
}

/// TCP connections accepted on local `port` that the server still holds a descriptor for
/// (ESTABLISHED, or CLOSE_WAIT: the peer closed and the server has not yet), from
/// /proc/net/tcp and tcp6.
pub fn connections_to(port: u16) -> usize {
    const ESTABLISHED: &str = "01";
    const CLOSE_WAIT: &str = "08";
    let mut n = 0;
    for table in ["/proc/net/tcp", "/proc/net/tcp6"] {
        let Ok(text) = std::fs::read_to_string(table) else {
            continue;
        };
        for line in text.lines().skip(1) {
            let cols: Vec<&str> = line.split_whitespace().collect();
            let local_port = cols
                .get(1)
                .and_then(|a| a.rsplit(':').next())
                .and_then(|p| u16::from_str_radix(p, 16).ok());
            let state = cols.get(3).copied().unwrap_or_default();
            if local_port == Some(port) && (state == ESTABLISHED || state == CLOSE_WAIT) {
                n += 1;
            }
        }
    }
    n
}

/// The state letter of `pid` (R, S, T for stopped, Z for a zombie…), `None` when it is gone.
pub fn state(pid: u32) -> Option<char> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    // pid (comm) S …: the command may hold spaces and parentheses; the state follows the last ')'.
    stat.rsplit_once(')')?.1.trim_start().chars().next()
}

/// Whether `pid` is a live process (not gone, not a zombie).
pub fn alive(pid: u32) -> bool {
    state(pid).is_some_and(|s| s != 'Z' && s != 'X')
}

/// Free space (KiB) on the file system holding `path`, from df(1).
pub fn free_kib(path: &std::path::Path) -> Option<u64> {
    let out = std::process::Command::new("df")
        .arg("-Pk")
        .arg(path)
        .output()
        .ok()?;
    let text = String::from_utf8_lossy(&out.stdout);
    text.lines().nth(1)?.split_whitespace().nth(3)?.parse().ok()
}
