//! `springbench analyze DIR --diagnose`: model diagnostics on the command line
//! (owned by the diagnostics work; called from `cli::analyze`).
