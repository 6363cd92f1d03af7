//! `springbench analyze` (placeholder until its issue lands).
#[derive(clap::Args, Debug, Default)]
pub struct AnalyzeArgs {}

pub fn run(_args: AnalyzeArgs) -> Result<(), String> {
    Err("analyze: not implemented yet".into())
}
