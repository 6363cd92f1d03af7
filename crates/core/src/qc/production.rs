//! The production procedure's data: what the approved golden units
//! established (their small-signal and large-signal resonances, Q and the
//! drive levels that reached the target), stored with the approved limits in
//! the recipe's `procedure.golden`, and the recipe's choice of procedure
//! (`procedure.mode`). Pure: the bench crate's `procedure::production` runs it.

use super::limits::GoldenUnit;
use serde::{Deserialize, Serialize};

pub use crate::job::ProcedureMode;

/// Default of [`GoldenReference::max_f0_deviation_percent`]: a part whose
/// small-signal f0 lies further than this from the golden units' mean falls
/// back to the full procedure (10 % in k0 at equal mass is 4.9 % in f0; the
/// lot's k0 spread is 1.5 %, a 25 % stiffer part is 11.8 % off in f0).
pub const DEFAULT_MAX_F0_DEVIATION_PERCENT: f64 = 5.0;

fn default_max_f0_dev() -> f64 {
    DEFAULT_MAX_F0_DEVIATION_PERCENT
}

/// One level of the golden units (index-aligned with `procedure.levels_m`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GoldenLevel {
    /// Mean large-signal resonance of the golden units' narrow sweeps (Hz).
    pub resonance_hz: f64,
    /// Mean drive amplitude that reached the target Xpeak (V): where the full
    /// procedure's search stopped, within its 8 % of the target.
    pub drive_v: f64,
    /// Mean Xpeak the golden units reached at that drive (m), as the analysis
    /// reads it. The production procedure scales `drive_v` by the target over
    /// it, so its first sweep aims at the target rather than at the search's
    /// tolerance edge. Absent in references stored before it was recorded
    /// (then the drive is taken as it is).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub xpeak_m: Option<f64>,
}

/// What the golden units established, stored with the approved limits.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct GoldenReference {
    /// How many golden units the means are over.
    pub units: usize,
    /// Mean small-signal resonance (Hz).
    pub f0_hz: f64,
    /// Mean small-signal Q (1): with f0 it gives the ringing time constant
    /// Q / (pi f0) that paces the short sweeps.
    pub q: f64,
    /// Mean drive amplitude of the pre-measurement (V).
    pub pre_drive_v: f64,
    /// Mean quality of the pre-measurement's drive-to-displacement response
    /// |X/U| (exciter and box included): how far a short sweep builds up the
    /// resonance; absent: `q` stands in.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pre_q_drive_to_x: Option<f64>,
    pub levels: Vec<GoldenLevel>,
    /// A part whose f0 deviates further than this from `f0_hz` (%) falls back to the full procedure.
    #[serde(default = "default_max_f0_dev")]
    pub max_f0_deviation_percent: f64,
}

impl GoldenReference {
    /// The means over the golden units' measurements (each unit: every level
    /// with its report, narrow-sweep drive and pre-measurement drive). None
    /// when any of them lacks a number (units measured before the drives were
    /// stored, or a small-signal value not determined).
    pub fn from_golden(golden: &[GoldenUnit], levels: usize) -> Option<GoldenReference> {
        if golden.is_empty() || levels == 0 {
            return None;
        }
        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
        let (mut f0, mut q, mut pre) = (vec![], vec![], vec![]);
        let mut q_xu: Vec<Option<f64>> = vec![];
        let mut res = vec![vec![]; levels];
        let mut drv = vec![vec![]; levels];
        let mut xpk: Vec<Vec<f64>> = vec![vec![]; levels];
        for g in golden {
            for li in 0..levels {
                let f = g.measurements.iter().find(|m| m.level_index == li)?;
                let rep = f.report.as_ref()?;
                if li == 0 {
                    let ss = rep.small_signal.as_ref()?;
                    f0.push(ss.f0_hz?);
                    q.push(ss.q?);
                    pre.push(f.pre_drive_v?);
                    q_xu.push(f.pre_q_drive_to_x);
                }
                res[li].push(rep.large_signal.resonance_hz);
                drv[li].push(f.drive_v?);
                xpk[li].push(rep.large_signal.xpeak_m);
            }
        }
        let g = GoldenReference {
            units: golden.len(),
            f0_hz: mean(&f0),
            q: mean(&q),
            pre_drive_v: mean(&pre),
            pre_q_drive_to_x: q_xu
                .iter()
                .copied()
                .collect::<Option<Vec<f64>>>()
                .map(|v| mean(&v)),
            levels: (0..levels)
                .map(|li| GoldenLevel {
                    resonance_hz: mean(&res[li]),
                    drive_v: mean(&drv[li]),
                    xpeak_m: xpk[li]
                        .iter()
                        .all(|x| x.is_finite() && *x > 0.0)
                        .then(|| mean(&xpk[li])),
                })
                .collect(),
            max_f0_deviation_percent: DEFAULT_MAX_F0_DEVIATION_PERCENT,
        };
        g.validate(levels).is_ok().then_some(g)
    }

    /// One message per bad member (field names relative to `procedure.golden`).
    pub fn validate(&self, levels: usize) -> Result<(), Vec<(String, String)>> {
        let mut e = vec![];
        let pos = |v: f64| v.is_finite() && v > 0.0 && v <= super::MAX_LIMIT;
        for (n, v) in [
            ("f0_hz", self.f0_hz),
            ("q", self.q),
            ("pre_drive_v", self.pre_drive_v),
            ("pre_q_drive_to_x", self.pre_q_drive_to_x.unwrap_or(self.q)),
        ] {
            if !pos(v) {
                e.push((n.to_string(), format!("must be a positive number, got {v}")));
            }
        }
        if self.units == 0 {
            e.push(("units".into(), "must be at least 1".into()));
        }
        if !(self.max_f0_deviation_percent.is_finite()
            && self.max_f0_deviation_percent > 0.0
            && self.max_f0_deviation_percent <= 50.0)
        {
            e.push((
                "max_f0_deviation_percent".into(),
                format!("must be in (0, 50], got {}", self.max_f0_deviation_percent),
            ));
        }
        if self.levels.len() != levels {
            e.push((
                "levels".into(),
                format!(
                    "one entry per level of procedure.levels_m ({levels}), got {}",
                    self.levels.len()
                ),
            ));
        }
        for (i, l) in self.levels.iter().enumerate() {
            let xpeak = l.xpeak_m.map(|x| ("xpeak_m", x));
            for (n, v) in [("resonance_hz", l.resonance_hz), ("drive_v", l.drive_v)]
                .into_iter()
                .chain(xpeak)
            {
                if !pos(v) {
                    e.push((
                        format!("levels[{i}].{n}"),
                        format!("must be a positive number, got {v}"),
                    ));
                }
            }
        }
        if e.is_empty() {
            Ok(())
        } else {
            Err(e)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::identify::{LargeSignal, Report, SmallSignal};
    use crate::qc::RunFacts;

    fn unit(f0: f64, q: f64, fr: f64, drive: f64, pre: f64, q_xu: Option<f64>) -> GoldenUnit {
        GoldenUnit {
            serial: format!("G-{f0}"),
            measurements: vec![RunFacts {
                report: Some(Report {
                    small_signal: Some(SmallSignal {
                        f0_hz: Some(f0),
                        q: Some(q),
                        ..Default::default()
                    }),
                    large_signal: LargeSignal {
                        resonance_hz: fr,
                        xpeak_m: fr * 1e-4,
                        ..Default::default()
                    },
                    ..Default::default()
                }),
                drive_v: Some(drive),
                pre_drive_v: Some(pre),
                pre_q_drive_to_x: q_xu,
                ..Default::default()
            }],
        }
    }

    #[test]
    fn the_reference_is_the_golden_units_means() {
        let g = GoldenReference::from_golden(
            &[
                unit(35.0, 6.0, 45.0, 50.0, 7.0, Some(8.0)),
                unit(36.0, 6.4, 46.0, 48.0, 7.4, Some(9.0)),
            ],
            1,
        )
        .unwrap();
        assert_eq!(g.units, 2);
        assert!((g.f0_hz - 35.5).abs() < 1e-12 && (g.q - 6.2).abs() < 1e-12);
        assert!((g.pre_drive_v - 7.2).abs() < 1e-12);
        assert_eq!(g.pre_q_drive_to_x, Some(8.5));
        assert!((g.levels[0].xpeak_m.unwrap() - 4.55e-3).abs() < 1e-15);
        assert_eq!(
            g.levels,
            [GoldenLevel {
                resonance_hz: 45.5,
                drive_v: 49.0,
                xpeak_m: g.levels[0].xpeak_m,
            }]
        );
        // A unit whose report has no Xpeak leaves the level without one (the
        // drive is then taken as it is), rather than a mean of a zero.
        let mut no_x = unit(36.0, 6.4, 46.0, 48.0, 7.4, Some(9.0));
        no_x.measurements[0]
            .report
            .as_mut()
            .unwrap()
            .large_signal
            .xpeak_m = 0.0;
        let g2 = GoldenReference::from_golden(&[unit(35.0, 6.0, 45.0, 50.0, 7.0, None), no_x], 1)
            .unwrap();
        assert_eq!(g2.levels[0].xpeak_m, None);
        let mut bad = g2.clone();
        bad.levels[0].xpeak_m = Some(f64::NAN);
        assert_eq!(bad.validate(1).unwrap_err()[0].0, "levels[0].xpeak_m");
        assert_eq!(g.max_f0_deviation_percent, DEFAULT_MAX_F0_DEVIATION_PERCENT);
        // One unit without its |X/U| quality: the part's Q stands in (None).
        let g = GoldenReference::from_golden(
            &[
                unit(35.0, 6.0, 45.0, 50.0, 7.0, None),
                unit(36.0, 6.4, 46.0, 48.0, 7.4, Some(9.0)),
            ],
            1,
        )
        .unwrap();
        assert_eq!(g.pre_q_drive_to_x, None);
        // A unit measured before the drives were stored gives no reference.
        let mut old = unit(35.0, 6.0, 45.0, 50.0, 7.0, None);
        old.measurements[0].pre_drive_v = None;
        assert!(GoldenReference::from_golden(&[old], 1).is_none());
        // ... nor one whose level is missing
        assert!(
            GoldenReference::from_golden(&[unit(35.0, 6.0, 45.0, 50.0, 7.0, None)], 2).is_none()
        );
    }

    #[test]
    fn a_bad_reference_is_named_by_field() {
        let mut g =
            GoldenReference::from_golden(&[unit(35.0, 6.0, 45.0, 50.0, 7.0, None)], 1).unwrap();
        g.levels[0].drive_v = -1.0;
        g.max_f0_deviation_percent = 80.0;
        let e = g.validate(2).unwrap_err();
        let f: Vec<&str> = e.iter().map(|(f, _)| f.as_str()).collect();
        assert_eq!(
            f,
            ["max_f0_deviation_percent", "levels", "levels[0].drive_v"]
        );
    }
}
