//! What a test's ISO 2631-1 figures cost when it is filed: the server's filing of a 140 s
//! test (result, 5 MB record, re-queue rule and audit row in one transaction, on a real
//! SQLite file) without the figures, against the same filing with a_w and VDV computed from
//! the record first and stored with it (and the action-value check they bring). In the
//! product the loop computes them as the test runs (`bdft_controller::exposure`), so the
//! filing only stores them; computing them at filing is the upper bound this measures. Also
//! the meter's cost per tick in the loop.
//!
//! Run: `cargo bench --profile dev -p bdft-server --bench exposure` (env RUNS, default 21
//! filings of each kind, interleaved).

use std::time::Instant;

use bdft_controller::exposure::{ExposureMeter, of_record};
use bdft_protocol::controller_to_server::TrialResult;
use bdft_protocol::trial::{Metrics, Outcome, TimingSummary};
use bdft_server::engine::dry_runs::pilot;
use bdft_server::engine::procedure::filing::file_result;
use bdft_server::store;

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let runs: usize = std::env::var("RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(21);
    let dir = std::env::temp_dir().join(format!("bdft-bench-exposure-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let rt = tokio::runtime::Runtime::new().unwrap();
    rt.block_on(async {
        let pool = store::db::open(&dir.join("bench.db")).await.unwrap();
        // One synthetic subject of the default study: 140 s tests with their records.
        pilot::run(&pool, None, 1, Some(3)).await.unwrap();
        let (trial_id, mse, ms): (i64, f64, f64) = sqlx::query_as(
            "SELECT id, mse_tracking_mm2, ms_cab_accel FROM trials WHERE station = 'on' AND status = 'complete' ORDER BY id LIMIT 1",
        )
        .fetch_one(&pool)
        .await
        .unwrap();
        let record = store::records::get(&pool, trial_id).await.unwrap();
        let cab = &record.channels[6];
        let result = TrialResult {
            trial_id: trial_id as u64,
            outcome: Outcome::Complete,
            metrics: Metrics {
                ticks: cab.len() as u64,
                mse_tracking_mm2: mse,
                ms_cab_accel: ms,
            },
            timing: TimingSummary::default(),
            dt: record.dt,
            record_chunks: 0,
            exposure: None,
            cancellation_off_at_s: None,
            adaptation: Default::default(),
        };
        let (mut without, mut with, mut compute) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..runs {
            for computed in [false, true] {
                sqlx::query("UPDATE trials SET status = 'running' WHERE id = ?")
                    .bind(trial_id)
                    .execute(&pool)
                    .await
                    .unwrap();
                let t0 = Instant::now();
                let mut r = result.clone();
                if computed {
                    r.exposure = Some(of_record(cab, record.dt));
                    compute.push(t0.elapsed().as_secs_f64() * 1e3);
                }
                assert!(
                    file_result(&pool, "system:bench", &r, &record)
                        .await
                        .unwrap()
                );
                let ms = t0.elapsed().as_secs_f64() * 1e3;
                if computed { &mut with } else { &mut without }.push(ms);
            }
        }
        // The loop's share: the meter per tick over the same record.
        let mut per_tick = Vec::new();
        for _ in 0..9 {
            let mut m = ExposureMeter::new(record.dt, None);
            let t0 = Instant::now();
            for &a in cab {
                std::hint::black_box(m.add(f64::from(std::hint::black_box(a))));
            }
            per_tick.push(t0.elapsed().as_secs_f64() * 1e9 / cab.len() as f64);
        }
        let (w0, w1, c) = (median(&mut without), median(&mut with), median(&mut compute));
        println!(
            "{{\"runs\":{runs},\"samples\":{},\"filing_without_ms\":{w0:.3},\"filing_with_ms\":{w1:.3},\"added_pct\":{:.3},\"compute_ms\":{c:.3},\"compute_pct_of_filing\":{:.3},\"meter_ns_per_tick\":{:.2}}}",
            cab.len(),
            (w1 / w0 - 1.0) * 100.0,
            c / w0 * 100.0,
            median(&mut per_tick)
        );
        pool.close().await;
    });
    std::fs::remove_dir_all(&dir).ok();
}
