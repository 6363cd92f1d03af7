//! The alignment's settings, one sweep as the audio side and the laser
//! captured it, and one sweep's result (displacement on the audio time base
//! and the report stored with the measurement).

use crate::laser::{LaserSample, SampleClock};
use serde::{Deserialize, Serialize};

/// Settings of the alignment (defaults fit a 1-10 kHz laser and a 48 kHz audio clock).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AlignConfig {
    /// Largest acceptable residual misalignment (RMS of the window delays about the line, s).
    pub max_residual_s: f64,
    /// Fewest tie points (windows) the job's line needs.
    pub min_windows: usize,
    /// Length of one delay window (s).
    pub window_s: f64,
    /// Half-width of the coarse offset search around the arrival-time seed (s).
    pub coarse_search_s: f64,
    /// Longest run of missing laser samples that is bridged (longer: invalid).
    pub max_gap_samples: u64,
    /// Largest plausible clock ratio error (ppm).
    pub max_ppm: f64,
    /// The fit band ends at this multiple of the highest drive frequency (the
    /// fundamental and a few harmonics; less band = less laser noise).
    pub band_factor: f64,
    /// Largest acceptable relative RMS residual of the force-balance fit.
    pub max_fit_residual: f64,
}

impl Default for AlignConfig {
    fn default() -> Self {
        AlignConfig {
            max_residual_s: 10e-6,
            min_windows: 8,
            window_s: 0.5,
            coarse_search_s: 0.05,
            max_gap_samples: 8,
            max_ppm: 1000.0,
            band_factor: 1.5,
            max_fit_residual: 0.3,
        }
    }
}

/// One sweep as the audio side captured it.
#[derive(Debug, Clone, Copy)]
pub struct AudioCapture<'a> {
    pub sample_rate_hz: f64,
    /// Audio-clock time of sample 0 (s): the input stream's frame position of
    /// the sweep's first sample divided by the rate. It must run on without a
    /// break across the sweeps of a job within one `audio_epoch`.
    pub start_s: f64,
    /// Increment when the input stream restarted (its frame counter no longer
    /// continues): the offset is then estimated afresh, the ratio is kept.
    pub audio_epoch: u32,
    /// Host time of sample 0 (s, same epoch as [`LaserSample::host_time_s`]);
    /// coarse (tens of ms are fine), seeds the search only.
    pub host_start_s: f64,
    /// Microphone samples (any fixed scale: V or Pa).
    pub microphone: &'a [f64],
    /// Highest frequency of the drive (Hz), e.g. the sweep's end frequency;
    /// `None`: estimated from the microphone's spectrum.
    pub max_drive_hz: Option<f64>,
}

/// The laser samples of (at least) the time of the sweep.
#[derive(Debug, Clone, Copy)]
pub struct LaserTrack<'a> {
    /// Nominal sample rate (Hz).
    pub nominal_rate_hz: f64,
    pub clock: SampleClock,
    /// In index order; may extend before and after the sweep.
    pub samples: &'a [LaserSample],
}

/// How the alignment of one sweep went; stored with the measurement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AlignmentReport {
    /// False: the displacement is not on the audio time base to the bound;
    /// the measurement must not be fitted.
    pub valid: bool,
    pub invalid_reason: Option<String>,
    pub clock: SampleClock,
    pub nominal_rate_hz: f64,
    /// Audio time of device index 0 in this sweep's epoch (s).
    pub offset_s: f64,
    /// Laser clock rate relative to the audio clock, minus one (ppm; + = laser fast).
    pub ratio_ppm: f64,
    /// Weighted RMS of this sweep's window delays about the job's line (s).
    pub residual_rms_s: f64,
    /// Largest |delay| about the line among this sweep's well-determined windows (s).
    pub residual_max_s: f64,
    /// Standard error of the line at the middle of this sweep (s).
    pub line_stderr_s: f64,
    /// Standard error of `ratio_ppm`.
    pub ratio_stderr_ppm: f64,
    /// Windows (tie points) of this sweep and of the whole job so far.
    pub windows: usize,
    pub job_windows: usize,
    /// Missing device samples bridged in this sweep.
    pub dropped_samples: u64,
    /// Relative RMS residual of the force-balance fit used for the delays.
    pub fit_residual: f64,
    /// Gauss-Newton iterations of this sweep.
    pub iterations: usize,
}

/// A sweep's displacement on the audio time base.
#[derive(Debug, Clone)]
pub struct AlignedSweep {
    /// One value per microphone sample (m).
    pub displacement_m: Vec<f64>,
    pub report: AlignmentReport,
}
