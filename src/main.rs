//! `springbench`: argument parsing and wiring only.
use clap::{Parser, Subcommand};
use springbench::cli;

#[derive(Parser)]
#[command(
    name = "springbench",
    version,
    about = "Dynamic measurement of loudspeaker suspension parts"
)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Run the bench daemon (the default when no command is given).
    Serve(cli::serve::ServeArgs),
    /// Analyse a recording set (pre.wav, main.wav, meta.json).
    Analyze(cli::analyze::AnalyzeArgs),
    /// Run the standard procedure on the virtual bench and write a recording set.
    Simulate(cli::simulate::SimulateArgs),
    /// Fit the ageing law to a long-term test's series (one recording set per subdirectory).
    Ageing(cli::ageing::AgeingArgs),
    /// List audio devices (channels, rates) and serial ports (feature `hardware`).
    Devices(cli::devices::DevicesArgs),
    /// Print the API's OpenAPI document (YAML, or JSON with --json).
    Openapi(cli::openapi::OpenapiArgs),
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        None => cli::serve::run(cli::serve::ServeArgs::default()),
        Some(Command::Serve(a)) => cli::serve::run(a),
        Some(Command::Analyze(a)) => cli::analyze::run(a),
        Some(Command::Simulate(a)) => cli::simulate::run(a),
        Some(Command::Ageing(a)) => cli::ageing::run(a),
        Some(Command::Devices(a)) => cli::devices::run(a),
        Some(Command::Openapi(a)) => cli::openapi::run(a),
    };
    match result {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // One clear line on stderr, never a panic.
            eprintln!("springbench: error: {e}");
            std::process::ExitCode::from(2)
        }
    }
}
