//! A verdict's traceability: what judged it (software, recipe version,
//! bench, procedure, bench calibration), for whom and when, and on a fleet
//! station whether its recipes were checked with the center lately. Stored
//! with each verdict (`qc_verdicts.trace_json`), shown by the API and the UI.
//!
//! The stored text is the one earlier versions built with `json!` and
//! merged with the fleet's object: serde_json's sorted members, every
//! member present (null when unknown), the fleet's at the top level.

use crate::job::{ProcedureRun, RecipeRef};
use serde::{Deserialize, Serialize};

/// The traceability of one verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VerdictTrace {
    pub software_version: String,
    /// The recipe version judged by (name, version, content hash).
    pub recipe: RecipeRef,
    pub bench_id: String,
    /// `virtual`, `hardware` or `emulated`.
    pub bench_kind: String,
    /// The bench's own description (the measurement's).
    pub bench_description: Option<String>,
    /// Full or production, and a production run's fall-back with its reason.
    pub procedure: Option<ProcedureRun>,
    /// The virtual bench has no calibration record and no sensor identities;
    /// hardware benches put theirs in the measurement's configuration.
    pub calibration: Option<serde_json::Value>,
    pub sensors: Vec<serde_json::Value>,
    /// The bench calibration from golden units the values were judged with
    /// (decision 0049), or that there is none; null without a recipe's.
    pub bench_calibration: Option<BenchCalibrationTrace>,
    /// The token that submitted the job (None with open access).
    pub submitted_by: Option<String>,
    pub job_created_at: String,
    pub job_started_at: String,
    pub judged_at: String,
    /// None for the verdict of a whole job.
    pub measurement_id: Option<String>,
    /// The pool of the job judged (issue 35, decision 0100): SPC and yield
    /// count `production` only. A verdict stored before purposes existed
    /// reads as `production`, as it was counted then.
    #[serde(default)]
    pub purpose: crate::job::Purpose,
    /// A fleet station: its recipes' provenance (`fleet::Link::recipe_trace`).
    #[serde(flatten, skip_serializing_if = "Option::is_none")]
    pub fleet: Option<FleetTrace>,
}

/// A fleet station's recipe provenance at the time of a verdict.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FleetTrace {
    pub station_id: String,
    /// When the station last checked its recipes with the center.
    pub recipes_synced_at: Option<String>,
    /// The station could not check its recipes with the center lately: a
    /// retirement there may not be known here.
    pub offline: bool,
}

/// The bench calibration a verdict was judged with.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum BenchCalibrationTrace {
    /// The bench's calibration under the recipe, applied to the values judged.
    Applied(AppliedCalibration),
    /// The bench has none for the recipe: judged as measured.
    None { state: String, detail: String },
}

/// A bench calibration as a verdict's trace names it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct AppliedCalibration {
    pub id: String,
    pub state: String,
    /// `full` or `production`: the procedure it was measured with and corrects.
    pub procedure: String,
    pub reference_bench_id: Option<String>,
    pub laser_gain_error: Option<f64>,
    pub k_scale: Option<f64>,
    pub kx_scale: Option<f64>,
    pub clamp_mass_kg: Option<f64>,
    pub created_at: String,
}

impl BenchCalibrationTrace {
    /// No bench calibration for the recipe on this bench.
    pub fn none() -> BenchCalibrationTrace {
        BenchCalibrationTrace::None {
            state: "none".into(),
            detail: "no bench calibration for this recipe on this bench: judged as measured".into(),
        }
    }

    /// A stored calibration (`id`, `state`, `procedure`, `created_at` of its
    /// row) and its figures (None: its document did not read).
    pub fn applied(
        id: &str,
        state: &str,
        procedure: &str,
        created_at: &str,
        cal: Option<&super::BenchCalibration>,
    ) -> BenchCalibrationTrace {
        BenchCalibrationTrace::Applied(AppliedCalibration {
            id: id.into(),
            state: state.into(),
            procedure: procedure.into(),
            reference_bench_id: cal.map(|c| c.reference_bench_id.clone()),
            laser_gain_error: cal.map(|c| c.laser_gain_error),
            k_scale: cal.map(|c| c.k_scale),
            kx_scale: cal.map(|c| c.kx_scale),
            clamp_mass_kg: cal.map(|c| c.clamp_mass_kg),
            created_at: created_at.into(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::job::{ProcedureMode, RepeatEnded};
    use serde_json::{json, Value};

    /// The trace as the runner built it with `json!` before this type.
    fn old(fleet: Option<Value>, cal: Value, procedure: Value) -> Value {
        let mut t = json!({
            "software_version": "0.1.0",
            "recipe": {"name": "spider", "version": 3, "sha256": "ab12"},
            "bench_id": "b1",
            "bench_kind": "virtual",
            "bench_description": "virtual bench (spider_4in)",
            "procedure": procedure,
            "calibration": Value::Null,
            "sensors": [],
            "bench_calibration": cal,
            "submitted_by": Option::<String>::None,
            "job_created_at": "2026-11-28T10:00:00.000Z",
            "job_started_at": "2026-11-28T10:00:01.000Z",
            "judged_at": "2026-11-28T10:00:40.000Z",
            "measurement_id": "m1",
            "purpose": "production",
        });
        if let (Some(t), Some(Value::Object(f))) = (t.as_object_mut(), fleet) {
            t.extend(f);
        }
        t
    }

    fn typed(fleet: Option<FleetTrace>, cal: Option<BenchCalibrationTrace>) -> VerdictTrace {
        VerdictTrace {
            software_version: "0.1.0".into(),
            recipe: RecipeRef {
                name: "spider".into(),
                version: 3,
                sha256: "ab12".into(),
                origin: None,
            },
            bench_id: "b1".into(),
            bench_kind: "virtual".into(),
            bench_description: Some("virtual bench (spider_4in)".into()),
            procedure: Some(ProcedureRun {
                mode: ProcedureMode::Production,
                ended: Some(RepeatEnded {
                    fallback: None,
                    bench_time_s: 8.5,
                    analysis_s: 1.25,
                }),
            }),
            calibration: None,
            sensors: vec![],
            bench_calibration: cal,
            submitted_by: None,
            job_created_at: "2026-11-28T10:00:00.000Z".into(),
            job_started_at: "2026-11-28T10:00:01.000Z".into(),
            judged_at: "2026-11-28T10:00:40.000Z".into(),
            measurement_id: Some("m1".into()),
            purpose: crate::job::Purpose::Production,
            fleet,
        }
    }

    #[test]
    fn the_stored_text_is_the_one_json_and_the_fleets_merge_wrote() {
        let procedure = json!({"mode": "production", "fallback": null, "bench_time_s": 8.5, "analysis_s": 1.25});
        let none = json!({"state": "none",
            "detail": "no bench calibration for this recipe on this bench: judged as measured"});
        let applied = json!({"id": "c1", "state": "approved", "procedure": "full",
            "reference_bench_id": "ref", "laser_gain_error": 0.02, "k_scale": 1.01,
            "kx_scale": 0.99, "clamp_mass_kg": 0.001, "created_at": "2026-11-27T09:00:00.000Z"});
        let applied_typed = BenchCalibrationTrace::Applied(AppliedCalibration {
            id: "c1".into(),
            state: "approved".into(),
            procedure: "full".into(),
            reference_bench_id: Some("ref".into()),
            laser_gain_error: Some(0.02),
            k_scale: Some(1.01),
            kx_scale: Some(0.99),
            clamp_mass_kg: Some(0.001),
            created_at: "2026-11-27T09:00:00.000Z".into(),
        });
        let fleet = json!({"station_id": "st-1", "recipes_synced_at": null, "offline": true});
        let fleet_typed = FleetTrace {
            station_id: "st-1".into(),
            recipes_synced_at: None,
            offline: true,
        };
        for (f, ft) in [(None, None), (Some(fleet), Some(fleet_typed))] {
            for (c, ct) in [
                (Value::Null, None),
                (none.clone(), Some(BenchCalibrationTrace::none())),
                (applied.clone(), Some(applied_typed.clone())),
            ] {
                let want = old(f.clone(), c, procedure.clone()).to_string();
                let t = typed(ft.clone(), ct);
                let got = serde_json::to_value(&t).unwrap().to_string();
                assert_eq!(got, want);
                let back: VerdictTrace = serde_json::from_str(&want).unwrap();
                assert_eq!(back, t);
                // written before purposes existed: read as production
                let mut older: Value = serde_json::from_str(&want).unwrap();
                older.as_object_mut().unwrap().remove("purpose");
                let back: VerdictTrace = serde_json::from_value(older).unwrap();
                assert_eq!(back, t);
            }
        }
    }
}
