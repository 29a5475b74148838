//! A bench run as one CSV file for analysts: one line per result and kept tick, with the
//! result's metrics and reductions repeated on each.

use super::text_cell;
use crate::engine::machine::bench::{DECIMATION, DT, RunView, TRACE_CHANNELS};

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
        let dt = trace["dt_s"].as_f64().unwrap_or(DT * DECIMATION as f64);
        let cols: Vec<&Vec<serde_json::Value>> = TRACE_CHANNELS
            .iter()
            .filter_map(|c| trace[*c].as_array())
            .collect();
        for k in 0..cols.first().map_or(0, |c| c.len()) {
            out.push_str(&prefix);
            out.push_str(&format!(",{:.3}", k as f64 * dt));
            for c in &cols {
                out.push(',');
                out.push_str(&c[k].to_string());
            }
            out.push('\n');
        }
    }
    out
}
