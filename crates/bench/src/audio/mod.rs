//! The audio seam of the hardware bench (feature `hardware`): one output
//! stream that pulls the drive from a [`DriveSource`] ([`drive`]: the drive
//! limit and ramp-down where samples are produced), one input stream that
//! delivers interleaved frames of every input channel. Implemented by cpal
//! ([`crate::hardware::cpal_io`]) and by the bench emulator
//! ([`crate::emulator::EmulatedAudio`]); both depend on this seam, never on
//! each other.

pub mod drive;

pub use drive::{DriveShared, DriveSource};

#[derive(Debug, Clone, thiserror::Error, PartialEq)]
pub enum AudioError {
    /// The device could not be found or opened (configuration, wiring).
    #[error("cannot open {0}")]
    Open(String),
    /// The running stream failed: device lost, xrun, invalidated stream.
    #[error("stream error: {0}")]
    Stream(String),
}

/// Output plus input of one bench.
pub trait AudioIo: Send {
    fn sample_rate_hz(&self) -> f64;
    /// Interleaved channels of each captured frame.
    fn input_channels(&self) -> usize;
    /// Starts both streams; the output plays `drive` (silence after its end).
    fn start(&mut self, drive: DriveSource) -> Result<(), AudioError>;
    /// Appends the next captured frames (interleaved) to `out`, blocking until some are there.
    fn read(&mut self, out: &mut Vec<f32>) -> Result<(), AudioError>;
    /// Keeps the output running until the drive is silent (ramp finished) or
    /// `timeout_s` passed, then stops both streams.
    fn stop(&mut self, timeout_s: f64);
    /// Device names and sample format, for the measurement record.
    fn describe(&self) -> String;
    /// The input clock of the running stream: its epoch (incremented when the
    /// converter's frame counter restarted) and the frame position of the
    /// first captured frame. `None`: unknown (each stream start is a new
    /// epoch at position 0).
    fn input_clock(&self) -> Option<(u32, u64)> {
        None
    }
}
