//! The hardware bench (feature `hardware`): audio through cpal behind the
//! small [`audio::AudioIo`] seam, the drive produced and limited in
//! [`drive`], latency from the loopback in [`latency`] (pure), the
//! [`bench::HardwareBench`] that implements [`crate::bench::Bench`].

pub mod audio;
pub mod bench;
pub mod cpal_io;
pub mod drive;
pub mod latency;

pub use audio::{AudioError, AudioIo};
pub use bench::SelfCheck;
pub use bench::{HardwareBench, RunInfo};
pub use drive::{DriveShared, DriveSource};

use crate::bench::Limits;
use crate::config::{BenchConfig, BenchKind};
use crate::physics::PartSpec;

/// Opens the bench of `cfg` for one job: the real devices (`kind = "hardware"`)
/// or the emulator with `part` mounted (`kind = "emulated"`). `job_seq` selects
/// the emulator's injected faults.
pub fn open(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    job_seq: i64,
    limits: Limits,
) -> Result<HardwareBench, String> {
    let hw = cfg
        .hardware
        .clone()
        .ok_or_else(|| format!("bench '{}' has no [benches.hardware] table", cfg.id))?;
    let audio: Box<dyn AudioIo> = match cfg.kind {
        BenchKind::Emulated => {
            let emu = cfg.emulator.clone().unwrap_or_default();
            Box::new(crate::bench::emulator::EmulatedAudio::new(
                &hw,
                &emu,
                part,
                seed,
                job_seq,
                limits.max_displacement_m,
            ))
        }
        BenchKind::Hardware => Box::new(cpal_io::CpalAudio::open(&hw).map_err(|e| e.to_string())?),
        BenchKind::Virtual => return Err(format!("bench '{}' is virtual", cfg.id)),
    };
    Ok(HardwareBench::new(&cfg.id, hw, limits, audio))
}
