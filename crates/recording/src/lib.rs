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
pub mod stimulus;
pub mod stream;

pub use springbench_core::recording::*;
use std::io::{Read, Seek, Write};
use std::mem::MaybeUninit;
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
        // Each file is decoded in blocks side by side, straight into the
        // channels (decision 0093), each block read from the file by its own
        // task into a small buffer that stays in cache: the file is never
        // held whole (a 15.5 MB buffer of fresh pages the kernel zeroed, a
        // quarter of the memory `analyze` touched; decision 0127). Not
        // mapped: memmap2 links libc, which this pure crate must not
        // (tests/it/layers.rs).
        let read = |name: &str| {
            let p = dir.join(name);
            let file = std::fs::File::open(&p).map_err(|source| RecordingError::Io {
                path: p.display().to_string(),
                source,
            })?;
            read_signals_file(&file, &meta)
                .map_err(in_memory_io)
                .map_err(|e| with_path(e, &p))
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
    read_signals_slice(wav, meta).map_err(in_memory_io)
}

/// A failed read of an open file or of bytes in memory is a short or bad
/// WAV file (a failed open keeps its `Io` error, named by path).
fn in_memory_io(e: RecordingError) -> RecordingError {
    match e {
        RecordingError::Io { source, .. } => RecordingError::Wav {
            path: String::new(),
            reason: source.to_string(),
        },
        e => e,
    }
}

/// [`read_signals_slice`] on an open file: the header through a small
/// buffer, then blocks of 256 kB side by side on rayon's pool, each read at
/// its offset (`pread`) into a buffer of its task's and decoded straight
/// into its part of the channels. The same values as [`read_signals_bytes`]
/// of the file's bytes, sample for sample; the file is never held whole.
#[cfg(unix)]
fn read_signals_file(file: &std::fs::File, meta: &Meta) -> Result<Signals, RecordingError> {
    use rayon::prelude::*;
    use std::os::unix::fs::FileExt;
    let l = match layout(&mut std::io::BufReader::with_capacity(4096, file), meta)? {
        Plan::Hound(r) => return r,
        Plan::Frames(l) => l,
    };
    let per_block = l.per_block(1 << 18);
    l.decode(per_block, |outs| {
        outs.into_par_iter()
            .enumerate()
            .map_init(Vec::new, |buf: &mut Vec<u8>, (k, mut outs)| {
                buf.resize(outs[0].len() * l.frame, 0);
                let at = l.start + (k * per_block * l.frame) as u64;
                file.read_exact_at(buf, at).map_err(|e| {
                    if e.kind() == std::io::ErrorKind::UnexpectedEof {
                        short_data()
                    } else {
                        RecordingError::Io {
                            path: String::new(),
                            source: e,
                        }
                    }
                })?;
                Ok(l.decode_block(buf, &mut outs))
            })
            // every block is decoded unless one fails to read: `decode`
            // then takes all the channels' values as written
            .try_reduce(|| true, |a, b| Ok(a & b))
    })
}

/// [`read_signals_bytes`] of the whole file where `pread` is not at hand.
#[cfg(not(unix))]
fn read_signals_file(file: &std::fs::File, meta: &Meta) -> Result<Signals, RecordingError> {
    let mut bytes = Vec::new();
    (&*file)
        .read_to_end(&mut bytes)
        .map_err(|source| RecordingError::Io {
            path: String::new(),
            source,
        })?;
    read_signals_slice(&bytes, meta)
}

/// [`read_signals`] on a seekable source (a file, bytes): the samples are
/// decoded block by block straight into the channels, so the WAV bytes are
/// never held whole. `RecordingError::Io` (empty path) when reading fails.
pub fn read_signals_seek<R: Read + Seek>(
    mut src: R,
    meta: &Meta,
) -> Result<Signals, RecordingError> {
    let io_err = |source: std::io::Error| RecordingError::Io {
        path: String::new(),
        source,
    };
    let l = match layout(&mut src, meta)? {
        Plan::Hound(r) => return r,
        Plan::Frames(l) => l,
    };
    src.seek(std::io::SeekFrom::Start(l.start))
        .map_err(io_err)?;
    let per_block = l.per_block(1 << 20);
    let mut block = vec![0u8; per_block.min(l.frames) * l.frame];
    l.decode(per_block, |outs| {
        let mut ok = true;
        for mut outs in outs {
            let buf = &mut block[..outs[0].len() * l.frame];
            src.read_exact(buf).map_err(|e| {
                if e.kind() == std::io::ErrorKind::UnexpectedEof {
                    short_data()
                } else {
                    io_err(e)
                }
            })?;
            ok &= l.decode_block(buf, &mut outs);
        }
        Ok(ok)
    })
}

/// [`read_signals`] on the bytes of a whole WAV file held in memory (the
/// API's import): the samples are decoded from the bytes in place, in blocks of 256 kB side by side on rayon's pool,
/// each straight into its part of the channels. The same values as
/// [`read_signals_seek`], sample for sample.
fn read_signals_slice(wav: &[u8], meta: &Meta) -> Result<Signals, RecordingError> {
    let mut cur = std::io::Cursor::new(wav);
    let l = match layout(&mut cur, meta)? {
        Plan::Hound(r) => return r,
        Plan::Frames(l) => l,
    };
    let data = &wav[l.start as usize..];
    let per_block = l.per_block(1 << 18);
    l.decode(per_block, |outs| {
        use rayon::prelude::*;
        Ok(outs
            .into_par_iter()
            .enumerate()
            .map(|(k, mut outs)| {
                let at = k * per_block * l.frame;
                l.decode_block(&data[at..at + outs[0].len() * l.frame], &mut outs)
            })
            // every block is decoded (no short cut): `decode` then takes
            // all the channels' values as written
            .reduce(|| true, |a, b| a & b))
    })
}

fn short_data() -> RecordingError {
    RecordingError::Wav {
        path: String::new(),
        reason: "data chunk shorter than its header says".into(),
    }
}

/// How a WAV's samples are read: whole frames of plain samples
/// ([`Frames`]), or sample by sample through hound (done already).
enum Plan {
    Frames(Frames),
    Hound(Result<Signals, RecordingError>),
}

/// A WAV of plain frames (every channel's sample in a container of its
/// size, little-endian) and the channels to take from it.
struct Frames {
    spec: hound::WavSpec,
    /// Byte offset of the first sample.
    start: u64,
    frames: usize,
    /// Bytes of a sample and of a frame.
    bytes: usize,
    frame: usize,
    is_pcm: bool,
    /// (byte offset in a frame, gain) of each channel read: displacement,
    /// microphone, drive when meta.json names it.
    picks: Vec<(usize, f64)>,
}

/// Reads the WAV header, checks it against `meta` and plans the reading;
/// `src` is left somewhere after the header. Unusual layouts (8-bit
/// unsigned, padded containers) are read through hound at once.
fn layout<R: Read + Seek>(src: &mut R, meta: &Meta) -> Result<Plan, RecordingError> {
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
        let r = hound::WavReader::new(&mut *src).map_err(|e| wav_err(e.to_string()))?;
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
        return Ok(Plan::Hound(read_with_hound(r, meta, nch, is_pcm, scale)));
    }
    let frame = nch * bytes;
    let end = src.seek(SeekFrom::End(0)).map_err(io_err)?;
    if end.saturating_sub(start) < frames as u64 * frame as u64 {
        return Err(short_data());
    }
    let full = if is_pcm {
        (1u64 << (spec.bits_per_sample - 1)) as f64
    } else {
        1.0
    };
    let gain = |s: Option<f64>| s.unwrap_or(1.0) / full;
    let picks = [
        Some((ch.displacement, scale.displacement)),
        Some((ch.microphone, scale.microphone)),
        ch.drive.map(|c| (c, scale.drive)),
    ]
    .into_iter()
    .flatten()
    .map(|(c, s)| (c * bytes, gain(s)))
    .collect();
    Ok(Plan::Frames(Frames {
        spec,
        start,
        frames,
        bytes,
        frame,
        is_pcm,
        picks,
    }))
}

/// Each channel's part of one block of frames, in the order of `picks`.
type BlockOuts<'a> = Vec<&'a mut [MaybeUninit<f64>]>;

impl Frames {
    /// Frames in a block of about `size` bytes (at least one frame).
    fn per_block(&self, size: usize) -> usize {
        (size / self.frame).max(1)
    }

    /// The channels: `fill` gets every block's parts of the channels (blocks
    /// of `per_block` frames, in order) and writes every value of them, or
    /// fails; it says whether all values were finite.
    fn decode(
        &self,
        per_block: usize,
        fill: impl FnOnce(Vec<BlockOuts<'_>>) -> Result<bool, RecordingError>,
    ) -> Result<Signals, RecordingError> {
        let mut chans: Vec<Vec<f64>> = self
            .picks
            .iter()
            .map(|_| Vec::with_capacity(self.frames))
            .collect();
        let all_finite = {
            let mut parts: Vec<_> = chans
                .iter_mut()
                .map(|c| c.spare_capacity_mut()[..self.frames].chunks_mut(per_block))
                .collect();
            let blocks = self.frames.div_ceil(per_block);
            let outs: Vec<BlockOuts<'_>> = (0..blocks)
                .map(|_| parts.iter_mut().filter_map(|p| p.next()).collect())
                .collect();
            fill(outs)?
        };
        for c in chans.iter_mut() {
            // SAFETY: `fill` returned Ok, so it wrote every value of every
            // block, and the blocks cover the first `frames` values.
            unsafe { c.set_len(self.frames) };
        }
        let mut it = chans.into_iter();
        let displacement_m = it.next().unwrap_or_default();
        let microphone_v = it.next().unwrap_or_default();
        let sig = Signals {
            // The file's rate: meta.json may state it within 1e-6 (checked
            // in `layout`), the samples were taken at the WAV's integer rate
            // (tests/fuzz.rs found 8000.0000001 read here and refused by
            // storage at 8000).
            sample_rate_hz: self.spec.sample_rate as f64,
            displacement_m,
            microphone_v,
            drive_v: it.next(),
        };
        if !all_finite {
            // The message names the channel and the sample.
            sig.validate("recording")?;
        }
        Ok(sig)
    }

    /// Decodes the frames in `buf` into each channel's part of the block
    /// (as many values as `buf` has frames); false if any value is not
    /// finite.
    fn decode_block(&self, buf: &[u8], outs: &mut [&mut [MaybeUninit<f64>]]) -> bool {
        let mut ok = true;
        for (&(o, g), out) in self.picks.iter().zip(outs.iter_mut()) {
            // One loop per sample format (the format's match hoisted out of
            // the per-sample loop); finiteness is checked while the block is
            // in cache.
            let frame = self.frame;
            ok &= match (self.is_pcm, self.bytes) {
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
        }
        ok
    }
}

/// Writes `gain * conv(sample)` for the sample at byte `off` of each
/// `frame`-byte frame of `buf` into `out` (one value a frame; a fixed-size
/// sample: one bounds check per frame); false if any value is not finite (a
/// float NaN or infinity, or a scale that overflows).
fn decode_into<const B: usize>(
    out: &mut [MaybeUninit<f64>],
    buf: &[u8],
    frame: usize,
    off: usize,
    gain: f64,
    conv: impl Fn([u8; B]) -> f64,
) -> bool {
    assert_eq!(out.len() * frame, buf.len(), "one value a frame");
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
            for (o, f) in out.iter_mut().zip(buf.chunks_exact(frame)) {
                let b: [u8; B] = f[off..off + B].try_into().expect("B bytes");
                let v = conv(b) * gain;
                ok &= v.is_finite();
                o.write(v);
            }
            ok
        }
    }
}

/// [`decode_into`] for frames of `F` bytes: the same conversion, sample for
/// sample.
fn decode_frames<const B: usize, const F: usize>(
    out: &mut [MaybeUninit<f64>],
    buf: &[u8],
    off: usize,
    gain: f64,
    conv: impl Fn([u8; B]) -> f64,
) -> bool {
    assert!(off + B <= F, "a sample inside its frame");
    let mut ok = true;
    for (o, f) in out.iter_mut().zip(buf.chunks_exact(F)) {
        let b: [u8; B] = f[off..off + B].try_into().expect("B bytes");
        let v = conv(b) * gain;
        ok &= v.is_finite();
        o.write(v);
    }
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

    /// The bytes in memory and a file (each block read at its offset) are
    /// decoded in 256 kB blocks side by side, a reader in 1 MiB blocks one
    /// after the other: the same values bit for bit, over many blocks and a
    /// short last one, and the same error naming a bad sample in a later
    /// block.
    #[test]
    fn blocks_side_by_side_read_as_the_stream_does() {
        let n = 150_001; // 1.8 MB of float frames: 7 blocks of 256 kB
        let dir = tempfile::tempdir().unwrap();
        let set = RecordingSet {
            meta: Meta::standard(0.05, 48000.0),
            pre: sig(n),
            main: sig(n / 3),
        };
        set.write_dir(dir.path()).unwrap();
        let wav = std::fs::read(dir.path().join("pre.wav")).unwrap();
        let meta = &set.meta;
        let stream = read_signals(std::io::Cursor::new(&wav), meta).unwrap();
        let bytes = read_signals_bytes(&wav, meta).unwrap();
        let from_file = RecordingSet::read_dir(dir.path()).unwrap();
        assert_eq!(stream.len(), n);
        for s in [&bytes, &from_file.pre] {
            for (a, b) in [
                (&stream.displacement_m, &s.displacement_m),
                (&stream.microphone_v, &s.microphone_v),
                (
                    stream.drive_v.as_ref().unwrap(),
                    s.drive_v.as_ref().unwrap(),
                ),
            ] {
                assert_eq!(a.len(), b.len());
                assert!(a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits()));
            }
        }
        assert_eq!(from_file.main.len(), n / 3);
        // 24-bit PCM, two channels (6-byte frames), scaled
        let spec = hound::WavSpec {
            channels: 2,
            sample_rate: 48000,
            bits_per_sample: 24,
            sample_format: hound::SampleFormat::Int,
        };
        let mut cur = std::io::Cursor::new(Vec::new());
        {
            let mut w = hound::WavWriter::new(&mut cur, spec).unwrap();
            for k in 0..n as i32 {
                w.write_sample((k * 37) % (1 << 23) - (1 << 22)).unwrap();
                w.write_sample(-(k % 5000)).unwrap();
            }
            w.finalize().unwrap();
        }
        let pcm = cur.into_inner();
        let meta: Meta = serde_json::from_str(
            r#"{"moving_mass_kg":0.1,"sample_rate_hz":48000,"channels":{"displacement":0,"microphone":1},
                "channel_scale":{"displacement":0.02,"microphone":3.0}}"#,
        )
        .unwrap();
        let a = read_signals(std::io::Cursor::new(&pcm), &meta).unwrap();
        let b = read_signals_bytes(&pcm, &meta).unwrap();
        assert_eq!(a, b);
        let file = |bytes: &[u8]| {
            let p = dir.path().join("other.wav");
            std::fs::write(&p, bytes).unwrap();
            std::fs::File::open(&p).unwrap()
        };
        assert_eq!(read_signals_file(&file(&pcm), &meta).unwrap(), a);
        assert_eq!(
            a.displacement_m[1],
            (37 - (1 << 22)) as f64 * 0.02 / (1 << 23) as f64
        );
        // a NaN in the sixth block: named by sample, both ways
        let mut bad = set.pre.clone();
        bad.microphone_v[140_000] = f64::NAN;
        let wav = signals_to_wav_bytes(&bad).unwrap();
        let e1 = read_signals(std::io::Cursor::new(&wav), &set.meta)
            .unwrap_err()
            .to_string();
        let e2 = read_signals_bytes(&wav, &set.meta).unwrap_err().to_string();
        assert!(
            e1.contains("microphone") && e1.contains("sample 140000"),
            "{e1}"
        );
        assert_eq!(e1, e2);
        let e3 = read_signals_file(&file(&wav), &set.meta).unwrap_err();
        assert_eq!(e3.to_string(), e2);
        // a data chunk cut short: refused, not read past its end
        let cut = &wav[..wav.len() - 5];
        let e = read_signals_bytes(cut, &set.meta).unwrap_err().to_string();
        assert!(e.contains("shorter than its header"), "{e}");
        let e4 = read_signals_file(&file(cut), &set.meta).unwrap_err();
        assert_eq!(e4.to_string(), e);
        // and cut inside the header: the same message both ways
        for at in [30, 44] {
            let e = read_signals_bytes(&wav[..at], &set.meta).unwrap_err();
            let f = read_signals_file(&file(&wav[..at]), &set.meta).map_err(in_memory_io);
            assert_eq!(f.unwrap_err().to_string(), e.to_string());
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
