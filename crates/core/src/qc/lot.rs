//! The lot export (issue 35): the measurement verdicts of a recipe as one
//! CSV table, a row per measurement and two columns per parameter (its
//! value, with the unit in the header, and its result).
//!
//! - Every row says who, when, where and under what: serial, measurement and
//!   job, time (UTC, as stored), bench, recipe name and version, purpose,
//!   verdict.
//! - An `invalid` row keeps its values as measured, each `not_judged`
//!   (never pass or fail), and names its reasons in `invalid_reasons`.
//! - A parameter is a column per name and unit: a recipe version that
//!   changed a parameter's unit gets a column of its own, never a mixed one.
//! - A value is written in Rust's shortest round-trip form, so it reads back
//!   as the same `f64` the API shows.
//! - A verdict whose stored detail cannot be read is still a row: its
//!   values are empty and `note` says why. Nothing is left out silently.
//!
//! Quoting is the `csv` crate's (RFC 4180): a serial or a reason with a
//! comma, a quote or a line break stays one cell.

use super::verdict::{ParamResult, Verdict};
use crate::job::Purpose;

/// One measurement verdict of the lot.
#[derive(Debug, Clone, PartialEq)]
pub struct LotRow {
    /// When it was judged (UTC, RFC 3339 as stored).
    pub time_utc: String,
    pub part_serial: String,
    pub measurement_id: String,
    pub job_id: Option<String>,
    /// The level's index in the job's series.
    pub level_index: Option<i64>,
    /// None when the verdict's traceability does not name it.
    pub bench_id: Option<String>,
    pub recipe_name: String,
    pub recipe_version: i64,
    /// None when the traceability cannot be read.
    pub purpose: Option<Purpose>,
    /// The verdict as stored (`pass`, `fail`, `invalid`, `no_limits`).
    pub verdict: String,
    /// The verdict's detail; `Err` holds why it could not be read.
    pub detail: Result<Verdict, String>,
}

/// The fixed columns, in order, before the parameters' columns.
pub const FIXED_COLUMNS: [&str; 10] = [
    "time_utc",
    "part_serial",
    "measurement_id",
    "job_id",
    "level_index",
    "bench_id",
    "recipe_name",
    "recipe_version",
    "purpose",
    "verdict",
];

fn result_str(r: ParamResult) -> &'static str {
    match r {
        ParamResult::Pass => "pass",
        ParamResult::Fail => "fail",
        ParamResult::NotJudged => "not_judged",
    }
}

/// The lot as CSV (header line first; `\n` line ends).
pub fn to_csv(rows: &[LotRow]) -> String {
    // The parameter columns: (name, unit) in order of first appearance.
    let mut params: Vec<(String, String)> = Vec::new();
    for r in rows {
        if let Ok(v) = &r.detail {
            for p in &v.parameters {
                if !params.iter().any(|(n, u)| *n == p.name && *u == p.unit) {
                    params.push((p.name.clone(), p.unit.clone()));
                }
            }
        }
    }
    let mut w = csv::WriterBuilder::new()
        .terminator(csv::Terminator::Any(b'\n'))
        .from_writer(Vec::new());
    let mut header: Vec<String> = FIXED_COLUMNS.iter().map(|s| s.to_string()).collect();
    for (n, u) in &params {
        header.push(format!("{n} [{u}]"));
        header.push(format!("{n} result"));
    }
    header.push("invalid_reasons".into());
    header.push("note".into());
    // Writing into a Vec cannot fail on I/O; a record of the header's
    // length cannot fail on shape.
    w.write_record(&header).expect("csv into memory");
    for r in rows {
        let mut rec: Vec<String> = vec![
            r.time_utc.clone(),
            r.part_serial.clone(),
            r.measurement_id.clone(),
            r.job_id.clone().unwrap_or_default(),
            r.level_index.map(|l| l.to_string()).unwrap_or_default(),
            r.bench_id.clone().unwrap_or_default(),
            r.recipe_name.clone(),
            r.recipe_version.to_string(),
            r.purpose
                .map(|p| p.as_str().to_string())
                .unwrap_or_default(),
            r.verdict.clone(),
        ];
        let (reasons, note) = match &r.detail {
            Ok(v) => {
                for (n, u) in &params {
                    match v.parameters.iter().find(|p| p.name == *n && p.unit == *u) {
                        Some(p) if p.value.is_finite() => {
                            rec.push(format!("{}", p.value));
                            rec.push(result_str(p.result).into());
                        }
                        // The store refuses non-finite values; one stored
                        // before that rule is not written as a number.
                        Some(p) => {
                            rec.push(String::new());
                            rec.push(result_str(p.result).into());
                        }
                        None => {
                            rec.push(String::new());
                            rec.push(String::new());
                        }
                    }
                }
                let reasons = v
                    .invalid_reasons
                    .iter()
                    .map(|x| format!("{}: {}", x.code, x.detail))
                    .collect::<Vec<_>>()
                    .join("; ");
                (reasons, String::new())
            }
            Err(e) => {
                rec.extend(std::iter::repeat_n(String::new(), 2 * params.len()));
                (String::new(), format!("detail unreadable: {e}"))
            }
        };
        rec.push(reasons);
        rec.push(note);
        w.write_record(&rec).expect("csv into memory");
    }
    String::from_utf8(w.into_inner().expect("csv into memory")).expect("csv of UTF-8 strings")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::qc::verdict::{InvalidReason, ParamOutcome, VerdictKind};

    fn p(name: &str, unit: &str, value: f64, result: ParamResult) -> ParamOutcome {
        ParamOutcome {
            name: name.into(),
            quantity: None,
            unit: unit.into(),
            value,
            lower: None,
            upper: None,
            result,
            x_m: None,
        }
    }

    fn row(serial: &str, verdict: VerdictKind, params: Vec<ParamOutcome>) -> LotRow {
        LotRow {
            time_utc: "2026-11-28T20:00:00.000Z".into(),
            part_serial: serial.into(),
            measurement_id: format!("m-{serial}"),
            job_id: Some(format!("j-{serial}")),
            level_index: Some(0),
            bench_id: Some("virtual-1".into()),
            recipe_name: "r".into(),
            recipe_version: 2,
            purpose: Some(Purpose::Production),
            verdict: verdict.as_str().into(),
            detail: Ok(Verdict {
                verdict,
                failures: vec![],
                invalid_reasons: vec![],
                parameters: params,
            }),
        }
    }

    #[test]
    fn values_read_back_exactly_and_cells_stay_whole() {
        let k0 = 2_417.000_000_123_456_7;
        let mut bad = row(
            "SN,\"7\"",
            VerdictKind::Invalid,
            vec![p("k0", "N/m", 8.3662e6, ParamResult::NotJudged)],
        );
        if let Ok(v) = &mut bad.detail {
            v.invalid_reasons.push(InvalidReason {
                code: "analysis_failed".into(),
                detail: "no resonance, line 1\nline 2".into(),
            });
        }
        let mut unreadable = row("SN-9", VerdictKind::Pass, vec![]);
        unreadable.detail = Err("missing field `verdict`".into());
        let rows = vec![
            row(
                "SN-1",
                VerdictKind::Pass,
                vec![
                    p("k0", "N/m", k0, ParamResult::Pass),
                    p("q", "", 3.5, ParamResult::NotJudged),
                ],
            ),
            bad,
            // A later version measures k0 in other units: a column of its own.
            row(
                "SN-3",
                VerdictKind::Fail,
                vec![p("k0", "N/mm", 2.4, ParamResult::Fail)],
            ),
            unreadable,
        ];
        let text = to_csv(&rows);
        let mut r = csv::Reader::from_reader(text.as_bytes());
        let h: Vec<String> = r.headers().unwrap().iter().map(String::from).collect();
        assert_eq!(
            &h[10..],
            [
                "k0 [N/m]",
                "k0 result",
                "q []",
                "q result",
                "k0 [N/mm]",
                "k0 result",
                "invalid_reasons",
                "note"
            ]
        );
        let recs: Vec<csv::StringRecord> = r.records().map(Result::unwrap).collect();
        assert_eq!(recs.len(), 4);
        assert_eq!(recs[0][10].parse::<f64>().unwrap(), k0);
        assert_eq!(&recs[0][11], "pass");
        assert_eq!(&recs[1][1], "SN,\"7\"");
        assert_eq!(&recs[1][9], "invalid");
        assert_eq!(recs[1][10].parse::<f64>().unwrap(), 8.3662e6);
        assert_eq!(&recs[1][11], "not_judged");
        assert_eq!(
            &recs[1][16],
            "analysis_failed: no resonance, line 1\nline 2"
        );
        assert_eq!((&recs[2][10], &recs[2][14]), ("", "2.4"));
        assert_eq!(&recs[2][15], "fail");
        assert_eq!(&recs[3][10], "");
        assert_eq!(&recs[3][17], "detail unreadable: missing field `verdict`");
    }
}
