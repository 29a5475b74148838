//! A bench run as one CSV file for analysts: one line per result and kept tick, with the
//! result's metrics and reductions repeated on each.

use super::text_cell;
use crate::engine::machine::bench::{RunView, TRACE_CHANNELS};

/// The run as CSV: one line per result and kept tick (`t_s`, the trace channels), with the
/// result's metrics and reductions repeated, so one file holds everything.
pub fn csv(v: &RunView) -> String {
    let mut out = format!(
        "run_id,position,label,controller,config_id,outcome,mse_tracking_mm2,ms_cab_accel,tracking_reduction_pct,cab_accel_reduction_pct,t_s,{}\n",
        TRACE_CHANNELS.join(",")
    );
    let num = |x: Option<f64>| x.map(|x| x.to_string()).unwrap_or_default();
    for (r, trace) in v.results.iter().zip(&v.traces) {
        let b = &r.result;
        let prefix = format!(
            "{},{},{},{},{},{},{},{},{},{}",
            b.run_id,
            b.position,
            text_cell(&b.label),
            b.kind.name(),
            b.config_id.map(|x| x.to_string()).unwrap_or_default(),
            text_cell(&b.outcome),
            b.mse_tracking_mm2,
            b.ms_cab_accel,
            num(r.tracking_reduction_pct),
            num(r.cab_accel_reduction_pct),
        );
        let cols = trace.columns();
        for k in 0..cols[0].len() {
            out.push_str(&prefix);
            out.push_str(&format!(",{:.3}", k as f64 * trace.dt_s));
            for c in &cols {
                out.push(',');
                // As the stored JSON writes it: shortest round-trip digits, null if not finite.
                out.push_str(&serde_json::Value::from(c[k]).to_string());
            }
            out.push('\n');
        }
    }
    out
}
