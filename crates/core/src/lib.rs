//! Springbench's pure numeric core: everything that turns signals into numbers
//! and numbers into verdicts, and the typed documents they travel in.
//!
//! Invariant: synchronous, no I/O, no async runtime, no logging, no global
//! state. The manifest carries no tokio, sqlx, axum, hyper, tracing, HTTP
//! client or device crate; `tests/layers.rs` fails the build's tests when one
//! appears, directly or through another crate.
//!
//! - [`dsp`]: differentiation, spectra, transfer functions, harmonics, least squares
//! - [`recording`]: the data of a recording set (meta, signals); files are `springbench-recording`'s
//! - [`identify`]: small-signal fit, Keff, K(x), and the result document [`identify::Report`]
//! - [`physics`]: the bench model (ODE, RK4), part presets, production lots
//! - [`effects`]: effects beyond the basic model (ids, parameters, laws)
//! - [`diagnose`]: residuals, candidate effects, the ladder, SVG plots, level series
//! - [`qc`]: recipes, verdicts, golden-unit limits, SPC, the IPC-CFX messages
//! - [`job`]: the job specification's bounds
//! - [`finite`]: the check that no document holds a non-finite number

pub mod ageing;
pub mod diagnose;
pub mod dsp;
pub mod effects;
pub mod finite;
pub mod identify;
pub mod job;
pub mod physics;
pub mod qc;
pub mod recording;

/// Software version recorded with every measurement (one version for the
/// whole workspace).
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
