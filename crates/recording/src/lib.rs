//! Recording sets on disk: `pre.wav`, `main.wav` and `meta.json` in one directory.
//!
//! The layout is the one of `shared/data/reference-recordings` (see its README):
//! WAV files (IEEE float32, or PCM 16/24/32-bit) with any number of channels,
//! and a `meta.json` naming which channel holds which signal:
//!
//! ```json
//! { "moving_mass_kg": 0.05, "sample_rate_hz": 48000,
//!   "channels": { "displacement": 0, "microphone": 1, "drive": 2 } }
//! ```
//!
//! Extensions (all optional, all read back):
//! - `"channel_scale": { "displacement": 0.01 }`: physical units per full scale
//!   for PCM files (metres per full scale for the laser, volts for the others).
//!   Float files are taken as physical values (scale 1) unless a scale is given.
//! - any other field is kept in [`Meta::extra`] and written back unchanged.
//!
//! This module does file I/O; everything downstream of it works on [`Signals`].

pub mod codec;
pub mod stream;

pub use springbench_core::recording::*;
use std::io::{Read, Seek, Write};
use std::path::Path;

/// A recording set read from and written to files: `DIR/meta.json`,
/// `DIR/pre.wav`, `DIR/main.wav`, or the same three parts in memory.
pub trait RecordingSetFiles: Sized {
    /// Reads `DIR/meta.json`, `DIR/pre.wav`, `DIR/main.wav`.
    fn read_dir(dir: impl AsRef<Path>) -> Result<Self, RecordingError>;
    /// Reads a set from in-memory parts (the API's multipart import).
    fn from_bytes(
        meta_json: &[u8],
        pre_wav: &[u8],
        main_wav: &[u8],
    ) -> Result<Self, RecordingError>;
    /// Writes the set as float32 WAV files in the standard channel layout
    /// (0 displacement, 1 microphone, 2 drive when present) plus meta.json.
    fn write_dir(&self, dir: impl AsRef<Path>) -> Result<(), RecordingError>;
}

impl RecordingSetFiles for RecordingSet {
    /// Reads `DIR/meta.json`, `DIR/pre.wav`, `DIR/main.wav`.
    fn read_dir(dir: impl AsRef<Path>) -> Result<RecordingSet, RecordingError> {
        let dir = dir.as_ref();
        let meta_path = dir.join("meta.json");
        let text = std::fs::read_to_string(&meta_path).map_err(|source| RecordingError::Io {
            path: meta_path.display().to_string(),
            source,
        })?;
        let meta = parse_meta(&text).map_err(|reason| RecordingError::Meta {
            path: meta_path.display().to_string(),
            reason,
        })?;
        // Each file is decoded straight from the file in blocks: holding the
        // 15 MB of WAV bytes first cost as many page faults as the analysis.
        let read = |name: &str| {
            let p = dir.join(name);
            let f = std::fs::File::open(&p).map_err(|source| RecordingError::Io {
                path: p.display().to_string(),
                source,
            })?;
            read_signals_seek(std::io::BufReader::new(f), &meta).map_err(|e| match e {
                RecordingError::Io { source, .. } => RecordingError::Io {
                    path: p.display().to_string(),
                    source,
                },
                e => with_path(e, &p),
            })
        };
        // the two files decode side by side (rayon's pool: the analysis
        // that follows runs there too)
        let (pre, main) = rayon::join(|| read("pre.wav"), || read("main.wav"));
        RecordingSet::settled(meta, pre?, main?)
    }

    /// Reads a set from in-memory parts (the API's multipart import).
    fn from_bytes(
        meta_json: &[u8],
        pre_wav: &[u8],
        main_wav: &[u8],
    ) -> Result<RecordingSet, RecordingError> {
        let text = std::str::from_utf8(meta_json).map_err(|_| RecordingError::Meta {
            path: "meta".into(),
            reason: "not UTF-8 text".into(),
        })?;
        let meta = parse_meta(text).map_err(|reason| RecordingError::Meta {
            path: "meta".into(),
            reason,
        })?;
        let pre = read_signals_bytes(pre_wav, &meta).map_err(|e| with_path(e, Path::new("pre")))?;
        let main =
            read_signals_bytes(main_wav, &meta).map_err(|e| with_path(e, Path::new("main")))?;
        RecordingSet::settled(meta, pre, main)
    }

    /// Writes the set as float32 WAV files in the standard channel layout
    /// (0 displacement, 1 microphone, 2 drive when present) plus meta.json.
    fn write_dir(&self, dir: impl AsRef<Path>) -> Result<(), RecordingError> {
        let dir = dir.as_ref();
        std::fs::create_dir_all(dir).map_err(|source| RecordingError::Io {
            path: dir.display().to_string(),
            source,
        })?;
        let io = |p: &Path| {
            let p = p.display().to_string();
            move |source| RecordingError::Io {
                path: p.clone(),
                source,
            }
        };
        for (name, s) in [("pre.wav", &self.pre), ("main.wav", &self.main)] {
            let p = dir.join(name);
            let bytes = signals_to_wav_bytes(s)?;
            std::fs::write(&p, bytes).map_err(io(&p))?;
        }
        let mut meta = self.meta.clone();
        meta.channels = Channels {
            displacement: 0,
            microphone: 1,
            drive: self.pre.drive_v.as_ref().map(|_| 2),
        };
        meta.channel_scale = None;
        let p = dir.join("meta.json");
        let mut f = std::fs::File::create(&p).map_err(io(&p))?;
        let text = serde_json::to_string_pretty(&meta).expect("meta serialises");
        f.write_all(text.as_bytes()).map_err(io(&p))?;
        f.write_all(b"\n").map_err(io(&p))?;
        Ok(())
    }
}

/// The error with the file's name in it.
fn with_path(e: RecordingError, p: &Path) -> RecordingError {
    match e {
        RecordingError::Wav { reason, .. } => RecordingError::Wav {
            path: p.display().to_string(),
            reason,
        },
        RecordingError::Invalid(m) => RecordingError::Invalid(format!("{}: {m}", p.display())),
        e => e,
    }
}

/// Reads one WAV stream and picks the channels named in `meta`.
pub fn read_signals<R: Read>(mut reader: R, meta: &Meta) -> Result<Signals, RecordingError> {
    let mut buf = Vec::new();
    reader
        .read_to_end(&mut buf)
        .map_err(|e| RecordingError::Wav {
            path: String::new(),
            reason: e.to_string(),
        })?;
    read_signals_bytes(&buf, meta)
}

/// [`read_signals`] on the bytes of a whole WAV file.
pub fn read_signals_bytes(wav: &[u8], meta: &Meta) -> Result<Signals, RecordingError> {
    read_signals_seek(std::io::Cursor::new(wav), meta).map_err(|e| match e {
        // In memory, a failed read is a short file.
        RecordingError::Io { source, .. } => RecordingError::Wav {
            path: String::new(),
            reason: source.to_string(),
        },
        e => e,
    })
}

/// [`read_signals`] on a seekable source (a file, bytes): the samples are
/// decoded block by block straight into the channels, so the WAV bytes are
/// never held whole. `RecordingError::Io` (empty path) when reading fails.
pub fn read_signals_seek<R: Read + Seek>(
    mut src: R,
    meta: &Meta,
) -> Result<Signals, RecordingError> {
    use std::io::SeekFrom;
    let wav_err = |reason: String| RecordingError::Wav {
        path: String::new(),
        reason,
    };
    let io_err = |source: std::io::Error| RecordingError::Io {
        path: String::new(),
        source,
    };
    let (spec, samples, frames) = {
        let r = hound::WavReader::new(&mut src).map_err(|e| wav_err(e.to_string()))?;
        (r.spec(), r.len() as usize, r.duration() as usize)
    };
    let nch = spec.channels as usize;
    if (spec.sample_rate as f64 - meta.sample_rate_hz).abs() > 1e-6 * meta.sample_rate_hz {
        return Err(RecordingError::Invalid(format!(
            "sample rate {} Hz differs from meta.json's sample_rate_hz {}",
            spec.sample_rate, meta.sample_rate_hz
        )));
    }
    let ch = meta.channels;
    for (name, idx) in [
        ("displacement", Some(ch.displacement)),
        ("microphone", Some(ch.microphone)),
        ("drive", ch.drive),
    ] {
        if let Some(i) = idx {
            if i >= nch {
                return Err(RecordingError::Invalid(format!(
                    "meta.json puts the {name} signal on channel {i}, but the file has only {nch} channel(s)"
                )));
            }
        }
    }
    let is_pcm = spec.sample_format == hound::SampleFormat::Int;
    let scale = meta.channel_scale.unwrap_or_default();
    if is_pcm && scale.displacement.is_none() {
        return Err(RecordingError::Invalid(
            "PCM file: meta.json needs channel_scale.displacement (metres per full scale) to read the laser channel".into(),
        ));
    }
    // hound parses the header and stops at the data chunk; the samples are
    // read in blocks and converted frame by frame straight into the channels
    // (hound's per-sample iterator was most of the time of `analyze`).
    let bytes = match (spec.sample_format, spec.bits_per_sample) {
        (hound::SampleFormat::Float, 32) => 4,
        (hound::SampleFormat::Int, b @ (8 | 16 | 24 | 32)) => (b as usize).div_ceil(8),
        (f, b) => {
            return Err(wav_err(format!(
                "unsupported sample format {f:?} with {b} bits"
            )))
        }
    };
    let start = src.stream_position().map_err(io_err)?;
    // The data chunk starts where hound stopped; its header (b"data", u32
    // length) precedes it and gives the container size of a sample.
    let mut head = [0u8; 8];
    let container = if start >= 8 {
        src.seek(SeekFrom::Start(start - 8)).map_err(io_err)?;
        src.read_exact(&mut head).map_err(io_err)?;
        (&head[..4] == b"data")
            .then(|| u32::from_le_bytes([head[4], head[5], head[6], head[7]]) as usize)
            .and_then(|len| len.checked_div(samples))
    } else {
        None
    };
    if spec.bits_per_sample == 8 || container != Some(bytes) {
        // Unusual layouts (8-bit unsigned, padded containers): hound's reader.
        src.seek(SeekFrom::Start(0)).map_err(io_err)?;
        let r = hound::WavReader::new(src).map_err(|e| wav_err(e.to_string()))?;
        return read_with_hound(r, meta, nch, is_pcm, scale);
    }
    let frame = nch * bytes;
    let end = src.seek(SeekFrom::End(0)).map_err(io_err)?;
    let need = frames as u64 * frame as u64;
    if end.saturating_sub(start) < need {
        return Err(wav_err("data chunk shorter than its header says".into()));
    }
    src.seek(SeekFrom::Start(start)).map_err(io_err)?;
    let full = if is_pcm {
        (1u64 << (spec.bits_per_sample - 1)) as f64
    } else {
        1.0
    };
    // (byte offset in a frame, gain, samples) of each channel read.
    let gain = |s: Option<f64>| s.unwrap_or(1.0) / full;
    let mut picks: Vec<(usize, f64, Vec<f64>)> = [
        Some((ch.displacement, scale.displacement)),
        Some((ch.microphone, scale.microphone)),
        ch.drive.map(|c| (c, scale.drive)),
    ]
    .into_iter()
    .flatten()
    .map(|(c, s)| (c * bytes, gain(s), Vec::with_capacity(frames)))
    .collect();
    // About 1 MiB per block (at least one frame).
    let per_block = ((1usize << 20) / frame).max(1);
    let mut block = vec![0u8; per_block.min(frames) * frame];
    let mut left = frames;
    let mut all_finite_so_far = true;
    while left > 0 {
        let n = per_block.min(left);
        let buf = &mut block[..n * frame];
        src.read_exact(buf).map_err(|e| {
            if e.kind() == std::io::ErrorKind::UnexpectedEof {
                wav_err("data chunk shorter than its header says".into())
            } else {
                io_err(e)
            }
        })?;
        for (off, g, out) in picks.iter_mut() {
            // One loop per sample format (the format's match hoisted out of
            // the per-sample loop); finiteness is checked while the block is
            // in cache.
            let (o, g) = (*off, *g);
            let ok = match (is_pcm, bytes) {
                (false, _) => decode_into(out, buf, frame, o, g, |b: [u8; 4]| {
                    f32::from_le_bytes(b) as f64
                }),
                (true, 2) => decode_into(out, buf, frame, o, g, |b: [u8; 2]| {
                    i16::from_le_bytes(b) as f64
                }),
                (true, 3) => decode_into(out, buf, frame, o, g, |b: [u8; 3]| {
                    (i32::from_le_bytes([0, b[0], b[1], b[2]]) >> 8) as f64
                }),
                (true, _) => decode_into(out, buf, frame, o, g, |b: [u8; 4]| {
                    i32::from_le_bytes(b) as f64
                }),
            };
            all_finite_so_far &= ok;
        }
        left -= n;
    }
    let mut it = picks.into_iter().map(|p| p.2);
    let displacement_m = it.next().unwrap_or_default();
    let microphone_v = it.next().unwrap_or_default();
    let sig = Signals {
        // The file's rate: meta.json may state it within 1e-6 (checked above),
        // the samples were taken at the WAV's integer rate (tests/fuzz.rs found
        // 8000.0000001 read here and refused by storage at 8000).
        sample_rate_hz: spec.sample_rate as f64,
        displacement_m,
        microphone_v,
        drive_v: it.next(),
    };
    if !all_finite_so_far {
        // The message names the channel and the sample.
        sig.validate("recording")?;
    }
    Ok(sig)
}

/// Appends `gain * conv(sample)` for the sample at byte `off` of each
/// `frame`-byte frame of `buf` (a fixed-size sample: one bounds check per
/// frame); false if any value is not finite (a float NaN or infinity, or a
/// scale that overflows).
fn decode_into<const B: usize>(
    out: &mut Vec<f64>,
    buf: &[u8],
    frame: usize,
    off: usize,
    gain: f64,
    conv: impl Fn([u8; B]) -> f64,
) -> bool {
    // The usual frames (2-4 channels of 2-4 bytes) with their size known to
    // the compiler: the per-frame slicing and bounds checks fold away
    // (the generic loop took ~20 instructions a sample, a fifth of `analyze`).
    match frame {
        4 => decode_frames::<B, 4>(out, buf, off, gain, conv),
        6 => decode_frames::<B, 6>(out, buf, off, gain, conv),
        8 => decode_frames::<B, 8>(out, buf, off, gain, conv),
        9 => decode_frames::<B, 9>(out, buf, off, gain, conv),
        12 => decode_frames::<B, 12>(out, buf, off, gain, conv),
        16 => decode_frames::<B, 16>(out, buf, off, gain, conv),
        _ => {
            let mut ok = true;
            out.extend(buf.chunks_exact(frame).map(|f| {
                let b: [u8; B] = f[off..off + B].try_into().expect("B bytes");
                let v = conv(b) * gain;
                ok &= v.is_finite();
                v
            }));
            ok
        }
    }
}

/// [`decode_into`] for frames of `F` bytes: the same conversion, sample for
/// sample.
fn decode_frames<const B: usize, const F: usize>(
    out: &mut Vec<f64>,
    buf: &[u8],
    off: usize,
    gain: f64,
    conv: impl Fn([u8; B]) -> f64,
) -> bool {
    assert!(off + B <= F, "a sample inside its frame");
    let n = buf.len() / F;
    out.reserve(n);
    let mut ok = true;
    for (o, f) in out.spare_capacity_mut()[..n]
        .iter_mut()
        .zip(buf.chunks_exact(F))
    {
        let b: [u8; B] = f[off..off + B].try_into().expect("B bytes");
        let v = conv(b) * gain;
        ok &= v.is_finite();
        o.write(v);
    }
    // SAFETY: the loop wrote the first n values of the spare capacity
    // (chunks_exact gives n frames).
    unsafe { out.set_len(out.len() + n) };
    ok
}

/// Sample by sample through hound (8-bit and other unusual layouts).
fn read_with_hound<R: Read>(
    mut r: hound::WavReader<R>,
    meta: &Meta,
    nch: usize,
    is_pcm: bool,
    scale: ChannelScale,
) -> Result<Signals, RecordingError> {
    let wav_err = |reason: String| RecordingError::Wav {
        path: String::new(),
        reason,
    };
    let bits = r.spec().bits_per_sample;
    let rate = r.spec().sample_rate as f64;
    let interleaved: Vec<f64> = if is_pcm {
        let full = (1u64 << (bits - 1)) as f64;
        r.samples::<i32>()
            .map(|s| s.map(|v| v as f64 / full))
            .collect::<Result<_, _>>()
            .map_err(|e| wav_err(e.to_string()))?
    } else {
        r.samples::<f32>()
            .map(|s| s.map(|v| v as f64))
            .collect::<Result<_, _>>()
            .map_err(|e| wav_err(e.to_string()))?
    };
    let frames = interleaved.len() / nch.max(1);
    let ch = meta.channels;
    let pick = |c: usize, s: Option<f64>| -> Vec<f64> {
        let g = s.unwrap_or(1.0);
        (0..frames).map(|k| interleaved[k * nch + c] * g).collect()
    };
    let sig = Signals {
        sample_rate_hz: rate,
        displacement_m: pick(ch.displacement, scale.displacement),
        microphone_v: pick(ch.microphone, scale.microphone),
        drive_v: ch.drive.map(|c| pick(c, scale.drive)),
    };
    sig.validate("recording")?;
    Ok(sig)
}

/// Encodes signals as a float32 WAV (0 displacement m, 1 microphone V, 2 drive V when present).
pub fn signals_to_wav_bytes(s: &Signals) -> Result<Vec<u8>, RecordingError> {
    let nch = if s.drive_v.is_some() { 3 } else { 2 };
    let spec = hound::WavSpec {
        channels: nch,
        sample_rate: s.sample_rate_hz.round() as u32,
        bits_per_sample: 32,
        sample_format: hound::SampleFormat::Float,
    };
    let mut cur = std::io::Cursor::new(Vec::with_capacity(s.len() * nch as usize * 4 + 64));
    {
        let mut w = hound::WavWriter::new(&mut cur, spec).map_err(|e| RecordingError::Wav {
            path: String::new(),
            reason: e.to_string(),
        })?;
        write_frames(&mut w, s).map_err(|e| RecordingError::Wav {
            path: String::new(),
            reason: e.to_string(),
        })?;
        w.finalize().map_err(|e| RecordingError::Wav {
            path: String::new(),
            reason: e.to_string(),
        })?;
    }
    Ok(cur.into_inner())
}

fn write_frames<W: Write + Seek>(
    w: &mut hound::WavWriter<W>,
    s: &Signals,
) -> Result<(), hound::Error> {
    for k in 0..s.len() {
        w.write_sample(s.displacement_m[k] as f32)?;
        w.write_sample(s.microphone_v[k] as f32)?;
        if let Some(d) = &s.drive_v {
            w.write_sample(d[k] as f32)?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sig(n: usize) -> Signals {
        Signals {
            sample_rate_hz: 48000.0,
            displacement_m: (0..n).map(|i| 1e-3 * (i as f64 * 0.01).sin()).collect(),
            microphone_v: (0..n).map(|i| 0.1 * (i as f64 * 0.02).cos()).collect(),
            drive_v: Some((0..n).map(|i| (i as f64 * 0.03).sin()).collect()),
        }
    }

    #[test]
    fn float_round_trip_is_exact_to_f32() {
        let dir = tempfile::tempdir().unwrap();
        let set = RecordingSet {
            meta: Meta::standard(0.05, 48000.0),
            pre: sig(1000),
            main: sig(500),
        };
        set.write_dir(dir.path()).unwrap();
        let back = RecordingSet::read_dir(dir.path()).unwrap();
        assert_eq!(back.meta.moving_mass_kg, 0.05);
        assert_eq!(back.pre.len(), 1000);
        assert_eq!(back.main.len(), 500);
        for (a, b) in set.pre.displacement_m.iter().zip(&back.pre.displacement_m) {
            assert!((a - b).abs() <= 1e-3 * f32::EPSILON as f64, "{a} vs {b}");
        }
    }

    #[test]
    fn pcm24_with_scale_and_other_channel_order() {
        // 2 channels: 0 microphone, 1 displacement; 24-bit PCM, 20 mm full scale.
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 8000,
            bits_per_sample: 24,
            sample_format: hound::SampleFormat::Int,
        };
        let mut cur = std::io::Cursor::new(Vec::new());
        {
            let mut w = hound::WavWriter::new(&mut cur, spec).unwrap();
            for k in 0..100 {
                w.write_sample(1000 * k).unwrap(); // microphone
                w.write_sample(-(1 << 22)).unwrap(); // displacement: -0.5 full scale
            }
            w.finalize().unwrap();
        }
        let meta: Meta = serde_json::from_str(
            r#"{"moving_mass_kg":0.1,"sample_rate_hz":8000,"channels":{"displacement":1,"microphone":0},
                "channel_scale":{"displacement":0.02},"operator":"kept"}"#,
        )
        .unwrap();
        let s = read_signals(std::io::Cursor::new(cur.into_inner()), &meta).unwrap();
        assert_eq!(s.len(), 100);
        assert!((s.displacement_m[3] + 0.01).abs() < 1e-12);
        assert!((s.microphone_v[2] - 2000.0 / (1u64 << 23) as f64).abs() < 1e-12);
        assert!(s.drive_v.is_none());
        assert_eq!(meta.extra["operator"], "kept");
    }

    /// meta.json may state the rate within 1e-6 of the file's; the signals
    /// carry the file's integer rate, so storage (FLAC, integer rates) keeps
    /// them (tests/fuzz.rs multipart finding: 8000.0000001 was refused).
    #[test]
    fn the_files_rate_is_the_signals_rate() {
        let s = Signals {
            sample_rate_hz: 8000.0,
            ..sig(200)
        };
        let wav = signals_to_wav_bytes(&s).unwrap();
        let meta = Meta::standard(0.05, 8000.0000001);
        let set =
            RecordingSet::from_bytes(serde_json::to_string(&meta).unwrap().as_bytes(), &wav, &wav)
                .unwrap();
        assert_eq!(set.main.sample_rate_hz, 8000.0);
        assert_eq!(set.meta.sample_rate_hz, 8000.0);
        let st = codec::encode_lossless(
            &set.main,
            codec::SampleFormat::Float32,
            &ChannelScale::default(),
        )
        .unwrap();
        assert_eq!(
            codec::decode(&st.bytes, st.channel_scale.as_ref()).unwrap(),
            set.main
        );
        // Beyond 1e-6 it is still refused.
        let meta = Meta::standard(0.05, 8000.01);
        let e =
            RecordingSet::from_bytes(serde_json::to_string(&meta).unwrap().as_bytes(), &wav, &wav)
                .unwrap_err();
        assert!(e.to_string().contains("differs"), "{e}");
    }

    #[test]
    fn clear_errors() {
        let bad = parse_meta(
            r#"{"moving_mass_kg":-1,"sample_rate_hz":48000,"channels":{"displacement":0,"microphone":1}}"#,
        );
        assert!(bad.unwrap_err().contains("moving_mass_kg"));
        let meta = Meta {
            channels: Channels {
                displacement: 0,
                microphone: 5,
                drive: None,
            },
            ..Meta::standard(0.05, 48000.0)
        };
        let bytes = signals_to_wav_bytes(&sig(10)).unwrap();
        let e = read_signals(std::io::Cursor::new(bytes.clone()), &meta)
            .unwrap_err()
            .to_string();
        assert!(e.contains("channel 5") && e.contains("3 channel"), "{e}");
        let meta = Meta::standard(0.05, 44100.0);
        let e = read_signals(std::io::Cursor::new(bytes), &meta)
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample rate"), "{e}");
        let mut s = sig(10);
        s.microphone_v[4] = f64::NAN;
        let e = s.validate("pre").unwrap_err().to_string();
        assert!(e.contains("microphone") && e.contains("sample 4"), "{e}");
        let e = RecordingSet::read_dir("/nonexistent/dir")
            .unwrap_err()
            .to_string();
        assert!(e.contains("meta.json"), "{e}");
    }
}
