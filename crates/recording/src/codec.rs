//! How raw signals are stored: losslessly, at the resolution they were captured with.
//!
//! A stored recording is a byte blob in the standard channel layout (0
//! displacement, 1 microphone, 2 drive when present) plus a [`ChannelScale`]
//! (physical value of digital full scale per channel, the same meaning as in
//! meta.json). The blob is one of
//!
//! - **FLAC** (integer captures of 8 to 24 bits; the usual case): code `c` of a
//!   `B`-bit stream means `c / 2^(B-1) * full_scale`, exactly the formula
//!   [`super::read_signals`] applies to a PCM WAV;
//! - **WAV** float32 or int32 (imports that are not on an integer grid of at
//!   most 24 bits, and rows written before FLAC storage, which have no scale).
//!
//! [`encode_lossless`] refuses to store anything that would not decode to the
//! very same `f64` samples: it decodes what it encoded and compares.
//! [`WavStream`] turns a stored blob into a float32 WAV block by block (what
//! `GET .../recordings/{file}` serves), with memory bounded by one FLAC block.
//! See `docs/decisions/0013-raw-data-storage.md`.

use super::{ChannelScale, Channels, Meta, RecordingError, Signals};
use flacenc::component::BitRepr;
use flacenc::error::Verify;
use serde::{Deserialize, Serialize};

/// The resolution a bench captures with: `bits`-bit integer codes, `scale`
/// the physical value of full scale (code `2^(bits-1)`) per channel.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Resolution {
    /// Bits per sample of the converter (8..=24 for FLAC storage).
    pub bits: u32,
    /// Metres (displacement) and volts (microphone, drive) per full scale;
    /// all three are set.
    pub scale: ChannelScale,
}

impl Resolution {
    /// The captured value of `v` on a channel with full scale `full_scale`:
    /// rounded to the nearest code and clipped to the converter's range, as
    /// an ADC does. Encoding the result with [`encode_flac`] is exact.
    pub fn quantise(bits: u32, full_scale: f64, v: f64) -> f64 {
        let full = (1u64 << (bits - 1)) as f64;
        // `+ 0.0`: a converter has no negative zero.
        let c = (v / full_scale * full).round().clamp(-full, full - 1.0) + 0.0;
        c / full * full_scale
    }
}

/// What the store keeps of one recording.
#[derive(Debug, Clone, PartialEq)]
pub struct Stored {
    pub bytes: Vec<u8>,
    /// Physical value of full scale per channel; `None` for a float WAV in
    /// physical units (rows written before FLAC storage).
    pub channel_scale: Option<ChannelScale>,
}

/// How a WAV file stores its samples (to keep an import at its resolution).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SampleFormat {
    Int(u32),
    Float32,
}

/// The sample format of a WAV file (from its header).
pub fn wav_format(wav: &[u8]) -> Result<SampleFormat, RecordingError> {
    let r = hound::WavReader::new(std::io::Cursor::new(wav)).map_err(wav_err)?;
    let spec = r.spec();
    Ok(match spec.sample_format {
        hound::SampleFormat::Float => SampleFormat::Float32,
        hound::SampleFormat::Int => SampleFormat::Int(spec.bits_per_sample as u32),
    })
}

fn invalid(m: impl Into<String>) -> RecordingError {
    RecordingError::Invalid(m.into())
}

fn channel_list(s: &Signals) -> Vec<&[f64]> {
    let mut v: Vec<&[f64]> = vec![&s.displacement_m, &s.microphone_v];
    if let Some(d) = &s.drive_v {
        v.push(d);
    }
    v
}

fn scales(scale: &ChannelScale, n: usize) -> Vec<f64> {
    [scale.displacement, scale.microphone, scale.drive][..n]
        .iter()
        .map(|s| s.unwrap_or(1.0))
        .collect()
}

/// Integer codes of `s` at `bits` bits with full scales `scale`, interleaved;
/// `None` if any sample is not exactly such a code (it would not round-trip).
pub fn codes(s: &Signals, bits: u32, scale: &ChannelScale) -> Option<Vec<i32>> {
    if !(2..=32).contains(&bits) {
        return None;
    }
    let chans = channel_list(s);
    let g = scales(scale, chans.len());
    let full = (1u64 << (bits - 1)) as f64;
    let n = s.len();
    let mut out = Vec::with_capacity(n * chans.len());
    for k in 0..n {
        for (c, ch) in chans.iter().enumerate() {
            let v = ch[k];
            let code = (v / g[c] * full).round();
            if !(-full..full).contains(&code) || code / full * g[c] != v {
                return None;
            }
            out.push(code as i32);
        }
    }
    Some(out)
}

/// FLAC bytes of `s` at `bits` (8..=24) bits with full scales `scale`; an
/// error if a sample is not on that grid.
pub fn encode_flac(
    s: &Signals,
    bits: u32,
    scale: &ChannelScale,
) -> Result<Vec<u8>, RecordingError> {
    if !(8..=24).contains(&bits) {
        return Err(invalid(format!("FLAC stores 8 to 24 bits, not {bits}")));
    }
    let codes = codes(s, bits, scale).ok_or_else(|| {
        invalid(format!(
            "the samples are not {bits}-bit codes of the given full scales"
        ))
    })?;
    let nch = channel_list(s).len();
    let rate = s.sample_rate_hz.round();
    if !(1.0..=655_350.0).contains(&rate) || rate != s.sample_rate_hz {
        return Err(invalid(format!(
            "sample rate {} Hz cannot be stored in FLAC",
            s.sample_rate_hz
        )));
    }
    let mut cfg = flacenc::config::Encoder::default();
    cfg.multithread = false;
    let cfg = cfg
        .into_verified()
        .map_err(|e| invalid(format!("FLAC encoder configuration: {e:?}")))?;
    let src = flacenc::source::MemSource::from_samples(&codes, nch, bits as usize, rate as usize);
    let mut stream = flacenc::encode_with_fixed_block_size(&cfg, src, cfg.block_size)
        .map_err(|e| invalid(format!("FLAC encoder: {e:?}")))?;
    // STREAMINFO's minimum block size excludes the last block (FLAC format);
    // flacenc counts a short last block, and a stream of 4096 k + r frames
    // with r < 16 was then refused by decoders (found by tests/fuzz.rs).
    stream
        .stream_info_mut()
        .set_block_sizes(cfg.block_size, cfg.block_size)
        .map_err(|e| invalid(format!("FLAC encoder: {e:?}")))?;
    let mut sink = flacenc::bitsink::ByteSink::new();
    stream
        .write(&mut sink)
        .map_err(|e| invalid(format!("FLAC encoder: {e:?}")))?;
    Ok(sink.into_inner())
}

fn wav_err(reason: impl ToString) -> RecordingError {
    RecordingError::Wav {
        path: String::new(),
        reason: reason.to_string(),
    }
}

/// WAV bytes (float32 or int32, standard layout) that decode with `scale` to `s`.
fn encode_wav(
    s: &Signals,
    format: SampleFormat,
    scale: &ChannelScale,
) -> Result<Vec<u8>, RecordingError> {
    let chans = channel_list(s);
    let g = scales(scale, chans.len());
    let (bits, fmt) = match format {
        SampleFormat::Float32 => (32, hound::SampleFormat::Float),
        SampleFormat::Int(b) => (b as u16, hound::SampleFormat::Int),
    };
    let spec = hound::WavSpec {
        channels: chans.len() as u16,
        sample_rate: s.sample_rate_hz.round() as u32,
        bits_per_sample: bits,
        sample_format: fmt,
    };
    let mut cur = std::io::Cursor::new(Vec::with_capacity(s.len() * chans.len() * 4 + 64));
    {
        let mut w = hound::WavWriter::new(&mut cur, spec).map_err(wav_err)?;
        match format {
            SampleFormat::Float32 => {
                for k in 0..s.len() {
                    for (c, ch) in chans.iter().enumerate() {
                        w.write_sample((ch[k] / g[c]) as f32).map_err(wav_err)?;
                    }
                }
            }
            SampleFormat::Int(b) => {
                let codes = codes(s, b, scale)
                    .ok_or_else(|| invalid(format!("the samples are not {b}-bit codes")))?;
                for c in codes {
                    w.write_sample(c).map_err(wav_err)?;
                }
            }
        }
        w.finalize().map_err(wav_err)?;
    }
    Ok(cur.into_inner())
}

/// Stores `s` without losing a bit. `format` and `scale` are how the signals
/// were captured (a bench's [`Resolution`], or an imported WAV's format and
/// meta.json `channel_scale`). Integer captures of at most 24 bits, and
/// float32 captures that are 24-bit codes, become FLAC; anything else a WAV
/// of the captured format. The result is decoded and compared sample by
/// sample (by value: a -0.0 read as a code comes back as 0.0); a mismatch
/// is an error (nothing is stored lossily).
pub fn encode_lossless(
    s: &Signals,
    format: SampleFormat,
    scale: &ChannelScale,
) -> Result<Stored, RecordingError> {
    if s.is_empty() {
        return Err(invalid("the recording has no samples"));
    }
    let nch = channel_list(s).len();
    let g = scales(scale, nch);
    let scale = ChannelScale {
        displacement: Some(g[0]),
        microphone: Some(g[1]),
        drive: g.get(2).copied(),
    };
    let flac_bits = match format {
        SampleFormat::Int(b) if (8..=24).contains(&b) => Some(b),
        SampleFormat::Float32 => Some(24),
        SampleFormat::Int(_) => None,
    };
    let bytes = match flac_bits.and_then(|b| encode_flac(s, b, &scale).ok()) {
        Some(b) => b,
        None => encode_wav(s, format, &scale)?,
    };
    let stored = Stored {
        bytes,
        channel_scale: Some(scale),
    };
    let back = decode(&stored.bytes, stored.channel_scale.as_ref())?;
    let same = back.len() == s.len()
        && back.sample_rate_hz == s.sample_rate_hz
        && channel_list(&back)
            .iter()
            .zip(channel_list(s))
            .all(|(a, b)| a.iter().zip(b).all(|(x, y)| x == y))
        && back.drive_v.is_some() == s.drive_v.is_some();
    if !same {
        return Err(invalid(
            "the recording does not survive storage bit for bit (not stored)",
        ));
    }
    Ok(stored)
}

/// What the store keeps of a bench capture: FLAC at the bench's resolution
/// (bit for bit what was captured), or float32 WAV when it declares none.
pub fn encode_capture(s: &Signals, res: Option<&Resolution>) -> Result<Stored, RecordingError> {
    match res {
        Some(r) => encode_lossless(s, SampleFormat::Int(r.bits), &r.scale),
        None => encode_float32(s),
    }
}

/// A float32 WAV of the physical values, for a bench that declares no
/// resolution: exact only if the samples are float32 values (decision 0013).
pub fn encode_float32(s: &Signals) -> Result<Stored, RecordingError> {
    Ok(Stored {
        bytes: encode_wav(s, SampleFormat::Float32, &ChannelScale::default())?,
        channel_scale: None,
    })
}

/// Reads a stored blob (FLAC or WAV, standard layout) back into signals.
pub fn decode(bytes: &[u8], scale: Option<&ChannelScale>) -> Result<Signals, RecordingError> {
    let mut st = WavStream::new(bytes.to_vec(), scale.copied())?;
    let n = st.frames as usize;
    let nch = st.channels as usize;
    // The header's frame count is not trusted for the allocation (found by
    // tests/fuzz.rs: a forged count asked for 31 GB); the vectors grow as decoded.
    let cap = n.min(1 << 20);
    let mut cols: Vec<Vec<f64>> = (0..nch).map(|_| Vec::with_capacity(cap)).collect();
    while let Some(block) = st.next_block()? {
        for (k, v) in block.iter().enumerate() {
            cols[k % nch].push(*v);
        }
    }
    let mut it = cols.into_iter();
    let displacement_m = it.next().unwrap_or_default();
    let microphone_v = it.next().unwrap_or_default();
    let drive_v = it.next();
    let s = Signals {
        sample_rate_hz: st.sample_rate_hz,
        displacement_m,
        microphone_v,
        drive_v,
    };
    if s.len() != n {
        return Err(invalid(format!(
            "stored recording has {} frames, its header says {n}",
            s.len()
        )));
    }
    s.validate("stored recording")?;
    Ok(s)
}

/// Where a [`WavStream`] reads the stored bytes from: a blob in memory or a
/// reader over the store (`GET .../recordings/*.wav` streams from SQLite).
pub type BlobRead = Box<dyn std::io::Read + Send>;

enum Source {
    Flac {
        frames: claxon::frame::FrameReader<claxon::input::BufferedReader<BlobRead>>,
        buf: Vec<i32>,
        full: f64,
    },
    Wav {
        reader: hound::WavReader<BlobRead>,
        full: Option<f64>,
    },
}

/// A stored blob decoded block by block: physical samples, interleaved in
/// the standard layout ([`WavStream::next_block`]), or the bytes of a float32
/// WAV of them (the `Iterator`: header first, then one chunk per block).
/// Memory: the blob plus one block (4096 frames for FLAC).
pub struct WavStream {
    src: Source,
    gains: Vec<f64>,
    pub channels: u16,
    pub frames: u64,
    pub sample_rate_hz: f64,
    done: u64,
    header_sent: bool,
    failed: bool,
}

/// Frames per chunk read from a WAV blob.
const WAV_CHUNK: usize = 4096;

/// Largest FLAC metadata accepted before the first frame (a stored
/// recording has STREAMINFO only; claxon's own limits are of the same order).
const FLAC_METADATA_MAX: usize = 16 << 20;

/// The FLAC metadata blocks after the `fLaC` marker (read from `r`, which is
/// left at the first frame), with the marker in front.
fn flac_metadata(r: &mut BlobRead) -> Result<Vec<u8>, RecordingError> {
    let truncated = |_| wav_err("FLAC metadata truncated");
    let mut head = b"fLaC".to_vec();
    loop {
        let mut h = [0u8; 4];
        r.read_exact(&mut h).map_err(truncated)?;
        let len = ((h[1] as usize) << 16) | ((h[2] as usize) << 8) | h[3] as usize;
        if head.len() + 4 + len > FLAC_METADATA_MAX {
            return Err(wav_err("FLAC metadata too large"));
        }
        head.extend_from_slice(&h);
        let at = head.len();
        head.resize(at + len, 0);
        r.read_exact(&mut head[at..]).map_err(truncated)?;
        if h[0] & 0x80 != 0 {
            return Ok(head);
        }
    }
}

impl WavStream {
    /// Opens a stored blob; `scale` as stored with it.
    pub fn new(bytes: Vec<u8>, scale: Option<ChannelScale>) -> Result<WavStream, RecordingError> {
        WavStream::from_reader(Box::new(std::io::Cursor::new(bytes)), scale)
    }

    /// Opens a stored recording read from `r` (the blob's bytes from the
    /// start); only the FLAC metadata or the WAV header is read here.
    pub fn from_reader(
        mut r: BlobRead,
        scale: Option<ChannelScale>,
    ) -> Result<WavStream, RecordingError> {
        use std::io::Read;
        let mut magic = Vec::with_capacity(4);
        (&mut r)
            .take(4)
            .read_to_end(&mut magic)
            .map_err(|e| wav_err(format!("stored recording: {e}")))?;
        let (src, channels, frames, rate) = if magic == b"fLaC" {
            let head = flac_metadata(&mut r)?;
            let info = claxon::FlacReader::new(std::io::Cursor::new(&head[..]))
                .map_err(|e| wav_err(format!("FLAC: {e}")))?
                .streaminfo();
            if !(8..=24).contains(&info.bits_per_sample) {
                return Err(wav_err(format!(
                    "FLAC with {} bits per sample",
                    info.bits_per_sample
                )));
            }
            let frames = info
                .samples
                .ok_or_else(|| wav_err("FLAC without a sample count"))?;
            (
                Source::Flac {
                    frames: claxon::frame::FrameReader::new(claxon::input::BufferedReader::new(r)),
                    buf: Vec::new(),
                    full: (1u64 << (info.bits_per_sample - 1)) as f64,
                },
                info.channels as u16,
                frames,
                info.sample_rate as f64,
            )
        } else {
            let r: BlobRead = Box::new(std::io::Cursor::new(magic).chain(r));
            let reader = hound::WavReader::new(r).map_err(wav_err)?;
            let spec = reader.spec();
            let full = match (spec.sample_format, spec.bits_per_sample) {
                (hound::SampleFormat::Float, 32) => None,
                (hound::SampleFormat::Int, b @ (8 | 16 | 24 | 32)) => {
                    Some((1u64 << (b - 1)) as f64)
                }
                (f, b) => {
                    return Err(wav_err(format!(
                        "unsupported sample format {f:?} with {b} bits"
                    )))
                }
            };
            let frames = reader.duration() as u64;
            (
                Source::Wav { reader, full },
                spec.channels,
                frames,
                spec.sample_rate as f64,
            )
        };
        if !(2..=3).contains(&channels) {
            return Err(invalid(format!(
                "a stored recording has 2 or 3 channels, not {channels}"
            )));
        }
        if !rate.is_finite() || rate <= 0.0 {
            return Err(invalid("stored recording without a sample rate"));
        }
        let s = scale.unwrap_or_default();
        let gains = scales(&s, channels as usize);
        Ok(WavStream {
            src,
            gains,
            channels,
            frames,
            sample_rate_hz: rate,
            done: 0,
            header_sent: false,
            failed: false,
        })
    }

    /// The next block of physical samples (interleaved), `None` at the end.
    pub fn next_block(&mut self) -> Result<Option<Vec<f64>>, RecordingError> {
        let nch = self.channels as usize;
        let out = match &mut self.src {
            Source::Flac { frames, buf, full } => {
                let b = frames
                    .read_next_or_eof(std::mem::take(buf))
                    .map_err(|e| wav_err(format!("FLAC: {e}")))?;
                let Some(b) = b else {
                    return self.end();
                };
                if b.channels() as usize != nch {
                    return Err(wav_err("FLAC frame with another channel count"));
                }
                let n = b.duration() as usize;
                let mut out = Vec::with_capacity(n * nch);
                for i in 0..n {
                    for c in 0..nch {
                        out.push(b.sample(c as u32, i as u32) as f64 / *full * self.gains[c]);
                    }
                }
                *buf = b.into_buffer();
                out
            }
            Source::Wav { reader, full } => {
                let want = WAV_CHUNK * nch;
                let mut out = Vec::with_capacity(want);
                match full {
                    None => {
                        for v in reader.samples::<f32>().take(want) {
                            let c = out.len() % nch;
                            out.push(v.map_err(wav_err)? as f64 * self.gains[c]);
                        }
                    }
                    Some(full) => {
                        for v in reader.samples::<i32>().take(want) {
                            let c = out.len() % nch;
                            out.push(v.map_err(wav_err)? as f64 / *full * self.gains[c]);
                        }
                    }
                }
                if out.is_empty() {
                    return self.end();
                }
                if out.len() % nch != 0 {
                    return Err(wav_err("WAV data ends inside a frame"));
                }
                out
            }
        };
        self.done += (out.len() / nch) as u64;
        if self.done > self.frames {
            return Err(wav_err("more samples than the header says"));
        }
        if let Some(i) = out.iter().position(|v| !v.is_finite()) {
            return Err(invalid(format!(
                "stored recording has a non-finite sample at frame {}",
                self.done as usize - out.len() / nch + i / nch
            )));
        }
        Ok(Some(out))
    }

    fn end(&mut self) -> Result<Option<Vec<f64>>, RecordingError> {
        if self.done != self.frames {
            return Err(wav_err(format!(
                "stored recording ends after {} of {} frames",
                self.done, self.frames
            )));
        }
        Ok(None)
    }

    /// Length in bytes of the float32 WAV this stream produces.
    pub fn wav_len(&self) -> u64 {
        44 + self.frames * self.channels as u64 * 4
    }

    fn header(&self) -> Vec<u8> {
        let data = self.frames * self.channels as u64 * 4;
        let data32 = u32::try_from(data).unwrap_or(u32::MAX - 36);
        let rate = self.sample_rate_hz.round() as u32;
        let align = self.channels * 4;
        let mut h = Vec::with_capacity(44);
        h.extend_from_slice(b"RIFF");
        h.extend_from_slice(&(36u32.saturating_add(data32)).to_le_bytes());
        h.extend_from_slice(b"WAVEfmt ");
        h.extend_from_slice(&16u32.to_le_bytes());
        h.extend_from_slice(&3u16.to_le_bytes()); // IEEE float
        h.extend_from_slice(&self.channels.to_le_bytes());
        h.extend_from_slice(&rate.to_le_bytes());
        h.extend_from_slice(&(rate * align as u32).to_le_bytes());
        h.extend_from_slice(&align.to_le_bytes());
        h.extend_from_slice(&32u16.to_le_bytes());
        h.extend_from_slice(b"data");
        h.extend_from_slice(&data32.to_le_bytes());
        h
    }
}

impl Iterator for WavStream {
    type Item = Result<Vec<u8>, RecordingError>;
    /// The float32 WAV: the 44-byte header, then one chunk per block.
    fn next(&mut self) -> Option<Self::Item> {
        if self.failed {
            return None;
        }
        if !self.header_sent {
            self.header_sent = true;
            return Some(Ok(self.header()));
        }
        match self.next_block() {
            Ok(Some(b)) => Some(Ok(b
                .iter()
                .flat_map(|v| (*v as f32).to_le_bytes())
                .collect())),
            Ok(None) => None,
            Err(e) => {
                self.failed = true;
                Some(Err(e))
            }
        }
    }
}

/// The meta.json a stored recording set answers to (standard layout).
pub fn standard_meta(moving_mass_kg: f64, sample_rate_hz: f64, drive: bool) -> Meta {
    Meta {
        channels: Channels {
            displacement: 0,
            microphone: 1,
            drive: drive.then_some(2),
        },
        ..Meta::standard(moving_mass_kg, sample_rate_hz)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn res24() -> Resolution {
        Resolution {
            bits: 24,
            scale: ChannelScale {
                displacement: Some(0.025),
                microphone: Some(100.0),
                drive: Some(100.0),
            },
        }
    }

    /// A sweep-like signal with noise, quantised like a 24-bit converter.
    fn captured(n: usize, r: &Resolution) -> Signals {
        let q = |fs: Option<f64>, v: f64| Resolution::quantise(r.bits, fs.unwrap(), v);
        let mut seed = 12345u64;
        let mut noise = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 1e-3
        };
        let t = |i: usize| i as f64 / 48000.0;
        Signals {
            sample_rate_hz: 48000.0,
            displacement_m: (0..n)
                .map(|i| {
                    q(
                        r.scale.displacement,
                        0.008 * (40.0 * t(i) * t(i)).sin() + 1e-3 * noise(),
                    )
                })
                .collect(),
            microphone_v: (0..n)
                .map(|i| {
                    q(
                        r.scale.microphone,
                        30.0 * (40.0 * t(i) * t(i)).cos() + noise(),
                    )
                })
                .collect(),
            drive_v: Some(
                (0..n)
                    .map(|i| q(r.scale.drive, 60.0 * (40.0 * t(i) * t(i) + 0.3).sin()))
                    .collect(),
            ),
        }
    }

    fn bit_equal(a: &Signals, b: &Signals) -> bool {
        let eq = |x: &[f64], y: &[f64]| {
            x.len() == y.len() && x.iter().zip(y).all(|(p, q)| p.to_bits() == q.to_bits())
        };
        a.sample_rate_hz == b.sample_rate_hz
            && eq(&a.displacement_m, &b.displacement_m)
            && eq(&a.microphone_v, &b.microphone_v)
            && match (&a.drive_v, &b.drive_v) {
                (Some(x), Some(y)) => eq(x, y),
                (None, None) => true,
                _ => false,
            }
    }

    #[test]
    fn a_24_bit_capture_reads_back_sample_for_sample_and_compresses() {
        let r = res24();
        let s = captured(20_000, &r);
        let st = encode_lossless(&s, SampleFormat::Int(24), &r.scale).unwrap();
        assert!(st.bytes.starts_with(b"fLaC"));
        let back = decode(&st.bytes, st.channel_scale.as_ref()).unwrap();
        assert!(bit_equal(&s, &back));
        // The integer codes too, not only the values.
        assert_eq!(
            codes(&back, 24, &r.scale).unwrap(),
            codes(&s, 24, &r.scale).unwrap()
        );
        // float32 WAV would be 12 bytes per frame.
        assert!(st.bytes.len() < 20_000 * 12 / 2, "{} bytes", st.bytes.len());
    }

    #[test]
    fn sixteen_bit_and_two_channels() {
        let r = Resolution {
            bits: 16,
            ..res24()
        };
        let mut s = captured(5000, &r);
        s.drive_v = None;
        let st = encode_lossless(&s, SampleFormat::Int(16), &r.scale).unwrap();
        let back = decode(&st.bytes, st.channel_scale.as_ref()).unwrap();
        assert!(bit_equal(&s, &back));
        assert!(back.drive_v.is_none());
    }

    #[test]
    fn off_grid_float_is_kept_as_float_wav_exactly() {
        // Physical float32 values (an imported float WAV with scale 1).
        let s = Signals {
            sample_rate_hz: 44100.0,
            displacement_m: (0..300)
                .map(|i| (1e-3 * (i as f64 * 0.1).sin()) as f32 as f64)
                .collect(),
            microphone_v: (0..300)
                .map(|i| (0.3 * (i as f64 * 0.2).cos()) as f32 as f64)
                .collect(),
            drive_v: None,
        };
        let st = encode_lossless(&s, SampleFormat::Float32, &ChannelScale::default()).unwrap();
        assert!(st.bytes.starts_with(b"RIFF"));
        assert!(bit_equal(
            &s,
            &decode(&st.bytes, st.channel_scale.as_ref()).unwrap()
        ));
        // With a scale: float samples times the scale still come back exactly.
        let g = ChannelScale {
            displacement: Some(0.013),
            microphone: Some(7.0),
            drive: None,
        };
        let scaled = Signals {
            displacement_m: s.displacement_m.iter().map(|v| v * 0.013).collect(),
            microphone_v: s.microphone_v.iter().map(|v| v * 7.0).collect(),
            ..s.clone()
        };
        let st = encode_lossless(&scaled, SampleFormat::Float32, &g).unwrap();
        assert!(bit_equal(
            &scaled,
            &decode(&st.bytes, st.channel_scale.as_ref()).unwrap()
        ));
    }

    #[test]
    fn float_that_is_24_bit_codes_becomes_flac() {
        let r = Resolution {
            bits: 24,
            scale: ChannelScale {
                displacement: Some(1.0),
                microphone: Some(1.0),
                drive: Some(1.0),
            },
        };
        let s = captured(3000, &r);
        let st = encode_lossless(&s, SampleFormat::Float32, &ChannelScale::default()).unwrap();
        assert!(st.bytes.starts_with(b"fLaC"));
        assert!(bit_equal(
            &s,
            &decode(&st.bytes, st.channel_scale.as_ref()).unwrap()
        ));
    }

    #[test]
    fn int32_is_kept_as_int32_wav() {
        let g = ChannelScale {
            displacement: Some(0.02),
            microphone: Some(5.0),
            drive: Some(100.0),
        };
        let q = |fs: f64, v: f64| Resolution::quantise(32, fs, v);
        let s = Signals {
            sample_rate_hz: 8000.0,
            displacement_m: (0..500).map(|i| q(0.02, 1e-3 * (i as f64).sin())).collect(),
            microphone_v: (0..500).map(|i| q(5.0, 0.1 * (i as f64).cos())).collect(),
            drive_v: Some((0..500).map(|i| q(100.0, (i as f64 * 0.3).sin())).collect()),
        };
        let st = encode_lossless(&s, SampleFormat::Int(32), &g).unwrap();
        assert!(st.bytes.starts_with(b"RIFF"));
        assert!(bit_equal(
            &s,
            &decode(&st.bytes, st.channel_scale.as_ref()).unwrap()
        ));
    }

    #[test]
    fn off_grid_samples_are_refused_for_flac() {
        let r = res24();
        let mut s = captured(100, &r);
        s.microphone_v[7] += 1e-9;
        assert!(encode_flac(&s, 24, &r.scale).is_err());
        // The lossless path still stores it, as a float WAV? No: an Int(24)
        // capture that is off its grid cannot be stored as 24-bit codes.
        assert!(encode_lossless(&s, SampleFormat::Int(24), &r.scale).is_err());
    }

    #[test]
    fn streamed_wav_is_the_float32_of_the_samples() {
        let r = res24();
        let s = captured(10_001, &r);
        let st = encode_lossless(&s, SampleFormat::Int(24), &r.scale).unwrap();
        let stream = WavStream::new(st.bytes.clone(), st.channel_scale).unwrap();
        let len = stream.wav_len();
        let chunks: Vec<Vec<u8>> = stream.collect::<Result<_, _>>().unwrap();
        assert!(chunks.len() > 2, "streamed in blocks");
        assert!(chunks.iter().all(|c| c.len() <= 4096 * 12 + 44));
        let wav: Vec<u8> = chunks.concat();
        assert_eq!(wav.len() as u64, len);
        let meta = standard_meta(0.05, 48000.0, true);
        let back = super::super::read_signals(std::io::Cursor::new(wav), &meta).unwrap();
        assert_eq!(back.len(), s.len());
        for (a, b) in s.microphone_v.iter().zip(&back.microphone_v) {
            assert_eq!(*a as f32 as f64, *b);
        }
    }

    #[test]
    fn quantise_is_a_converter() {
        // 24-bit over +-100 V: an LSB of 100/2^23 V, rounding to nearest, clipping.
        let lsb = 100.0 / (1u64 << 23) as f64;
        assert_eq!(Resolution::quantise(24, 100.0, 0.0), 0.0);
        assert_eq!(Resolution::quantise(24, 100.0, 0.6 * lsb), lsb);
        assert_eq!(Resolution::quantise(24, 100.0, -0.4 * lsb), 0.0);
        assert_eq!(Resolution::quantise(24, 100.0, 1e9), 100.0 - lsb);
        assert_eq!(Resolution::quantise(24, 100.0, -1e9), -100.0);
    }

    /// Lengths whose last FLAC block is shorter than 16 frames (and a
    /// recording shorter than one block) store and read back exactly.
    #[test]
    fn short_last_blocks_decode() {
        let r = res24();
        for n in [1, 7, 15, 16, 4096 + 5, 2 * 4096 + 15, 4096] {
            let s = captured(n, &r);
            let st = encode_lossless(&s, SampleFormat::Int(24), &r.scale)
                .unwrap_or_else(|e| panic!("{n} frames: {e}"));
            assert!(st.bytes.starts_with(b"fLaC"), "{n} frames");
            assert!(bit_equal(
                &decode(&st.bytes, st.channel_scale.as_ref()).unwrap(),
                &s
            ));
        }
    }

    #[test]
    fn damaged_blobs_are_errors_not_panics() {
        let r = res24();
        let s = captured(9000, &r);
        let st = encode_lossless(&s, SampleFormat::Int(24), &r.scale).unwrap();
        for cut in [0, 3, 4, 20, 42, 100, st.bytes.len() / 2, st.bytes.len() - 1] {
            assert!(
                decode(&st.bytes[..cut], st.channel_scale.as_ref()).is_err(),
                "cut {cut}"
            );
        }
        // A forged frame count (2^36 - 1 frames in STREAMINFO) is an error, not
        // a 31 GB allocation.
        let mut forged = st.bytes.clone();
        forged[21] |= 0x0f;
        forged[22..26].copy_from_slice(&[0xff; 4]);
        assert!(decode(&forged, st.channel_scale.as_ref()).is_err());
        let mut flipped = st.bytes.clone();
        let i = flipped.len() / 3;
        flipped[i] ^= 0x10;
        assert!(decode(&flipped, st.channel_scale.as_ref()).is_err());
    }
}
