//! The `shapeforest` command-line tool: a thin layer over the library.

mod cli;

use clap::Parser;

fn main() -> std::process::ExitCode {
    let args = cli::Cli::parse();
    // A daemon reports what it does (claimed, matched, rejected, model saved) by default.
    // The demo rejects a broken file on purpose and says so: its logs stay quiet unless asked.
    let daemon = matches!(args.command, cli::Command::Watch(_) | cli::Command::Run(_));
    let demo = matches!(args.command, cli::Command::Demo(_));
    cli::init_tracing(args.verbose + u8::from(daemon), demo && args.verbose == 0);
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            std::process::ExitCode::FAILURE
        }
    }
}
