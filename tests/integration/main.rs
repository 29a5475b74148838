//! End-to-end tests, one binary: each module drives real processes of the product.

mod accounts;
mod browser;
mod controller_cli;
mod controller_link_auth;
mod controller_serve;
mod design_aids;
mod exports_analyst;
mod exports_audit;
mod hardening;
mod server_api;
mod server_layers;
mod soak;
mod station_safety;
mod statistics;
mod structure;
mod study_params;
mod subject_page;
mod validity;
mod workbench_analysis;
mod workbench_bench;
