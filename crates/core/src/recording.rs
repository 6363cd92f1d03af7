//! The data of a recording set: [`Meta`] (what `meta.json` says), [`Signals`]
//! (one sweep's channels in SI units) and [`RecordingSet`] (pre-measurement
//! plus main sweep). Pure data and checks; reading and writing WAV, FLAC and
//! directories is the `springbench-recording` crate's.

use serde::{Deserialize, Serialize};

/// Errors reading or writing a recording set. `Display` is one line, for the CLI and the API.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    #[error("{path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("{path}: not a readable WAV file: {reason}")]
    Wav { path: String, reason: String },
    #[error("{path}: invalid meta.json: {reason}")]
    Meta { path: String, reason: String },
    #[error("{0}")]
    Invalid(String),
}

/// Which WAV channel holds which signal (0-based).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Channels {
    pub displacement: usize,
    pub microphone: usize,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive: Option<usize>,
}

/// Physical units per digital full scale, per signal (PCM files).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct ChannelScale {
    /// Metres per full scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub displacement: Option<f64>,
    /// Volts per full scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub microphone: Option<f64>,
    /// Volts per full scale.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drive: Option<f64>,
}

/// What a user knows about a recording set (`meta.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Meta {
    /// Moving mass: part plus inner clamp, weighed (kg).
    pub moving_mass_kg: f64,
    /// Sample rate of both WAV files (Hz).
    pub sample_rate_hz: f64,
    pub channels: Channels,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel_scale: Option<ChannelScale>,
    /// Where the set sits in a long-term test (top-level members of
    /// `meta.json`; `springbench ageing` reads them).
    #[serde(flatten)]
    pub long_term: LongTermStamp,
    /// Any further fields, kept as they are.
    #[serde(flatten)]
    pub extra: serde_json::Map<String, serde_json::Value>,
}

/// A long-term test's interval, as its recording set says it (issue 32).
/// Every member is optional: an ordinary set has none of them.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LongTermStamp {
    /// The stimulus ran faster than real time (the virtual bench).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub accelerated: Option<bool>,
    /// Time under the stimulus when the interval's measurement started (s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub elapsed_s: Option<f64>,
    /// Load accumulated by then (J; decision 0110's measure).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub load_j: Option<f64>,
    /// The interval's index in its test, from 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub long_term_interval: Option<u32>,
    /// The test's job id.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub long_term_test: Option<String>,
}

impl Meta {
    /// Standard three-channel layout (0 displacement, 1 microphone, 2 drive).
    pub fn standard(moving_mass_kg: f64, sample_rate_hz: f64) -> Meta {
        Meta {
            moving_mass_kg,
            sample_rate_hz,
            channels: Channels {
                displacement: 0,
                microphone: 1,
                drive: Some(2),
            },
            channel_scale: None,
            long_term: LongTermStamp::default(),
            extra: Default::default(),
        }
    }

    /// Checks the physical plausibility of the fields; one-line error.
    pub fn validate(&self) -> Result<(), RecordingError> {
        // Bounds that keep every derived value finite (1e-300 kg overflowed).
        if !(self.moving_mass_kg.is_finite() && (1e-4..=10.0).contains(&self.moving_mass_kg)) {
            return Err(RecordingError::Invalid(format!(
                "moving_mass_kg must be in [0.0001, 10] kg, got {}",
                self.moving_mass_kg
            )));
        }
        if !self.sample_rate_hz.is_finite() || self.sample_rate_hz <= 0.0 {
            return Err(RecordingError::Invalid(format!(
                "sample_rate_hz must be positive, got {}",
                self.sample_rate_hz
            )));
        }
        if let Some(s) = &self.channel_scale {
            for (name, v) in [
                ("displacement", s.displacement),
                ("microphone", s.microphone),
                ("drive", s.drive),
            ] {
                if let Some(v) = v {
                    // |scale| in [1e-9, 1e6] units per full scale: a float32
                    // sample times the scale stays finite (1e300 overflowed).
                    if !(v.is_finite() && (1e-9..=1e6).contains(&v.abs())) {
                        return Err(RecordingError::Invalid(format!(
                            "channel_scale.{name} must be a number with magnitude in [1e-9, 1e6], got {v}"
                        )));
                    }
                }
            }
        }
        Ok(())
    }
}

/// The signals of one sweep, in SI units, sampled at `sample_rate_hz`.
#[derive(Debug, Clone, PartialEq)]
pub struct Signals {
    pub sample_rate_hz: f64,
    /// Laser displacement (m); positive moves the part out of the box.
    pub displacement_m: Vec<f64>,
    /// Microphone output (V); sensitivity unknown to the analysis.
    pub microphone_v: Vec<f64>,
    /// Exciter drive (V), when recorded.
    pub drive_v: Option<Vec<f64>>,
}

impl Signals {
    pub fn len(&self) -> usize {
        self.displacement_m.len()
    }
    pub fn is_empty(&self) -> bool {
        self.displacement_m.is_empty()
    }
    pub fn duration_s(&self) -> f64 {
        self.len() as f64 / self.sample_rate_hz
    }
    /// Every sample finite, channels of equal length.
    pub fn validate(&self, what: &str) -> Result<(), RecordingError> {
        let n = self.displacement_m.len();
        if self.microphone_v.len() != n || self.drive_v.as_ref().is_some_and(|d| d.len() != n) {
            return Err(RecordingError::Invalid(format!(
                "{what}: channels have different lengths"
            )));
        }
        let chans: [(&str, Option<&Vec<f64>>); 3] = [
            ("displacement", Some(&self.displacement_m)),
            ("microphone", Some(&self.microphone_v)),
            ("drive", self.drive_v.as_ref()),
        ];
        for (name, c) in chans {
            if let Some(c) = c.filter(|c| !all_finite(c)) {
                if let Some(i) = c.iter().position(|v| !v.is_finite()) {
                    return Err(RecordingError::Invalid(format!(
                        "{what}: {name} channel has a non-finite sample (NaN or infinity) at sample {i} (t = {:.4} s)",
                        i as f64 / self.sample_rate_hz
                    )));
                }
            }
        }
        Ok(())
    }
}

/// Every sample finite; blocks without an early exit, so that the check
/// vectorises (it runs on every channel of every sweep read and analysed).
fn all_finite(c: &[f64]) -> bool {
    c.chunks(1024)
        .all(|b| b.iter().fold(true, |ok, v| ok & v.is_finite()))
}

/// A complete recording set: small-signal pre-measurement and large-signal main sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordingSet {
    pub meta: Meta,
    pub pre: Signals,
    pub main: Signals,
}

impl RecordingSet {
    /// A set whose meta states the files' (equal) sample rate exactly.
    pub fn settled(
        mut meta: Meta,
        pre: Signals,
        main: Signals,
    ) -> Result<RecordingSet, RecordingError> {
        if pre.sample_rate_hz != main.sample_rate_hz {
            return Err(RecordingError::Invalid(format!(
                "sample_rate_hz: pre.wav is sampled at {} Hz, main.wav at {} Hz",
                pre.sample_rate_hz, main.sample_rate_hz
            )));
        }
        meta.sample_rate_hz = main.sample_rate_hz;
        Ok(RecordingSet { meta, pre, main })
    }
}

/// Parses and validates meta.json text.
pub fn parse_meta(text: &str) -> Result<Meta, String> {
    let meta: Meta = serde_json::from_str(text).map_err(|e| e.to_string())?;
    meta.validate().map_err(|e| e.to_string())?;
    Ok(meta)
}
