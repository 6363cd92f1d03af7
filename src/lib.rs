//! Springbench: dynamic measurement of loudspeaker suspension parts. This
//! root crate is the daemon and its command line; the layers below it are
//! crates of their own (ARCHITECTURE.md):
//! - `springbench-core`: the pure numeric core and the typed documents
//!   ([`dsp`], [`identify`], [`physics`], [`effects`], [`diagnose`], [`qc`], [`job`], [`finite`])
//! - `springbench-recording`: recording formats and files ([`recording`])
//! - `springbench-bench`: the device seam, the virtual and hardware benches, the procedure ([`bench`], [`procedure`])
//! - `springbench-store`: schema, migrations, queries ([`store`])
//!
//! Here: [`config`], [`runner`] (job queue, one owner per bench), [`mes`]
//! (the delivery worker), [`fleet`] (replication to the fleet's center, the fleet role), [`api`] (HTTP + websocket), [`ui`] (web pages
//! compiled in), [`cli`]. The lower crates are re-exported under their usual
//! names, so that `springbench::identify::Report` and
//! `springbench_core::identify::Report` are one type.

pub use springbench_bench as bench;
pub use springbench_bench::procedure;
pub use springbench_core::{ageing, diagnose, dsp, effects, finite, identify, job, physics, qc};
pub use springbench_recording as recording;
pub use springbench_store as store;

pub mod api;
pub mod cli;
pub mod config;
pub mod fleet;
pub mod mes;
pub mod runner;
pub mod ui;
pub use springbench_core::VERSION;
