//! A finished trial's result: status, metrics, the controller's timing, and the full 1 kHz
//! record (one little-endian f32 blob per channel of `RECORD_CHANNELS`).

use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::records::TrialStatus;
use bdft_protocol::trial::RECORD_CHANNELS;
use sqlx::{AnyConnection, AnyExecutor};

use super::db::now_ms;
use crate::error::Result;

/// The full-rate record of a trial, one channel per `RECORD_CHANNELS` entry.
#[derive(Debug, Clone, Default)]
pub struct Record {
    pub dt: f64,
    pub channels: Vec<Vec<f32>>,
}

fn blob(values: &[f32]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_le_bytes()).collect()
}

fn unblob(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

/// Files a finished trial — status, metrics, timing and the full record — on `db` (the
/// caller's transaction); returns the status and reason filed. A trial the server found
/// invalid while it ran is filed invalid with that reason, whatever the outcome. Only a
/// running trial takes a result: `None` when it was no longer running (a result arriving
/// after a restart marked it incomplete is dropped).
pub async fn file_result(
    db: &mut AnyConnection,
    result: &TrialResult,
    status: TrialStatus,
    reason: Option<&str>,
    record: &Record,
) -> Result<Option<(TrialStatus, Option<String>)>> {
    let filed: Option<(String, Option<String>)> = sqlx::query_as(
        "UPDATE trials SET status = CASE WHEN invalid_reason IS NULL THEN $1 ELSE 'invalid' END, status_reason = COALESCE(invalid_reason, $2), \
         finished_at = CASE WHEN COALESCE(started_at, 0) > $3 THEN COALESCE(started_at, 0) ELSE $3 END, mse_tracking_mm2 = $4, ms_cab_accel = $5, timing_json = $6, \
         cab_aw_m_s2 = $8, cab_vdv_m_s175 = $9, exposure_s = $10, cancellation_off_at_s = NULLIF($11, -1.0), adaptation_json = NULLIF($12, '') WHERE id = $7 AND status = 'running' \
         RETURNING status, status_reason",
    )
    .bind(status.as_str())
    .bind(reason)
    .bind(now_ms())
    .bind(result.metrics.mse_tracking_mm2)
    .bind(result.metrics.ms_cab_accel)
    .bind(serde_json::to_string(&result.timing).expect("timing serializes"))
    .bind(result.trial_id as i64)
    .bind(result.exposure.map(|e| e.aw_m_s2))
    .bind(result.exposure.map(|e| e.vdv_m_s175))
    .bind(result.exposure.map(|e| e.duration_s))
    // Never NULL as a parameter: the store's driver prepares a statement with the types of
    // its first binding, and PostgreSQL then refuses a number where a NULL's type was
    // declared. A trip time is never negative, so −1 stands for none.
    .bind(result.cancellation_off_at_s.unwrap_or(-1.0))
    // Empty for none, as above.
    .bind(
        result
            .adaptation
            .map(|a| serde_json::to_string(&a).expect("status serializes"))
            .unwrap_or_default(),
    )
    .fetch_optional(&mut *db)
    .await?;
    let Some((status, reason)) = filed else {
        return Ok(None);
    };
    let status: TrialStatus = status
        .parse()
        .map_err(|e: String| crate::error::AppError::Internal(anyhow::anyhow!(e)))?;
    if record.channels.len() == RECORD_CHANNELS.len() && !record.channels[0].is_empty() {
        let mut q = sqlx::query(
            "INSERT INTO trial_records (trial_id, dt, samples, target_mm, hand_mm, feedthrough_mm, cyl_ref_mm, valve_cmd, cyl_pos_mm, cab_accel_mm_s2, device_mm, tick_latency_us, cancellation_mm) \
             VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11, $12, $13) \
             ON CONFLICT (trial_id) DO UPDATE SET dt = excluded.dt, samples = excluded.samples, target_mm = excluded.target_mm, \
             hand_mm = excluded.hand_mm, feedthrough_mm = excluded.feedthrough_mm, cyl_ref_mm = excluded.cyl_ref_mm, \
             valve_cmd = excluded.valve_cmd, cyl_pos_mm = excluded.cyl_pos_mm, cab_accel_mm_s2 = excluded.cab_accel_mm_s2, \
             device_mm = excluded.device_mm, tick_latency_us = excluded.tick_latency_us, cancellation_mm = excluded.cancellation_mm",
        )
        .bind(result.trial_id as i64)
        .bind(record.dt)
        .bind(record.channels[0].len() as i64);
        for c in &record.channels {
            q = q.bind(blob(c));
        }
        q.execute(db).await?;
    }
    Ok(Some((status, reason)))
}

/// The record of one trial (about 5 MB for 140 s), channels in `RECORD_CHANNELS` order. A
/// record filed before a channel existed (`cancellation_mm`, migration 0031) reads it as
/// zeros: nothing was cancelled then.
pub async fn get<'c>(db: impl AnyExecutor<'c>, trial_id: i64) -> Result<Record> {
    use sqlx::Row;
    let channels = RECORD_CHANNELS.map(|c| c.name).join(", ");
    let row = sqlx::query(&format!(
        "SELECT dt, samples, {channels} FROM trial_records WHERE trial_id = $1"
    ))
    .bind(trial_id)
    .fetch_one(db)
    .await?;
    let samples = usize::try_from(row.try_get::<i64, _>(1)?).unwrap_or(0);
    Ok(Record {
        dt: row.try_get(0)?,
        channels: (0..RECORD_CHANNELS.len())
            .map(|i| {
                row.try_get::<Option<Vec<u8>>, _>(i + 2)
                    .map(|b| b.map_or_else(|| vec![0.0; samples], |b| unblob(&b)))
            })
            .collect::<Result<_, _>>()?,
    })
}
