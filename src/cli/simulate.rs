//! `springbench simulate` (placeholder until its issue lands).
#[derive(clap::Args, Debug, Default)]
pub struct SimulateArgs {}

pub fn run(_args: SimulateArgs) -> Result<(), String> {
    Err("simulate: not implemented yet".into())
}
