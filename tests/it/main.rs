//! The integration tests: one binary (issue 37). Each test file is a module;
//! linking the daemon's library once instead of once per file is what the
//! test build's time was mostly made of. Run one file's tests with
//! `cargo test --test it qc::` (the module path is the filter).
//!
//! Shared harness: `common` (the daemon on an ephemeral port, HTTP helpers),
//! `browser` (headless Chromium over WebDriver), `contract_check` (responses
//! against the OpenAPI document). The hardware feature's tests are the
//! `tests/hardware_*.rs` binaries beside this one (process-wide ALSA
//! configuration, wall-clock-paced laser emulators).

mod browser;
// The CFX SDK's shapes and the checker's fixtures (tests/cfx_sdk, decision 0095).
#[path = "../cfx_sdk/mod.rs"]
mod cfx_sdk;
mod common;
mod contract_check;

mod ageing;
mod api;
mod beyond_library;
mod contract;
mod daemon;
mod daemon_load;
mod diagnose_engine;
mod diagnose_reference;
mod diagnose_virtual;
mod fleet;
mod fleet_limits;
mod fuzz;
mod gauge;
mod hardening;
mod hardening_io;
mod hardening_memory;
mod identify_cli;
mod identify_reference;
mod identify_synthetic;
mod layers;
mod longterm;
mod memory;
mod mes;
mod migration_0150;
mod physics_analyze;
mod physics_cli;
mod physics_numerics;
mod physics_procedure;
mod physics_reference;
mod production;
mod qc;
mod qc_faults;
mod qc_station_keff;
mod series;
mod storage;
mod trust_bad_parts;
mod trust_virtual;
mod ui_browser;
