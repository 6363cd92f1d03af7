//! The hardware bench (feature `hardware`): audio through cpal behind the
//! small [`crate::audio::AudioIo`] seam (the drive produced and limited in
//! [`crate::audio::drive`]), latency from the loopback in [`latency`] (pure),
//! the [`bench::HardwareBench`] that implements [`crate::Bench`], and
//! [`open`], which puts the real devices or the emulator behind the seam.

pub mod bench;
pub mod cpal_io;
pub mod latency;
pub mod serial_rig;

pub use crate::audio::{AudioError, AudioIo, DriveShared, DriveSource};
pub use bench::SelfCheck;
pub use bench::{HardwareBench, RunInfo};

use crate::laser::emulator::{
    EmulatorConfig as LaserEmulatorConfig, LaserEmulator, Pacing, SharedFeed,
};
use crate::laser::serial::SerialLaser;
use crate::laser::SerialLaserConfig;
use crate::settings::{BenchConfig, BenchKind};
use crate::settings::{FaultKind, LaserConfig};
use crate::Limits;
use serial_rig::SerialRig;
use springbench_core::physics::PartSpec;

/// Opens the bench of `cfg` for one job: the real devices (`kind = "hardware"`)
/// or the emulator with `part` mounted (`kind = "emulated"`). `job_seq` selects
/// the emulator's injected faults. `ageing`: the emulated part ages with
/// this true load (`EmulatedAudio::with_ageing`, decision 0135); a real
/// bench's part ages by itself and ignores it.
pub fn open(
    cfg: &BenchConfig,
    part: PartSpec,
    seed: u64,
    job_seq: i64,
    limits: Limits,
    ageing: Option<crate::true_part::TrueLoad>,
) -> Result<HardwareBench, String> {
    let hw = cfg
        .hardware
        .clone()
        .ok_or_else(|| format!("bench '{}' has no [benches.hardware] table", cfg.id))?;
    let range_m = hw.laser.range_m();
    let (audio, rig): (Box<dyn AudioIo>, Option<SerialRig>) = match cfg.kind {
        BenchKind::Emulated => {
            let emu = cfg.emulator.clone().unwrap_or_default();
            let mut audio = crate::emulator::EmulatedAudio::new(
                &hw,
                &emu,
                part,
                seed,
                job_seq,
                limits.max_displacement_m,
            );
            if let Some(load) = ageing {
                audio = audio.with_ageing(load);
            }
            let rig = match &hw.laser {
                LaserConfig::Serial(lc) => {
                    let (laser, emulator) = emulated_serial_laser(
                        &mut audio,
                        &emu,
                        lc,
                        hw.sample_rate_hz as f64,
                        seed,
                    )?;
                    Some(SerialRig::new(
                        Box::new(laser),
                        Some(Box::new(emulator)),
                        limits.max_displacement_m,
                        range_m,
                    ))
                }
                LaserConfig::Analog { .. } => None,
            };
            (Box::new(audio), rig)
        }
        BenchKind::Hardware => {
            let rig = match &hw.laser {
                LaserConfig::Serial(lc) => Some(SerialRig::new(
                    Box::new(SerialLaser::open(lc).map_err(|e| e.to_string())?),
                    None,
                    limits.max_displacement_m,
                    range_m,
                )),
                LaserConfig::Analog { .. } => None,
            };
            let audio = cpal_io::CpalAudio::open(&hw).map_err(|e| e.to_string())?;
            (Box::new(audio), rig)
        }
        BenchKind::Virtual => return Err(format!("bench '{}' is virtual", cfg.id)),
    };
    let bench = HardwareBench::new(&cfg.id, hw, limits, audio);
    Ok(match rig {
        Some(r) => bench.with_serial_laser(r),
        None => bench,
    })
}

/// The serial laser of an emulated bench: a laser emulator on a fresh
/// pseudo-terminal that samples the emulated physics (through the audio
/// device's displacement tap) on its own clock, and the real [`SerialLaser`]
/// reading it by path. The configured `port` is not opened.
fn emulated_serial_laser(
    audio: &mut crate::emulator::EmulatedAudio,
    emu: &crate::settings::EmulatorConfig,
    lc: &SerialLaserConfig,
    audio_rate_hz: f64,
    seed: u64,
) -> Result<(SerialLaser, LaserEmulator), String> {
    let feed = SharedFeed::new(audio_rate_hz, 4.0);
    let tap = feed.clone();
    audio.set_displacement_tap(Box::new(move |t_s, x| tap.push(t_s, x)));
    let s = &emu.serial_laser;
    let emulator = LaserEmulator::spawn(
        LaserEmulatorConfig {
            protocol: lc.protocol.clone(),
            rate_hz: lc.rate_hz,
            ppm: s.ppm,
            offset_s: s.offset_s,
            jitter_s: s.jitter_s,
            noise_m: emu.laser_noise_m,
            chunk_s: s.chunk_s,
            pacing: Pacing::Unpaced,
            model: s.model.clone(),
            serial: s.serial.clone(),
            seed,
        },
        Box::new(feed),
    )
    .map_err(|e| format!("laser emulator: {e}"))?;
    let ctl = emulator.controls();
    audio.set_laser_fault_hook(Box::new(move |k| match k {
        FaultKind::LaserUnplugged => ctl.close(),
        FaultKind::LaserGarbage => ctl.inject_garbage(),
        FaultKind::AudioStreamError | FaultKind::PartSlips => {}
    }));
    let mut lc = lc.clone();
    lc.port = emulator.path().to_string();
    let laser = SerialLaser::open(&lc).map_err(|e| e.to_string())?;
    Ok((laser, emulator))
}
