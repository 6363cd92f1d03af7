//! [`SerialRig`]: a serial laser attached to a [`super::HardwareBench`]: the
//! [`LaserSource`] (its reader thread), the job's [`JobAligner`], and the
//! bookkeeping that ties the laser's samples to the audio input clock.
//!
//! During a sweep, after every captured audio block the rig
//! - collects the laser samples received so far, waiting (bounded) until the
//!   laser has caught up with the audio to within [`CATCH_UP_MARGIN_S`]
//!   (an emulated bench runs faster than real time; a real laser is always
//!   there already), so a laser fault or a displacement beyond the limit is
//!   seen within a block or two of the audio time it happened;
//! - checks every new sample against the displacement limit and the range;
//! - gives the observer a live displacement on the audio frames through a
//!   coarse map `t(n) = a + b n`: the job's clock line once a sweep was
//!   aligned in this input-clock epoch, otherwise the low envelope of
//!   "audio time at which sample n was collected - n / rate" (collection is
//!   never before the sample was taken; this seeds the alignment's ±50 ms
//!   search only, it is never the time base).
//!
//! After the sweep the samples are aligned to the microphone by
//! [`JobAligner::align`] (force balance; device counter or counted stream);
//! the sweep's displacement is the laser resampled on the audio instants and
//! the [`crate::align::AlignmentReport`] goes with the measurement.

use crate::align::{AlignConfig, AlignedSweep, AudioCapture, JobAligner, LaserTrack};
use crate::laser::{LaserIdentity, LaserSample, LaserSource, SampleClock};
use std::time::{Duration, Instant};

/// The laser may lag the captured audio by this much before the bench waits for it (s).
pub const CATCH_UP_MARGIN_S: f64 = 0.005;
/// Longest wall-clock wait for the laser to catch up before it is a fault (s).
pub const CATCH_UP_TIMEOUT_S: f64 = 2.0;
/// Laser samples kept from before a sweep (s of laser time).
const KEEP_BEFORE_S: f64 = 0.3;

pub struct SerialRig {
    source: Box<dyn LaserSource>,
    /// Keeps what the source needs alive (the laser emulator of an emulated bench); dropped after `source`.
    _keep: Option<Box<dyn Send>>,
    aligner: JobAligner,
    started: bool,
    /// Samples of the current sweep (and a little before); `host_time_s` is
    /// the audio input-clock time at which the bench collected them.
    samples: Vec<LaserSample>,
    /// Samples before this one were checked against the limits.
    checked: usize,
    /// Low envelope of `collected - n / rate` in this sweep (s).
    envelope_a: f64,
    /// Samples collected after the last audio block.
    fresh: usize,
    limit_m: f64,
    range_m: f64,
}

impl SerialRig {
    pub fn new(
        source: Box<dyn LaserSource>,
        keep: Option<Box<dyn Send>>,
        limit_m: f64,
        range_m: f64,
    ) -> SerialRig {
        SerialRig {
            source,
            _keep: keep,
            aligner: JobAligner::new(AlignConfig::default()),
            started: false,
            samples: Vec::new(),
            checked: 0,
            envelope_a: f64::INFINITY,
            fresh: 0,
            limit_m,
            range_m,
        }
    }

    pub fn identity(&self) -> &LaserIdentity {
        self.source.identity()
    }

    pub fn clock(&self) -> SampleClock {
        self.source.clock()
    }

    fn rate(&self) -> f64 {
        self.source.nominal_rate_hz()
    }

    /// Before the audio starts: the laser streaming and watched; the samples
    /// of the last `KEEP_BEFORE_S` kept.
    pub fn begin_sweep(&mut self, now_s: f64) -> Result<(), String> {
        if !self.started {
            self.source
                .start(Instant::now())
                .map_err(|e| format!("{e}"))?;
            self.started = true;
        }
        self.source.arm(true);
        let mut fresh = Vec::new();
        let r = self.source.poll(&mut fresh);
        self.samples.append(&mut fresh);
        r.map_err(|e| format!("{e} (before the sweep)"))?;
        if let Some(last) = self.samples.last().map(|s| s.index) {
            let keep_from = last.saturating_sub((KEEP_BEFORE_S * self.rate()) as u64);
            self.samples.retain(|s| s.index >= keep_from);
        }
        for s in &mut self.samples {
            s.host_time_s = now_s;
        }
        self.checked = self.samples.len();
        self.envelope_a = f64::INFINITY;
        self.fresh = 0;
        Ok(())
    }

    /// After the sweep (or its fault): the silence watch off until the next one.
    pub fn end_sweep(&mut self) {
        self.source.arm(false);
    }

    /// Coarse map of device index to audio time in `epoch`: (a, b).
    fn map(&self, epoch: u32) -> Option<(f64, f64)> {
        if let Some(l) = self.aligner.clock_line() {
            if let Some((_, a)) = l.offsets_s.iter().find(|(e, _)| *e == epoch) {
                return Some((*a, l.period_s));
            }
        }
        self.envelope_a
            .is_finite()
            .then(|| (self.envelope_a, 1.0 / self.rate()))
    }

    /// The laser has delivered up to (about) audio time `t_s`.
    fn covers(&self, epoch: u32, t_s: f64) -> bool {
        if self.clock() == SampleClock::HostPoll {
            return self.fresh > 0;
        }
        match (self.map(epoch), self.samples.last()) {
            (Some((a, b)), Some(s)) => a + b * s.index as f64 >= t_s,
            _ => false,
        }
    }

    /// Collects what the reader has; `now_s` is the audio time captured so far.
    fn collect(&mut self, now_s: f64) -> Result<(), String> {
        let mut fresh = Vec::new();
        let r = self.source.poll(&mut fresh);
        let b = 1.0 / self.rate();
        for mut s in fresh {
            s.host_time_s = now_s;
            self.envelope_a = self.envelope_a.min(now_s - b * s.index as f64);
            self.samples.push(s);
            self.fresh += 1;
        }
        r.map_err(|e| format!("{e}"))
    }

    /// After an audio block that ends at audio time `now_s`: waits for the
    /// laser to catch up, checks the new samples. Err: a fault (one line).
    pub fn after_block(&mut self, epoch: u32, now_s: f64) -> Result<(), String> {
        self.fresh = 0;
        let deadline = Instant::now() + Duration::from_secs_f64(CATCH_UP_TIMEOUT_S);
        loop {
            self.collect(now_s)?;
            if self.covers(epoch, now_s - CATCH_UP_MARGIN_S) {
                break;
            }
            if Instant::now() > deadline {
                return Err(format!(
                    "laser: no samples up to the audio time {now_s:.3} s within {CATCH_UP_TIMEOUT_S} s (the laser lags the audio; the sweep is invalid)"
                ));
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        self.check_new()
    }

    /// After the capture: the laser samples up to the capture's end.
    pub fn finish(&mut self, epoch: u32, end_s: f64) -> Result<(), String> {
        self.after_block(epoch, end_s + CATCH_UP_MARGIN_S)
    }

    fn check_new(&mut self) -> Result<(), String> {
        for s in &self.samples[self.checked..] {
            let x = s.displacement_m;
            if !x.is_finite() || x.abs() >= self.range_m {
                return Err(format!(
                    "laser out of range: {x:.5} m at device sample {} (range +-{} m)",
                    s.index, self.range_m
                ));
            }
            if x.abs() > self.limit_m {
                return Err(format!(
                    "displacement limit exceeded: |x| = {:.5} m > {} m at laser sample {}",
                    x.abs(),
                    self.limit_m,
                    s.index
                ));
            }
        }
        self.checked = self.samples.len();
        Ok(())
    }

    /// Extends `x` (one value per captured frame, frame `k` at audio time
    /// `start_s + k / fs`) to `len` frames with the live (coarse) displacement.
    pub fn fill(&self, epoch: u32, start_s: f64, fs: f64, x: &mut Vec<f64>, len: usize) {
        let Some(last) = self.samples.last() else {
            x.resize(len, 0.0);
            return;
        };
        if self.clock() == SampleClock::HostPoll || self.map(epoch).is_none() {
            x.resize(len, last.displacement_m);
            return;
        }
        let (a, b) = self.map(epoch).expect("checked");
        let s = &self.samples;
        for k in x.len()..len {
            let n = (start_s + k as f64 / fs - a) / b;
            // First sample with index > n.
            let j = s.partition_point(|p| (p.index as f64) <= n);
            let v = if j == 0 {
                s[0].displacement_m
            } else if j == s.len() {
                last.displacement_m
            } else {
                let (p, q) = (s[j - 1], s[j]);
                let u = (n - p.index as f64) / (q.index - p.index) as f64;
                p.displacement_m + u * (q.displacement_m - p.displacement_m)
            };
            x.push(v);
        }
    }

    /// Aligns the sweep whose microphone segment starts at audio time `start_s`.
    pub fn align(&mut self, epoch: u32, start_s: f64, fs: f64, mic: &[f64]) -> AlignedSweep {
        let mut samples = self.samples.clone();
        if self.clock() != SampleClock::HostPoll {
            // The seed: the coarse map (collection times are only an upper bound).
            if let Some((a, b)) = self.map(epoch) {
                for s in &mut samples {
                    s.host_time_s = a + b * s.index as f64;
                }
            }
        }
        self.aligner.align(
            &AudioCapture {
                sample_rate_hz: fs,
                start_s,
                audio_epoch: epoch,
                host_start_s: start_s,
                microphone: mic,
                max_drive_hz: None,
            },
            &LaserTrack {
                nominal_rate_hz: self.rate(),
                clock: self.clock(),
                samples: &samples,
            },
        )
    }
}
