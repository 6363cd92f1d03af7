//! Plain ASCII stream: one value per line, streamed at the sensor's rate
//! (many sensors and converter boxes offer such an output).
//!
//! A line is `[counter<sep>]value` ending with LF (CR LF accepted), `sep` one
//! of `,` `;` TAB or spaces. `value` is a decimal number in `unit_m` metres
//! (mm by default). The tokens `OOR`, `OUT`, `---` (any case) flag an
//! out-of-range sample; `ERR<code>` or `E<digits>` a sensor error. With
//! `counter_bits` set, every line must carry the counter; without it, the
//! index counts the lines. The first line after start is dropped (it may be
//! the tail of a line sent before the host listened).

use super::{FrameError, LaserIdentity, LaserProtocol, Reading, SampleClock};
use serde::{Deserialize, Serialize};

/// Longest line accepted.
pub const MAX_LINE: usize = 64;

/// `protocol = { name = "ascii_lines", ... }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AsciiLinesConfig {
    /// Metres per unit of the values (default 1e-3: mm).
    #[serde(default = "mm")]
    pub unit_m: f64,
    /// Lines carry a counter of this many bits before the value.
    #[serde(default)]
    pub counter_bits: Option<u32>,
    /// Measuring range (m, full span), for the identity; optional.
    #[serde(default)]
    pub range_m: Option<f64>,
    /// Command (without line end) that starts the stream, if the sensor needs one.
    #[serde(default)]
    pub start_command: Option<String>,
    /// Command that stops the stream, if any.
    #[serde(default)]
    pub stop_command: Option<String>,
    #[serde(default)]
    pub invert: bool,
}

fn mm() -> f64 {
    1e-3
}

impl Default for AsciiLinesConfig {
    fn default() -> Self {
        AsciiLinesConfig {
            unit_m: 1e-3,
            counter_bits: None,
            range_m: None,
            start_command: None,
            stop_command: None,
            invert: false,
        }
    }
}

impl AsciiLinesConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.unit_m.is_finite() && self.unit_m > 0.0) {
            return Err(format!("unit_m must be > 0, got {}", self.unit_m));
        }
        if let Some(b) = self.counter_bits {
            if !(8..=32).contains(&b) {
                return Err(format!("counter_bits must be 8..=32, got {b}"));
            }
        }
        if let Some(r) = self.range_m {
            if !(r.is_finite() && r > 0.0) {
                return Err(format!("range_m must be > 0, got {r}"));
            }
        }
        for c in [&self.start_command, &self.stop_command]
            .into_iter()
            .flatten()
        {
            if c.len() > 64 || !c.bytes().all(|b| (0x20..0x7f).contains(&b)) {
                return Err(format!(
                    "command '{c}' must be printable ASCII, at most 64 bytes"
                ));
            }
        }
        Ok(())
    }
}

/// The parser.
#[derive(Debug, Clone)]
pub struct AsciiLines {
    cfg: AsciiLinesConfig,
    line: Vec<u8>,
    offset: u64,
    /// The first line may be the tail of one sent before we listened.
    first: bool,
}

impl AsciiLines {
    pub fn new(cfg: AsciiLinesConfig) -> AsciiLines {
        AsciiLines {
            cfg,
            line: Vec::new(),
            offset: 0,
            first: true,
        }
    }

    fn line_done(&mut self, at: u64, out: &mut Vec<Reading>) -> Result<(), FrameError> {
        let line = std::mem::take(&mut self.line);
        let first = std::mem::replace(&mut self.first, false);
        let start = at - line.len() as u64;
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            self.first = first;
            return Ok(());
        }
        // The first line is dropped: we may have started listening mid-line
        // (a tail like "34" of "1.234" would parse as a wrong value).
        if first {
            return Ok(());
        }
        match parse_line(text, &self.cfg) {
            Ok(r) => {
                out.push(r);
                Ok(())
            }
            Err(reason) => Err(FrameError {
                offset: start,
                reason,
            }),
        }
    }
}

fn parse_line(text: &str, cfg: &AsciiLinesConfig) -> Result<Reading, String> {
    let fields: Vec<&str> = text
        .split([',', ';', '\t', ' '])
        .filter(|f| !f.is_empty())
        .collect();
    let (counter, value) = match (cfg.counter_bits, fields.as_slice()) {
        (None, [v]) => (None, *v),
        (Some(bits), [c, v]) => {
            let c: u32 = c
                .parse()
                .map_err(|_| format!("counter '{c}' is not an unsigned integer"))?;
            if bits < 32 && c >> bits != 0 {
                return Err(format!("counter {c} does not fit in {bits} bits"));
            }
            (Some(c), *v)
        }
        (None, _) => return Err(format!("expected one value per line, got '{text}'")),
        (Some(_), _) => return Err(format!("expected 'counter,value', got '{text}'")),
    };
    let upper = value.to_ascii_uppercase();
    if matches!(upper.as_str(), "OOR" | "OUT" | "---") {
        return Ok(Reading::OutOfRange { code: 0, counter });
    }
    if let Some(code) = upper.strip_prefix("ERR").or_else(|| {
        upper
            .strip_prefix('E')
            .filter(|r| !r.is_empty() && r.bytes().all(|b| b.is_ascii_digit()))
    }) {
        return Ok(Reading::DeviceError {
            code: code.to_string(),
        });
    }
    // Decimal numbers only (no 'inf', 'nan', exponents of absurd size).
    if value.len() > 24
        || !value
            .bytes()
            .all(|b| b.is_ascii_digit() || matches!(b, b'.' | b'+' | b'-' | b'e' | b'E'))
    {
        return Err(format!("'{value}' is not a number"));
    }
    let v: f64 = value
        .parse()
        .map_err(|_| format!("'{value}' is not a number"))?;
    let d = v * cfg.unit_m;
    if !d.is_finite() || d.abs() > 10.0 {
        return Err(format!("'{value}' is not a plausible displacement"));
    }
    Ok(Reading::Value {
        displacement_m: if cfg.invert { -d } else { d },
        counter,
    })
}

impl LaserProtocol for AsciiLines {
    fn name(&self) -> &'static str {
        "ascii_lines"
    }
    fn clock(&self) -> SampleClock {
        if self.cfg.counter_bits.is_some() {
            SampleClock::DeviceCounter
        } else {
            SampleClock::DeviceStream
        }
    }
    fn counter_bits(&self) -> Option<u32> {
        self.cfg.counter_bits
    }
    fn identity_request(&self) -> Option<Vec<u8>> {
        None
    }
    fn parse_identity(&self, _reply: &[u8]) -> Result<Option<LaserIdentity>, FrameError> {
        Err(FrameError {
            offset: 0,
            reason: "the ascii_lines protocol has no identity command".into(),
        })
    }
    fn start_request(&self) -> Option<Vec<u8>> {
        self.cfg
            .start_command
            .as_ref()
            .map(|c| format!("{c}\r\n").into_bytes())
    }
    fn stop_request(&self) -> Option<Vec<u8>> {
        self.cfg
            .stop_command
            .as_ref()
            .map(|c| format!("{c}\r\n").into_bytes())
    }
    fn poll_request(&self) -> Option<Vec<u8>> {
        None
    }

    fn feed(&mut self, bytes: &[u8], out: &mut Vec<Reading>) -> Result<(), FrameError> {
        for &b in bytes {
            let at = self.offset;
            self.offset += 1;
            match b {
                b'\n' => self.line_done(at, out)?,
                b'\r' => {}
                0x20..=0x7e | b'\t' => {
                    if self.line.len() >= MAX_LINE {
                        return Err(FrameError {
                            offset: at,
                            reason: format!("line longer than {MAX_LINE} bytes"),
                        });
                    }
                    self.line.push(b);
                }
                _ => {
                    return Err(FrameError {
                        offset: at,
                        reason: format!("byte 0x{b:02x} in an ASCII line"),
                    })
                }
            }
        }
        Ok(())
    }

    fn reset(&mut self) {
        *self = AsciiLines::new(self.cfg.clone());
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_with_and_without_counter() {
        let mut out = Vec::new();
        let mut p = AsciiLines::new(AsciiLinesConfig::default());
        // The first partial line (tail of one sent before we listened) is dropped.
        p.feed(b"34\n1.5\r\n-0.25\n\nOOR\nERR7\n", &mut out)
            .unwrap();
        assert_eq!(out.len(), 4, "{out:?}");
        assert_eq!(
            out[0],
            Reading::Value {
                displacement_m: 1.5e-3,
                counter: None
            }
        );
        assert_eq!(
            out[1],
            Reading::Value {
                displacement_m: -0.25e-3,
                counter: None
            }
        );
        assert_eq!(
            out[2],
            Reading::OutOfRange {
                code: 0,
                counter: None
            }
        );
        assert_eq!(out[3], Reading::DeviceError { code: "7".into() });

        let cfg = AsciiLinesConfig {
            counter_bits: Some(16),
            unit_m: 1.0,
            ..AsciiLinesConfig::default()
        };
        let mut out = Vec::new();
        let mut p = AsciiLines::new(cfg);
        p.feed(b"2,0.005\n12,0.001\n13;-0.002\n", &mut out).unwrap();
        assert_eq!(
            out[1],
            Reading::Value {
                displacement_m: -0.002,
                counter: Some(13)
            }
        );
        assert_eq!(p.clock(), SampleClock::DeviceCounter);
        assert!(p
            .feed(b"70000,0.1\n", &mut out)
            .unwrap_err()
            .reason
            .contains("16 bits"));
    }

    #[test]
    fn garbage_lines_are_errors_after_the_first() {
        for bad in [
            &b"1\nabc\n"[..],
            b"1\n1.0 2.0\n",
            b"1\nnan\n",
            b"1\ninf\n",
            b"1\n1e300\n",
            b"1\n\x01\n",
        ] {
            let e = AsciiLines::new(AsciiLinesConfig::default())
                .feed(bad, &mut Vec::new())
                .unwrap_err();
            assert!(e.offset >= 2, "{bad:?}: {e}");
        }
        let long = vec![b'1'; 100];
        assert!(AsciiLines::new(AsciiLinesConfig::default())
            .feed(&long, &mut Vec::new())
            .is_err());
    }
}
