//! Room **operations**: the lab's duties to its data and its ethics board over the years,
//! apart from running a study.
//!
//! - Backups: `backup` (one consistent, checked copy with its `manifest`), `schedule` (the
//!   server's backup directory, its period and how many it keeps), `restore` onto a stopped
//!   server, the `checks` both run on a database file, and the serving process's `presence`
//!   (its heartbeat, by which a restore knows a server holds the database).
//! - Erasure on request: `erasure` erases a subject's data and lists the backups (by their
//!   manifests) that still hold them.
//! - The audit log's integrity: `audit_signing`, the server's key that signs the hash
//!   chain's checkpoints (`store::audit_chain`), the task that signs one every 5 minutes,
//!   and the read-only check of a database file's chain.
//! - The ethics board's protocol package: `protocol_package`, rendered from the parameters
//!   the protocol hash is computed from.
//!
//! *May use:* `study` (a study's parameters and protocol hash: to check a copy, to render
//! the package), `procedure` (the station's texts and the attempts a test allows, for the
//! package), `results` (the exports' codebook: the data kept, for the package), and what
//! those use (`machine`).

pub mod audit_signing;
pub mod backup;
pub mod checks;
pub mod erasure;
pub mod manifest;
pub mod presence;
pub mod protocol_package;
pub mod restore;
pub mod schedule;
