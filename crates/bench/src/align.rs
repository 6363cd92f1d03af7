//! Clock alignment: puts the samples of a serial laser (its own clock, device
//! index `n`) on the audio time base of the microphone. Pure: no I/O, no
//! clock; the hardware bench calls it after each sweep with what it captured.
//!
//! Model: the laser sample with device index `n` was taken at audio time
//! `t(n) = A_e + B n`, with one offset `A_e` per audio clock epoch (a
//! continuous run of the input stream) and one period `B = 1 / (f_nom (1 +
//! ppm 1e-6))` per job (`ppm > 0`: the laser clock runs fast).
//!
//! Estimator (docs/decisions/0010-clock-alignment.md): the microphone (box
//! pressure, audio clock) drives the part, `Ss p = m x'' + R x' + K(x) x`. A
//! time error `d` of `x` adds `d * d/dt(m x'' + R x' + K(x) x)` to the
//! residual: for a sine at `w` a damping change `(K - m w^2) d` that a
//! constant `R` cannot absorb over a sweep covering a band. Per sweep, a
//! Gauss-Newton iteration fits the force balance (`m, R, k_0..k_4` and a
//! constant, all linear) jointly with a line `d(t)`, re-resampling `x` each
//! time; then the delay is estimated in windows (tie points `(n, t)`), and a
//! weighted line through the tie points of all sweeps of the job gives `A_e`,
//! `B`; the scatter of the tie points about that line is the reported
//! residual. Arrival times are used only to seed a coarse search (+-50 ms).
//!
//! The output displacement is the laser resampled at the audio sample
//! instants with a windowed-sinc (Kaiser) interpolator ([`SincKernel`]).

use crate::laser::{LaserSample, SampleClock};
use serde::{Deserialize, Serialize};
use springbench_core::dsp::lstsq::lstsq;
use springbench_core::dsp::spectrum::{with_thread_planner, LowPass, Spectrum};

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

/// The clock line of a job.
#[derive(Debug, Clone, PartialEq)]
pub struct ClockLine {
    /// Audio time of device index 0 per epoch (s).
    pub offsets_s: Vec<(u32, f64)>,
    /// Audio time per device sample (s).
    pub period_s: f64,
    pub period_stderr_s: f64,
}

impl ClockLine {
    pub fn ratio_ppm(&self, nominal_rate_hz: f64) -> f64 {
        (1.0 / (self.period_s * nominal_rate_hz) - 1.0) * 1e6
    }
    fn offset(&self, epoch: u32) -> Option<f64> {
        self.offsets_s
            .iter()
            .find(|(e, _)| *e == epoch)
            .map(|p| p.1)
    }
}

/// A delay estimate of one window: device index `n` was taken at audio time `t_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Tie {
    epoch: u32,
    sweep: u32,
    n: f64,
    t_s: f64,
    sigma_s: f64,
}

/// Aligns the sweeps of one job: keeps the tie points of the sweeps seen so
/// far, so the line (offset, ratio) improves sweep by sweep. Make a new one
/// (or [`JobAligner::reset`]) per job.
#[derive(Debug, Clone)]
pub struct JobAligner {
    cfg: AlignConfig,
    ties: Vec<Tie>,
    line: Option<ClockLine>,
    /// Line fit: reference index and covariance.
    cov: Option<LineCov>,
    sweeps: u32,
    kernel: SincKernel,
}

#[derive(Debug, Clone)]
struct LineCov {
    n_ref: f64,
    /// Parameters: offsets (per epoch, in `line.offsets_s` order, at n_ref) then period.
    cov: Vec<f64>,
    p: usize,
}

/// Mapping of one sweep: t(n) = a + b n.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Map {
    a: f64,
    b: f64,
}

impl Map {
    fn n_of(&self, t: f64) -> f64 {
        (t - self.a) / self.b
    }
}

impl JobAligner {
    pub fn new(cfg: AlignConfig) -> JobAligner {
        JobAligner {
            cfg,
            ties: Vec::new(),
            line: None,
            cov: None,
            sweeps: 0,
            kernel: SincKernel::default(),
        }
    }

    /// Forgets the job (a new job starts).
    pub fn reset(&mut self) {
        self.ties.clear();
        self.line = None;
        self.cov = None;
        self.sweeps = 0;
    }

    /// The job's clock line so far.
    pub fn clock_line(&self) -> Option<&ClockLine> {
        self.line.as_ref()
    }

    /// Aligns one sweep: the displacement at every microphone sample and the
    /// report. Never fails: a sweep whose alignment cannot be established gets
    /// a best-effort displacement (for level decisions and safety only) and
    /// `report.valid == false` with the reason.
    pub fn align(&mut self, audio: &AudioCapture<'_>, laser: &LaserTrack<'_>) -> AlignedSweep {
        self.sweeps += 1;
        let sweep = self.sweeps;
        let n_audio = audio.microphone.len();
        let mut report = AlignmentReport {
            valid: false,
            invalid_reason: None,
            clock: laser.clock,
            nominal_rate_hz: laser.nominal_rate_hz,
            offset_s: f64::NAN,
            ratio_ppm: 0.0,
            residual_rms_s: f64::INFINITY,
            residual_max_s: f64::INFINITY,
            line_stderr_s: f64::INFINITY,
            ratio_stderr_ppm: f64::INFINITY,
            windows: 0,
            job_windows: self.ties.len(),
            dropped_samples: 0,
            fit_residual: f64::NAN,
            iterations: 0,
        };
        let fs = audio.sample_rate_hz;
        let plausible = fs.is_finite()
            && fs > 0.0
            && laser.nominal_rate_hz.is_finite()
            && laser.nominal_rate_hz > 0.0
            && audio.start_s.is_finite()
            && audio.host_start_s.is_finite();
        if !plausible {
            return invalid(
                vec![0.0; n_audio],
                report,
                "sample rates and start times must be finite and positive".into(),
            );
        }
        if laser.samples.is_empty() {
            return invalid(
                vec![0.0; n_audio],
                report,
                "no laser samples in this sweep".into(),
            );
        }
        if laser.clock == SampleClock::HostPoll {
            let x = by_host_time(audio, laser.samples);
            return invalid(
                x,
                report,
                "polled laser: its samples carry no device clock, only host poll times \
                 (jitter of milliseconds), so the alignment to the audio clock cannot be established"
                    .into(),
            );
        }
        // Seed mapping: the job's line, or the arrival times.
        let b_nom = 1.0 / laser.nominal_rate_hz;
        let seeded = self.line.as_ref().and_then(|l| {
            l.offset(audio.audio_epoch)
                .map(|a| Map { a, b: l.period_s })
        });
        let seed = seeded.unwrap_or_else(|| Map {
            a: arrival_seed(laser.samples, b_nom) - audio.host_start_s + audio.start_s,
            b: b_nom,
        });
        // Laser samples near the sweep (with margin for the search and the kernel).
        let t0 = audio.start_s;
        let t1 = audio.start_s + n_audio as f64 / fs;
        let margin_s = self.cfg.coarse_search_s * 2.0 + 0.05;
        let n_lo = seed.n_of(t0 - margin_s).floor();
        let n_hi = seed.n_of(t1 + margin_s).ceil();
        let dense = match Dense::new(laser.samples, n_lo, n_hi, self.cfg.max_gap_samples) {
            Ok(d) => d,
            Err(reason) => {
                return invalid(vec![0.0; n_audio], report, reason);
            }
        };
        report.dropped_samples = dense.dropped;
        if let Some((at, len)) = dense.long_gap {
            let x = self.resample(&dense, seed, audio);
            return invalid(
                x,
                report,
                format!(
                    "laser dropout of {len} samples at device index {at} (more than {} bridged)",
                    self.cfg.max_gap_samples
                ),
            );
        }
        let covered = (dense.n_first() <= seed.n_of(t0)) && (dense.n_last() >= seed.n_of(t1));
        let coverage = coverage_fraction(&dense, seed, t0, t1);
        if coverage < 0.98 || n_audio < 16 {
            let x = self.resample(&dense, seed, audio);
            return invalid(
                x,
                report,
                format!(
                    "the laser samples cover {:.0} % of the sweep{}",
                    coverage * 100.0,
                    if covered {
                        ""
                    } else {
                        " (they start late or end early)"
                    }
                ),
            );
        }
        // The fit grid.
        let grid = match FitGrid::new(audio, laser.nominal_rate_hz, &self.cfg) {
            Ok(g) => g,
            Err(reason) => {
                let x = self.resample(&dense, seed, audio);
                return invalid(x, report, reason);
            }
        };
        // Coarse search without a line of this epoch.
        let mut map = seed;
        if seeded.is_none() {
            map = self.coarse(&dense, &grid, audio, seed);
        }
        // Gauss-Newton on this sweep alone.
        let mut fit = None;
        for it in 0..12 {
            report.iterations = it + 1;
            let f = match grid.fit(&self.kernel, &dense, map, audio.start_s, true) {
                Ok(f) => f,
                Err(reason) => {
                    let x = self.resample(&dense, map, audio);
                    return invalid(x, report, reason);
                }
            };
            let (da, db) = (f.delay_offset_s, f.delay_slope);
            // t_new(n) = t(n) - d(t(n)), d(t) = da + db (t - t_mid).
            let tm = grid.t_mid_s + audio.start_s;
            map = Map {
                a: map.a - da - db * (map.a - tm),
                b: map.b * (1.0 - db),
            };
            let step = da.abs() + db.abs() * 0.5 * grid.duration_s;
            fit = Some(f);
            if !step.is_finite() || step > 0.05 {
                let x = self.resample(&dense, seed, audio);
                return invalid(x, report, "the delay estimate diverged".into());
            }
            if step < 1e-8 {
                break;
            }
        }
        // Tie points of this sweep from the converged map.
        let f = match grid.fit(&self.kernel, &dense, map, audio.start_s, false) {
            Ok(f) => f,
            Err(reason) => {
                let x = self.resample(&dense, map, audio);
                return invalid(x, report, reason);
            }
        };
        let _ = fit;
        report.fit_residual = f.rel_residual;
        if f.rel_residual > self.cfg.max_fit_residual {
            let x = self.resample(&dense, map, audio);
            return invalid(
                x,
                report,
                format!(
                    "microphone and displacement do not follow the force balance (fit residual {:.0} % > {:.0} %): too little motion, or not the same part",
                    f.rel_residual * 100.0,
                    self.cfg.max_fit_residual * 100.0
                ),
            );
        }
        self.ties.retain(|t| t.sweep != sweep);
        let mut mine = 0;
        for w in &f.windows {
            let s = audio.start_s + w.t_s;
            self.ties.push(Tie {
                epoch: audio.audio_epoch,
                sweep,
                n: map.n_of(s),
                t_s: s - w.delay_s,
                sigma_s: w.sigma_s,
            });
            mine += 1;
        }
        report.windows = mine;
        // The job's line.
        if let Err(reason) = self.fit_line(laser.nominal_rate_hz) {
            let x = self.resample(&dense, map, audio);
            return invalid(x, report, reason);
        }
        let line = self.line.clone().expect("fit_line sets the line");
        let jmap = Map {
            a: line.offset(audio.audio_epoch).unwrap_or(map.a),
            b: line.period_s,
        };
        report.offset_s = jmap.a;
        report.ratio_ppm = line.ratio_ppm(laser.nominal_rate_hz);
        report.ratio_stderr_ppm =
            line.period_stderr_s / line.period_s / line.period_s / laser.nominal_rate_hz * 1e6;
        report.job_windows = self.ties.len();
        let (rms, max) = self.scatter(sweep, jmap);
        report.residual_rms_s = rms;
        report.residual_max_s = max;
        report.line_stderr_s = self.line_stderr(
            audio.audio_epoch,
            jmap.n_of(audio.start_s + 0.5 * grid.duration_s),
        );
        let x = self.resample(&dense, jmap, audio);
        let reason = if self.ties.len() < self.cfg.min_windows {
            Some(format!(
                "too few windows to establish the clock line ({} < {})",
                self.ties.len(),
                self.cfg.min_windows
            ))
        } else if rms.is_nan() || rms > self.cfg.max_residual_s {
            Some(format!(
                "residual misalignment {:.1} us above the bound {:.1} us",
                rms * 1e6,
                self.cfg.max_residual_s * 1e6
            ))
        } else if report.ratio_ppm.abs() > self.cfg.max_ppm {
            Some(format!(
                "clock ratio {:.0} ppm is implausible (bound {:.0} ppm): wrong nominal rate?",
                report.ratio_ppm, self.cfg.max_ppm
            ))
        } else {
            None
        };
        match reason {
            Some(r) => invalid(x, report, r),
            None => {
                report.valid = true;
                AlignedSweep {
                    displacement_m: x,
                    report,
                }
            }
        }
    }

    /// Displacement at the audio instants under `map`.
    fn resample(&self, dense: &Dense, map: Map, audio: &AudioCapture<'_>) -> Vec<f64> {
        let fs = audio.sample_rate_hz;
        (0..audio.microphone.len())
            .map(|k| {
                let t = audio.start_s + k as f64 / fs;
                self.kernel.eval(&dense.x, map.n_of(t) - dense.n0 as f64)
            })
            .collect()
    }

    /// Offset search over +-coarse_search_s around `seed`, in up to four
    /// segments of the sweep, then a line through the segments' best offsets.
    ///
    /// For every shift `s` (grid samples) the force balance (x'', x', x, x^2,
    /// x^3, 1) is fitted to the microphone; the cost is its residual. The
    /// cross products are sliding sums, so all shifts cost about as much as
    /// a few fits.
    fn coarse(&self, dense: &Dense, grid: &FitGrid, audio: &AudioCapture<'_>, seed: Map) -> Map {
        let fs_audio = audio.sample_rate_hz;
        let h = (self.cfg.coarse_search_s * grid.fs_hz).ceil() as usize;
        let len = grid.mic.len();
        let dt = grid.decim as f64 / fs_audio;
        // x on the grid, extended by h samples either side.
        let x: Vec<f64> = (0..len + 2 * h)
            .map(|k| {
                let t = audio.start_s + (k as f64 - h as f64) * dt;
                self.kernel.eval(&dense.x, seed.n_of(t) - dense.n0 as f64)
            })
            .collect();
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        let cols: Vec<Vec<f64>> = with_thread_planner(|pl| {
            let sx = Spectrum::with_planner(&x, grid.fs_hz, x.len() / 8, pl);
            let mut c = vec![
                sx.derivative(grid.lp, 2, 1, pl),
                sx.derivative(grid.lp, 1, 1, pl),
                sx.derivative(grid.lp, 0, 1, pl),
            ];
            for k in 2..=3 {
                let xk: Vec<f64> = x.iter().map(|v| (v / scale).powi(k)).collect();
                let sk = Spectrum::with_planner(&xk, grid.fs_hz, xk.len() / 8, pl);
                c.push(sk.derivative(grid.lp, 0, 1, pl));
            }
            c.push(vec![1.0; x.len()]);
            c
        });
        let p = cols.len();
        // Prefix sums of the column products: Gram matrices of any window in O(1).
        let mut prefix: Vec<Vec<f64>> = vec![Vec::new(); p * p];
        for a in 0..p {
            for b in 0..=a {
                let mut acc = 0.0;
                let mut v = Vec::with_capacity(x.len() + 1);
                v.push(0.0);
                for (u, w) in cols[a].iter().zip(&cols[b]) {
                    acc += u * w;
                    v.push(acc);
                }
                prefix[a * p + b] = v;
            }
        }
        let segs = ((grid.duration_s / 4.0).floor() as usize).clamp(1, 4);
        let usable = (grid.edge, len - grid.edge);
        let mut pts: Vec<(f64, f64)> = Vec::new(); // (t_mid from start, delay)
        for sgi in 0..segs {
            let j0 = usable.0 + sgi * (usable.1 - usable.0) / segs;
            let j1 = usable.0 + (sgi + 1) * (usable.1 - usable.0) / segs;
            if j1 <= j0 + 4 * p {
                continue;
            }
            let y = &grid.mic[j0..j1];
            let yy: f64 = y.iter().map(|v| v * v).sum();
            let mut costs = Vec::with_capacity(2 * h + 1);
            for s in 0..=2 * h {
                // Columns at grid sample j + s - h (x-extended index j + s).
                let mut gm = nalgebra::DMatrix::<f64>::zeros(p, p);
                let mut c = nalgebra::DVector::<f64>::zeros(p);
                for a in 0..p {
                    let ca = &cols[a][j0 + s..j1 + s];
                    c[a] = ca.iter().zip(y).map(|(u, v)| u * v).sum();
                    for b in 0..=a {
                        let pr = &prefix[a * p + b];
                        let v = pr[j1 + s] - pr[j0 + s];
                        gm[(a, b)] = v;
                        gm[(b, a)] = v;
                    }
                }
                // Scale to unit diagonal for the solve.
                let d: Vec<f64> = (0..p).map(|i| gm[(i, i)].max(1e-300).sqrt()).collect();
                for a in 0..p {
                    c[a] /= d[a];
                    for b in 0..p {
                        gm[(a, b)] /= d[a] * d[b];
                    }
                }
                let cost = match gm.cholesky() {
                    Some(ch) => yy - c.dot(&ch.solve(&c)),
                    None => f64::INFINITY,
                };
                costs.push(cost);
            }
            let Some((ib, _)) = costs.iter().enumerate().min_by(|a, b| a.1.total_cmp(b.1)) else {
                continue;
            };
            let mut sh = ib as f64;
            if ib > 0 && ib < 2 * h {
                let (c0, c1, c2) = (costs[ib - 1], costs[ib], costs[ib + 1]);
                let den = c0 - 2.0 * c1 + c2;
                if den > 0.0 {
                    sh += 0.5 * (c0 - c2) / den;
                }
            }
            // x_true(t) = x~(t + d): the columns were taken d = (s - h) dt later.
            let d = (sh - h as f64) * dt;
            pts.push(((j0 + j1) as f64 * 0.5 * dt, d));
        }
        if pts.is_empty() {
            return seed;
        }
        let n = pts.len() as f64;
        let mt = pts.iter().map(|p| p.0).sum::<f64>() / n;
        let md = pts.iter().map(|p| p.1).sum::<f64>() / n;
        let stt: f64 = pts.iter().map(|p| (p.0 - mt).powi(2)).sum();
        let std: f64 = pts.iter().map(|p| (p.0 - mt) * (p.1 - md)).sum();
        let mut slope = if stt > 0.0 { std / stt } else { 0.0 };
        if slope.abs() > 2e-3 {
            slope = 0.0;
        }
        // d(t) = md + slope (t - tm); t_new(n) = t(n) - d(t(n)).
        let tm = audio.start_s + mt;
        Map {
            a: seed.a - md - slope * (seed.a - tm),
            b: seed.b * (1.0 - slope),
        }
    }

    /// Weighted line through the tie points (per-epoch offsets, one period),
    /// with a 5-sigma rejection pass.
    fn fit_line(&mut self, nominal_rate_hz: f64) -> Result<(), String> {
        if self.ties.is_empty() {
            return Err("no windows with a usable delay".into());
        }
        let mut epochs: Vec<u32> = self.ties.iter().map(|t| t.epoch).collect();
        epochs.sort_unstable();
        epochs.dedup();
        let p = epochs.len() + 1;
        let n_ref = self.ties[0].n;
        let mut use_tie = vec![true; self.ties.len()];
        let mut sol = None;
        for pass in 0..3 {
            let mut g = nalgebra::DMatrix::<f64>::zeros(p, p);
            let mut h = nalgebra::DVector::<f64>::zeros(p);
            let mut count = 0;
            for (t, _) in self.ties.iter().zip(&use_tie).filter(|(_, u)| **u) {
                let e = epochs.iter().position(|&e| e == t.epoch).unwrap_or(0);
                let w = 1.0 / (t.sigma_s * t.sigma_s);
                let dn = (t.n - n_ref) * 1e-4; // scaled for conditioning
                let row = |i: usize| -> f64 {
                    if i == e {
                        1.0
                    } else if i == p - 1 {
                        dn
                    } else {
                        0.0
                    }
                };
                for i in 0..p {
                    for j in 0..p {
                        g[(i, j)] += w * row(i) * row(j);
                    }
                    h[i] += w * row(i) * t.t_s;
                }
                count += 1;
            }
            if count < 2 {
                // One tie: the nominal period.
                let t = self.ties[0];
                let b = 1.0 / nominal_rate_hz;
                self.line = Some(ClockLine {
                    offsets_s: vec![(t.epoch, t.t_s - b * t.n)],
                    period_s: b,
                    period_stderr_s: f64::INFINITY,
                });
                self.cov = None;
                return Ok(());
            }
            let Some(inv) = g.clone().try_inverse() else {
                return Err("the tie points do not determine a clock line".into());
            };
            let x = &inv * &h;
            // Reduced chi^2 scales the covariance when the scatter exceeds the sigmas.
            let mut chi2 = 0.0;
            let mut resid = vec![0.0; self.ties.len()];
            for (i, t) in self.ties.iter().enumerate() {
                let e = epochs.iter().position(|&e| e == t.epoch).unwrap_or(0);
                let pred = x[e] + x[p - 1] * (t.n - n_ref) * 1e-4;
                resid[i] = t.t_s - pred;
                if use_tie[i] {
                    chi2 += (resid[i] / t.sigma_s).powi(2);
                }
            }
            let dof = (count as f64 - p as f64).max(1.0);
            let scale = (chi2 / dof).max(1.0);
            sol = Some((x.clone(), inv.clone() * scale));
            if pass == 2 {
                break;
            }
            let s = scale.sqrt();
            let mut changed = false;
            for (i, t) in self.ties.iter().enumerate() {
                let keep = (resid[i] / t.sigma_s).abs() <= 5.0 * s
                    || resid[i].abs() <= self.cfg.max_residual_s;
                if keep != use_tie[i] {
                    changed = true;
                }
                use_tie[i] = keep;
            }
            if !changed {
                break;
            }
        }
        let (x, cov) = sol.ok_or("no clock line")?;
        let period = x[p - 1] * 1e-4;
        if !(period.is_finite() && period > 0.0) {
            return Err("the tie points give a non-positive clock period".into());
        }
        self.line = Some(ClockLine {
            offsets_s: epochs
                .iter()
                .enumerate()
                .map(|(i, &e)| (e, x[i] - period * n_ref))
                .collect(),
            period_s: period,
            period_stderr_s: cov[(p - 1, p - 1)].sqrt() * 1e-4,
        });
        self.cov = Some(LineCov {
            n_ref,
            cov: cov.iter().copied().collect(),
            p,
        });
        Ok(())
    }

    /// Standard error of the line's time at device index `n` of `epoch`.
    fn line_stderr(&self, epoch: u32, n: f64) -> f64 {
        let (Some(line), Some(c)) = (&self.line, &self.cov) else {
            return f64::INFINITY;
        };
        let Some(e) = line.offsets_s.iter().position(|(ep, _)| *ep == epoch) else {
            return f64::INFINITY;
        };
        let p = c.p;
        // nalgebra stores column-major; the matrix is symmetric.
        let at = |i: usize, j: usize| c.cov[i + j * p];
        let dn = (n - c.n_ref) * 1e-4;
        let v = at(e, e) + 2.0 * dn * at(e, p - 1) + dn * dn * at(p - 1, p - 1);
        v.max(0.0).sqrt()
    }

    /// Weighted RMS and max |deviation| of this sweep's ties about `map`.
    fn scatter(&self, sweep: u32, map: Map) -> (f64, f64) {
        let (mut sw, mut swd2, mut max) = (0.0, 0.0, 0.0f64);
        let mine: Vec<&Tie> = self.ties.iter().filter(|t| t.sweep == sweep).collect();
        if mine.is_empty() {
            return (f64::INFINITY, f64::INFINITY);
        }
        let best = mine.iter().map(|t| t.sigma_s).fold(f64::INFINITY, f64::min);
        for t in mine {
            let d = t.t_s - (map.a + map.b * t.n);
            let w = 1.0 / (t.sigma_s * t.sigma_s);
            sw += w;
            swd2 += w * d * d;
            if t.sigma_s <= 3.0 * best {
                max = max.max(d.abs());
            }
        }
        ((swd2 / sw).sqrt(), max)
    }
}

fn invalid(x: Vec<f64>, mut report: AlignmentReport, reason: String) -> AlignedSweep {
    report.valid = false;
    report.invalid_reason = Some(reason);
    AlignedSweep {
        displacement_m: x,
        report,
    }
}

/// Best-effort displacement of a polled laser: linear interpolation over the
/// host poll times (not on the audio clock to better than milliseconds).
fn by_host_time(audio: &AudioCapture<'_>, samples: &[LaserSample]) -> Vec<f64> {
    let fs = audio.sample_rate_hz;
    let mut j = 0;
    (0..audio.microphone.len())
        .map(|k| {
            let h = audio.host_start_s + k as f64 / fs;
            while j + 1 < samples.len() && samples[j + 1].host_time_s <= h {
                j += 1;
            }
            let a = samples[j];
            match samples.get(j + 1) {
                Some(b) if b.host_time_s > a.host_time_s && h > a.host_time_s => {
                    let u = (h - a.host_time_s) / (b.host_time_s - a.host_time_s);
                    a.displacement_m + u.min(1.0) * (b.displacement_m - a.displacement_m)
                }
                _ => a.displacement_m,
            }
        })
        .collect()
}

/// Host time of device index 0 from arrival times: arrivals are late by the
/// adapter's latency (0-16 ms), so the low envelope (2nd percentile) of
/// `host_time - n b` is the best guess.
fn arrival_seed(samples: &[LaserSample], b: f64) -> f64 {
    let mut v: Vec<f64> = samples
        .iter()
        .map(|s| s.host_time_s - s.index as f64 * b)
        .filter(|v| v.is_finite())
        .collect();
    if v.is_empty() {
        return 0.0;
    }
    let k = v.len() / 50;
    let (_, x, _) = v.select_nth_unstable_by(k, |a, b| a.total_cmp(b));
    *x
}

/// The laser samples on a dense index grid, short gaps bridged.
#[derive(Debug, Clone)]
struct Dense {
    n0: u64,
    x: Vec<f64>,
    dropped: u64,
    /// First gap longer than allowed: (index, length).
    long_gap: Option<(u64, u64)>,
}

impl Dense {
    /// Samples with index in [n_lo, n_hi] (plus one either side).
    fn new(samples: &[LaserSample], n_lo: f64, n_hi: f64, max_gap: u64) -> Result<Dense, String> {
        let lo = n_lo.max(0.0) as u64;
        let hi = if n_hi.is_finite() && n_hi >= 0.0 {
            n_hi as u64
        } else {
            0
        };
        let first = samples.partition_point(|s| s.index < lo).saturating_sub(1);
        let last = samples
            .partition_point(|s| s.index <= hi)
            .min(samples.len());
        let sel = &samples[first..last.max(first)];
        let sel: Vec<&LaserSample> = {
            let mut v: Vec<&LaserSample> = Vec::with_capacity(sel.len());
            for s in sel {
                if s.displacement_m.is_finite() && v.last().is_none_or(|l| s.index > l.index) {
                    v.push(s);
                }
            }
            v
        };
        let (Some(f), Some(l)) = (sel.first(), sel.last()) else {
            return Err("no laser samples during the sweep".into());
        };
        let span = l.index - f.index + 1;
        if span > 50_000_000 {
            return Err(format!("laser indices span {span} samples: counter jump"));
        }
        let mut x = Vec::with_capacity(span as usize);
        let mut dropped = 0;
        let mut long_gap = None;
        for w in sel.windows(2) {
            let (a, b) = (w[0], w[1]);
            x.push(a.displacement_m);
            let gap = b.index - a.index - 1;
            if gap > 0 {
                dropped += gap;
                if gap > max_gap && long_gap.is_none() {
                    long_gap = Some((a.index + 1, gap));
                }
                for i in 1..=gap {
                    let u = i as f64 / (gap + 1) as f64;
                    x.push(a.displacement_m + u * (b.displacement_m - a.displacement_m));
                }
            }
        }
        x.push(l.displacement_m);
        Ok(Dense {
            n0: f.index,
            x,
            dropped,
            long_gap,
        })
    }
    fn n_first(&self) -> f64 {
        self.n0 as f64
    }
    fn n_last(&self) -> f64 {
        (self.n0 + self.x.len() as u64 - 1) as f64
    }
}

fn coverage_fraction(d: &Dense, map: Map, t0: f64, t1: f64) -> f64 {
    let (a, b) = (map.n_of(t0), map.n_of(t1));
    if b.is_nan() || a.is_nan() || b <= a {
        return 0.0;
    }
    let lo = a.max(d.n_first());
    let hi = b.min(d.n_last());
    ((hi - lo) / (b - a)).clamp(0.0, 1.0)
}

/// One window's delay estimate (relative to the sweep's map).
#[derive(Debug, Clone, Copy)]
struct WindowDelay {
    /// Window centre (s from the sweep start).
    t_s: f64,
    delay_s: f64,
    sigma_s: f64,
}

/// Result of one force-balance fit on the grid.
#[derive(Debug, Clone)]
struct GridFit {
    delay_offset_s: f64,
    delay_slope: f64,
    rel_residual: f64,
    windows: Vec<WindowDelay>,
}

/// The decimated, band-limited microphone and the grid the fit runs on.
struct FitGrid {
    fs_hz: f64,
    /// Audio samples per grid sample.
    decim: usize,
    /// Grid samples of x before their decimation (x is resampled at fs/x_decim).
    x_decim: usize,
    lp: LowPass,
    mic: Vec<f64>,
    duration_s: f64,
    t_mid_s: f64,
    window: usize,
    /// Grid samples excluded at each end (filter edges).
    edge: usize,
    /// sqrt(grid oversampling): the residual's samples are correlated.
    corr: f64,
}

/// Powers of x in the force balance: K(x) up to x^4.
const POWERS: usize = 5;

impl FitGrid {
    fn new(
        audio: &AudioCapture<'_>,
        laser_rate_hz: f64,
        cfg: &AlignConfig,
    ) -> Result<FitGrid, String> {
        let fs = audio.sample_rate_hz;
        let mic = audio.microphone;
        if mic.iter().any(|v| !v.is_finite()) {
            return Err("the microphone signal is not finite".into());
        }
        let f_max = match audio.max_drive_hz {
            Some(f) if f.is_finite() && f > 0.0 => f,
            _ => band_of(mic, fs),
        };
        let pass = (cfg.band_factor * f_max).clamp(20.0, 0.3 * fs);
        let lp = LowPass {
            pass_hz: pass,
            stop_hz: pass * 1.25,
        };
        // Grid: about 4x the stop frequency, a power-of-two decimation of the audio.
        let mut decim = 1usize;
        while fs / (2.0 * decim as f64) >= 4.0 * lp.stop_hz && decim < 1 << 12 {
            decim *= 2;
        }
        // x is resampled at fs/x_decim: fast enough that the laser's band
        // [0, rate/2] does not fold into the fit band.
        let mut x_decim = decim;
        while x_decim > 1 && fs / x_decim as f64 - lp.stop_hz < 0.5 * laser_rate_hz {
            x_decim /= 2;
        }
        let (out, grid_fs) = with_thread_planner(|pl| {
            let sp = Spectrum::with_planner(mic, fs, mic.len() / 8, pl);
            let d = decim.min(sp.n_fft / 4).max(1);
            (sp.derivative(lp, 0, d, pl), fs / d as f64)
        });
        let decim = (fs / grid_fs).round() as usize;
        let n = out.len();
        let duration_s = n as f64 / grid_fs;
        let window = ((cfg.window_s * grid_fs).round() as usize).max(16);
        let edge = ((0.05 * grid_fs).round() as usize).min(n / 8);
        if n < 64 || n < 2 * edge + window {
            return Err(format!(
                "the sweep is too short for the alignment ({duration_s:.2} s)"
            ));
        }
        Ok(FitGrid {
            fs_hz: grid_fs,
            decim,
            x_decim: x_decim.min(decim),
            lp,
            mic: out,
            duration_s,
            t_mid_s: 0.5 * duration_s,
            window,
            edge,
            corr: (grid_fs / (2.0 * lp.stop_hz)).max(1.0).sqrt(),
        })
    }

    /// x at the grid's pre-decimation instants under `map` (first audio sample at `start_s`).
    fn x_at(
        &self,
        kernel: &SincKernel,
        dense: &Dense,
        map: Map,
        start_s: f64,
        fs_audio: f64,
    ) -> Vec<f64> {
        let n_x = self.mic.len() * (self.decim / self.x_decim);
        let dt = self.x_decim as f64 / fs_audio;
        (0..n_x)
            .map(|k| {
                kernel.eval(
                    &dense.x,
                    map.n_of(start_s + k as f64 * dt) - dense.n0 as f64,
                )
            })
            .collect()
    }

    /// Band-limited columns (x'', x', x^1..x^POWERS, 1) and their time derivatives.
    fn columns(&self, x: &[f64], fs_x: f64, with_derivs: bool) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
        let d = self.decim / self.x_decim;
        let n = self.mic.len();
        let scale = x.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        with_thread_planner(|pl| {
            let mut cols = Vec::with_capacity(POWERS + 3);
            let mut ders = Vec::with_capacity(POWERS + 3);
            let fit = |v: Vec<f64>| -> Vec<f64> {
                let mut v = v;
                v.resize(n, 0.0);
                v
            };
            let sx = Spectrum::with_planner(x, fs_x, x.len() / 8, pl);
            cols.push(fit(sx.derivative(self.lp, 2, d, pl)));
            cols.push(fit(sx.derivative(self.lp, 1, d, pl)));
            if with_derivs {
                ders.push(fit(sx.derivative(self.lp, 3, d, pl)));
                ders.push(cols[0].clone());
            }
            for k in 1..=POWERS {
                if k == 1 {
                    cols.push(fit(sx.derivative(self.lp, 0, d, pl)));
                    if with_derivs {
                        ders.push(cols[1].clone());
                    }
                    continue;
                }
                let xk: Vec<f64> = x.iter().map(|v| (v / scale).powi(k as i32)).collect();
                let sk = Spectrum::with_planner(&xk, fs_x, xk.len() / 8, pl);
                cols.push(fit(sk.derivative(self.lp, 0, d, pl)));
                if with_derivs {
                    ders.push(fit(sk.derivative(self.lp, 1, d, pl)));
                }
            }
            cols.push(vec![1.0; n]);
            if with_derivs {
                ders.push(vec![0.0; n]);
            }
            (cols, ders)
        })
    }

    /// The force-balance fit with the delay line (`joint`) or, after
    /// convergence, with the window delays.
    fn fit(
        &self,
        kernel: &SincKernel,
        dense: &Dense,
        map: Map,
        start_s: f64,
        joint: bool,
    ) -> Result<GridFit, String> {
        let fs_audio = self.fs_hz * self.decim as f64;
        let x = self.x_at(kernel, dense, map, start_s, fs_audio);
        let (cols, ders) = self.columns(&x, fs_audio / self.x_decim as f64, true);
        let (a, b) = (self.edge, self.mic.len() - self.edge);
        // The force balance solved for the acceleration: x'' = c mic - (R x'
        // + K(x) x) / m + const. The laser's twice-differentiated noise sits
        // in the dependent variable (no errors-in-variables bias); the
        // regressors (microphone, x', powers of x) are quiet.
        let y = &cols[0][a..b];
        let mut sel: Vec<&[f64]> = vec![&self.mic[a..b]];
        sel.extend(cols[1..].iter().map(|c| &c[a..b]));
        let base = lstsq(&sel, y).map_err(|e| format!("force-balance fit: {e}"))?;
        // g = d/dt of the x-dependent prediction minus x''' (module docs).
        let mut g: Vec<f64> = ders[0][a..b].iter().map(|v| -v).collect();
        for (c, d) in base.coefficients[1..].iter().zip(&ders[1..]) {
            for (gi, di) in g.iter_mut().zip(&d[a..b]) {
                *gi += c * di;
            }
        }
        let y_rms = (y.iter().map(|v| v * v).sum::<f64>() / y.len() as f64).sqrt();
        let rel_residual = if y_rms > 0.0 {
            (base.rss / y.len() as f64).sqrt() / y_rms
        } else {
            f64::INFINITY
        };
        if joint {
            let tm = self.t_mid_s;
            let gt: Vec<f64> = g
                .iter()
                .enumerate()
                .map(|(j, v)| v * ((a + j) as f64 / self.fs_hz - tm))
                .collect();
            let mut sel2 = sel.clone();
            sel2.push(&g);
            sel2.push(&gt);
            let r = lstsq(&sel2, y).map_err(|e| format!("delay fit: {e}"))?;
            let p = r.coefficients.len();
            return Ok(GridFit {
                delay_offset_s: r.coefficients[p - 2],
                delay_slope: r.coefficients[p - 1],
                rel_residual,
                windows: Vec::new(),
            });
        }
        // Window delays from the residual of the converged fit.
        let mut windows = Vec::new();
        let r = &base.residual;
        let mut j = 0;
        while j + self.window <= r.len() {
            let (mut rg, mut gg, mut rr) = (0.0, 0.0, 0.0);
            for k in j..j + self.window {
                rg += r[k] * g[k];
                gg += g[k] * g[k];
                rr += r[k] * r[k];
            }
            if gg > 0.0 {
                let d = rg / gg;
                let var = (rr - d * rg).max(0.0) / (self.window as f64 - 1.0);
                let sigma = (var / gg).sqrt() * self.corr;
                if sigma.is_finite() && sigma > 0.0 && d.is_finite() {
                    windows.push(WindowDelay {
                        t_s: (a + j) as f64 / self.fs_hz + 0.5 * self.window as f64 / self.fs_hz,
                        delay_s: d,
                        sigma_s: sigma,
                    });
                }
            }
            j += self.window;
        }
        // Keep windows that say something (sigma within 20x of the best).
        let best = windows
            .iter()
            .map(|w| w.sigma_s)
            .fold(f64::INFINITY, f64::min);
        windows.retain(|w| w.sigma_s <= 20.0 * best);
        Ok(GridFit {
            delay_offset_s: 0.0,
            delay_slope: 0.0,
            rel_residual,
            windows,
        })
    }
}

/// Frequency below which 99 % of the microphone's power (above 2 Hz) lies.
fn band_of(mic: &[f64], fs: f64) -> f64 {
    with_thread_planner(|pl| {
        let sp = Spectrum::with_planner(mic, fs, 0, pl);
        let k2 = (2.0 / sp.df_hz()).ceil() as usize;
        let p: Vec<f64> = sp.bins.iter().map(|c| c.norm_sqr()).collect();
        let total: f64 = p.iter().skip(k2).sum();
        let mut acc = 0.0;
        for (k, v) in p.iter().enumerate().skip(k2) {
            acc += v;
            if acc >= 0.99 * total {
                return sp.freq_hz(k).max(10.0);
            }
        }
        fs / 4.0
    })
}

/// Windowed-sinc interpolator (Kaiser window) evaluated at arbitrary
/// fractional positions, from a table of `phases` sub-sample phases with
/// linear interpolation between them. Samples beyond the ends are held.
#[derive(Debug, Clone)]
pub struct SincKernel {
    half: usize,
    phases: usize,
    /// (phases + 1) rows of 2*half taps; row p is for fraction p/phases.
    table: Vec<f64>,
}

impl Default for SincKernel {
    /// 32 taps, cutoff 0.9 of the input Nyquist, Kaiser beta 8, 512 phases:
    /// flat (< 1e-4) up to 0.4 of the input rate.
    fn default() -> Self {
        SincKernel::new(16, 0.9, 8.0, 512)
    }
}

impl SincKernel {
    /// `half` taps either side; `cutoff` as a fraction of the input Nyquist.
    pub fn new(half: usize, cutoff: f64, beta: f64, phases: usize) -> SincKernel {
        let half = half.max(1);
        let phases = phases.max(1);
        let i0b = bessel_i0(beta);
        let mut table = Vec::with_capacity((phases + 1) * 2 * half);
        for p in 0..=phases {
            let frac = p as f64 / phases as f64;
            let mut row: Vec<f64> = (0..2 * half)
                .map(|m| {
                    let d = frac + half as f64 - 1.0 - m as f64;
                    let z = d / half as f64;
                    if z.abs() >= 1.0 {
                        return 0.0;
                    }
                    let w = bessel_i0(beta * (1.0 - z * z).sqrt()) / i0b;
                    let s = cutoff * d;
                    let sinc = if s.abs() < 1e-12 {
                        1.0
                    } else {
                        (std::f64::consts::PI * s).sin() / (std::f64::consts::PI * s)
                    };
                    cutoff * sinc * w
                })
                .collect();
            let sum: f64 = row.iter().sum();
            if sum.abs() > 1e-12 {
                row.iter_mut().for_each(|v| *v /= sum);
            }
            table.extend(row);
        }
        SincKernel {
            half,
            phases,
            table,
        }
    }

    /// The band-limited value of `x` at fractional index `u`.
    pub fn eval(&self, x: &[f64], u: f64) -> f64 {
        if x.is_empty() || !u.is_finite() {
            return 0.0;
        }
        let last = x.len() as f64 - 1.0;
        if u <= -(self.half as f64) {
            return x[0];
        }
        if u >= last + self.half as f64 {
            return x[x.len() - 1];
        }
        let i0 = u.floor();
        let frac = u - i0;
        let pos = frac * self.phases as f64;
        let p = (pos.floor() as usize).min(self.phases - 1);
        let a = pos - p as f64;
        let w = 2 * self.half;
        let r0 = &self.table[p * w..(p + 1) * w];
        let r1 = &self.table[(p + 1) * w..(p + 2) * w];
        let base = i0 as i64 - self.half as i64 + 1;
        let n = x.len() as i64;
        let mut s = 0.0;
        if base >= 0 && base + w as i64 <= n {
            let xs = &x[base as usize..base as usize + w];
            for m in 0..w {
                s += xs[m] * (r0[m] + a * (r1[m] - r0[m]));
            }
        } else {
            for m in 0..w {
                let i = (base + m as i64).clamp(0, n - 1) as usize;
                s += x[i] * (r0[m] + a * (r1[m] - r0[m]));
            }
        }
        s
    }
}

/// Modified Bessel function of the first kind, order 0 (series).
fn bessel_i0(x: f64) -> f64 {
    let q = x * x / 4.0;
    let (mut term, mut sum) = (1.0, 1.0);
    for k in 1..60 {
        term *= q / (k * k) as f64;
        sum += term;
        if term < sum * 1e-17 {
            break;
        }
    }
    sum
}

#[cfg(test)]
#[path = "align_tests.rs"]
mod tests;
