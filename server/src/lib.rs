//! bdft-lab's experiment server: runs the ethics-board-approved protocol of a
//! biodynamic-feedthrough study — studies, subjects, schedules, targets, consent, trials on
//! the real-time controller, surveys — stores everything in SQLite and exports it.

pub mod cli;
pub mod db;
pub mod export;
pub mod orchestrator;
pub mod pilot;
pub mod store;
pub mod study;
