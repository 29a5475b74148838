//! Request bodies that several areas of the API take.

use serde::Deserialize;
use utoipa::ToSchema;

/// The reason for an irreversible action (withdraw, abort, file incomplete).
#[derive(Debug, Deserialize, ToSchema)]
#[serde(deny_unknown_fields)]
pub struct ReasonBody {
    /// 1 to 500 characters.
    pub reason: String,
}
