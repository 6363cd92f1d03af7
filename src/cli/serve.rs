//! `springbench serve` (placeholder until its issue lands).
#[derive(clap::Args, Debug, Default)]
pub struct ServeArgs {}

pub fn run(_args: ServeArgs) -> Result<(), String> {
    Err("serve: not implemented yet".into())
}
