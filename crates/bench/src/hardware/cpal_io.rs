//! The one small adapter around cpal 0.18 (cpal's master renames `play` to
//! `start` and moves xruns into the callback info: only this file changes).
//! Output: a callback pulls the drive from the [`DriveSource`] (limit and
//! ramp applied there) and converts to the device's sample format. Input: a
//! callback converts to f32 and sends the interleaved frames over a channel;
//! the error callback sends every stream error (xrun, device lost) the same
//! way, so the bench sees it in order with the data and faults the sweep.

use crate::audio::drive::{DriveShared, DriveSource};
use crate::audio::{AudioError, AudioIo};
use crate::settings::HardwareConfig;
use cpal::traits::{DeviceTrait, HostTrait, StreamTrait};
use cpal::{FromSample, SampleFormat, SizedSample, StreamConfig};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError, SyncSender};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How long `read` waits for captured frames before calling the device dead.
pub const READ_TIMEOUT_S: f64 = 2.0;

enum Msg {
    Frames(Vec<f32>),
    Error(String),
}

/// An audio device pair opened through cpal.
pub struct CpalAudio {
    hw: HardwareConfig,
    out_dev: cpal::Device,
    in_dev: cpal::Device,
    out_fmt: SampleFormat,
    in_fmt: SampleFormat,
    streams: Option<(cpal::Stream, cpal::Stream)>,
    rx: Option<Receiver<Msg>>,
    shared: Option<Arc<DriveShared>>,
}

/// Every device of the default host: (id, description, input configs, output configs).
pub fn list_devices() -> Result<Vec<DeviceInfo>, String> {
    let host = cpal::default_host();
    let devs = host.devices().map_err(|e| e.to_string())?;
    let mut out = vec![];
    for d in devs {
        let id = d.id().map(|i| i.to_string()).unwrap_or_default();
        let name = d
            .description()
            .map(|x| x.name().to_string())
            .unwrap_or_default();
        let ranges = |it: Result<Vec<cpal::SupportedStreamConfigRange>, cpal::Error>| {
            it.map(|v| {
                v.iter()
                    .map(|r| {
                        format!(
                            "{} ch {} {}-{} Hz",
                            r.channels(),
                            r.sample_format(),
                            r.min_sample_rate(),
                            r.max_sample_rate()
                        )
                    })
                    .collect::<Vec<_>>()
            })
            .unwrap_or_default()
        };
        let inputs = ranges(d.supported_input_configs().map(|i| i.collect()));
        let outputs = ranges(d.supported_output_configs().map(|i| i.collect()));
        out.push(DeviceInfo {
            id,
            name,
            inputs,
            outputs,
        });
    }
    Ok(out)
}

/// One audio device as `springbench devices` shows it.
#[derive(Debug, Clone, serde::Serialize)]
pub struct DeviceInfo {
    pub id: String,
    pub name: String,
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
}

/// The device whose ALSA PCM name (cpal id without the host prefix), full id or description is `name`.
fn find(host: &cpal::Host, name: &str) -> Result<cpal::Device, AudioError> {
    if let Ok(id) = format!("{}:{name}", host.id().name().to_lowercase()).parse() {
        if let Some(d) = host.device_by_id(&id) {
            return Ok(d);
        }
    }
    let devs: Vec<cpal::Device> = host
        .devices()
        .map_err(|e| AudioError::Open(format!("audio devices: {e}")))?
        .collect();
    let mut names = vec![];
    for d in devs {
        let id = d.id().map(|i| i.to_string()).unwrap_or_default();
        let short = id
            .split_once(':')
            .map(|(_, s)| s.to_string())
            .unwrap_or_default();
        let desc = d
            .description()
            .map(|x| x.name().to_string())
            .unwrap_or_default();
        if short == name || id == name || desc == name {
            return Ok(d);
        }
        names.push(short);
    }
    Err(AudioError::Open(format!(
        "no audio device '{name}' (devices: {})",
        names.join(", ")
    )))
}

/// The best sample format the device offers at `channels` and `rate`: f32, then i32, i16.
fn pick_format(
    ranges: Vec<cpal::SupportedStreamConfigRange>,
    channels: u16,
    rate: u32,
    what: &str,
) -> Result<SampleFormat, AudioError> {
    let fits: Vec<SampleFormat> = ranges
        .iter()
        .filter(|r| {
            r.channels() == channels && r.min_sample_rate() <= rate && rate <= r.max_sample_rate()
        })
        .map(|r| r.sample_format())
        .collect();
    [SampleFormat::F32, SampleFormat::I32, SampleFormat::I16]
        .into_iter()
        .find(|f| fits.contains(f))
        .ok_or_else(|| {
            AudioError::Open(format!(
                "{what}: no f32/i32/i16 configuration with {channels} channels at {rate} Hz"
            ))
        })
}

impl CpalAudio {
    /// Opens both devices by name and checks they offer the configured channels and rate.
    pub fn open(hw: &HardwareConfig) -> Result<CpalAudio, AudioError> {
        let host = cpal::default_host();
        let out_dev = find(&host, &hw.output_device)?;
        let in_dev = find(&host, &hw.input_device)?;
        let out_fmt = pick_format(
            out_dev
                .supported_output_configs()
                .map_err(|e| AudioError::Open(format!("{}: {e}", hw.output_device)))?
                .collect(),
            hw.output_channels,
            hw.sample_rate_hz,
            &hw.output_device,
        )?;
        let in_fmt = pick_format(
            in_dev
                .supported_input_configs()
                .map_err(|e| AudioError::Open(format!("{}: {e}", hw.input_device)))?
                .collect(),
            hw.input_channels,
            hw.sample_rate_hz,
            &hw.input_device,
        )?;
        Ok(CpalAudio {
            hw: hw.clone(),
            out_dev,
            in_dev,
            out_fmt,
            in_fmt,
            streams: None,
            rx: None,
            shared: None,
        })
    }

    fn config(&self, channels: u16) -> StreamConfig {
        StreamConfig {
            channels,
            sample_rate: self.hw.sample_rate_hz,
            buffer_size: cpal::BufferSize::Fixed(self.hw.buffer_frames),
        }
    }

    fn output<T>(
        &self,
        mut drive: DriveSource,
        tx: SyncSender<Msg>,
    ) -> Result<cpal::Stream, cpal::Error>
    where
        T: SizedSample + FromSample<f32>,
    {
        let channels = self.hw.output_channels as usize;
        let ch = self.hw.channels.drive as usize;
        let mut scratch: Vec<f32> = Vec::new();
        self.out_dev.build_output_stream::<T, _, _>(
            self.config(self.hw.output_channels),
            move |out: &mut [T], _| {
                scratch.resize(out.len(), 0.0);
                drive.fill(&mut scratch, channels, ch);
                for (o, s) in out.iter_mut().zip(&scratch) {
                    *o = T::from_sample(*s);
                }
            },
            move |e| {
                let _ = tx.try_send(Msg::Error(format!("output: {e} ({:?})", e.kind())));
            },
            None,
        )
    }

    fn input<T>(&self, tx: SyncSender<Msg>) -> Result<cpal::Stream, cpal::Error>
    where
        T: SizedSample,
        f32: FromSample<T>,
    {
        let txe = tx.clone();
        self.in_dev.build_input_stream::<T, _, _>(
            self.config(self.hw.input_channels),
            move |data: &[T], _| {
                let v: Vec<f32> = data.iter().map(|s| s.to_sample::<f32>()).collect();
                // A full channel means the bench thread fell behind: that is an overrun too.
                if tx.try_send(Msg::Frames(v)).is_err() {
                    let _ = tx.try_send(Msg::Error("input: capture queue overrun".into()));
                }
            },
            move |e| {
                let _ = txe.try_send(Msg::Error(format!("input: {e} ({:?})", e.kind())));
            },
            None,
        )
    }
}

impl AudioIo for CpalAudio {
    fn sample_rate_hz(&self) -> f64 {
        self.hw.sample_rate_hz as f64
    }

    fn input_channels(&self) -> usize {
        self.hw.input_channels as usize
    }

    fn start(&mut self, drive: DriveSource) -> Result<(), AudioError> {
        // Room for 20 s of callbacks: the bench thread reads much faster than real time.
        let (tx, rx) = sync_channel(4096);
        self.shared = Some(drive.shared());
        let input = match self.in_fmt {
            SampleFormat::F32 => self.input::<f32>(tx.clone()),
            SampleFormat::I32 => self.input::<i32>(tx.clone()),
            _ => self.input::<i16>(tx.clone()),
        }
        .map_err(|e| AudioError::Open(format!("input {}: {e}", self.hw.input_device)))?;
        let output = match self.out_fmt {
            SampleFormat::F32 => self.output::<f32>(drive, tx),
            SampleFormat::I32 => self.output::<i32>(drive, tx),
            _ => self.output::<i16>(drive, tx),
        }
        .map_err(|e| AudioError::Open(format!("output {}: {e}", self.hw.output_device)))?;
        input
            .play()
            .map_err(|e| AudioError::Open(format!("input {}: {e}", self.hw.input_device)))?;
        output
            .play()
            .map_err(|e| AudioError::Open(format!("output {}: {e}", self.hw.output_device)))?;
        self.streams = Some((output, input));
        self.rx = Some(rx);
        Ok(())
    }

    fn read(&mut self, out: &mut Vec<f32>) -> Result<(), AudioError> {
        let Some(rx) = self.rx.as_ref() else {
            return Err(AudioError::Stream("stream not started".into()));
        };
        match rx.recv_timeout(Duration::from_secs_f64(READ_TIMEOUT_S)) {
            Ok(Msg::Frames(v)) => {
                out.extend_from_slice(&v);
                Ok(())
            }
            Ok(Msg::Error(e)) => Err(AudioError::Stream(e)),
            Err(RecvTimeoutError::Timeout) => Err(AudioError::Stream(format!(
                "no captured frames for {READ_TIMEOUT_S} s (device stalled)"
            ))),
            Err(RecvTimeoutError::Disconnected) => {
                Err(AudioError::Stream("the input stream ended".into()))
            }
        }
    }

    fn stop(&mut self, timeout_s: f64) {
        let t = Instant::now();
        if let Some(sh) = &self.shared {
            while !sh.silent() && t.elapsed().as_secs_f64() < timeout_s {
                std::thread::sleep(Duration::from_millis(2));
            }
        }
        // The output buffer still holds up to one buffer of what was produced.
        let buffer_s = 2.0 * self.hw.buffer_frames as f64 / self.hw.sample_rate_hz as f64;
        std::thread::sleep(Duration::from_secs_f64(buffer_s.min(0.1)));
        if let Some((out, inp)) = self.streams.take() {
            let _ = out.pause();
            let _ = inp.pause();
        }
        self.rx = None;
        self.shared = None;
    }

    fn describe(&self) -> String {
        format!(
            "cpal: out '{}' ({:?}, {} ch), in '{}' ({:?}, {} ch), {} frames/buffer",
            self.hw.output_device,
            self.out_fmt,
            self.hw.output_channels,
            self.hw.input_device,
            self.in_fmt,
            self.hw.input_channels,
            self.hw.buffer_frames
        )
    }
}
