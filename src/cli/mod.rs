//! Command-line front ends. Each subcommand returns `Result<(), String>`;
//! `main` prints the error as one line on stderr and exits non-zero.
pub mod ageing;
pub mod analyze;
pub mod devices;
pub mod openapi;
pub mod serve;
pub mod simulate;
