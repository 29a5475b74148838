//! The protocol engine: the study's rules with no HTTP in them, in seven rooms. Each room is a
//! folder with a module doc saying what it holds and which rooms it may use; imports between
//! rooms run one way only (checked by the integration test `structure`, drawn in ARCHITECTURE.md):
//!
//! ```text
//! dry_runs   → results, procedure, machine, study      (the top room)
//! operations → results, procedure, machine, study      (the lab's duties to its data and
//!                                                        its ethics board)
//! results    → machine, study
//! procedure  → machine, study
//! machine    → study
//! study      → nothing                                 (every room builds on it)
//! accounts   → nothing                                 (stands alone)
//! ```
//!
//! A room may use the rooms listed after its arrow, and no other. Every change
//! goes through `store::Change`, so it is committed with its audit row. The root holds only
//! what every room shares: `name_rule` — the one rule of every name (studies, stations,
//! configuration versions, usernames and sites, the last two with a stricter alphabet after
//! it): a length in characters, no control characters, no bidirectional marks, overrides or
//! isolates —, `check_name` (its 1–200 of a study, a station or a configuration version),
//! `check_reason`, `beat_every` (the heartbeat of a pilot process or a server in its
//! database), and `COMPUTE`, the one permit the statistics, the planner and the workbench's
//! analysis take in turn, off the async threads.
//!
//! *Invariant:* nothing here imports axum; `http` calls in, never the reverse.

pub mod accounts;
pub mod dry_runs;
pub mod machine;
pub mod operations;
pub mod procedure;
pub mod results;
pub mod study;

use crate::error::{AppError, Result};

/// The statistics, the planner and the workbench's analysis run one at a time, off the async
/// threads: each is seconds of CPU at most (the work is bounded per request), so a burst of
/// requests waits its turn instead of taking every core from the live sockets.
pub static COMPUTE: tokio::sync::Semaphore = tokio::sync::Semaphore::const_new(1);

/// Runs `beat` every `period` until the returned task is aborted: how a process tells the
/// database it is alive (a pilot process, a server), so others can tell when it stopped. A
/// failed beat is logged and the next one tries again.
pub fn beat_every<F, Fut>(
    period: std::time::Duration,
    what: &'static str,
    beat: F,
) -> tokio::task::JoinHandle<()>
where
    F: Fn() -> Fut + Send + 'static,
    Fut: std::future::Future<Output = Result<()>> + Send,
{
    tokio::spawn(async move {
        let mut tick = tokio::time::interval(period);
        loop {
            tick.tick().await;
            if let Err(e) = beat().await {
                tracing::warn!("{what} heartbeat: {e}");
            }
        }
    })
}

/// Longest name of a study, a station or a configuration version, in characters.
pub const MAX_NAME_CHARS: usize = 200;

/// A study's, a station's or a configuration version's name: 1 to [`MAX_NAME_CHARS`]
/// characters, not only spaces, none of them one [`name_rule`] refuses.
pub fn check_name(name: &str) -> Result<()> {
    name_rule("name", name, 1, MAX_NAME_CHARS).map_err(AppError::BadRequest)
}

/// The one rule of every name someone gives a thing (a study, a station, a configuration
/// version, an account, a site): `min` to `max` characters — counted as characters, as the
/// message says, not bytes —, not only spaces, and none of the characters that make a name
/// read, print or export other than it is: control characters (NUL, tab, line breaks, the
/// rest of C0 and C1, DEL: a CSV row or a log line split in two) and the bidirectional
/// marks, embeddings, overrides and isolates (text shown reversed or reordered: a name
/// posing as another). Kinds of names with a stricter alphabet (usernames, sites) check it
/// after this. `field` is how the error names the value.
pub fn name_rule(
    field: &str,
    name: &str,
    min: usize,
    max: usize,
) -> std::result::Result<(), String> {
    let chars = name.chars().count();
    if name.trim().is_empty() || chars < min || chars > max {
        let min = min.max(1);
        return Err(format!(
            "{field}: {min} to {max} characters, not only spaces (it has {chars})"
        ));
    }
    match name.chars().find(|&c| refused_in_names(c).is_some()) {
        None => Ok(()),
        Some(c) => Err(format!(
            "{field}: it holds U+{:04X} ({}), which no name may hold; a name may hold letters, digits, spaces, punctuation and symbols of any script, but no control characters (NUL, tab, line breaks, U+0000–U+001F, U+007F–U+009F) and no bidirectional marks, embeddings, overrides or isolates (U+061C, U+200E, U+200F, U+202A–U+202E, U+2066–U+2069)",
            u32::from(c),
            refused_in_names(c).unwrap_or_default()
        )),
    }
}

/// What `c` is, when no name may hold it.
fn refused_in_names(c: char) -> Option<&'static str> {
    Some(match c {
        '\0' => "NUL",
        '\t' => "a tab",
        '\n' => "a line feed",
        '\r' => "a carriage return",
        c if c.is_control() => "a control character",
        '\u{061C}' => "the Arabic letter mark",
        '\u{200E}' => "the left-to-right mark",
        '\u{200F}' => "the right-to-left mark",
        '\u{202A}'..='\u{202E}' => "a bidirectional embedding or override",
        '\u{2066}'..='\u{2069}' => "a bidirectional isolate",
        _ => return None,
    })
}

/// A reason given for an irreversible action: 1 to 500 characters.
pub fn check_reason(reason: &str) -> Result<()> {
    if reason.trim().is_empty() || reason.chars().count() > 500 {
        return Err(AppError::BadRequest("reason: 1 to 500 characters".into()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_counted_in_characters() {
        assert!(check_name(&"é".repeat(200)).is_ok());
        let e = check_name(&"é".repeat(201)).unwrap_err().to_string();
        assert!(
            e.contains("1 to 200 characters") && e.contains("201"),
            "{e}"
        );
        for empty in ["", "   ", "\u{3000}"] {
            assert!(check_name(empty).is_err(), "{empty:?}");
        }
        let e = name_rule("username", "ab", 3, 40).unwrap_err();
        assert!(e.starts_with("username: 3 to 40 characters"), "{e}");
    }

    #[test]
    fn names_refuse_control_and_bidirectional_characters_naming_them() {
        for (name, code, what) in [
            ("a\0b", "U+0000", "NUL"),
            ("a\tb", "U+0009", "a tab"),
            ("a\nb", "U+000A", "a line feed"),
            ("a\rb", "U+000D", "a carriage return"),
            ("a\u{1B}[31m", "U+001B", "a control character"),
            ("a\u{7F}", "U+007F", "a control character"),
            ("a\u{85}", "U+0085", "a control character"),
            ("a\u{9F}", "U+009F", "a control character"),
            ("\u{061C}a", "U+061C", "Arabic letter mark"),
            ("\u{200E}a", "U+200E", "left-to-right mark"),
            ("\u{200F}a", "U+200F", "right-to-left mark"),
            ("\u{202A}a", "U+202A", "embedding or override"),
            ("\u{202E}a", "U+202E", "embedding or override"),
            ("\u{2066}a", "U+2066", "isolate"),
            ("\u{2069}a", "U+2069", "isolate"),
        ] {
            let e = check_name(name).unwrap_err().to_string();
            assert!(
                e.starts_with("name: it holds ") && e.contains(code) && e.contains(what),
                "{name:?}: {e}"
            );
            assert!(
                e.contains("no control characters") && e.contains("bidirectional"),
                "{e}"
            );
        }
        for fine in [
            "Study 2 — Delft",
            "試験",
            "Ünïcode ✓",
            "a\u{2065}",
            "\u{202F}x",
            "\u{A0}x",
        ] {
            assert!(check_name(fine).is_ok(), "{fine:?}");
        }
    }
}
