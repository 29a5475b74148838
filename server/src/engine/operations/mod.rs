//! Room **operations**: a lab's duties around its studies over the years, beyond running
//! them — erasing a subject's data on request, with the backups that still hold them
//! (`erasure`), and the protocol package for the ethics board, rendered from the hashed
//! parameters (`protocol_package`).
//!
//! *May use:* every other room (`study`, `machine`, `procedure`, `results`, `dry_runs`,
//! `accounts`) — it is above them all.

pub mod erasure;
pub mod protocol_package;
