//! Room **results**: what a study's data become — descriptive statistics (`stats`), the
//! inferential tests (`inference`, pure functions on numbers) and their table
//! (`inference_table`), the learning curve (`learning`), the figures (`plots`, and the
//! results page's set in `page`), every export (`export`) and a subject's identification
//! tests against the population (`identification`). What counts in an analysis is decided
//! once (`study_data`).
//!
//! *May use:* `study`, `machine` (a bench run's results, for their export). Read-only on the
//! store: nothing here changes a study.
//!
//! Files: `study_data` (what the analyses count, decided once: `valid`, `counts`, `analysable`,
//! each subject's cells of the summary variables), `stats` (descriptive: the box plots' and
//! averages' numbers), `inference/` (pure inferential statistics: the special functions —
//! log-gamma, incomplete gamma and beta for the χ², F and normal tails — come from the controller
//! crate (`bdft_controller::special`), whose identification fit takes its t quantiles from them;
//! `nonparametric` — Friedman with Kendall's W, the exact signed-rank test by counting sign
//! patterns over doubled midranks, Holm, the rank-biserial r —, `rm_anova` — two-way repeated
//! measures with Greenhouse–Geisser ε from orthonormal contrasts and generalized η² —, `bootstrap`,
//! `quantile` — the one quantile rule, numpy's linear; checked against scipy and pingouin in
//! `server/fixtures/stats_reference.json`, made by `tools/fixtures/make_stats_fixtures.py`),
//! `identification` (a subject's identification tests as the dashboard's Bode plot draws them —
//! points, fitted body, the population's 2.5–97.5 % band — and every design's stability for the
//! subject's identified body, `GET /api/subjects/{id}/stability`), `inference_table` (a study's
//! statistics as one table, with whether each comparison can reach significance at its n),
//! `learning` (the learning curve's numbers: error by test position per subject, medians per seat,
//! the learning slope), `plots` (SVG, PNG via resvg with the vendored DejaVu Sans in
//! `server/assets/`; user text made XML-safe at the drawing boundary, no zero-length lines; box
//! plots and the learning curve share the frame, value axis and legend), `page` (the results page's
//! figures), `export/` (streamed CSV or Parquet — trials, samples cut per subject or test, subjects
//! with drawn parameters, codebook, summary, stats, notes and reasons, the whole audit log, and a
//! bench run's CSV (`bench`): `columns` one spec table per export — name, unit, type, resolution,
//! meaning —, `sink` the CSV and Parquet (arrow-rs, row groups) writers, `tables` the rows — the
//! subjects export's daily exposure from `study::exposure` —; `bids/` the study as a BIDS dataset —
//! `layout` the file names and their TSV and JSON sidecars (the beh table is the trials export's
//! rows and columns), `sink` a directory renamed into place when complete or a zip streamed entry
//! by entry (async_zip)).
//!
//! *Invariants:* header, Parquet schema and codebook all come from `export::columns`, so they
//! cannot drift; every number goes through `bdft_protocol::numbers::format_number` at its column's
//! resolution, Parquet stores the same rounded value; `valid`/`latest` are
//! `study_data::valid`/`counts`, the statistics' own rule; formula neutralization also behind
//! leading Unicode whitespace. The box plots, statistics and learning curve count the same attempts
//! (`study_data::analysable`).

pub mod export;
pub mod identification;
pub mod inference;
pub mod inference_table;
pub mod learning;
pub mod page;
pub mod plots;
pub mod stats;
pub mod study_data;
