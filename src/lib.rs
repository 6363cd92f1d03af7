//! Springbench: dynamic measurement of loudspeaker suspension parts.
//!
//! Layers (see ARCHITECTURE.md):
//! - numeric core, pure and synchronous, no I/O: [`dsp`], [`identify`], [`physics`], [`effects`], [`diagnose`]
//! - recordings on disk: [`recording`] (WAV + meta.json)
//! - measurement: [`bench`] (device seam: virtual or hardware), [`procedure`] (steps as data)
//! - daemon shell (async): [`config`], [`store`], [`runner`], [`api`], [`ui`] (web pages compiled in)
//! - command line: [`cli`]

pub mod api;
pub mod bench;
pub mod cli;
pub mod config;
pub mod diagnose;
pub mod dsp;
pub mod effects;
pub mod identify;
pub mod mes;
pub mod physics;
pub mod procedure;
pub mod qc;
pub mod recording;
pub mod runner;
pub mod store;
pub mod ui;

/// Software version recorded with every measurement.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
