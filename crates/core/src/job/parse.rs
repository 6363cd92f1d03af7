//! A typed request from a JSON body, with one message per bad field.
//!
//! serde stops at the first error. A client fixing a request wants every bad
//! field at once, so [`parse_lenient`] records the error with its JSON path
//! (`serde_path_to_error`), drops the member at fault and tries again, until
//! the body parses or an error repeats. The typed struct stays the one
//! definition of the request's shape (`deny_unknown_fields`, its schema).

use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::Value;

/// One message per bad field (`field` is a JSON path like `levels_m[1]`;
/// empty for the body as a whole).
#[derive(Debug, Clone, PartialEq, Serialize, utoipa::ToSchema)]
pub struct FieldError {
    pub field: String,
    pub message: String,
}

impl FieldError {
    pub fn new(field: impl Into<String>, message: impl Into<String>) -> FieldError {
        FieldError {
            field: field.into(),
            message: message.into(),
        }
    }
}

/// Refuses a text longer than `max` characters (Unicode scalar values, as
/// the schema's `maxLength` counts them).
pub fn check_chars(text: Option<&str>, field: &str, max: usize, errors: &mut Vec<FieldError>) {
    if text.is_some_and(|t| t.chars().count() > max) {
        errors.push(FieldError::new(field, format!("at most {max} characters")));
    }
    if let Some(c) = text.and_then(bad_char) {
        errors.push(FieldError::new(
            field,
            format!(
                "holds the control character U+{:04X}; text only (tab and line breaks allowed)",
                c as u32
            ),
        ));
    }
}

/// The first control character of `text` other than tab and line breaks
/// (a NUL byte in a part's notes was stored, then refused by the fleet's
/// center for good, issue 36), if any.
pub fn bad_char(text: &str) -> Option<char> {
    text.chars()
        .find(|c| c.is_control() && !matches!(c, '\t' | '\n' | '\r'))
}

/// One step of a JSON path.
#[derive(Debug, Clone, PartialEq)]
enum Step {
    Key(String),
    Index(usize),
}

fn steps(path: &serde_path_to_error::Path) -> Vec<Step> {
    use serde_path_to_error::Segment;
    path.iter()
        .filter_map(|s| match s {
            Segment::Map { key } => Some(Step::Key(key.clone())),
            Segment::Seq { index } => Some(Step::Index(*index)),
            Segment::Enum { variant } => Some(Step::Key(variant.clone())),
            Segment::Unknown => None,
        })
        .collect()
}

fn path_text(steps: &[Step]) -> String {
    let mut s = String::new();
    for st in steps {
        match st {
            Step::Key(k) if s.is_empty() => s.push_str(k),
            Step::Key(k) => {
                s.push('.');
                s.push_str(k);
            }
            Step::Index(i) => s.push_str(&format!("[{i}]")),
        }
    }
    s
}

/// The text between the first pair of backticks of serde's message.
fn quoted(msg: &str) -> Option<&str> {
    let a = msg.find('`')? + 1;
    let b = a + msg[a..].find('`')?;
    Some(&msg[a..b])
}

/// serde's message in the request's words.
fn wording(msg: &str) -> String {
    if let Some(rest) = msg.strip_prefix("invalid type: ") {
        let (got, want) = rest.split_once(", expected ").unwrap_or((rest, ""));
        let want = match want {
            "f64" => "a number".to_string(),
            "u64" | "u32" | "usize" => "a non-negative integer".to_string(),
            "i64" => "an integer".to_string(),
            "a string" => "a string".to_string(),
            w if w.starts_with("struct ") || w.starts_with("a map") => "an object".to_string(),
            w if w.starts_with("a sequence") => "a list".to_string(),
            w => w.to_string(),
        };
        return format!("must be {want}, got {got}");
    }
    if let Some(rest) = msg.strip_prefix("invalid value: ") {
        let (got, want) = rest.split_once(", expected ").unwrap_or((rest, ""));
        return format!("must be {want}, got {got}");
    }
    msg.to_string()
}

/// Parses `body` into `T` with one [`FieldError`] per bad member, and the
/// value the rest of the body makes (each member at fault dropped) when there
/// is one: its semantic checks can then name further bad fields in the same
/// answer.
pub fn parse_lenient<T: DeserializeOwned>(body: &Value) -> (Option<T>, Vec<FieldError>) {
    match rounds(body) {
        Ok((t, e)) => (Some(t), e),
        Err(e) => (None, e),
    }
}

fn rounds<T: DeserializeOwned>(body: &Value) -> Result<(T, Vec<FieldError>), Vec<FieldError>> {
    if !body.is_object() {
        return Err(vec![FieldError::new("", "the body must be a JSON object")]);
    }
    let mut v = body.clone();
    let mut errors: Vec<FieldError> = vec![];
    let mut dropped: Vec<Vec<Step>> = vec![];
    // Each round drops one member: bounded by the body's size.
    loop {
        let e = match serde_path_to_error::deserialize::<_, T>(&v) {
            Ok(t) => return Ok((t, errors)),
            Err(e) => e,
        };
        let mut at = steps(e.path());
        let msg = e.inner().to_string();
        let (mut field_steps, message) = if let Some(k) = msg
            .strip_prefix("missing field ")
            .and_then(|_| quoted(&msg))
        {
            let mut p = at.clone();
            p.push(Step::Key(k.to_string()));
            if dropped.contains(&p) {
                // a required member dropped for its own error: no further round
                return Err(errors);
            }
            (p, "required".to_string())
        } else if msg.starts_with("unknown field ") {
            // serde_path_to_error's path ends at the unknown key already
            if let (Some(k), Some(Step::Key(last))) = (quoted(&msg), at.last()) {
                if last != k {
                    at.push(Step::Key(k.to_string()));
                }
            }
            (at.clone(), "unknown field".to_string())
        } else {
            (at.clone(), wording(&msg))
        };
        if field_steps.is_empty() && !errors.is_empty() {
            return Err(errors);
        }
        let field = path_text(&field_steps);
        if errors.iter().any(|x| x.field == field) {
            return Err(errors);
        }
        errors.push(FieldError::new(&field, message));
        // Drop the nearest object member holding the fault (a list's member
        // as a whole: its indices must not shift for later messages).
        while matches!(field_steps.last(), Some(Step::Index(_))) {
            field_steps.pop();
        }
        if !remove(&mut v, &field_steps) {
            return Err(errors);
        }
        dropped.push(field_steps);
    }
}

/// Removes the member at `path` (ending with a key); false when absent.
fn remove(v: &mut Value, path: &[Step]) -> bool {
    let Some((Step::Key(last), parent)) = path.split_last() else {
        return false;
    };
    let mut node = v;
    for st in parent {
        node = match (st, node) {
            (Step::Key(k), Value::Object(m)) => match m.get_mut(k) {
                Some(n) => n,
                None => return false,
            },
            (Step::Index(i), Value::Array(a)) => match a.get_mut(*i) {
                Some(n) => n,
                None => return false,
            },
            _ => return false,
        };
    }
    node.as_object_mut()
        .is_some_and(|m| m.remove(last).is_some())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;
    use serde_json::json;

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Inner {
        serial: String,
        kind: Option<String>,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields, rename_all = "kebab-case")]
    enum Mode {
        TwoSignal,
        OneSignal,
    }

    #[derive(Debug, Deserialize)]
    #[serde(deny_unknown_fields)]
    #[allow(dead_code)]
    struct Body {
        part: Inner,
        mass_kg: Option<f64>,
        levels_m: Option<Vec<f64>>,
        mode: Option<Mode>,
    }

    fn parse_all(body: &serde_json::Value) -> Result<Body, Vec<FieldError>> {
        match parse_lenient(body) {
            (Some(t), e) if e.is_empty() => Ok(t),
            (_, e) => Err(e),
        }
    }

    fn fields(r: Result<Body, Vec<FieldError>>) -> Vec<(String, String)> {
        r.unwrap_err()
            .into_iter()
            .map(|e| (e.field, e.message))
            .collect()
    }

    #[test]
    fn every_bad_member_is_named_once() {
        let f = fields(parse_all(&json!({
            "part": {"serial": "S", "colour": 1},
            "mass_kg": "heavy",
            "levels_m": [0.004, "x"],
            "mode": "three-signal",
            "extra": true
        })));
        let names: Vec<&str> = f.iter().map(|(f, _)| f.as_str()).collect();
        // in the body's member order (serde_json sorts members)
        assert_eq!(
            names,
            ["extra", "levels_m[1]", "mass_kg", "mode", "part.colour"]
        );
        assert_eq!(f[0].1, "unknown field");
        assert_eq!(f[1].1, "must be a number, got string \"x\"");
        assert_eq!(f[2].1, "must be a number, got string \"heavy\"");
        assert!(
            f[3].1.contains("unknown variant `three-signal`"),
            "{}",
            f[3].1
        );
    }

    #[test]
    fn a_missing_or_dropped_required_member_ends_the_rounds() {
        let f = fields(parse_all(&json!({"mass_kg": 1.0})));
        assert_eq!(f, [("part".to_string(), "required".to_string())]);
        let f = fields(parse_all(&json!({"part": {"kind": "x"}})));
        assert_eq!(f, [("part.serial".to_string(), "required".to_string())]);
        // a bad required member: named once, not again as missing
        let f = fields(parse_all(&json!({"part": 3, "extra": 1})));
        let names: Vec<&str> = f.iter().map(|(f, _)| f.as_str()).collect();
        assert_eq!(names, ["extra", "part"]);
        let f = fields(parse_all(&json!([1])));
        assert_eq!(f[0].0, "");
    }

    #[test]
    fn a_good_body_parses() {
        let b: Body =
            parse_all(&json!({"part": {"serial": "S", "kind": null}, "mode": "one-signal"}))
                .unwrap();
        assert!(matches!(b.mode, Some(Mode::OneSignal)));
        assert!(b.part.kind.is_none());
    }
}
