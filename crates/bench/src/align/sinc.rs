//! Windowed-sinc (Kaiser) resampling of the laser at the audio instants.

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
