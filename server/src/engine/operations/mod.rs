//! Room **operations**: the lab's duties to its data over the years, apart from running a
//! study — backups (`backup`: one consistent, checked copy with its `manifest`; `schedule`:
//! the server's backup directory, its period and how many it keeps), `restore` onto a
//! stopped server, the `checks` both run on a database file, and the serving process's
//! `presence` (its heartbeat, by which a restore knows a server holds the database).
//!
//! *May use:* `study` (a study's protocol hash, recomputed to check a copy).

pub mod backup;
pub mod checks;
pub mod manifest;
pub mod presence;
pub mod restore;
pub mod schedule;
