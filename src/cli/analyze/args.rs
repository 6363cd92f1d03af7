//! The `analyze` command's flags, and the checks made before anything is read.
use crate::identify::Method;
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
    /// Recording sets of the same part at other levels, comma separated
    /// (with --diagnose): K(x) and the effects fitted jointly over DIR and
    /// these, beside each level's own fit.
    #[arg(long, value_delimiter = ',')]
    pub series: Vec<PathBuf>,
}

/// Parses `--method`.
pub fn parse_method(s: &str) -> Result<Method, String> {
    match s {
        "two-signal" => Ok(Method::TwoSignal),
        "one-signal" => Ok(Method::OneSignal),
        other => Err(format!(
            "unknown --method '{other}' (known: two-signal, one-signal)"
        )),
    }
}

/// Flags that would do nothing, and unknown effect names, are refused
/// before anything is read (one line, exit 2).
pub fn check_flags(args: &AnalyzeArgs) -> Result<(), String> {
    for e in args
        .effects
        .iter()
        .map(|e| e.trim())
        .filter(|e| !e.is_empty())
    {
        crate::effects::EffectId::parse(e).map_err(|m| format!("--effects: {m}"))?;
    }
    if !args.diagnose && !args.effects.is_empty() {
        return Err("--effects only acts with --diagnose (it names effects forced into the diagnosed model); add --diagnose or drop --effects".into());
    }
    if !args.diagnose && args.plots.is_some() {
        return Err("--plots only acts with --diagnose (the plots are the diagnostics'); add --diagnose or drop --plots".into());
    }
    if !args.diagnose && !args.series.is_empty() {
        return Err("--series only acts with --diagnose (the joint fit is the diagnostics'); add --diagnose or drop --series".into());
    }
    if args.order == Some(0) {
        return Err("--order must be at least 1".into());
    }
    Ok(())
}
