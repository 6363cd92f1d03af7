//! Fuzzing harness for the parsers that take outside input, on stable Rust
//! (decision 0013a): seeded random mutation of the corpus in
//! `fuzz/corpus/<target>/`, every input run under `catch_unwind`. A panic
//! writes the input to `fuzz/artifacts/<target>/` and fails the test with the
//! seed and the iteration.
//!
//! `cargo test` runs a short pass (`SPRINGBENCH_FUZZ_ITERS`, default 2 000
//! inputs per target). The long run (figures in `docs/fuzzing.md`):
//!
//! ```sh
//! SPRINGBENCH_FUZZ_ITERS=1000000 cargo test --release --test it fuzz:: -- --nocapture --test-threads=1
//! ```
//!
//! `SPRINGBENCH_FUZZ_SEED=N` picks another random stream; `SPRINGBENCH_FUZZ_WRITE_CORPUS=1`
//! rewrites the generated seed files of the corpus.
//!
//! Adding a target: a `fn(&[u8])` that feeds the bytes to the parser the way
//! the daemon does, a seed list in `seeds()`, a `#[test]` calling `fuzz()`.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde_json::{json, Value};
use springbench::bench::laser::{self, ascii_lines, keyence, optoncdt, ProtocolConfig, Reading};
use springbench::recording::codec::{self, Resolution, SampleFormat};
use springbench::recording::RecordingSetFiles;
use springbench::recording::{self as rec, ChannelScale, Meta, Signals};
use std::path::{Path, PathBuf};
use std::time::Instant;

const MAX_INPUT: usize = 1 << 16;

fn corpus_dir(target: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("fuzz/corpus")
        .join(target)
}

fn iters() -> u64 {
    std::env::var("SPRINGBENCH_FUZZ_ITERS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2_000)
}

fn seed() -> u64 {
    std::env::var("SPRINGBENCH_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(11)
}

// ---------------------------------------------------------------- targets

fn small_signals(n: usize, drive: bool) -> Signals {
    let r = Resolution {
        bits: 16,
        scale: ChannelScale {
            displacement: Some(0.02),
            microphone: Some(10.0),
            drive: Some(100.0),
        },
    };
    let q = |fs: Option<f64>, v: f64| Resolution::quantise(r.bits, fs.unwrap(), v);
    Signals {
        sample_rate_hz: 8000.0,
        displacement_m: (0..n)
            .map(|i| q(r.scale.displacement, 1e-3 * (i as f64 * 0.05).sin()))
            .collect(),
        microphone_v: (0..n)
            .map(|i| q(r.scale.microphone, 0.5 * (i as f64 * 0.07).cos()))
            .collect(),
        drive_v: drive.then(|| {
            (0..n)
                .map(|i| q(r.scale.drive, 3.0 * (i as f64 * 0.05).sin()))
                .collect()
        }),
    }
}

fn metas() -> Vec<Meta> {
    let mut pcm = Meta::standard(0.05, 8000.0);
    pcm.channel_scale = Some(ChannelScale {
        displacement: Some(0.02),
        microphone: None,
        drive: Some(100.0),
    });
    let mut two = Meta::standard(0.05, 8000.0);
    two.channels.drive = None;
    two.channels.displacement = 1;
    two.channels.microphone = 0;
    vec![Meta::standard(0.05, 8000.0), pcm, two]
}

/// A WAV as `read_signals` gets it from an import or a recording set.
fn target_wav(data: &[u8]) {
    for meta in metas() {
        let _ = rec::read_signals(std::io::Cursor::new(data), &meta);
    }
    let _ = codec::wav_format(data);
}

/// meta.json text.
fn target_meta(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    if let Ok(m) = rec::parse_meta(&text) {
        // What is accepted serialises again and reads back the same (to one
        // part in 1e15: serde_json's default float parsing is not correctly
        // rounded for long decimals, docs/fuzzing.md).
        let again = rec::parse_meta(&serde_json::to_string(&m).unwrap()).unwrap();
        let close = |a: f64, b: f64| a == b || (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
        assert!(close(again.moving_mass_kg, m.moving_mass_kg));
        assert!(close(again.sample_rate_hz, m.sample_rate_hz));
        assert_eq!(again.channels, m.channels);
        let sc = |c: Option<rec::ChannelScale>| {
            let c = c.unwrap_or_default();
            [c.displacement, c.microphone, c.drive]
        };
        for (a, b) in sc(again.channel_scale).iter().zip(sc(m.channel_scale)) {
            match (a, b) {
                (Some(a), Some(b)) => assert!(close(*a, b)),
                (a, b) => assert_eq!(a.is_some(), b.is_some()),
            }
        }
        assert_eq!(again.extra.len(), m.extra.len());
    }
}

/// A stored recording blob (FLAC or WAV): whole and streamed.
fn target_flac(data: &[u8]) {
    let scale = ChannelScale {
        displacement: Some(0.025),
        microphone: Some(100.0),
        drive: Some(100.0),
    };
    let whole = codec::decode(data, Some(&scale));
    if let Ok(mut st) = codec::WavStream::new(data.to_vec(), Some(scale)) {
        let declared = st.wav_len();
        let mut n = 0u64;
        let mut ok = true;
        for chunk in st.by_ref() {
            match chunk {
                Ok(c) => n += c.len() as u64,
                Err(_) => {
                    ok = false;
                    break;
                }
            }
        }
        if ok {
            // A stream that ends cleanly delivers exactly its Content-Length.
            assert_eq!(n, declared);
            assert!(whole.is_ok());
        }
    }
}

/// A job body as `POST /api/v1/jobs` validates it.
fn target_job(data: &[u8]) {
    thread_local! {
        static CFG: springbench::config::Config = springbench::config::Config::default();
    }
    if let Ok(v) = serde_json::from_slice::<Value>(data) {
        CFG.with(|cfg| {
            if let Ok(spec) = springbench::runner::job::validate(&v, cfg) {
                assert!(spec.moving_mass_kg.is_finite() && spec.moving_mass_kg > 0.0);
                assert!(spec.levels_m.iter().all(|x| x.is_finite() && *x > 0.0));
            }
        });
    }
}

/// A fit body as `POST /api/v1/measurements/{id}/fits` validates it.
fn target_fit(data: &[u8]) {
    if let Ok(v) = serde_json::from_slice::<Value>(data) {
        if let Ok(f) = springbench::api::measurements::fit_request(&v) {
            if let Some(o) = f.order {
                assert!((1..=springbench::runner::job::MAX_ORDER).contains(&o));
            }
        }
    }
}

const BOUNDARY: &str = "sb-fuzz-boundary";

/// A multipart import body: the multipart parser the daemon uses (multer,
/// through axum), then the recording set and its lossless storage.
fn target_multipart(data: &[u8]) {
    thread_local! {
        static RT: tokio::runtime::Runtime = tokio::runtime::Builder::new_current_thread().build().unwrap();
    }
    let body = bytes::Bytes::copy_from_slice(data);
    let fields = RT.with(|rt| {
        rt.block_on(async move {
            let stream = futures_util::stream::once(async move { Ok::<_, std::io::Error>(body) });
            let mut mp = multer::Multipart::new(stream, BOUNDARY);
            let mut fields = std::collections::HashMap::new();
            while let Ok(Some(f)) = mp.next_field().await {
                let name = f.name().unwrap_or("").to_string();
                match f.bytes().await {
                    Ok(b) => {
                        fields.insert(name, b.to_vec());
                    }
                    Err(_) => return None,
                }
            }
            Some(fields)
        })
    });
    let Some(fields) = fields else { return };
    let (Some(meta), Some(pre), Some(main)) =
        (fields.get("meta"), fields.get("pre"), fields.get("main"))
    else {
        return;
    };
    // The daemon's import path (spooled files, stored block by block) agrees
    // with reading the whole set: the same verdict, the same samples stored.
    thread_local! {
        // In memory where the machine has a tmpfs (the target writes and
        // removes six files per input).
        static DIR: tempfile::TempDir = tempfile::tempdir_in("/dev/shm").or_else(|_| tempfile::tempdir()).unwrap();
    }
    let streamed = DIR.with(|d| {
        let (pp, mp) = (d.path().join("pre.wav"), d.path().join("main.wav"));
        std::fs::write(&pp, pre).unwrap();
        std::fs::write(&mp, main).unwrap();
        springbench::api::import::prepare(meta, &pp, &mp, d.path(), &Default::default(), 0).map(
            |p| {
                let back = |(s, f): &(
                    springbench::recording::stream::Streamed,
                    springbench::api::import::Spool,
                )| {
                    codec::decode(&std::fs::read(f.path()).unwrap(), Some(&s.channel_scale))
                        .unwrap()
                };
                (back(&p.pre), back(&p.main))
            },
        )
    });
    match rec::RecordingSet::from_bytes(meta, pre, main) {
        Ok(set) if !set.pre.is_empty() && !set.main.is_empty() => {
            let (a, b) = streamed.expect("what reads is stored by the import path");
            assert_eq!((&a, &b), (&set.pre, &set.main));
        }
        _ => assert!(
            streamed.is_err(),
            "the import path stored what does not read"
        ),
    }
    if let Ok(set) = rec::RecordingSet::from_bytes(meta, pre, main) {
        if set.pre.is_empty() || set.main.is_empty() {
            // Refused at storage ("no samples"), not stored.
            let f = codec::wav_format(pre).unwrap();
            let scale = set.meta.channel_scale.unwrap_or_default();
            let empty = if set.pre.is_empty() {
                &set.pre
            } else {
                &set.main
            };
            assert!(codec::encode_lossless(empty, f, &scale).is_err());
            return;
        }
        let scale = set.meta.channel_scale.unwrap_or_default();
        for (s, wav) in [(&set.pre, pre), (&set.main, main)] {
            let f = codec::wav_format(wav).expect("a WAV that was read has a format");
            let st =
                codec::encode_lossless(s, f, &scale).expect("what was read is stored losslessly");
            assert_eq!(
                &codec::decode(&st.bytes, st.channel_scale.as_ref()).unwrap(),
                s
            );
        }
    }
}

/// The serial laser protocols' configurations the `laser_frames` target picks from.
fn laser_configs() -> Vec<ProtocolConfig> {
    vec![
        ProtocolConfig::Optoncdt(optoncdt::OptoncdtConfig {
            range_m: 0.01,
            counter: true,
            invert: false,
        }),
        ProtocolConfig::Optoncdt(optoncdt::OptoncdtConfig {
            range_m: 0.05,
            counter: false,
            invert: true,
        }),
        ProtocolConfig::Keyence(keyence::KeyenceConfig {
            head: 1,
            unit_m: 1e-3,
            range_m: None,
            invert: false,
        }),
        ProtocolConfig::AsciiLines(ascii_lines::AsciiLinesConfig::default()),
        ProtocolConfig::AsciiLines(ascii_lines::AsciiLinesConfig {
            counter_bits: Some(16),
            ..ascii_lines::AsciiLinesConfig::default()
        }),
    ]
}

/// Bytes from a serial laser (`bench::laser::parse_stream` of each protocol).
/// Byte 0 picks the protocol, byte 1 the chunk size the bytes arrive in, the
/// rest is the stream. Besides no panic: every value is finite, and the
/// readings do not depend on how the bytes were chunked (the parsers keep
/// their partial frame between calls).
fn target_laser_frames(data: &[u8]) {
    let configs = laser_configs();
    let (Some(&sel), Some(&chunk)) = (data.first(), data.get(1)) else {
        return;
    };
    let cfg = &configs[sel as usize % configs.len()];
    let bytes = &data[2..];
    let whole = laser::parse_stream(cfg, bytes);
    let mut p = cfg.build();
    let mut out = Vec::new();
    let mut chunked = Ok(());
    for c in bytes.chunks(1 + chunk as usize % 64) {
        chunked = p.feed(c, &mut out);
        if chunked.is_err() {
            break;
        }
    }
    for r in whole.iter().flatten().chain(&out) {
        if let Reading::Value { displacement_m, .. } = r {
            assert!(displacement_m.is_finite(), "{r:?}");
        }
    }
    match (&whole, &chunked) {
        (Ok(w), Ok(())) => assert_eq!(w, &out, "chunking changed the readings"),
        (Err(e), Err(f)) => assert_eq!(e.offset, f.offset, "chunking moved the error"),
        (w, c) => panic!("chunking changed the outcome: whole {w:?}, chunked {c:?}"),
    }
    let _ = p.parse_identity(bytes);
    let _ = optoncdt::parse_getinfo(bytes);
}

// ---------------------------------------------------------------- seeds

fn wav_bytes(s: &Signals, format: SampleFormat, scale: &ChannelScale) -> Vec<u8> {
    // encode_lossless picks FLAC when it can; the WAV seeds need WAV.
    let nch = if s.drive_v.is_some() { 3 } else { 2 };
    let (bits, fmt) = match format {
        SampleFormat::Float32 => (32, hound::SampleFormat::Float),
        SampleFormat::Int(b) => (b as u16, hound::SampleFormat::Int),
    };
    let spec = hound::WavSpec {
        channels: nch,
        sample_rate: s.sample_rate_hz as u32,
        bits_per_sample: bits,
        sample_format: fmt,
    };
    let mut cur = std::io::Cursor::new(Vec::new());
    let mut w = hound::WavWriter::new(&mut cur, spec).unwrap();
    let g = [
        scale.displacement.unwrap_or(1.0),
        scale.microphone.unwrap_or(1.0),
        scale.drive.unwrap_or(1.0),
    ];
    for k in 0..s.len() {
        let mut vals = vec![s.displacement_m[k], s.microphone_v[k]];
        if let Some(d) = &s.drive_v {
            vals.push(d[k]);
        }
        for (c, v) in vals.into_iter().enumerate() {
            match format {
                SampleFormat::Float32 => w.write_sample((v / g[c]) as f32).unwrap(),
                SampleFormat::Int(b) => {
                    let full = (1i64 << (b - 1)) as f64;
                    w.write_sample(((v / g[c]) * full).round() as i32).unwrap()
                }
            }
        }
    }
    w.finalize().unwrap();
    cur.into_inner()
}

fn multipart(parts: &[(&str, &[u8])]) -> Vec<u8> {
    let mut b = Vec::new();
    for (name, data) in parts {
        b.extend_from_slice(
            format!("--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"{name}\"\r\n\r\n")
                .as_bytes(),
        );
        b.extend_from_slice(data);
        b.extend_from_slice(b"\r\n");
    }
    b.extend_from_slice(format!("--{BOUNDARY}--\r\n").as_bytes());
    b
}

/// Generated seeds per target (also written to the corpus directory).
fn seeds(target: &str) -> Vec<(String, Vec<u8>)> {
    let s3 = small_signals(64, true);
    let s2 = small_signals(48, false);
    let pcm_scale = ChannelScale {
        displacement: Some(0.02),
        microphone: None,
        drive: Some(100.0),
    };
    let one = ChannelScale::default();
    let f32_3 = wav_bytes(&s3, SampleFormat::Float32, &one);
    let pcm16_3 = wav_bytes(&s3, SampleFormat::Int(16), &pcm_scale);
    let pcm24_3 = wav_bytes(&s3, SampleFormat::Int(24), &pcm_scale);
    let f32_2 = wav_bytes(&s2, SampleFormat::Float32, &one);
    let meta_std = br#"{"moving_mass_kg": 0.05, "sample_rate_hz": 8000, "channels": {"displacement": 0, "microphone": 1, "drive": 2}}"#.to_vec();
    let meta_pcm = br#"{"moving_mass_kg": 0.05, "sample_rate_hz": 8000, "channels": {"displacement": 0, "microphone": 1, "drive": 2}, "channel_scale": {"displacement": 0.02, "drive": 100.0}, "part_serial": "SN-1", "operator": "x"}"#.to_vec();
    let s = |n: &str, b: Vec<u8>| (n.to_string(), b);
    match target {
        "wav" => vec![
            s("float32-3ch.wav", f32_3),
            s("pcm16-3ch.wav", pcm16_3),
            s("pcm24-3ch.wav", pcm24_3),
            s("float32-2ch.wav", f32_2),
        ],
        "meta" => vec![
            s("standard.json", meta_std),
            s("pcm-scale.json", meta_pcm),
            s("two-channel.json", br#"{"moving_mass_kg": 1e-3, "sample_rate_hz": 48000.0, "channels": {"displacement": 1, "microphone": 0}, "channel_scale": {"microphone": -2.5}}"#.to_vec()),
        ],
        "flac" => {
            let r24 = ChannelScale {
                displacement: Some(0.025),
                microphone: Some(100.0),
                drive: Some(100.0),
            };
            let q = |bits: u32, s: &Signals| Signals {
                displacement_m: s.displacement_m.iter().map(|v| Resolution::quantise(bits, 0.025, *v)).collect(),
                microphone_v: s.microphone_v.iter().map(|v| Resolution::quantise(bits, 100.0, *v)).collect(),
                drive_v: s.drive_v.as_ref().map(|d| d.iter().map(|v| Resolution::quantise(bits, 100.0, *v)).collect()),
                ..s.clone()
            };
            let long = small_signals(5000, true);
            vec![
                s("24bit-3ch.flac", codec::encode_flac(&q(24, &s3), 24, &r24).unwrap()),
                s("16bit-2ch.flac", codec::encode_flac(&q(16, &s2), 16, &r24).unwrap()),
                s("24bit-3ch-two-blocks.flac", codec::encode_flac(&q(24, &long), 24, &r24).unwrap()),
                s("float32-3ch.wav", wav_bytes(&s3, SampleFormat::Float32, &one)),
            ]
        }
        "job" => vec![
            s("minimal.json", br#"{"part": {"serial": "SN-0001"}}"#.to_vec()),
            s("full.json", br#"{"part": {"serial": "SN-0002", "kind": "spider", "notes": "lot 7"}, "bench": "virtual-1", "moving_mass_kg": 0.05, "target_xpeak_m": 0.008, "method": "two-signal", "order": 4, "repeats": 2, "priority": 5, "limits": {"max_displacement_m": 0.01, "max_drive_v": 50.0}}"#.to_vec()),
            s("levels.json", br#"{"part": {"serial": "P.3"}, "levels_m": [0.002, 0.004, 0.008], "preset": "cone_6in", "method": "one-signal"}"#.to_vec()),
            s("bad.json", br#"{"part": {"serial": ".."}, "moving_mass_kg": -1, "target_xpeak_m": 1e300, "order": 99, "x": null}"#.to_vec()),
        ],
        "fit" => vec![
            s("empty.json", b"{}".to_vec()),
            s("effects.json", br#"{"effects": ["creep", "coulomb_friction"], "order": 5, "method": "one-signal"}"#.to_vec()),
            s("bad.json", br#"{"effects": ["nope", 3], "order": 0, "method": "x", "extra": []}"#.to_vec()),
        ],
        "multipart" => vec![
            s("float32-import.txt", multipart(&[("meta", &meta_std), ("pre", &f32_3), ("main", &f32_3), ("serial", b"SN-9")])),
            s("pcm-import.txt", multipart(&[("meta", &meta_pcm), ("pre", &pcm16_3), ("main", &pcm24_3), ("method", b"one-signal"), ("order", b"4")])),
            s("missing-main.txt", multipart(&[("meta", &meta_std), ("pre", &f32_3)])),
        ],
        "laser_frames" => {
            let with = |sel: u8, chunk: u8, b: &[u8]| [&[sel, chunk][..], b].concat();
            let mut opto = Vec::new();
            for k in 0..40u32 {
                opto.extend(optoncdt::encode_value(1000 + 1500 * k, false));
                opto.extend(optoncdt::encode_value(k, true));
            }
            let mut opto_plain = b"->\r\n".to_vec();
            for raw in [0, 32768, 65535, optoncdt::CODE_NO_TARGET, optoncdt::CODE_TOO_FAR, 70000] {
                opto_plain.extend(optoncdt::encode_value(raw, false));
            }
            vec![
                s("optoncdt-counter.bin", with(0, 7, &opto)),
                s("optoncdt-codes.bin", with(1, 0, &opto_plain)),
                s("keyence.txt", with(2, 3, b"MS,OUT01,+01.2345\rMS,OUT01,-0.0040\rMS,OUT01,FFFFFFF\rER,MS,02\rMS,OUT01,+12.5\r")),
                s("ascii-lines.txt", with(3, 5, b"0.25\n1.234\r\n-0.5\nOOR\n---\nERR7\nE12\n3.5e-1\n")),
                s("ascii-counter.txt", with(4, 11, b"65534,0.25\n65535;0.3\n0\t0.35\n1 OUT\n2,-1.0\n")),
            ]
        }
        _ => vec![],
    }
}

// ---------------------------------------------------------------- engine

fn load_corpus(target: &str) -> Vec<Vec<u8>> {
    let dir = corpus_dir(target);
    if std::env::var("SPRINGBENCH_FUZZ_WRITE_CORPUS").is_ok() {
        std::fs::create_dir_all(&dir).unwrap();
        for (name, b) in seeds(target) {
            std::fs::write(dir.join(name), b).unwrap();
        }
    }
    let mut out: Vec<Vec<u8>> = match std::fs::read_dir(&dir) {
        Ok(rd) => {
            let mut paths: Vec<_> = rd
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.is_file())
                .collect();
            paths.sort();
            paths.iter().map(|p| std::fs::read(p).unwrap()).collect()
        }
        Err(_) => vec![],
    };
    assert!(
        !out.is_empty(),
        "fuzz corpus {} is empty (SPRINGBENCH_FUZZ_WRITE_CORPUS=1 writes the seeds)",
        dir.display()
    );
    out.push(Vec::new());
    out
}

const INTERESTING: [u32; 12] = [
    0,
    1,
    2,
    3,
    0x7f,
    0x80,
    0xff,
    0x7fff,
    0x8000,
    0xffff,
    0x7fff_ffff,
    0xffff_ffff,
];

const TOKENS: [&str; 26] = [
    "\"",
    "{",
    "}",
    "[",
    "]",
    ":",
    ",",
    "null",
    "true",
    "-1",
    "0",
    "1e308",
    "-1e-308",
    "1e999",
    "NaN",
    "\"part\"",
    "\"serial\"",
    "\"channels\"",
    "\"channel_scale\"",
    "\"levels_m\"",
    "\"effects\"",
    "\"order\"",
    "\\u0000",
    "\r\n",
    "--sb-fuzz-boundary",
    "Content-Disposition: form-data; name=\"main\"",
];

fn mutate(rng: &mut ChaCha8Rng, corpus: &[Vec<u8>]) -> Vec<u8> {
    let mut d = corpus[rng.random_range(0..corpus.len())].clone();
    let rounds = 1 + rng.random_range(0..6u32).min(rng.random_range(0..6u32));
    for _ in 0..rounds {
        let len = d.len();
        let pos = |rng: &mut ChaCha8Rng| {
            if len == 0 {
                0
            } else {
                rng.random_range(0..len)
            }
        };
        match rng.random_range(0..11u32) {
            0 if len > 0 => {
                let i = pos(rng);
                d[i] ^= 1 << rng.random_range(0..8);
            }
            1 if len > 0 => {
                let i = pos(rng);
                d[i] = rng.random();
            }
            2 if len >= 4 => {
                let i = rng.random_range(0..=len - 4);
                let v = INTERESTING[rng.random_range(0..INTERESTING.len())];
                let v = if rng.random() { v } else { v.swap_bytes() };
                d[i..i + 4].copy_from_slice(&v.to_le_bytes());
            }
            3 if len >= 2 => {
                let i = rng.random_range(0..=len - 2);
                let v = INTERESTING[rng.random_range(0..INTERESTING.len())] as u16;
                d[i..i + 2].copy_from_slice(&v.to_le_bytes());
            }
            4 => {
                let i = pos(rng);
                let n = rng.random_range(1..=16);
                let ins: Vec<u8> = (0..n).map(|_| rng.random()).collect();
                d.splice(i..i, ins);
            }
            5 if len > 0 => {
                let i = pos(rng);
                let n = rng.random_range(1..=(len - i).min(64));
                d.drain(i..i + n);
            }
            6 if len > 0 => {
                let i = pos(rng);
                let n = rng.random_range(1..=(len - i).min(64));
                let chunk = d[i..i + n].to_vec();
                let j = pos(rng);
                d.splice(j..j, chunk);
            }
            7 if len > 0 => d.truncate(pos(rng)),
            8 => {
                let o = &corpus[rng.random_range(0..corpus.len())];
                if !o.is_empty() {
                    let a = rng.random_range(0..o.len());
                    let b = rng.random_range(a..o.len()) + 1;
                    let i = pos(rng);
                    let j = (i + rng.random_range(0..64)).min(len);
                    d.splice(i..j, o[a..b].iter().copied());
                }
            }
            9 => {
                let t = TOKENS[rng.random_range(0..TOKENS.len())].as_bytes();
                let i = pos(rng);
                if rng.random() || len == 0 {
                    d.splice(i..i, t.iter().copied());
                } else {
                    let j = (i + t.len()).min(len);
                    d.splice(i..j, t.iter().copied());
                }
            }
            _ if len > 0 => {
                // A number in text: replace a digit run by an extreme one.
                let i = pos(rng);
                if d[i].is_ascii_digit() {
                    let mut j = i;
                    while j < d.len() && (d[j].is_ascii_digit() || d[j] == b'.') {
                        j += 1;
                    }
                    let v = [
                        "0",
                        "-0",
                        "1e309",
                        "4294967296",
                        "18446744073709551616",
                        "0.0000001",
                        "-5",
                    ];
                    d.splice(i..j, v[rng.random_range(0..v.len())].bytes());
                }
            }
            _ => {}
        }
    }
    d.truncate(MAX_INPUT);
    d
}

/// Runs `iters()` mutated inputs (after every corpus entry as is) through `f`.
fn fuzz(target: &str, f: fn(&[u8])) {
    let corpus = load_corpus(target);
    let n = iters();
    let seed = seed();
    let mut rng = ChaCha8Rng::seed_from_u64(
        seed ^ target
            .bytes()
            .fold(0u64, |h, b| h.wrapping_mul(31).wrapping_add(b as u64)),
    );
    let t = Instant::now();
    let mut bytes = 0u64;
    for i in 0..n + corpus.len() as u64 {
        let input = match corpus.get(i as usize) {
            Some(c) => c.clone(),
            None => mutate(&mut rng, &corpus),
        };
        bytes += input.len() as u64;
        let r = std::panic::catch_unwind(|| f(&input));
        if r.is_err() {
            let dir = Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("fuzz/artifacts")
                .join(target);
            let _ = std::fs::create_dir_all(&dir);
            let p = dir.join(format!("crash-seed{seed}-iter{i}"));
            let _ = std::fs::write(&p, &input);
            panic!(
                "fuzz target {target}: panic on input {i} (seed {seed}), saved to {}",
                p.display()
            );
        }
    }
    let s = t.elapsed().as_secs_f64();
    let total = n + corpus.len() as u64;
    println!(
        "fuzz {target}: {total} inputs ({} corpus), mean {:.0} bytes, {s:.1} s, {:.0} inputs/s, no panic",
        corpus.len(),
        bytes as f64 / total as f64,
        total as f64 / s
    );
}

#[test]
fn fuzz_wav() {
    fuzz("wav", target_wav);
}

#[test]
fn fuzz_meta() {
    fuzz("meta", target_meta);
}

#[test]
fn fuzz_flac() {
    fuzz("flac", target_flac);
}

#[test]
fn fuzz_job_body() {
    fuzz("job", target_job);
}

#[test]
fn fuzz_fit_body() {
    fuzz("fit", target_fit);
}

#[test]
fn fuzz_multipart_import() {
    fuzz("multipart", target_multipart);
}

#[test]
fn fuzz_laser_frames() {
    fuzz("laser_frames", target_laser_frames);
}

/// The seeds are valid inputs: the harness mutates something that parses.
#[test]
fn seeds_parse() {
    let meta = Meta::standard(0.05, 8000.0);
    for (name, b) in seeds("wav") {
        let m = if name.starts_with("pcm") {
            &metas()[1]
        } else {
            &meta
        };
        let m = if name.contains("2ch") {
            let mut m = m.clone();
            m.channels.drive = None;
            m
        } else {
            m.clone()
        };
        rec::read_signals(std::io::Cursor::new(&b), &m).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    for (name, b) in seeds("flac") {
        codec::decode(
            &b,
            Some(&ChannelScale {
                displacement: Some(0.025),
                microphone: Some(100.0),
                drive: Some(100.0),
            }),
        )
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    for (name, b) in seeds("meta") {
        rec::parse_meta(std::str::from_utf8(&b).unwrap()).unwrap_or_else(|e| panic!("{name}: {e}"));
    }
    let cfg = springbench::config::Config::default();
    for (name, b) in seeds("job") {
        let r = springbench::runner::job::validate(&serde_json::from_slice(&b).unwrap(), &cfg);
        assert_eq!(r.is_ok(), name != "bad.json", "{name}: {:?}", r.err());
    }
    let v = json!({"effects": ["creep", "channel_delay"], "order": 3});
    assert!(springbench::api::measurements::fit_request(&v).is_ok());
}
