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
//!
//! Files: `backup` (one backup: `VACUUM INTO` a `.partial` file — one read transaction, so a
//! consistent copy while trials are filed —, checked, hashed, renamed to its name, its manifest
//! written beside it; audited `backup.create` or `backup.fail`), `manifest` (`FILE.manifest.json`:
//! SHA-256, size, program and schema version, time, who, row counts, protocol hashes checked),
//! `checks` (what a file must pass to be kept or restored, read-only: `PRAGMA integrity_check`,
//! migrations all this program's — same number *and* checksum; unknown ones mean a newer program —,
//! each locked study's protocol hash recomputed from its parameters and every trial carrying its
//! study's hash), `restore` (copy beside the database, SHA-256 and row counts against the manifest,
//! checks, migrate, audit `backup.restore`, fold into one file, keep the replaced database as
//! `DB.replaced-TIME` by a hard link (made 0600), one rename; then list the replaced database's
//! erasures whose subjects the restored one holds again), `schedule` (period, how many kept, "back
//! up now", the listing; one backup at a time), `presence` (the serving process's heartbeat in
//! `server_runs`; a restore refuses a database a server or pilot beat on within 5 s). `erasure` (in
//! one transaction its `subject.erase` audit row first (`Change::audit_first`), then
//! `store::erasure` — the subject's row reduced to id, study, code, enrolment index, starting seat
//! and synthetic flag and marked erased, the details of the older audit rows about it redacted, its
//! stations released, its notes, surveys, records and trials deleted; each redacted entry's salt
//! deleted and its redaction recorded under the chain key —, then the write-ahead log emptied;
//! refused for a running test; the backups of the backup directory still holding each erasure's
//! data: those whose manifest counts fewer audit rows than the erasure row's id — copied before it
//! committed, no clock compared —, and those whose manifest cannot be read), `protocol_package`
//! (rendered from the study's parameters — the value `schedule::canonical_json` is of and
//! `protocol_hash` hashes, printed in full at the end —, with the locked hash on every printed page
//! and the audit signing key; every user text through `plots::esc`), `audit_signing` (the Ed25519
//! key beside the database or in `--keys-dir`, made at the first start, and the chain's HMAC key
//! derived from it — loaded by `serve` and by every command that finds the key file, so what they
//! append is keyed; a checkpoint of the audit chain signed at every start, every 5 minutes while
//! the head moves, and within a second of an entry written without the key; `verify_store`: a
//! store's chain checked read-only with the key file's keys, a store that is no bdft-lab database
//! refused — `bdft-server audit verify`).
//!
//! *Invariants:* a backup or a restored database takes its name only after its checks passed;
//! nothing is written half. The audit log keeps of an erased subject only that the erasure
//! happened, when, by whom, why, and the code; exports and statistics are computed on read and
//! leave them out.

pub mod audit_signing;
pub mod backup;
pub mod checks;
pub mod erasure;
pub mod manifest;
pub mod presence;
pub mod protocol_package;
pub mod restore;
pub mod schedule;
