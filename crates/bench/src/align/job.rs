//! `JobAligner`: aligns the sweeps of one job (coarse offset search,
//! force-balance delay fit per sweep, the weighted clock line through the
//! tie points of all sweeps, resampling), and the fallbacks when a sweep
//! cannot be aligned.

use super::dense::{coverage_fraction, Dense};
use super::grid::FitGrid;
use super::line::{ClockLine, LineCov, Map, Tie};
use super::sinc::SincKernel;
use super::sweep::{AlignConfig, AlignedSweep, AlignmentReport, AudioCapture, LaserTrack};
use crate::laser::{LaserSample, SampleClock};
use springbench_core::dsp::spectrum::{with_thread_planner, Spectrum};

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
