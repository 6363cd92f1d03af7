//! The force-balance fit of one sweep on a decimated, band-limited grid:
//! a Gauss-Newton fit of `m, R, k_0..k_4` and a constant jointly with a
//! delay line `d(t)`, and the window delays (tie points) it gives.

use super::dense::Dense;
use super::line::Map;
use super::sinc::SincKernel;
use super::sweep::{AlignConfig, AudioCapture};
use springbench_core::dsp::lstsq::lstsq;
use springbench_core::dsp::spectrum::{with_thread_planner, LowPass, Spectrum};

/// One window's delay estimate (relative to the sweep's map).
#[derive(Debug, Clone, Copy)]
pub(super) struct WindowDelay {
    /// Window centre (s from the sweep start).
    pub(super) t_s: f64,
    pub(super) delay_s: f64,
    pub(super) sigma_s: f64,
}

/// Result of one force-balance fit on the grid.
#[derive(Debug, Clone)]
pub(super) struct GridFit {
    pub(super) delay_offset_s: f64,
    pub(super) delay_slope: f64,
    pub(super) rel_residual: f64,
    pub(super) windows: Vec<WindowDelay>,
}

/// The decimated, band-limited microphone and the grid the fit runs on.
pub(super) struct FitGrid {
    pub(super) fs_hz: f64,
    /// Audio samples per grid sample.
    pub(super) decim: usize,
    /// Grid samples of x before their decimation (x is resampled at fs/x_decim).
    pub(super) x_decim: usize,
    pub(super) lp: LowPass,
    pub(super) mic: Vec<f64>,
    pub(super) duration_s: f64,
    pub(super) t_mid_s: f64,
    pub(super) window: usize,
    /// Grid samples excluded at each end (filter edges).
    pub(super) edge: usize,
    /// sqrt(grid oversampling): the residual's samples are correlated.
    pub(super) corr: f64,
}

/// Powers of x in the force balance: K(x) up to x^4.
pub(super) const POWERS: usize = 5;

impl FitGrid {
    pub(super) fn new(
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
    pub(super) fn x_at(
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
    pub(super) fn columns(
        &self,
        x: &[f64],
        fs_x: f64,
        with_derivs: bool,
    ) -> (Vec<Vec<f64>>, Vec<Vec<f64>>) {
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
    pub(super) fn fit(
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
pub(super) fn band_of(mic: &[f64], fs: f64) -> f64 {
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
