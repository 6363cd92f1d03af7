//! What a measurement was made with, stored beside its result
//! (`measurements.config_json`): the procedure's settings, the analysis
//! options, the limits, the sweeps the procedure chose, what ran (full or
//! production, a fall-back) and, on a hardware bench, what the bench
//! measured about itself. The runner writes it, the verdicts' traceability,
//! the limits from golden units and the refits read it: one type, so that
//! renaming a member is a compile error in each of them (decision 0080).
//!
//! The stored text is the one earlier versions wrote with `json!`
//! (serde_json's sorted members; [`MeasurementConfig::to_json`]). Rows of
//! earlier versions lack members added since: those are `Option`, and a
//! member that no longer reads is left out (`lenient`) rather than making
//! the whole document unreadable.

use super::spec::{Limits, ProcedureMode};
use crate::identify::AnalyzeOptions;
use serde::{Deserialize, Deserializer, Serialize};
use serde_json::Value;

/// Parameters of the whole procedure. All SI.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProcedureConfig {
    /// Moving mass of part + inner clamp (kg), as the user weighed it.
    pub moving_mass_kg: f64,
    /// Target peak displacements of the narrow sweeps (m), one sweep each (level series).
    pub levels_m: Vec<f64>,
    /// Displacement the pre-measurement aims for at resonance (m); about 1 mm.
    pub pre_target_x_m: f64,
    /// Start and end of the pre-measurement log sweep (Hz).
    pub pre_f_start_hz: f64,
    pub pre_f_end_hz: f64,
    /// Length of the pre-measurement sweep (s).
    pub pre_duration_s: f64,
    /// Length of each narrow sweep (s).
    pub narrow_duration_s: f64,
}

impl Default for ProcedureConfig {
    fn default() -> Self {
        ProcedureConfig {
            moving_mass_kg: 0.05,
            levels_m: vec![0.008],
            pre_target_x_m: 1e-3,
            pre_f_start_hz: 5.0,
            pre_f_end_hz: 100.0,
            pre_duration_s: 16.0,
            narrow_duration_s: 10.0,
        }
    }
}

/// A measurement's configuration as stored. A measurement made on a bench
/// has every member but `hardware` (a hardware bench's) set; an imported
/// one only `analysis`. Readers take its members by name, never by a JSON
/// key, so a renamed member is a compile error where it is read (decision 0080).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct MeasurementConfig {
    /// The analysis options of the fit.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub analysis: Option<AnalyzeOptions>,
    /// The procedure's settings.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub procedure: Option<ProcedureConfig>,
    /// The procedure the job asked for (`full` or `production`).
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub procedure_mode: Option<ProcedureMode>,
    /// What ran: the procedure and, once the repeat ended, its fall-back and times.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub procedure_run: Option<ProcedureRun>,
    /// The job's limits.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub limits: Option<Limits>,
    /// The bench's id.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub bench: Option<String>,
    /// The bench's own description (`Bench::describe`).
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub bench_description: Option<String>,
    /// The seed of the virtual bench's noise.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub seed: Option<u64>,
    /// The narrow sweep of this level, as the procedure chose it.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub narrow_sweep: Option<SweepSettings>,
    /// The repeat's pre-measurement (stored since 2026-11-26).
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub pre_sweep: Option<PreSweepSettings>,
    /// A hardware bench: its calibration record, sensors, latency, alignment.
    #[serde(
        default,
        deserialize_with = "lenient",
        skip_serializing_if = "Option::is_none"
    )]
    pub hardware: Option<HardwareRecord>,
    /// Members this version does not know (a newer station's, replicated
    /// to the center), kept as they came.
    #[serde(flatten)]
    pub other: serde_json::Map<String, Value>,
}

/// What ran for a measurement's repeat.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ProcedureRun {
    /// `full` or `production`.
    pub mode: ProcedureMode,
    /// Known when the repeat has ended (written into its measurements then).
    #[serde(flatten)]
    pub ended: Option<RepeatEnded>,
}

/// A repeat's fall-back and times, known when it ends.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RepeatEnded {
    /// Why a production run fell back to the full procedure (null: it did not).
    pub fallback: Option<String>,
    /// Stimulus time played and captured (s).
    pub bench_time_s: f64,
    /// Wall time of the repeat's analyses (s).
    pub analysis_s: f64,
}

/// A sweep as the procedure played it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SweepSettings {
    /// Drive amplitude (V peak).
    pub drive_v: f64,
    pub f_start_hz: f64,
    pub f_end_hz: f64,
    /// Length (s); absent in rows stored before 2026-11-26.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
}

/// The pre-measurement's sweep and the drive-to-displacement Q it found.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PreSweepSettings {
    #[serde(flatten)]
    pub sweep: SweepSettings,
    /// Q of the drive-to-displacement response at the resonance (None: not found).
    pub q_drive_to_x: Option<f64>,
}

/// What a measurement on a hardware bench stores about the bench: the
/// calibration record in effect and the bench's own records of the sweeps
/// (documents the bench made: `Bench::run_records`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct HardwareRecord {
    pub calibration_id: String,
    /// The bench's calibration as configured (`[benches.hardware.calibration]`).
    pub calibration: Value,
    /// The sensors' identities as configured.
    pub sensors: Value,
    /// Loopback latency of the narrow sweep (s).
    pub latency_s: Option<f64>,
    /// How the narrow sweep's displacement was put on the audio clock.
    pub alignment: Value,
    /// The same for the pre-measurement (a serial laser only).
    pub pre_alignment: Option<Value>,
    /// The bench's record of the narrow sweep and of the pre-measurement.
    pub main_sweep: Option<Value>,
    pub pre_sweep: Option<Value>,
}

impl HardwareRecord {
    /// The record of level `li` of a repeat: `runs` are the bench's records
    /// of the repeat's sweeps (`Bench::run_records`, each with its
    /// `frames`); the pre-measurement is the last sweep of its length, the
    /// narrow sweep of level `li` the `li`-th of its length.
    pub fn of_level(
        calibration_id: &str,
        calibration: &Value,
        sensors: &Value,
        runs: &[Value],
        pre_frames: usize,
        main_frames: usize,
        li: usize,
    ) -> HardwareRecord {
        let frames = |r: &&Value| r.get("frames").and_then(Value::as_u64).map(|f| f as usize);
        let pre = runs
            .iter()
            .rev()
            .find(|r| frames(r) == Some(pre_frames))
            .cloned();
        let main = runs
            .iter()
            .filter(|r| frames(r) == Some(main_frames))
            .nth(li)
            .or_else(|| runs.iter().rev().find(|r| frames(r) == Some(main_frames)))
            .cloned();
        let field = |r: &Option<Value>, k: &str| r.as_ref().and_then(|m| m.get(k)).cloned();
        HardwareRecord {
            calibration_id: calibration_id.to_string(),
            calibration: calibration.clone(),
            sensors: sensors.clone(),
            latency_s: field(&main, "latency_s").and_then(|l| l.as_f64()),
            // Analog laser: displacement, microphone and loopback on one converter clock.
            alignment: field(&main, "alignment").unwrap_or_else(|| {
                serde_json::json!({"method": "same converter", "offset_s": 0.0, "clock_ppm": 0.0, "residual_s": 0.0})
            }),
            pre_alignment: field(&pre, "alignment"),
            main_sweep: main,
            pre_sweep: pre,
        }
    }

    /// Why the measurement must not be fitted: the serial laser's samples of
    /// its narrow sweep or of its pre-measurement could not be put on the
    /// audio clock (the bench marks such an alignment `"valid": false`).
    pub fn alignment_invalid(&self) -> Option<String> {
        for (a, what) in [
            (Some(&self.alignment), "narrow sweep"),
            (self.pre_alignment.as_ref(), "pre-measurement"),
        ] {
            let Some(a) = a else { continue };
            if a.get("valid").and_then(Value::as_bool) == Some(false) {
                let why = a["invalid_reason"].as_str().unwrap_or("no reason given");
                return Some(format!(
                    "the laser alignment of the {what} is invalid: {why}"
                ));
            }
        }
        None
    }
}

impl MeasurementConfig {
    /// The document as stored: serde_json's sorted members, the text earlier
    /// versions wrote with `json!`.
    pub fn to_json(&self) -> String {
        serde_json::to_value(self)
            .map(|v| v.to_string())
            .unwrap_or_default()
    }
}

/// A member of a stored document that no longer reads (a row of an earlier
/// version) is left out, not the whole document.
fn lenient<'de, D: Deserializer<'de>, T: serde::de::DeserializeOwned>(
    d: D,
) -> Result<Option<T>, D::Error> {
    let v = Value::deserialize(d)?;
    Ok(serde_json::from_value(v).ok())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// The document as the runner built it with `json!` before this type
    /// (the code of `runner/execute.rs` then, verbatim but for the inputs).
    fn old_document(ended: bool, hardware: bool) -> Value {
        let pcfg = ProcedureConfig {
            levels_m: vec![0.004, 0.008],
            ..ProcedureConfig::default()
        };
        let opts = AnalyzeOptions::default();
        let limits = Limits {
            max_displacement_m: 0.012,
            max_drive_v: 4.0,
        };
        let mut cfg = json!({"procedure": pcfg, "procedure_mode": "production",
                        "analysis": opts, "limits": limits,
                        "bench": "b1", "seed": 42u64, "bench_description": "virtual bench (spider_4in)"});
        cfg["procedure_run"] = json!({"mode": "production"});
        cfg["narrow_sweep"] = json!({"drive_v": 1.25, "f_start_hz": 40.0,
                                       "f_end_hz": 90.0,
                                       "duration_s": 1.5});
        cfg["pre_sweep"] = json!({"drive_v": 0.1,
                                    "f_start_hz": 5.0,
                                    "f_end_hz": 100.0,
                                    "duration_s": 4.0,
                                    "q_drive_to_x": Option::<f64>::None});
        if hardware {
            cfg["hardware"] = json!({
                "calibration_id": "c1",
                "calibration": {"laser_m_per_v": 0.001},
                "sensors": {"laser": "optoncdt"},
                "latency_s": 0.0021,
                "alignment": {"method": "same converter", "offset_s": 0.0, "clock_ppm": 0.0, "residual_s": 0.0},
                "pre_alignment": null,
                "main_sweep": {"frames": 480000},
                "pre_sweep": null,
            });
        }
        if ended {
            cfg["procedure_run"] = json!({
                "mode": "production",
                "fallback": "part too far from the golden units",
                "bench_time_s": 8.5,
                "analysis_s": 1.25,
            });
        }
        cfg
    }

    #[test]
    fn the_stored_text_is_the_one_the_json_bag_wrote() {
        for ended in [false, true] {
            for hardware in [false, true] {
                let old = old_document(ended, hardware);
                let typed: MeasurementConfig = serde_json::from_value(old.clone()).unwrap();
                assert_eq!(typed.to_json(), old.to_string(), "{ended} {hardware}");
                assert!(typed.procedure.is_some() && typed.pre_sweep.is_some());
                assert_eq!(typed.hardware.is_some(), hardware);
                assert_eq!(
                    typed.procedure_run.unwrap().ended.is_some(),
                    ended,
                    "{ended}"
                );
            }
        }
        // an import's: the analysis options alone
        let import = json!({"analysis": {"method": "one-signal", "order": 4}});
        let typed: MeasurementConfig = serde_json::from_value(import.clone()).unwrap();
        assert_eq!(typed.analysis.as_ref().unwrap().order, Some(4));
        assert_eq!(typed.to_json(), import.to_string());
    }

    #[test]
    fn a_row_of_an_earlier_version_still_reads() {
        // 2026-11-23: no duration, no pre-measurement, no procedure mode
        let old = json!({"procedure": ProcedureConfig::default(), "analysis": AnalyzeOptions::default(),
                         "limits": {"max_displacement_m": 0.01, "max_drive_v": 5.0}, "bench": "b1", "seed": 1,
                         "narrow_sweep": {"drive_v": 2.5, "f_start_hz": 30.0, "f_end_hz": 80.0},
                         "procedure_run": {"mode": "a mode that no longer exists"}});
        let typed: MeasurementConfig = serde_json::from_value(old).unwrap();
        let n = typed.narrow_sweep.unwrap();
        assert_eq!((n.drive_v, n.duration_s), (2.5, None));
        assert_eq!(typed.limits.unwrap().max_drive_v, 5.0);
        assert!(typed.pre_sweep.is_none() && typed.procedure_mode.is_none());
        // the member that no longer reads is left out, not the document
        assert!(typed.procedure_run.is_none());
    }

    #[test]
    fn members_of_a_newer_version_are_kept() {
        let newer = json!({"analysis": {"method": "two-signal", "order": null}, "bench": "b2",
                           "thermal_chamber": {"temperature_k": 313.15}});
        let typed: MeasurementConfig = serde_json::from_value(newer.clone()).unwrap();
        assert_eq!(typed.bench.as_deref(), Some("b2"));
        assert_eq!(typed.to_json(), newer.to_string());
        assert_eq!(MeasurementConfig::default().to_json(), "{}");
    }

    #[test]
    fn an_invalid_alignment_is_named() {
        let mut h: HardwareRecord =
            serde_json::from_value(old_document(false, true)["hardware"].clone()).unwrap();
        assert_eq!(h.alignment_invalid(), None);
        h.pre_alignment = Some(json!({"valid": false, "invalid_reason": "no tie points"}));
        assert_eq!(
            h.alignment_invalid().as_deref(),
            Some("the laser alignment of the pre-measurement is invalid: no tie points")
        );
        h.alignment = json!({"valid": false});
        assert_eq!(
            h.alignment_invalid().as_deref(),
            Some("the laser alignment of the narrow sweep is invalid: no reason given")
        );
    }
}
