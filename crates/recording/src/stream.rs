//! An imported WAV file stored without holding the recording in memory
//! (issue 11): read block by block, laid out in the standard channel order
//! (0 displacement, 1 microphone, 2 drive when present) and written at its
//! own resolution to a file, in the form [`super::codec`] keeps it:
//!
//! - integer PCM of 8 to 24 bits, and float32 whose samples are all 24-bit
//!   codes of the channel scales: FLAC, encoded frame by frame, then decoded
//!   again and compared code by code with a second pass over the WAV;
//! - anything else (float32 off that grid, int32): a WAV of the same format
//!   holding the very same samples.
//!
//! The stored form decodes (with the returned channel scale) to exactly the
//! `f64` samples [`super::read_signals`] reads from the file. Memory: one
//! block of [`BLOCK`] frames, whatever the length of the file.

use super::codec::SampleFormat;
use super::{ChannelScale, Meta, RecordingError};
use flacenc::component::{BitRepr, Stream, StreamInfo};
use flacenc::error::Verify;
use flacenc::source::{Context, Fill, FrameBuf};
use std::fs::File;
use std::io::{BufReader, BufWriter, Write};
use std::path::Path;

/// Frames per block (also the FLAC block size).
pub const BLOCK: usize = 4096;

/// What was written: the stored form's facts.
#[derive(Debug, Clone, PartialEq)]
pub struct Streamed {
    pub sample_rate_hz: f64,
    pub frames: u64,
    /// Stored channels (2 or 3).
    pub channels: usize,
    /// Physical value of full scale per stored channel (all set).
    pub channel_scale: ChannelScale,
    /// `true` for FLAC, `false` for a WAV of the imported format.
    pub flac: bool,
}

fn wav_err(reason: impl ToString) -> RecordingError {
    RecordingError::Wav {
        path: String::new(),
        reason: reason.to_string(),
    }
}

fn invalid(m: impl Into<String>) -> RecordingError {
    RecordingError::Invalid(m.into())
}

fn io(e: std::io::Error) -> RecordingError {
    RecordingError::Io {
        path: String::new(),
        source: e,
    }
}

/// The WAV file as read: which file channel feeds which stored channel.
struct Input {
    reader: hound::WavReader<BufReader<File>>,
    format: SampleFormat,
    /// File channel of each stored channel.
    pick: Vec<usize>,
    nch_file: usize,
    frames: u64,
    rate: u32,
    /// Frames read so far.
    done: u64,
}

impl Input {
    fn open(path: &Path, meta: &Meta) -> Result<Input, RecordingError> {
        let f = File::open(path).map_err(io)?;
        let reader = hound::WavReader::new(BufReader::new(f)).map_err(wav_err)?;
        let spec = reader.spec();
        let nch_file = spec.channels as usize;
        // The same checks, in the same words, as read_signals.
        if (spec.sample_rate as f64 - meta.sample_rate_hz).abs() > 1e-6 * meta.sample_rate_hz {
            return Err(invalid(format!(
                "sample rate {} Hz differs from meta.json's sample_rate_hz {}",
                spec.sample_rate, meta.sample_rate_hz
            )));
        }
        let ch = meta.channels;
        let mut pick = vec![ch.displacement, ch.microphone];
        pick.extend(ch.drive);
        for (name, i) in ["displacement", "microphone", "drive"].iter().zip(&pick) {
            if *i >= nch_file {
                return Err(invalid(format!(
                    "meta.json puts the {name} signal on channel {i}, but the file has only {nch_file} channel(s)"
                )));
            }
        }
        let format = match (spec.sample_format, spec.bits_per_sample) {
            (hound::SampleFormat::Float, 32) => SampleFormat::Float32,
            (hound::SampleFormat::Int, b @ (8 | 16 | 24 | 32)) => SampleFormat::Int(b as u32),
            (f, b) => {
                return Err(wav_err(format!(
                    "unsupported sample format {f:?} with {b} bits"
                )))
            }
        };
        let scale = meta.channel_scale.unwrap_or_default();
        if matches!(format, SampleFormat::Int(_)) && scale.displacement.is_none() {
            return Err(invalid(
                "PCM file: meta.json needs channel_scale.displacement (metres per full scale) to read the laser channel",
            ));
        }
        let frames = reader.duration() as u64;
        if reader.len() as u64 != frames * nch_file as u64 {
            return Err(wav_err("data chunk ends inside a frame"));
        }
        Ok(Input {
            reader,
            format,
            pick,
            nch_file,
            frames,
            rate: spec.sample_rate,
            done: 0,
        })
    }

    /// The next block of integer samples (PCM), stored layout, interleaved.
    fn next_int(
        &mut self,
        out: &mut Vec<i32>,
        raw: &mut Vec<i32>,
    ) -> Result<usize, RecordingError> {
        raw.clear();
        for v in self.reader.samples::<i32>().take(BLOCK * self.nch_file) {
            raw.push(v.map_err(wav_err)?);
        }
        Ok(self.lay_out(raw, out))
    }

    /// The next block of float samples, stored layout, interleaved.
    fn next_f32(
        &mut self,
        out: &mut Vec<f32>,
        raw: &mut Vec<f32>,
    ) -> Result<usize, RecordingError> {
        raw.clear();
        for v in self.reader.samples::<f32>().take(BLOCK * self.nch_file) {
            raw.push(v.map_err(wav_err)?);
        }
        let n = self.lay_out(raw, out);
        // As read_signals: a NaN or infinity in a used channel is refused
        // (found by tests/fuzz.rs: it was stored).
        if let Some(i) = out.iter().position(|v| !v.is_finite()) {
            let names = ["displacement", "microphone", "drive"];
            return Err(invalid(format!(
                "recording: {} channel has a non-finite sample (NaN or infinity) at sample {}",
                names[i % self.pick.len()],
                self.done - n as u64 + (i / self.pick.len()) as u64
            )));
        }
        Ok(n)
    }

    fn lay_out<T: Copy>(&mut self, raw: &[T], out: &mut Vec<T>) -> usize {
        out.clear();
        let n = raw.len() / self.nch_file;
        self.done += n as u64;
        for f in raw.chunks_exact(self.nch_file) {
            out.extend(self.pick.iter().map(|&c| f[c]));
        }
        n
    }
}

/// Physical value of full scale per stored channel (1 where meta.json has none).
fn gains(meta: &Meta, n: usize) -> Vec<f64> {
    let s = meta.channel_scale.unwrap_or_default();
    [s.displacement, s.microphone, s.drive][..n]
        .iter()
        .map(|g| g.unwrap_or(1.0))
        .collect()
}

/// Frames and rate from a WAV header (nothing else read).
pub fn wav_frames(path: &Path) -> Result<(u64, u32), RecordingError> {
    let f = File::open(path).map_err(io)?;
    let r = hound::WavReader::new(BufReader::new(f)).map_err(wav_err)?;
    Ok((r.duration() as u64, r.spec().sample_rate))
}

/// Stores the WAV at `wav` (read with `meta`, as [`super::read_signals`]
/// does) into `out`; `scratch` is a file name for the FLAC frames while the
/// header is not yet known (removed).
pub fn store_wav(
    wav: &Path,
    meta: &Meta,
    out: &Path,
    scratch: &Path,
) -> Result<Streamed, RecordingError> {
    let input = Input::open(wav, meta)?;
    if input.frames == 0 {
        return Err(invalid("the recording has no samples"));
    }
    let nch = input.pick.len();
    let g = gains(meta, nch);
    let channel_scale = ChannelScale {
        displacement: Some(g[0]),
        microphone: Some(g[1]),
        drive: g.get(2).copied(),
    };
    let facts = |flac| Streamed {
        sample_rate_hz: input.rate as f64,
        frames: input.frames,
        channels: nch,
        channel_scale,
        flac,
    };
    let flac_bits = match input.format {
        SampleFormat::Int(b) if (8..=24).contains(&b) => Some(b),
        SampleFormat::Float32 => Some(24),
        SampleFormat::Int(_) => None,
    };
    let res = match flac_bits {
        Some(bits) => {
            let r = encode_flac(wav, meta, bits, &g, out, scratch);
            let _ = std::fs::remove_file(scratch);
            match r {
                Ok(()) => Ok(facts(true)),
                // float32 off the 24-bit grid: kept as float32 WAV
                Err(None) => write_wav(wav, meta, out).map(|_| facts(false)),
                Err(Some(e)) => Err(e),
            }
        }
        None => write_wav(wav, meta, out).map(|_| facts(false)),
    };
    if res.is_err() {
        let _ = std::fs::remove_file(out);
    }
    res
}

/// Code of a float sample on the `full`-code grid of gain `g`, as
/// `codec::codes` computes it; `None` off the grid.
fn float_code(f: f32, g: f64, full: f64) -> Option<i32> {
    let v = f as f64 * g;
    let code = (v / g * full).round();
    ((-full..full).contains(&code) && code / full * g == v).then_some(code as i32)
}

/// The codes of the next block (FLAC input); `Err(None)` for a float sample
/// off the grid.
struct Codes {
    input: Input,
    bits: u32,
    g: Vec<f64>,
    ibuf: (Vec<i32>, Vec<i32>),
    fbuf: (Vec<f32>, Vec<f32>),
}

impl Codes {
    fn next(&mut self, out: &mut Vec<i32>) -> Result<usize, Option<RecordingError>> {
        out.clear();
        match self.input.format {
            SampleFormat::Int(_) => {
                let n = self.input.next_int(&mut self.ibuf.0, &mut self.ibuf.1)?;
                out.extend_from_slice(&self.ibuf.0);
                Ok(n)
            }
            SampleFormat::Float32 => {
                let n = self.input.next_f32(&mut self.fbuf.0, &mut self.fbuf.1)?;
                let full = (1u64 << (self.bits - 1)) as f64;
                let nch = self.g.len();
                for (k, f) in self.fbuf.0.iter().enumerate() {
                    out.push(float_code(*f, self.g[k % nch], full).ok_or(None)?);
                }
                Ok(n)
            }
        }
    }
}

fn flac_err(e: impl std::fmt::Debug) -> Option<RecordingError> {
    Some(invalid(format!("FLAC encoder: {e:?}")))
}

fn encode_flac(
    wav: &Path,
    meta: &Meta,
    bits: u32,
    g: &[f64],
    out: &Path,
    scratch: &Path,
) -> Result<(), Option<RecordingError>> {
    let codes = |path: &Path| -> Result<Codes, Option<RecordingError>> {
        Ok(Codes {
            input: Input::open(path, meta)?,
            bits,
            g: g.to_vec(),
            ibuf: Default::default(),
            fbuf: Default::default(),
        })
    };
    let mut src = codes(wav)?;
    let nch = g.len();
    let rate = src.input.rate as usize;
    if !(1..=655_350).contains(&rate) {
        return Err(Some(invalid(format!(
            "sample rate {rate} Hz cannot be stored in FLAC"
        ))));
    }
    let mut cfg = flacenc::config::Encoder::default();
    cfg.multithread = false;
    cfg.block_size = BLOCK;
    let cfg = cfg.into_verified().map_err(flac_err)?;
    let mut info = StreamInfo::new(rate, nch, bits as usize).map_err(flac_err)?;
    let mut fb = (
        FrameBuf::with_size(nch, BLOCK).map_err(flac_err)?,
        Context::new(bits as usize, nch),
    );
    let mut frames_out = BufWriter::new(File::create(scratch).map_err(io)?);
    let mut sink = flacenc::bitsink::ByteSink::new();
    let mut block = Vec::with_capacity(BLOCK * nch);
    loop {
        let n = src.next(&mut block)?;
        if n == 0 {
            break;
        }
        fb.fill_interleaved(&block).map_err(flac_err)?;
        let number = fb.1.current_frame_number().unwrap_or(0);
        let frame =
            flacenc::encode_fixed_size_frame(&cfg, &fb.0, number, &info).map_err(flac_err)?;
        info.update_frame_info(&frame);
        sink.clear();
        frame.write(&mut sink).map_err(flac_err)?;
        frames_out.write_all(sink.as_slice()).map_err(io)?;
    }
    frames_out.flush().map_err(io)?;
    drop(frames_out);
    // STREAMINFO: fixed block size (its minimum excludes the short last block).
    info.set_block_sizes(BLOCK, BLOCK).map_err(flac_err)?;
    info.set_md5_digest(&fb.1.md5_digest());
    let header = Stream::with_stream_info(info);
    sink.clear();
    header.write(&mut sink).map_err(flac_err)?;
    {
        let mut w = BufWriter::new(File::create(out).map_err(io)?);
        w.write_all(sink.as_slice()).map_err(io)?;
        let mut r = BufReader::new(File::open(scratch).map_err(io)?);
        std::io::copy(&mut r, &mut w).map_err(io)?;
        w.flush().map_err(io)?;
    }
    // Decode what was written and compare with a second pass over the WAV.
    let mut again = codes(wav)?;
    let f = File::open(out).map_err(io)?;
    let mut dec = claxon::FlacReader::new(BufReader::new(f))
        .map_err(|e| Some(wav_err(format!("FLAC: {e}"))))?;
    let mut blocks = dec.blocks();
    let mut buf = Vec::new();
    let mut total = 0u64;
    loop {
        let n = again.next(&mut block)?;
        let b = blocks
            .read_next_or_eof(std::mem::take(&mut buf))
            .map_err(|e| Some(wav_err(format!("FLAC: {e}"))))?;
        match b {
            None if n == 0 => break,
            Some(b) if b.duration() as usize == n && b.channels() as usize == nch => {
                for i in 0..n {
                    for c in 0..nch {
                        if b.sample(c as u32, i as u32) != block[i * nch + c] {
                            return Err(Some(invalid(
                                "the recording does not survive storage bit for bit (not stored)",
                            )));
                        }
                    }
                }
                total += n as u64;
                buf = b.into_buffer();
            }
            _ => {
                return Err(Some(invalid(
                    "the recording does not survive storage bit for bit (not stored)",
                )))
            }
        }
    }
    if total != again.input.frames {
        return Err(Some(invalid("stored FLAC has another length than the WAV")));
    }
    Ok(())
}

/// The samples as they are, in the stored layout, as a WAV of their format.
fn write_wav(wav: &Path, meta: &Meta, out: &Path) -> Result<(), RecordingError> {
    let mut input = Input::open(wav, meta)?;
    let nch = input.pick.len();
    let (bits, fmt) = match input.format {
        SampleFormat::Float32 => (32, hound::SampleFormat::Float),
        SampleFormat::Int(b) => (b as u16, hound::SampleFormat::Int),
    };
    let spec = hound::WavSpec {
        channels: nch as u16,
        sample_rate: input.rate,
        bits_per_sample: bits,
        sample_format: fmt,
    };
    let f = BufWriter::new(File::create(out).map_err(io)?);
    let mut w = hound::WavWriter::new(f, spec).map_err(wav_err)?;
    match input.format {
        SampleFormat::Float32 => {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            while input.next_f32(&mut a, &mut b)? > 0 {
                for v in &a {
                    w.write_sample(*v).map_err(wav_err)?;
                }
            }
        }
        SampleFormat::Int(_) => {
            let (mut a, mut b) = (Vec::new(), Vec::new());
            while input.next_int(&mut a, &mut b)? > 0 {
                for v in &a {
                    w.write_sample(*v).map_err(wav_err)?;
                }
            }
        }
    }
    w.finalize().map_err(wav_err)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec;

    fn write(path: &Path, spec: hound::WavSpec, n: usize, f: impl Fn(usize, usize) -> f64) {
        let mut w = hound::WavWriter::create(path, spec).unwrap();
        for k in 0..n {
            for c in 0..spec.channels as usize {
                let v = f(k, c);
                match spec.sample_format {
                    hound::SampleFormat::Float => w.write_sample(v as f32).unwrap(),
                    hound::SampleFormat::Int => w.write_sample(v as i32).unwrap(),
                }
            }
        }
        w.finalize().unwrap();
    }

    #[allow(clippy::type_complexity)]
    /// The stored file decodes to exactly what `read_signals` reads, for
    /// PCM 16/24 (FLAC), float on and off the 24-bit grid, int32 (WAV),
    /// another channel order, lengths around the block size.
    #[test]
    fn stored_file_decodes_to_what_read_signals_reads() {
        let dir = tempfile::tempdir().unwrap();
        let (wav, out, scratch) = (
            dir.path().join("in.wav"),
            dir.path().join("out"),
            dir.path().join("scratch"),
        );
        let spec = |bits: u16, fmt| hound::WavSpec {
            channels: 3,
            sample_rate: 8000,
            bits_per_sample: bits,
            sample_format: fmt,
        };
        let mut pcm_meta = Meta::standard(0.05, 8000.0);
        pcm_meta.channels.displacement = 2;
        pcm_meta.channels.drive = Some(0);
        pcm_meta.channel_scale = Some(ChannelScale {
            displacement: Some(0.02),
            microphone: Some(10.0),
            drive: None,
        });
        let float_meta = Meta::standard(0.05, 8000.0);
        let noise = |k: usize, c: usize| ((k * 7919 + c * 104729) % 2001) as f64 - 1000.0;
        let cases: Vec<(
            hound::WavSpec,
            &Meta,
            usize,
            Box<dyn Fn(usize, usize) -> f64>,
            bool,
        )> = vec![
            (
                spec(16, hound::SampleFormat::Int),
                &pcm_meta,
                5000,
                Box::new(move |k, c| noise(k, c) * 20.0),
                true,
            ),
            (
                spec(24, hound::SampleFormat::Int),
                &pcm_meta,
                2 * BLOCK + 7,
                Box::new(move |k, c| noise(k, c) * 4000.0),
                true,
            ),
            (
                spec(32, hound::SampleFormat::Float),
                &float_meta,
                3000,
                Box::new(move |k, c| noise(k, c) / (1u64 << 23) as f64),
                true,
            ),
            (
                spec(32, hound::SampleFormat::Float),
                &float_meta,
                3000,
                Box::new(move |k, c| 1e-3 * (k as f64 * 0.1 + c as f64).sin()),
                false,
            ),
            (
                spec(32, hound::SampleFormat::Int),
                &pcm_meta,
                1000,
                Box::new(move |k, c| noise(k, c) * 1e6),
                false,
            ),
            (
                spec(24, hound::SampleFormat::Int),
                &pcm_meta,
                5,
                Box::new(noise),
                true,
            ),
        ];
        for (i, (sp, meta, n, f, flac)) in cases.into_iter().enumerate() {
            write(&wav, sp, n, f);
            let read = crate::read_signals(File::open(&wav).unwrap(), meta).unwrap();
            let st =
                store_wav(&wav, meta, &out, &scratch).unwrap_or_else(|e| panic!("case {i}: {e}"));
            assert_eq!(st.flac, flac, "case {i}");
            assert_eq!(st.frames, n as u64);
            let bytes = std::fs::read(&out).unwrap();
            let back = codec::decode(&bytes, Some(&st.channel_scale)).unwrap();
            assert_eq!(back, read, "case {i}");
            assert!(!scratch.exists());
        }
        // Errors, not panics: no samples, a rate meta.json does not state;
        // nothing is left at `out`.
        std::fs::remove_file(&out).unwrap();
        write(&wav, spec(16, hound::SampleFormat::Int), 0, |_, _| 0.0);
        assert!(store_wav(&wav, &pcm_meta, &out, &scratch).is_err());
        write(&wav, spec(16, hound::SampleFormat::Int), 10, |_, _| 0.0);
        let other = Meta {
            sample_rate_hz: 9000.0,
            ..pcm_meta.clone()
        };
        assert!(store_wav(&wav, &other, &out, &scratch)
            .unwrap_err()
            .to_string()
            .contains("differs"));
        assert!(!out.exists());
    }
}
