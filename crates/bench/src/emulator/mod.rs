//! The bench emulator (feature `hardware`): the project's physics behind the
//! same device interfaces as the real bench, so the hardware code path runs
//! end to end without devices (tests, and `springbench serve` by hand).

pub mod audio;

pub use audio::EmulatedAudio;
