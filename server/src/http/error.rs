//! How an [`AppError`] reaches the client: a status code and a JSON body
//! `{"error": "...", "fields": [...]}`; 500 only for bugs and broken infrastructure, its
//! cause logged and not shown. And [`AppJson`], the JSON extractor whose rejections are such
//! errors too.

use axum::Json;
use axum::extract::FromRequest;
use axum::extract::rejection::JsonRejection;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use bdft_protocol::study::FieldError;
use serde::Serialize;

pub use crate::error::AppError;

/// The body of every error answer.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct ErrorBody {
    /// What was wrong, in words a user can act on.
    pub error: String,
    /// The fields of a form that were wrong, each with its message.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub fields: Option<Vec<FieldError>>,
}

impl AppError {
    pub fn status(&self) -> StatusCode {
        match self {
            Self::BadRequest(_) | Self::Fields(_) => StatusCode::UNPROCESSABLE_ENTITY,
            Self::Unauthorized => StatusCode::UNAUTHORIZED,
            Self::Forbidden(_) => StatusCode::FORBIDDEN,
            Self::NotFound(_) => StatusCode::NOT_FOUND,
            Self::Conflict(_) => StatusCode::CONFLICT,
            Self::TooManyRequests { .. } => StatusCode::TOO_MANY_REQUESTS,
            Self::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            Self::Unavailable(_) => StatusCode::SERVICE_UNAVAILABLE,
            Self::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        }
    }
}

impl IntoResponse for AppError {
    fn into_response(self) -> Response {
        if let Self::Internal(e) = &self {
            tracing::error!("internal error: {e:#}");
        }
        let status = self.status();
        let fields = match &self {
            Self::Fields(f) => Some(f.clone()),
            _ => None,
        };
        let retry_after = match &self {
            Self::TooManyRequests { retry_after, .. } => {
                Some(crate::error::whole_seconds(*retry_after))
            }
            _ => None,
        };
        let body = ErrorBody {
            error: self.to_string(),
            fields,
        };
        let mut response = (status, Json(body)).into_response();
        if let Some(secs) = retry_after {
            response
                .headers_mut()
                .insert(axum::http::header::RETRY_AFTER, secs.into());
        }
        response
    }
}

/// `Json` whose rejection (malformed JSON, wrong types, missing fields, wrong content type)
/// is a 4xx `AppError` saying what was wrong.
#[derive(Debug, FromRequest)]
#[from_request(via(Json), rejection(AppError))]
pub struct AppJson<T>(pub T);

impl From<JsonRejection> for AppError {
    fn from(r: JsonRejection) -> Self {
        if r.status() == StatusCode::PAYLOAD_TOO_LARGE {
            return Self::TooLarge;
        }
        Self::BadRequest(r.body_text())
    }
}

impl<T: Serialize> IntoResponse for AppJson<T> {
    fn into_response(self) -> Response {
        Json(self.0).into_response()
    }
}

pub type ApiResult<T> = Result<AppJson<T>, AppError>;

/// A request body that may be left empty (then the type's default) or be JSON of `T`.
pub fn optional_json<T: serde::de::DeserializeOwned + Default>(
    body: &[u8],
    what: &str,
) -> Result<T, AppError> {
    if body.iter().all(u8::is_ascii_whitespace) {
        return Ok(T::default());
    }
    serde_json::from_slice(body).map_err(|e| AppError::BadRequest(format!("{what} body: {e}")))
}

/// `{"ok": true}`: the answer of an action that has nothing else to say.
#[derive(Debug, Serialize, utoipa::ToSchema)]
pub struct Done {
    pub ok: bool,
}

impl Done {
    pub fn ok() -> AppJson<Self> {
        AppJson(Self { ok: true })
    }
}
