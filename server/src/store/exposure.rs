//! The tests a subject rode the machine in: what their vibration exposure is summed from.

use sqlx::AnyExecutor;

use crate::error::Result;

/// A test the subject sat on the machine for (seat `on`, started), with its ISO 2631-1
/// figures when the loop measured them.
#[derive(Debug, Clone, sqlx::FromRow)]
pub struct RiddenTest {
    pub trial_id: i64,
    pub started_at: i64,
    pub finished_at: Option<i64>,
    /// The test's planned length (s).
    pub duration_s: f64,
    pub cab_aw_m_s2: Option<f64>,
    pub cab_vdv_m_s175: Option<f64>,
    pub exposure_s: Option<f64>,
}

/// The subject's tests on the machine that started at or after `since_ms`, oldest first.
pub async fn ridden_since<'c>(
    db: impl AnyExecutor<'c>,
    subject_id: i64,
    since_ms: i64,
) -> Result<Vec<RiddenTest>> {
    Ok(sqlx::query_as(
        "SELECT id AS trial_id, started_at, finished_at, duration_s, cab_aw_m_s2, cab_vdv_m_s175, exposure_s \
         FROM trials WHERE subject_id = $1 AND station = 'on' AND started_at IS NOT NULL AND started_at >= $2 \
         ORDER BY started_at, id",
    )
    .bind(subject_id)
    .bind(since_ms)
    .fetch_all(db)
    .await?)
}
