//! A drive loop played through a bench at an RMS displacement (issue 32,
//! decision 0137): the long-term test's band-limited noise on a hardware or
//! emulated bench. As the sine's hold (`break_in::hold_at_resonance`) it
//! plays in chunks, each faded in and out, within the bench's limits: the
//! drive's gain never puts the loop's peak beyond the drive limit, every
//! block's displacement is checked against the displacement limit (a chunk
//! that passes it is stopped, ramped down by the bench, and the gain
//! lowered), and the bench's own checks (the laser, the stream, the drive
//! on the loopback) fault it as for a measurement. The level is closed-loop
//! on the measured displacement: each chunk's gain is the last one's scaled
//! by the target over the RMS displacement measured in its steady part.

// The chunks, their fades and their guarded play are the sine's hold's.
use super::break_in::{chunk_fade, play_chunk, CHUNK_S, FADE_S};
use super::ProcedureError;
use crate::Bench;

/// The first chunk is this short, at a low gain: a probe of the level.
const PROBE_S: f64 = 2.0;
/// The probe's drive peak (V), below the drive limit.
const PROBE_PEAK_V: f64 = 0.5;
/// The level is met when a chunk's RMS displacement is within this of it.
const SETTLED: f64 = 0.05;

/// The held time that fits in `bench_s` of bench time (s): the probe and
/// a few short chunks while the level is found, then each chunk's fades.
pub fn held_within_s(bench_s: f64) -> f64 {
    let search = 4.0 * (PROBE_S + 2.0 * FADE_S);
    ((bench_s - search) * (CHUNK_S - 2.0 * FADE_S) / CHUNK_S).max(0.0)
}

/// What was played.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LoopDone {
    /// Time played at the level (the fades and the probe excluded, s).
    pub held_s: f64,
    /// RMS displacement over the held time (m): the steady parts' mean square.
    pub x_rms_m: f64,
    /// The last chunk's gain (V per unit of the loop) and peak drive (V).
    pub gain_v: f64,
    pub drive_peak_v: f64,
    /// Bench time including the probe and the fades (s).
    pub bench_time_s: f64,
}

/// Plays `wave` (a loop, unit RMS or any) at the RMS displacement
/// `x_rms_m` for `duration_s` of held time, from sample `*phase` of the
/// loop (advanced: a later call continues the loop). `stop` ends it at the
/// end of a chunk (the user's pause); `on_run` receives every chunk's
/// signals (the load is measured from them).
#[allow(clippy::too_many_arguments)]
pub fn hold_loop(
    bench: &mut dyn Bench,
    wave: &[f64],
    phase: &mut usize,
    x_rms_m: f64,
    duration_s: f64,
    cancelled: &mut dyn FnMut() -> bool,
    stop: &mut dyn FnMut() -> bool,
    on_run: &mut dyn FnMut(&crate::Signals),
) -> Result<LoopDone, ProcedureError> {
    let limits = bench.limits();
    if wave.is_empty() {
        return Err(ProcedureError::Invalid(
            "the stimulus' loop is empty".into(),
        ));
    }
    if !(x_rms_m.is_finite() && x_rms_m > 0.0 && x_rms_m < limits.max_displacement_m) {
        return Err(ProcedureError::Invalid(format!(
            "the RMS displacement must be > 0 and below the bench's limit {} m, got {x_rms_m}",
            limits.max_displacement_m
        )));
    }
    let fs = bench.sample_rate_hz();
    let limit = limits.max_displacement_m;
    let peak = wave.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    if !(peak.is_finite() && peak > 0.0) {
        return Err(ProcedureError::Invalid(
            "the stimulus' loop is silent or not finite".into(),
        ));
    }
    let max_gain = limits.max_drive_v / peak;
    let mut g = (PROBE_PEAK_V / peak).min(max_gain);
    let (mut probing, mut settled) = (true, false);
    let (mut held, mut sq, mut bench_time) = (0.0, 0.0, 0.0);
    let nf = (FADE_S * fs).round() as usize;
    while held < duration_s - 1e-9 {
        if cancelled() {
            return Err(ProcedureError::Cancelled);
        }
        if stop() {
            break;
        }
        // Short chunks until the level is met, then long ones.
        let hold = if probing {
            PROBE_S
        } else if !settled {
            (duration_s - held).clamp(0.5, PROBE_S)
        } else {
            (duration_s - held).clamp(0.5, CHUNK_S - 2.0 * FADE_S)
        };
        let n = ((hold + 2.0 * FADE_S) * fs).round() as usize;
        let start = *phase;
        let drive: Vec<f64> = (0..n)
            .map(|k| chunk_fade(k, n, nf) * g * wave[(start + k) % wave.len()])
            .collect();
        let played = play_chunk(bench, &drive, limit, cancelled);
        bench_time += n as f64 / fs;
        let Some(sig) = played? else {
            // The bench ramped the drive down; lower the level's gain.
            g *= 0.7;
            continue;
        };
        on_run(&sig);
        *phase = (start + n) % wave.len();
        // The steady part: after the fade in and the part's settling (half
        // a second), before the fade out.
        let from = (nf + (0.5 * fs) as usize).min(n);
        let to = n.saturating_sub(nf).max(from);
        let x = &sig.displacement_m
            [from.min(sig.displacement_m.len())..to.min(sig.displacement_m.len())];
        let rms = if x.is_empty() {
            0.0
        } else {
            (x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64).sqrt()
        };
        if !probing {
            held += hold;
            sq += rms * rms * hold;
        }
        let ratio = x_rms_m / rms.max(1e-12);
        // Met, or as near as the drive limit allows.
        settled = (ratio - 1.0).abs() < SETTLED || (ratio > 1.0 && g >= max_gain);
        // From the probe the gain goes straight to the level (a hardening
        // part then falls short, a softening one is caught by the
        // displacement limit); then at most x2 or /2 per chunk.
        let clamp = if probing { (0.01, 100.0) } else { (0.5, 2.0) };
        g = (g * ratio.clamp(clamp.0, clamp.1)).min(max_gain);
        probing = false;
    }
    Ok(LoopDone {
        held_s: held,
        x_rms_m: if held > 0.0 { (sq / held).sqrt() } else { 0.0 },
        gain_v: g,
        drive_peak_v: g * peak,
        bench_time_s: bench_time,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::virtual_bench::VirtualBench;
    use crate::Limits;
    use springbench_core::physics::{preset, waveform};

    #[test]
    fn the_loop_is_held_at_its_rms_displacement_within_the_drive_limit() {
        let part = preset("spider_3in").unwrap();
        let mut vb = VirtualBench::new(part.clone(), 2);
        let fs = vb.bench.sample_rate_hz;
        let w = waveform::noise_loop(fs, [20.0, 100.0], 4.0, waveform::NOISE_SEED).unwrap();
        let mut phase = 0;
        let mut runs = vec![];
        let done = hold_loop(
            &mut vb,
            &w,
            &mut phase,
            0.0015,
            60.0,
            &mut || false,
            &mut || false,
            &mut |s| {
                runs.push(
                    s.drive_v
                        .as_ref()
                        .unwrap()
                        .iter()
                        .fold(0.0f64, |m, v| m.max(v.abs())),
                )
            },
        )
        .unwrap();
        println!("{done:?}");
        assert!((done.held_s - 60.0).abs() < 1e-9, "{done:?}");
        // The closed loop reaches the level after the probe and a chunk or two.
        assert!((done.x_rms_m / 0.0015 - 1.0).abs() < 0.05, "{done:?}");
        // The level needs more than 5 V of peak drive: at a 5 V limit it is
        // held at the limit, never beyond (the loopback's peak per chunk).
        let mut vb = VirtualBench::new(part, 2).with_limits(Limits {
            max_displacement_m: 0.02,
            max_drive_v: 5.0,
        });
        let mut peaks = vec![];
        let low = hold_loop(
            &mut vb,
            &w,
            &mut 0,
            0.0015,
            30.0,
            &mut || false,
            &mut || false,
            &mut |s| {
                peaks.push(
                    s.drive_v
                        .as_ref()
                        .unwrap()
                        .iter()
                        .fold(0.0f64, |m, v| m.max(v.abs())),
                )
            },
        )
        .unwrap();
        println!("{low:?} {peaks:?}");
        assert!(done.drive_peak_v > 5.0, "{done:?}");
        assert!(peaks.iter().all(|p| *p <= 5.0 + 1e-6), "{peaks:?}");
        assert!(peaks.iter().skip(1).any(|p| *p > 4.9), "{peaks:?}");
        assert!(low.x_rms_m < 0.0015 * 0.95, "{low:?}");
    }
}
