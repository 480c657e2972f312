//! Command-line parsing and one module per subcommand.

mod demo;
mod eval;
mod match_cmd;

use clap::{Parser, Subcommand};

/// Dense non-rigid shape correspondence with random forests.
#[derive(Debug, Parser)]
#[command(name = "shapeforest", version, about)]
pub struct Cli {
    /// More log output (-v: debug, -vv: trace). `RUST_LOG` overrides.
    #[arg(short, long, action = clap::ArgAction::Count, global = true)]
    pub verbose: u8,
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run the method end to end on built-in synthetic data and report what it reached.
    Demo(demo::DemoArgs),
    /// Evaluate the method on a class of shapes with ground truth (the paper's protocol).
    Eval(eval::EvalArgs),
    /// Match a mesh to a reference with a trained model; write the map and coloured meshes.
    Match(match_cmd::MatchArgs),
}

/// Sets up `tracing` output on stderr.
pub fn init_tracing(verbose: u8) {
    let default = match verbose {
        0 => "info",
        1 => "debug",
        _ => "trace",
    };
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new(default));
    let _ = tracing_subscriber::fmt().with_env_filter(filter).with_writer(std::io::stderr).try_init();
}

/// Dispatches a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Demo(args) => demo::run(args),
        Command::Eval(args) => eval::run(args),
        Command::Match(args) => match_cmd::run(args),
    }
}
