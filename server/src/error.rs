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
    #[error("too many attempts; wait a minute and try again")]
    TooManyRequests,
    #[error("the request body is too large")]
    TooLarge,
    /// Something the request needs (the controller, the database) cannot serve it now.
    #[error("{0}")]
    Unavailable(String),
    #[error("internal error")]
    Internal(#[from] anyhow::Error),
}

pub type Result<T, E = AppError> = std::result::Result<T, E>;

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

/// SQLite's primary result code for a database another connection holds locked.
const SQLITE_BUSY: &str = "5";

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
            if db.code().as_deref() == Some(SQLITE_BUSY) {
                return Self::Unavailable("the database is busy; try again".into());
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
