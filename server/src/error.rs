//! The one error type of the server, shared by every layer. It says what went wrong in words
//! a user can act on; `http::error` turns it into a status code and a JSON body (4xx for a
//! user's mistake or a race between users, 500 only for bugs and broken infrastructure).
//! Nothing here knows about HTTP.

use bdft_protocol::study::FieldError;

#[derive(Debug, thiserror::Error)]
pub enum AppError {
    /// A value the user sent is not allowed; the message names it and what is allowed.
    #[error("{0}")]
    BadRequest(String),
    /// Several fields of a form are wrong, each with its message.
    #[error("the request has invalid fields")]
    Fields(Vec<FieldError>),
    #[error("log in first")]
    Unauthorized,
    #[error("{0}")]
    Forbidden(String),
    #[error("{0} not found")]
    NotFound(&'static str),
    /// Not allowed in the current state (or another user changed it first).
    #[error("{0}")]
    Conflict(String),
    /// Asked too often; the message says the limit, `retry_after` when asking again can
    /// succeed (sent as the `Retry-After` header).
    #[error("{message}")]
    TooManyRequests {
        message: String,
        retry_after: std::time::Duration,
    },
    #[error("the request body is too large")]
    TooLarge,
    /// Something the request needs (the controller, the database) cannot serve it now.
    #[error("{0}")]
    Unavailable(String),
    #[error("internal error")]
    Internal(#[from] anyhow::Error),
}

pub type Result<T, E = AppError> = std::result::Result<T, E>;

/// A wait in whole seconds, as `Retry-After` and the messages that go with it say it:
/// rounded up, and at least 1 (0 would invite asking again at once, before a limit has
/// freed anything).
pub fn whole_seconds(wait: std::time::Duration) -> u64 {
    let secs = wait.as_secs() + u64::from(wait.subsec_nanos() > 0);
    secs.max(1)
}

impl AppError {
    /// The words of the error with the inner cause of an internal one (which a user is only
    /// shown as "internal error"): for the operator's log, an audit row, the command line.
    pub fn describe(&self) -> String {
        match self {
            Self::Internal(inner) => format!("{inner:#}"),
            other => other.to_string(),
        }
    }
}

/// SQLite's primary result codes of a state the server is in rather than a bug: another
/// connection holds the database locked; the disk (or the database's page cap) is full.
const SQLITE_BUSY: i32 = 5;
const SQLITE_FULL: i32 = 13;

/// PostgreSQL's SQLSTATEs of the same two states: a lock not granted in time, a
/// serialization failure or a deadlock (busy); no space left on the server's disk (full).
const POSTGRES_BUSY: [&str; 3] = ["55P03", "40001", "40P01"];
const POSTGRES_FULL: &str = "53100";

/// Busy or full, as either store says it; `None` for any other error.
fn store_state(db: &dyn sqlx::error::DatabaseError) -> Option<AppError> {
    let code = db.code()?;
    let (busy, full) = if db.try_downcast_ref::<sqlx::sqlite::SqliteError>().is_some() {
        // sqlx gives the extended code; its low byte is the primary one.
        let primary = code.parse::<i32>().ok()? & 0xff;
        (primary == SQLITE_BUSY, primary == SQLITE_FULL)
    } else {
        (
            POSTGRES_BUSY.contains(&code.as_ref()),
            code == POSTGRES_FULL,
        )
    };
    if busy {
        Some(AppError::Unavailable(
            "the database is busy; try again".into(),
        ))
    } else if full {
        Some(AppError::Unavailable(DISK_FULL.into()))
    } else {
        None
    }
}

/// What the server answers while its disk is full.
pub const DISK_FULL: &str =
    "the server's disk is full: nothing can be stored until there is room on it again";

/// How the SQL triggers refusing any change to an erased subject begin their message.
pub(crate) const ERASED: &str = "the subject's data were erased";

impl From<sqlx::Error> for AppError {
    fn from(e: sqlx::Error) -> Self {
        if let sqlx::Error::Database(db) = &e {
            // Two users racing for the same row is a conflict they can resolve, not a bug.
            if db.is_unique_violation() {
                return Self::Conflict(
                    "someone else made the same change at the same moment; reload and try again"
                        .into(),
                );
            }
            if let Some(state) = store_state(db.as_ref()) {
                return state;
            }
            // A row this change refers to was deleted since it was read (an erasure removed
            // the subject's trials while a survey or a note was on its way): a race.
            if db.is_foreign_key_violation() {
                return Self::Conflict(
                    "what this change refers to was removed at the same moment (a subject's data erased); reload and try again"
                        .into(),
                );
            }
            // The triggers that keep an erased subject erased (migration 0021) say so.
            if db.message().starts_with(ERASED) {
                return Self::Conflict(db.message().to_string());
            }
        }
        Self::Internal(e.into())
    }
}

impl From<bdft_protocol::params::ParamError> for AppError {
    fn from(e: bdft_protocol::params::ParamError) -> Self {
        Self::BadRequest(e.to_string())
    }
}
