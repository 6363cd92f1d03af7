//! Micro-Epsilon optoNCDT-style binary RS422 stream (ILD1420 family).
//!
//! Commands are ASCII lines ending in CR LF; replies end with the prompt `->`,
//! errors start with `E` and a number. Values are binary, 3 bytes each, sent
//! L, M, H; the two top bits of each byte mark it:
//!
//! | byte | bit 7 | bit 6 | bits 5..0 |
//! |------|-------|-------|-----------|
//! | L    | 0     | 0     | value bits 5..0 |
//! | M    | 0     | 1     | value bits 11..6 |
//! | H    | 1     | f     | value bits 17..12 |
//!
//! `f` = 0 for the first value of an output block, 1 for further values of
//! the same block. (The hardware notes phrase it as "bit 7 of H"; with L = 00,
//! M = 01, H = 10 the free bit of H is bit 6, which is what sensors of this
//! family use.) A block is the distance value, followed by the 18-bit
//! measurement counter when it is enabled (`counter = true`).
//!
//! Distance values are 16-bit: `distance = raw / 65536 * range_m`, reported
//! as displacement from the middle of the range, `raw / 65536 * range_m -
//! range_m / 2` (sign flipped with `invert`). Raw values of 65536 and above
//! are error codes: 262075 (no target), 262076 (too near), 262077 (too far)
//! are out-of-range flags, every other code a sensor error.
//!
//! The parser synchronises on the first L, M, H triple and drops that first
//! block (it may be made of a reply's last bytes and a value's tail).

use super::{FrameError, LaserIdentity, LaserProtocol, Reading, SampleClock};
use serde::{Deserialize, Serialize};

/// Out-of-range codes (18-bit error space).
pub const CODE_NO_TARGET: u32 = 262_075;
pub const CODE_TOO_NEAR: u32 = 262_076;
pub const CODE_TOO_FAR: u32 = 262_077;
/// Width of the measurement counter.
pub const COUNTER_BITS: u32 = 18;
/// Bytes skipped while looking for the first frame (a command's prompt, a
/// partial value) before the stream counts as garbage.
pub const MAX_SYNC_SKIP: usize = 64;

/// `protocol = { name = "optoncdt", ... }`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct OptoncdtConfig {
    /// Measuring range (m, full span), e.g. 0.01 for an ILD1420-10. Read from the
    /// sensor's `GETINFO` when it reports one; this value is the fallback.
    pub range_m: f64,
    /// Each block carries the measurement counter after the value.
    #[serde(default)]
    pub counter: bool,
    /// Flip the sign (sensor mounted facing the other way).
    #[serde(default)]
    pub invert: bool,
}

impl OptoncdtConfig {
    pub fn validate(&self) -> Result<(), String> {
        if !(self.range_m.is_finite() && self.range_m > 0.0 && self.range_m < 10.0) {
            return Err(format!(
                "range_m must be in (0, 10) m, got {}",
                self.range_m
            ));
        }
        Ok(())
    }
}

/// Encodes one 18-bit value as L, M, H (for the emulator and tests).
pub fn encode_value(raw: u32, further: bool) -> [u8; 3] {
    let v = raw & 0x3_FFFF;
    [
        (v & 0x3F) as u8,
        0x40 | ((v >> 6) & 0x3F) as u8,
        0x80 | if further { 0x40 } else { 0 } | ((v >> 12) & 0x3F) as u8,
    ]
}

/// Raw 16-bit code of a displacement (m from mid-range), clamped to the range.
pub fn raw_of_displacement(displacement_m: f64, range_m: f64) -> u32 {
    let r = ((displacement_m / range_m + 0.5) * 65536.0).round();
    r.clamp(0.0, 65535.0) as u32
}

/// The parser.
#[derive(Debug, Clone)]
pub struct Optoncdt {
    cfg: OptoncdtConfig,
    /// Range in use (configured, or read from the sensor).
    range_m: f64,
    synced: bool,
    /// Bytes of the current value (0..3).
    part: [u8; 3],
    n_part: usize,
    /// Position in the block: 0 = expecting the value, 1 = expecting the counter.
    slot: usize,
    /// The value of the current block while its counter is still to come.
    pending: Option<u32>,
    offset: u64,
    skipped: usize,
    /// The first block after synchronisation is dropped: a command's reply
    /// (`->` CR LF) ends in bytes that look like an L byte, so the triple
    /// that synchronised may be made of reply bytes and a value's tail.
    skip_block: bool,
}

impl Optoncdt {
    pub fn new(cfg: OptoncdtConfig) -> Optoncdt {
        Optoncdt {
            range_m: cfg.range_m,
            cfg,
            synced: false,
            part: [0; 3],
            n_part: 0,
            slot: 0,
            pending: None,
            offset: 0,
            skipped: 0,
            skip_block: true,
        }
    }

    /// Uses the range the sensor reported instead of the configured one.
    pub fn set_range_m(&mut self, range_m: f64) {
        if range_m.is_finite() && range_m > 0.0 {
            self.range_m = range_m;
        }
    }

    fn block_len(&self) -> usize {
        if self.cfg.counter {
            2
        } else {
            1
        }
    }

    fn reading(&self, raw: u32, counter: Option<u32>) -> Reading {
        if raw <= 0xFFFF {
            let d = f64::from(raw) / 65536.0 * self.range_m - 0.5 * self.range_m;
            Reading::Value {
                displacement_m: if self.cfg.invert { -d } else { d },
                counter,
            }
        } else if (CODE_NO_TARGET..=CODE_TOO_FAR).contains(&raw) {
            Reading::OutOfRange { code: raw, counter }
        } else {
            Reading::DeviceError {
                code: format!("value code {raw}"),
            }
        }
    }

    fn garbage(&self, at: u64, reason: String) -> FrameError {
        FrameError { offset: at, reason }
    }

    /// A complete value (3 bytes) at position `slot` of the block.
    fn value_done(
        &mut self,
        raw: u32,
        further: bool,
        at: u64,
        out: &mut Vec<Reading>,
    ) -> Result<(), FrameError> {
        let want_further = self.slot > 0;
        if further != want_further {
            return Err(self.garbage(
                at,
                format!(
                    "H byte says {} value of a block, expected the {}",
                    if further { "a further" } else { "the first" },
                    if want_further {
                        "counter"
                    } else {
                        "first value"
                    }
                ),
            ));
        }
        let done = if self.block_len() == 1 {
            Some(self.reading(raw, None))
        } else if self.slot == 0 {
            self.pending = Some(raw);
            self.slot = 1;
            None
        } else {
            let value = self.pending.take().unwrap_or(0);
            self.slot = 0;
            Some(self.reading(value, Some(raw)))
        };
        if let Some(r) = done {
            if self.skip_block {
                self.skip_block = false;
            } else {
                out.push(r);
            }
        }
        Ok(())
    }
}

impl LaserProtocol for Optoncdt {
    fn name(&self) -> &'static str {
        "optoncdt"
    }

    fn clock(&self) -> SampleClock {
        if self.cfg.counter {
            SampleClock::DeviceCounter
        } else {
            SampleClock::DeviceStream
        }
    }

    fn counter_bits(&self) -> Option<u32> {
        self.cfg.counter.then_some(COUNTER_BITS)
    }

    fn identity_request(&self) -> Option<Vec<u8>> {
        Some(b"GETINFO\r\n".to_vec())
    }

    fn parse_identity(&self, reply: &[u8]) -> Result<Option<LaserIdentity>, FrameError> {
        parse_getinfo(reply)
    }

    fn start_request(&self) -> Option<Vec<u8>> {
        Some(b"OUTPUT RS422\r\n".to_vec())
    }

    fn stop_request(&self) -> Option<Vec<u8>> {
        Some(b"OUTPUT NONE\r\n".to_vec())
    }

    fn poll_request(&self) -> Option<Vec<u8>> {
        None
    }

    fn feed(&mut self, bytes: &[u8], out: &mut Vec<Reading>) -> Result<(), FrameError> {
        for &b in bytes {
            let at = self.offset;
            self.offset += 1;
            if !self.synced {
                // Look for L, M, H of a first value: keep the last two bytes.
                self.part[0] = self.part[1];
                self.part[1] = self.part[2];
                self.part[2] = b;
                self.n_part = (self.n_part + 1).min(3);
                if self.n_part == 3
                    && self.part[0] >> 6 == 0
                    && self.part[1] >> 6 == 1
                    && self.part[2] >> 6 == 2
                {
                    self.synced = true;
                    self.n_part = 0;
                    self.slot = 0;
                    let raw = decode(&self.part);
                    self.value_done(raw, false, at, out)?;
                    continue;
                }
                if self.n_part == 3 {
                    self.skipped += 1;
                }
                if self.skipped > MAX_SYNC_SKIP {
                    return Err(self.garbage(
                        at,
                        format!("no optoNCDT frame in the first {MAX_SYNC_SKIP} bytes"),
                    ));
                }
                continue;
            }
            let marker = b >> 6;
            match (self.n_part, marker) {
                (0, 0) | (1, 1) => {
                    self.part[self.n_part] = b;
                    self.n_part += 1;
                }
                (2, 2) | (2, 3) => {
                    self.part[2] = b;
                    self.n_part = 0;
                    let raw = decode(&self.part);
                    self.value_done(raw, marker == 3, at, out)?;
                }
                (n, m) => {
                    let want = ["L (00)", "M (01)", "H (1x)"][n.min(2)];
                    return Err(self.garbage(
                        at,
                        format!("byte 0x{b:02x} has marker {m:02b}, expected {want}"),
                    ));
                }
            }
        }
        Ok(())
    }

    fn reset(&mut self) {
        *self = Optoncdt::new(self.cfg.clone());
    }
}

fn decode(p: &[u8; 3]) -> u32 {
    u32::from(p[0] & 0x3F) | (u32::from(p[1] & 0x3F) << 6) | (u32::from(p[2] & 0x3F) << 12)
}

/// Parses a `GETINFO` reply: `Key: value` lines ending with the prompt `->`.
/// Recognised keys: `Name`, `Serial`, `Version`/`Firmware`, `Measuring range`/`Range`
/// (in mm). An `E<digits>` line is an error reply.
pub fn parse_getinfo(reply: &[u8]) -> Result<Option<LaserIdentity>, FrameError> {
    if reply.len() > 4096 {
        return Err(FrameError {
            offset: 4096,
            reason: "identity reply longer than 4096 bytes".into(),
        });
    }
    let Ok(text) = std::str::from_utf8(reply) else {
        let bad = reply
            .iter()
            .position(|b| !b.is_ascii())
            .unwrap_or(reply.len());
        return Err(FrameError {
            offset: bad as u64,
            reason: "identity reply is not text".into(),
        });
    };
    let mut id = LaserIdentity {
        protocol: "optoncdt".into(),
        read_from_sensor: true,
        ..LaserIdentity::default()
    };
    let mut done = false;
    for line in text.split(['\r', '\n']) {
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        if line == "->" || line.ends_with("->") && !line.contains(':') {
            done = true;
            break;
        }
        if line.starts_with('E')
            && line[1..].chars().take(3).all(|c| c.is_ascii_digit())
            && line.len() >= 4
        {
            return Err(FrameError {
                offset: 0,
                reason: format!("sensor answered GETINFO with an error: {line}"),
            });
        }
        let Some((key, value)) = line.split_once(':') else {
            continue;
        };
        let (key, value) = (key.trim().to_ascii_lowercase(), value.trim());
        match key.as_str() {
            "name" => id.model = value.to_string(),
            "serial" => id.serial = value.to_string(),
            "version" | "firmware" => id.firmware = value.to_string(),
            "measuring range" | "range" => {
                let num: String = value
                    .chars()
                    .take_while(|c| c.is_ascii_digit() || *c == '.')
                    .collect();
                match num.parse::<f64>() {
                    Ok(mm) if mm.is_finite() && mm > 0.0 => id.range_m = Some(mm * 1e-3),
                    _ => {
                        return Err(FrameError {
                            offset: 0,
                            reason: format!("measuring range '{value}' is not a number of mm"),
                        })
                    }
                }
            }
            _ => {}
        }
    }
    Ok(done.then_some(id))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(counter: bool) -> OptoncdtConfig {
        OptoncdtConfig {
            range_m: 0.01,
            counter,
            invert: false,
        }
    }

    /// The values as a stream, after one block the parser drops at sync.
    fn stream(values: &[(u32, u32)], counter: bool) -> Vec<u8> {
        let mut v = encode_value(1, false).to_vec();
        if counter {
            v.extend_from_slice(&encode_value(0, true));
        }
        for &(raw, c) in values {
            v.extend_from_slice(&encode_value(raw, false));
            if counter {
                v.extend_from_slice(&encode_value(c, true));
            }
        }
        v
    }

    #[test]
    fn values_scale_with_the_range_and_counters_pass_through() {
        let bytes = stream(&[(0, 7), (32768, 8), (65535, 9), (49152, 262_143)], true);
        let mut p = Optoncdt::new(cfg(true));
        let mut out = Vec::new();
        // In chunks of every size.
        for chunk in bytes.chunks(2) {
            p.feed(chunk, &mut out).unwrap();
        }
        let want = [
            (-0.005, 7),
            (0.0, 8),
            (0.005 - 0.01 / 65536.0, 9),
            (0.0025, 262_143),
        ];
        assert_eq!(out.len(), 4);
        for (r, (d, c)) in out.iter().zip(want) {
            match r.clone() {
                Reading::Value {
                    displacement_m,
                    counter,
                } => {
                    assert!(
                        (displacement_m - d).abs() < 1e-12,
                        "{displacement_m} vs {d}"
                    );
                    assert_eq!(counter, Some(c));
                }
                other => panic!("{other:?}"),
            }
        }
        // Round trip of the emulator's encoder: within half a code.
        for d in [-0.0049, -0.001234, 0.0, 0.003, 0.00499] {
            let raw = raw_of_displacement(d, 0.01);
            let bytes = stream(&[(raw, 0)], false);
            let r = super::super::parse_stream(
                &crate::laser::ProtocolConfig::Optoncdt(cfg(false)),
                &bytes,
            )
            .unwrap();
            let Reading::Value {
                displacement_m,
                counter: None,
            } = r[0]
            else {
                panic!()
            };
            assert!((displacement_m - d).abs() <= 0.5 * 0.01 / 65536.0 + 1e-15);
        }
    }

    #[test]
    fn error_codes_become_out_of_range_or_device_errors() {
        let bytes = stream(&[(CODE_NO_TARGET, 1), (CODE_TOO_FAR, 2), (70_000, 3)], true);
        let mut out = Vec::new();
        Optoncdt::new(cfg(true)).feed(&bytes, &mut out).unwrap();
        assert_eq!(
            out[0],
            Reading::OutOfRange {
                code: CODE_NO_TARGET,
                counter: Some(1)
            }
        );
        assert_eq!(
            out[1],
            Reading::OutOfRange {
                code: CODE_TOO_FAR,
                counter: Some(2)
            }
        );
        assert!(matches!(&out[2], Reading::DeviceError { code } if code.contains("70000")));
    }

    #[test]
    fn the_prompt_before_the_stream_is_skipped_but_garbage_after_sync_is_an_error() {
        let mut bytes = b"->\r\n".to_vec();
        // Start in the middle of a value: M and H of a previous one.
        bytes.extend_from_slice(&encode_value(1234, false)[1..]);
        for raw in [100, 200] {
            bytes.extend_from_slice(&encode_value(raw, false));
        }
        let mut out = Vec::new();
        let mut p = Optoncdt::new(cfg(false));
        p.feed(&bytes, &mut out).unwrap();
        assert_eq!(out.len(), 2);
        // A dropped byte (M missing) after sync.
        let v = encode_value(300, false);
        let e = p.feed(&[v[0], v[2]], &mut out).unwrap_err();
        assert!(e.reason.contains("marker"), "{e}");
        assert_eq!(e.offset, bytes.len() as u64 + 1);
        // Counter slot mismatch: two first values in a row with counter on.
        let mut out = Vec::new();
        let e = Optoncdt::new(cfg(true))
            .feed(&stream(&[(1, 0), (2, 0)], false), &mut out)
            .unwrap_err();
        assert!(e.reason.contains("expected the counter"), "{e}");
        // Pure noise never syncs.
        let noise = vec![b'A'; 200];
        let e = Optoncdt::new(cfg(false))
            .feed(&noise, &mut Vec::new())
            .unwrap_err();
        assert!(e.reason.contains("no optoNCDT frame"), "{e}");
    }

    #[test]
    fn getinfo_reply_gives_the_identity() {
        let reply = b"GETINFO\r\nName:      ILD1420-10\r\nSerial:    11020123\r\nOption:    000\r\nMeasuring range: 10 mm\r\nVersion:   004.093.087\r\n->";
        assert_eq!(parse_getinfo(&reply[..40]).unwrap(), None);
        let id = parse_getinfo(reply).unwrap().unwrap();
        assert_eq!(id.model, "ILD1420-10");
        assert_eq!(id.serial, "11020123");
        assert_eq!(id.firmware, "004.093.087");
        assert_eq!(id.range_m, Some(0.01));
        assert!(id.read_from_sensor);
        assert!(parse_getinfo(b"E200 unknown command\r\n->").is_err());
        assert!(parse_getinfo(b"Measuring range: lots\r\n->").is_err());
        assert!(parse_getinfo(&[0xff, 0xfe]).is_err());
    }
}
