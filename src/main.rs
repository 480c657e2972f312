//! The `shapeforest` command-line tool: a thin layer over the library.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    // A daemon reports what it does (claimed, matched, rejected, model saved) by default.
    let daemon = matches!(args.command, cli::Command::Watch(_) | cli::Command::Run(_));
    cli::init_tracing(args.verbose + u8::from(daemon));
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
