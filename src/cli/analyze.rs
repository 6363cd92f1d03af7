//! `springbench analyze DIR`: offline analysis of a recording set
//! (owned by the identification work; `--diagnose` hands over to [`super::diagnose`]).
use std::path::PathBuf;

#[derive(clap::Args, Debug, Default, Clone)]
pub struct AnalyzeArgs {
    /// Recording-set directory (pre.wav, main.wav, meta.json).
    pub dir: PathBuf,
    /// Nonlinear stiffness method: two-signal (default) or one-signal.
    #[arg(long, default_value = "two-signal")]
    pub method: String,
    /// Highest power of K(x); chosen from the data when omitted.
    #[arg(long)]
    pub order: Option<usize>,
    /// Print the result document as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Run the model diagnostics (candidate effects, ladder).
    #[arg(long)]
    pub diagnose: bool,
    /// Effects forced into the model, comma separated (with --diagnose).
    #[arg(long, value_delimiter = ',')]
    pub effects: Vec<String>,
    /// Directory to write the diagnostic SVG plots into (with --diagnose).
    #[arg(long)]
    pub plots: Option<PathBuf>,
}

pub fn run(_args: AnalyzeArgs) -> Result<(), String> {
    Err("analyze: not implemented yet".into())
}
