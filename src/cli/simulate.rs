//! `springbench simulate --part PRESET_OR_FILE --out DIR [--seed N]`: runs the
//! standard procedure on the virtual bench and writes the recording set
//! (pre.wav, main.wav, meta.json) that `analyze` reads, plus truth.json.
use crate::bench::simulate::SimulateOptions;
use crate::physics::{self, PartSpec};
use crate::recording::RecordingSetFiles;
use std::path::{Path, PathBuf};

#[derive(clap::Args, Debug, Default)]
pub struct SimulateArgs {
    /// Part: a preset name (spider_3in, spider_4in, cone_6in, cone_18in,
    /// passive_radiator) or the path of a part TOML file.
    #[arg(long)]
    pub part: String,
    /// Output directory (created if missing).
    #[arg(long)]
    pub out: PathBuf,
    /// Seed of the sensor noise.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Target peak displacement of the narrow sweep (m).
    #[arg(long)]
    pub xpeak_m: Option<f64>,
    /// Largest drive amplitude the virtual bench allows (V peak); its default otherwise.
    #[arg(long)]
    pub max_drive_v: Option<f64>,
}

/// A preset by name, else a part TOML file by path; one-line error.
pub fn resolve_part(arg: &str) -> Result<PartSpec, String> {
    if physics::preset_names().contains(&arg) {
        return physics::preset(arg);
    }
    let p = Path::new(arg);
    if p.is_file() {
        let text = std::fs::read_to_string(p).map_err(|e| format!("{arg}: {e}"))?;
        return physics::parse_part_toml(&text).map_err(|e| format!("{arg}: {e}"));
    }
    Err(format!(
        "--part '{arg}' is neither a preset ({}) nor a part TOML file",
        physics::preset_names().join(", ")
    ))
}

pub fn run(args: SimulateArgs) -> Result<(), String> {
    let part = resolve_part(&args.part)?;
    let mut opts = SimulateOptions::default();
    if let Some(x) = args.xpeak_m {
        if !(x.is_finite() && x > 0.0) {
            return Err(format!(
                "--xpeak-m must be a positive number of metres, got {x}"
            ));
        }
        opts.procedure.levels_m = vec![x];
    }
    if let Some(v) = args.max_drive_v {
        if !(v.is_finite() && v > 0.0) {
            return Err(format!(
                "--max-drive-v must be a positive number of volts, got {v}"
            ));
        }
        let mut limits =
            crate::bench::virtual_bench::VirtualBench::new(part.clone(), args.seed).limits;
        limits.max_drive_v = v;
        opts.limits = Some(limits);
    }
    let sim = crate::bench::simulate::simulate(&part, args.seed, &opts)?;
    sim.set.write_dir(&args.out).map_err(|e| e.to_string())?;
    let tp = args.out.join("truth.json");
    let text = serde_json::to_string_pretty(&sim.truth).map_err(|e| e.to_string())?;
    std::fs::write(&tp, text + "\n").map_err(|e| format!("{}: {e}", tp.display()))?;
    for l in &sim.outcome.log {
        println!("{l}");
    }
    println!(
        "wrote {}/{{pre.wav, main.wav, meta.json, truth.json}} (part '{}', seed {})",
        args.out.display(),
        part.name,
        args.seed
    );
    for w in sim.outcome.narrow.iter().filter_map(|n| n.warning.as_ref()) {
        eprintln!("WARNING: {w}");
    }
    Ok(())
}
