//! The one log set-up of both programs: to standard error, filtered by `RUST_LOG` (default
//! `info`), coloured only on a terminal — a log written to a file or a pipe (a lab's
//! service manager, a test's capture) carries no escape codes — and never when `NO_COLOR`
//! is set to anything (<https://no-color.org>).

use std::io::IsTerminal;

/// Installs the subscriber; call once, first thing.
pub fn init() {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()),
        )
        .with_writer(std::io::stderr)
        .with_ansi(colour(
            std::io::stderr().is_terminal(),
            std::env::var_os("NO_COLOR").as_deref(),
        ))
        .init();
}

/// Whether to colour: on a terminal, unless `NO_COLOR` holds a non-empty value.
fn colour(terminal: bool, no_color: Option<&std::ffi::OsStr>) -> bool {
    terminal && no_color.is_none_or(|v| v.is_empty())
}

#[cfg(test)]
mod tests {
    use super::colour;
    use std::ffi::OsStr;

    #[test]
    fn colour_only_on_a_terminal_without_no_color() {
        assert!(colour(true, None));
        assert!(colour(true, Some(OsStr::new(""))));
        assert!(!colour(true, Some(OsStr::new("1"))));
        assert!(!colour(false, None));
    }
}
