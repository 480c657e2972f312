//! Command-line parsing and one module per subcommand.

mod bench;
mod common;
mod demo;
mod eval;
mod eval_pairs;
mod info;
mod match_cmd;
mod perturb;
mod predict;
mod run;
mod scale;
mod train;
mod view;
mod visual;

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
    /// Run the method end to end on built-in synthetic data and report the accuracy reached.
    Demo(demo::DemoArgs),
    /// Summarise mesh files: counts, area, components, boundary loops, reader warnings.
    Info(info::InfoArgs),
    /// Train a forest from labelled shapes and write a model file.
    Train(train::TrainArgs),
    /// Label the vertices of a mesh with a trained forest.
    Predict(predict::PredictArgs),
    /// Time shapeforest on benchmark meshes (`--out`), or compare with the peers' timings (`--report`).
    Bench(bench::BenchArgs),
    /// Evaluate the method on a class of shapes with ground truth (the paper's protocol).
    Eval(Box<eval::EvalArgs>),
    /// Match a mesh to a reference with a trained model; write the map and coloured meshes.
    Match(match_cmd::MatchArgs),
    /// Turn a clean mesh into a scan-like one (holes, a single view, a crop, noise), keeping its
    /// ground truth through a vertex map.
    Perturb(perturb::PerturbArgs),
    /// Write the interactive view.html of a match result (a `match` output or a daemon's matched/NAME/).
    View(view::ViewArgs),
    /// Run a pipeline file (pipelines/*.toml): batch training, matching, evaluation or a daemon.
    Run(run::RunArgs),
    /// The watch-folder daemon: match scans arriving in incoming/, learn from labeled/.
    Watch(run::WatchArgs),
    /// Run some or all stages of a pipeline as a worker on NATS JetStream (any number of
    /// workers, on any number of machines, share the work).
    Worker(scale::WorkerArgs),
    /// Publish scans (or labelled shapes, or a model) to the workers through NATS JetStream.
    Submit(scale::SubmitArgs),
    /// Write the workers' results into OUT/matched/ and OUT/rejected/ (the daemon's layout).
    Results(scale::ResultsArgs),
    /// Delete what the NATS object store no longer needs: objects no waiting message refers
    /// to, model versions older than the last few.
    Gc(scale::GcArgs),
}

/// Sets up `tracing` output on stderr (`quiet`: errors only, unless `RUST_LOG` says otherwise).
pub fn init_tracing(verbose: u8, quiet: bool) {
    let default = match verbose {
        0 if quiet => "error",
        0 => "warn",
        1 => "info,notify=warn",
        2 => "debug,notify=info",
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
        Command::Info(args) => info::run(args),
        Command::Train(args) => train::run(args),
        Command::Predict(args) => predict::run(args),
        Command::Bench(args) => bench::run(args),
        Command::Eval(args) => eval::run(*args),
        Command::Match(args) => match_cmd::run(args),
        Command::Perturb(args) => perturb::run(args),
        Command::View(args) => view::run(args),
        Command::Run(args) => run::run(args),
        Command::Watch(args) => run::watch(args),
        Command::Worker(args) => scale::worker(args),
        Command::Submit(args) => scale::submit(args),
        Command::Results(args) => scale::results(args),
        Command::Gc(args) => scale::gc(args),
    }
}
