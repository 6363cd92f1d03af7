//! Keyence LK-G-style ASCII protocol (RS-232C): the host polls, one command in
//! flight at a time, commands and replies end with CR.
//!
//! - poll: `MS,01` (head 01) -> `MS,OUT01,+01.2345` (value: a sign and up to
//!   7 characters with the decimal point, in mm by default);
//! - out of range: the value is `FFFFFF` (with or without a sign, any number
//!   of `F`s from 6 on);
//! - error: `ER,MS,02` (command, code).
//!
//! The samples carry **no device clock**: their only time is the host's poll
//! time, so a serial Keyence laser cannot be aligned to the audio clock to
//! microseconds (the alignment marks such measurements invalid). There is no
//! identity command in this protocol: model and serial come from the
//! configuration.

use super::{FrameError, LaserIdentity, LaserProtocol, Reading, SampleClock};
use serde::{Deserialize, Serialize};

/// Longest reply line accepted.
pub const MAX_LINE: usize = 64;

/// `protocol = { name = "keyence", ... }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyenceConfig {
    /// Sensor head number (1..=2).
    #[serde(default = "one")]
    pub head: u8,
    /// Metres per unit of the reported value (default 1e-3: mm).
    #[serde(default = "mm")]
    pub unit_m: f64,
    /// Measuring range (m, full span), for the identity; optional.
    #[serde(default)]
    pub range_m: Option<f64>,
    /// Flip the sign.
    #[serde(default)]
    pub invert: bool,
}

fn one() -> u8 {
    1
}
fn mm() -> f64 {
    1e-3
}

impl KeyenceConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(1..=2).contains(&self.head) {
            return Err(format!("head must be 1 or 2, got {}", self.head));
        }
        if !(self.unit_m.is_finite() && self.unit_m > 0.0) {
            return Err(format!("unit_m must be > 0, got {}", self.unit_m));
        }
        if let Some(r) = self.range_m {
            if !(r.is_finite() && r > 0.0) {
                return Err(format!("range_m must be > 0, got {r}"));
            }
        }
        Ok(())
    }
}

/// The parser.
#[derive(Debug, Clone)]
pub struct Keyence {
    cfg: KeyenceConfig,
    line: Vec<u8>,
    offset: u64,
}

impl Keyence {
    pub fn new(cfg: KeyenceConfig) -> Keyence {
        Keyence {
            cfg,
            line: Vec::new(),
            offset: 0,
        }
    }

    fn line_done(&mut self, at: u64, out: &mut Vec<Reading>) -> Result<(), FrameError> {
        let line = std::mem::take(&mut self.line);
        if line.is_empty() {
            return Ok(());
        }
        let start = at - line.len() as u64;
        let err = |reason: String| FrameError {
            offset: start,
            reason,
        };
        // ASCII was checked byte by byte.
        let text = String::from_utf8_lossy(&line);
        let fields: Vec<&str> = text.split(',').collect();
        match fields.as_slice() {
            ["ER", cmd, code] => {
                out.push(Reading::DeviceError {
                    code: format!("{cmd},{code}"),
                });
                Ok(())
            }
            ["MS", out_field, value] => {
                let want = format!("OUT{:02}", self.cfg.head);
                if *out_field != want {
                    return Err(err(format!("reply for {out_field}, polled {want}")));
                }
                match parse_value(value) {
                    Some(Parsed::Value(v)) => {
                        let d = v * self.cfg.unit_m;
                        out.push(Reading::Value {
                            displacement_m: if self.cfg.invert { -d } else { d },
                            counter: None,
                        });
                        Ok(())
                    }
                    Some(Parsed::OutOfRange) => {
                        out.push(Reading::OutOfRange {
                            code: 0,
                            counter: None,
                        });
                        Ok(())
                    }
                    None => Err(err(format!("value '{value}' is not a LK-G number"))),
                }
            }
            _ => Err(err(format!(
                "'{}' is not an MS or ER reply",
                text.chars().take(24).collect::<String>()
            ))),
        }
    }
}

enum Parsed {
    Value(f64),
    OutOfRange,
}

/// A sign and up to 7 characters of digits with at most one decimal point,
/// or `FFFFFF...` (out of range).
fn parse_value(s: &str) -> Option<Parsed> {
    let body = s.strip_prefix(['+', '-']).unwrap_or(s);
    if body.len() >= 6 && body.bytes().all(|b| b == b'F') {
        return Some(Parsed::OutOfRange);
    }
    if body.is_empty()
        || body.len() > 8
        || body.bytes().filter(|&b| b == b'.').count() > 1
        || !body.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        || !body.bytes().any(|b| b.is_ascii_digit())
    {
        return None;
    }
    let v: f64 = s.parse().ok()?;
    v.is_finite().then_some(Parsed::Value(v))
}

impl LaserProtocol for Keyence {
    fn name(&self) -> &'static str {
        "keyence"
    }
    fn clock(&self) -> SampleClock {
        SampleClock::HostPoll
    }
    fn counter_bits(&self) -> Option<u32> {
        None
    }
    fn identity_request(&self) -> Option<Vec<u8>> {
        None
    }
    fn parse_identity(&self, _reply: &[u8]) -> Result<Option<LaserIdentity>, FrameError> {
        Err(FrameError {
            offset: 0,
            reason: "the keyence protocol has no identity command".into(),
        })
    }
    fn start_request(&self) -> Option<Vec<u8>> {
        None
    }
    fn stop_request(&self) -> Option<Vec<u8>> {
        None
    }
    fn poll_request(&self) -> Option<Vec<u8>> {
        Some(format!("MS,{:02}\r", self.cfg.head).into_bytes())
    }

    fn feed(&mut self, bytes: &[u8], out: &mut Vec<Reading>) -> Result<(), FrameError> {
        for &b in bytes {
            let at = self.offset;
            self.offset += 1;
            match b {
                b'\r' | b'\n' => self.line_done(at, out)?,
                0x20..=0x7e => {
                    if self.line.len() >= MAX_LINE {
                        return Err(FrameError {
                            offset: at,
                            reason: format!("reply line longer than {MAX_LINE} bytes"),
                        });
                    }
                    self.line.push(b);
                }
                _ => {
                    return Err(FrameError {
                        offset: at,
                        reason: format!("byte 0x{b:02x} in an ASCII reply"),
                    })
                }
            }
        }
        Ok(())
    }

    fn reset(&mut self) {
        self.line.clear();
        self.offset = 0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> Keyence {
        Keyence::new(KeyenceConfig {
            head: 1,
            unit_m: 1e-3,
            range_m: None,
            invert: false,
        })
    }

    #[test]
    fn replies_give_values_out_of_range_and_errors() {
        let mut out = Vec::new();
        let mut k = p();
        let bytes = b"MS,OUT01,+01.2345\rMS,OUT01,-0.50000\r\nMS,OUT01,+FFFFFFF\rER,MS,02\r";
        for c in bytes.chunks(3) {
            k.feed(c, &mut out).unwrap();
        }
        assert_eq!(out.len(), 4);
        let Reading::Value {
            displacement_m,
            counter: None,
        } = out[0]
        else {
            panic!("{:?}", out[0])
        };
        assert!((displacement_m - 1.2345e-3).abs() < 1e-15);
        let Reading::Value { displacement_m, .. } = out[1] else {
            panic!()
        };
        assert!((displacement_m + 0.5e-3).abs() < 1e-15);
        assert_eq!(
            out[2],
            Reading::OutOfRange {
                code: 0,
                counter: None
            }
        );
        assert_eq!(
            out[3],
            Reading::DeviceError {
                code: "MS,02".into()
            }
        );
        assert_eq!(k.poll_request().unwrap(), b"MS,01\r");
        assert_eq!(k.clock(), SampleClock::HostPoll);
    }

    #[test]
    fn malformed_replies_are_garbage() {
        for bad in [
            &b"MS,OUT02,+01.2345\r"[..],
            b"MS,OUT01,+01.23.45\r",
            b"MS,OUT01,nan\r",
            b"MS,OUT01,+1e300\r",
            b"MS,OUT01,\r",
            b"hello\r",
            b"MS,OUT01,+0\x001\r",
        ] {
            let e = p().feed(bad, &mut Vec::new()).unwrap_err();
            assert!(!e.reason.is_empty(), "{bad:?}");
        }
        let long = vec![b'1'; 100];
        assert!(p()
            .feed(&long, &mut Vec::new())
            .unwrap_err()
            .reason
            .contains("longer"));
    }
}
