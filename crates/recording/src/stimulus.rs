//! A stimulus file (issue 32, decision 0144): the samples of an uploaded
//! WAV file, read from its bytes (no I/O), and the loop a long-term test
//! plays from them. Shared by the API (which refuses a file it cannot
//! play) and the runner (which plays it).

/// The largest stimulus file (bytes): 10 minutes of mono 24-bit audio at 96 kHz.
pub const MAX_STIMULUS_BYTES: usize = 32 * 1024 * 1024;
/// The longest loop (s): a stimulus longer than this is a test of its own.
pub const MAX_STIMULUS_S: f64 = 600.0;
/// The shortest loop (s): two periods of the slowest tone a bench plays (1 Hz).
pub const MIN_STIMULUS_S: f64 = 2.0;

/// The samples of a mono WAV file, full scale = 1, and what was read.
pub struct Decoded {
    pub samples: Vec<f64>,
    pub sample_rate_hz: u32,
    pub bits: u16,
    pub sample_format: &'static str,
}

impl Decoded {
    /// RMS and peak of the samples (full scale = 1).
    pub fn rms_fs(&self) -> f64 {
        (self.samples.iter().map(|v| v * v).sum::<f64>() / self.samples.len() as f64).sqrt()
    }
    pub fn peak_fs(&self) -> f64 {
        self.samples.iter().fold(0.0f64, |p, v| p.max(v.abs()))
    }
}

/// Reads a WAV file's samples (one line saying what is wrong otherwise).
pub fn decode(bytes: &[u8]) -> Result<Decoded, String> {
    if bytes.is_empty() {
        return Err("the body is empty: send the WAV file's bytes".into());
    }
    let mut r = hound::WavReader::new(std::io::Cursor::new(bytes))
        .map_err(|e| format!("not a WAV file this daemon reads: {e}"))?;
    let spec = r.spec();
    if spec.channels != 1 {
        return Err(format!(
            "{} channels: a stimulus is one channel (the exciter's drive); mix down or pick a channel first",
            spec.channels
        ));
    }
    let (samples, format): (Result<Vec<f64>, hound::Error>, _) = match spec.sample_format {
        hound::SampleFormat::Float => (
            r.samples::<f32>().map(|s| s.map(f64::from)).collect(),
            "float",
        ),
        hound::SampleFormat::Int => {
            let full = (1i64 << (spec.bits_per_sample.max(1) - 1)) as f64;
            (
                r.samples::<i32>()
                    .map(|s| s.map(|v| v as f64 / full))
                    .collect(),
                "int",
            )
        }
    };
    let samples = samples.map_err(|e| format!("the WAV file's samples are unreadable: {e}"))?;
    let fs = spec.sample_rate;
    let len_s = samples.len() as f64 / f64::from(fs.max(1));
    if let Some(i) = samples.iter().position(|v| !v.is_finite()) {
        return Err(format!("sample {i} is not a finite number"));
    }
    if !(MIN_STIMULUS_S..=MAX_STIMULUS_S).contains(&len_s) {
        return Err(format!(
            "{len_s} s long ({} frames at {fs} Hz): a stimulus loop lasts {MIN_STIMULUS_S} to {MAX_STIMULUS_S} s",
            samples.len()
        ));
    }
    Ok(Decoded {
        samples,
        sample_rate_hz: fs,
        bits: spec.bits_per_sample,
        sample_format: format,
    })
}

/// The loop a test plays: the samples without their mean, at unit RMS
/// (its level is set by the test's `excursion_rms_m`). Err: silent.
pub fn drive_loop(samples: &[f64]) -> Result<Vec<f64>, String> {
    springbench_core::physics::waveform::unit_loop(samples)
        .ok_or_else(|| "the file is silent (its samples less their mean are all zero)".to_string())
}
