//! Where drive samples are produced: the output callback (cpal) or the
//! emulated DAC pulls them from a [`DriveSource`]. The drive limit is enforced
//! here, on every sample, and an abort (fault, limit, cancel) turns the rest
//! of the signal into a raised-cosine ramp to zero, from whatever the output
//! is playing at that moment. Lock-free: the callback owns the source; the
//! bench thread holds only the shared atomics.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;

/// Flags shared between the producing callback and the bench thread.
#[derive(Debug, Default)]
pub struct DriveShared {
    abort: AtomicBool,
    silent: AtomicBool,
    produced: AtomicU64,
    clamped: AtomicU64,
}

impl DriveShared {
    /// Asks the producer to ramp down now.
    pub fn abort(&self) {
        self.abort.store(true, Ordering::SeqCst);
    }
    pub fn aborted(&self) -> bool {
        self.abort.load(Ordering::SeqCst)
    }
    /// True once every further sample is zero (signal played out or ramp finished).
    pub fn silent(&self) -> bool {
        self.silent.load(Ordering::SeqCst)
    }
    /// Frames produced so far.
    pub fn produced(&self) -> u64 {
        self.produced.load(Ordering::SeqCst)
    }
    /// Samples that hit the drive limit (and were clamped to it).
    pub fn clamped(&self) -> u64 {
        self.clamped.load(Ordering::SeqCst)
    }
}

/// The drive of one sweep, in DAC full-scale units (-1..1).
pub struct DriveSource {
    samples: Arc<[f32]>,
    pos: usize,
    /// Largest |sample| allowed (the drive limit in DAC units, at most 1).
    limit: f32,
    ramp_len: usize,
    /// Position in the ramp-down and the gain it started from.
    ramp: Option<usize>,
    shared: Arc<DriveShared>,
}

impl DriveSource {
    /// `limit` is the drive limit in DAC units; `ramp_len` the ramp-down length in frames.
    pub fn new(samples: Vec<f32>, limit: f32, ramp_len: usize) -> DriveSource {
        DriveSource {
            samples: samples.into(),
            pos: 0,
            limit: limit.clamp(0.0, 1.0),
            ramp_len: ramp_len.max(1),
            ramp: None,
            shared: Arc::new(DriveShared::default()),
        }
    }

    pub fn shared(&self) -> Arc<DriveShared> {
        self.shared.clone()
    }

    /// Next frame's drive sample.
    #[inline]
    pub fn next_sample(&mut self) -> f32 {
        if self.ramp.is_none() && self.shared.abort.load(Ordering::Relaxed) {
            self.ramp = Some(0);
        }
        let raw = match self.samples.get(self.pos) {
            Some(&v) if v.is_finite() => v,
            Some(_) => 0.0,
            None => {
                self.shared.silent.store(true, Ordering::Relaxed);
                0.0
            }
        };
        self.pos += 1;
        let mut v = raw;
        if v.abs() > self.limit {
            self.shared.clamped.fetch_add(1, Ordering::Relaxed);
            v = v.clamp(-self.limit, self.limit);
        }
        if let Some(j) = self.ramp {
            if j >= self.ramp_len {
                self.shared.silent.store(true, Ordering::Relaxed);
                v = 0.0;
            } else {
                let g =
                    0.5 * (1.0 + (std::f64::consts::PI * j as f64 / self.ramp_len as f64).cos());
                v *= g as f32;
                self.ramp = Some(j + 1);
            }
        }
        self.shared.produced.fetch_add(1, Ordering::Relaxed);
        v
    }

    /// Fills interleaved frames: the drive on `channel`, silence elsewhere.
    pub fn fill(&mut self, out: &mut [f32], channels: usize, channel: usize) {
        for frame in out.chunks_mut(channels.max(1)) {
            let v = self.next_sample();
            for (c, s) in frame.iter_mut().enumerate() {
                *s = if c == channel { v } else { 0.0 };
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn limit_is_enforced_on_every_sample() {
        let mut d = DriveSource::new(vec![0.2, 0.9, -0.95, f32::NAN, 0.1], 0.5, 4);
        let out: Vec<f32> = (0..6).map(|_| d.next_sample()).collect();
        assert_eq!(out, vec![0.2, 0.5, -0.5, 0.0, 0.1, 0.0]);
        assert_eq!(d.shared().clamped(), 2);
        assert!(d.shared().silent());
    }

    #[test]
    fn abort_ramps_to_zero_in_ramp_len_frames() {
        let mut d = DriveSource::new(vec![1.0; 1000], 1.0, 100);
        let sh = d.shared();
        for _ in 0..10 {
            assert_eq!(d.next_sample(), 1.0);
        }
        sh.abort();
        let after: Vec<f32> = (0..200).map(|_| d.next_sample()).collect();
        assert_eq!(after[0], 1.0);
        assert!(after[50] > 0.4 && after[50] < 0.6, "{}", after[50]);
        assert!(after[..100].windows(2).all(|w| w[1] <= w[0]));
        assert!(after[100..].iter().all(|&v| v == 0.0));
        assert!(sh.silent());
        assert_eq!(sh.produced(), 210);
    }

    #[test]
    fn fill_puts_the_drive_on_its_channel_only() {
        let mut d = DriveSource::new(vec![0.5, -0.5], 1.0, 1);
        let mut buf = vec![9.0f32; 6];
        d.fill(&mut buf, 3, 1);
        assert_eq!(buf, vec![0.0, 0.5, 0.0, 0.0, -0.5, 0.0]);
    }
}
