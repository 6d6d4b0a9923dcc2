//! `bevworld`: run, check and draw dataflow graphs; generate, inspect and evaluate data.

mod commands;
mod registry;

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

use anyhow::{Context, Result, bail};
use bevworld_graph::{Override, RunOptions, StopHandle};
use clap::{Parser, Subcommand};

/// Training and rendering allocate and free tensors of tens of megabytes every step; glibc's
/// malloc hands those back to the kernel and page-faults them in again (a fifth of a tiny
/// training step, measured with perf). mimalloc keeps them.
#[global_allocator]
static ALLOCATOR: mimalloc::MiMalloc = mimalloc::MiMalloc;

#[derive(Parser)]
#[command(
    name = "bevworld",
    version,
    about = "BEVWorld: a multimodal world model for autonomous driving, as a dataflow graph of actors"
)]
struct Cli {
    /// Threads for the tensor ops of inference (rayon's global pool). Default: one per core,
    /// or RAYON_NUM_THREADS. Training spreads frames over its own threads and runs each
    /// frame's ops serially, so it never oversubscribes the cores.
    #[arg(long, global = true, value_name = "N", value_parser = thread_count, allow_negative_numbers = true)]
    threads: Option<u16>,
    #[command(subcommand)]
    command: Command,
}

// One value, parsed once at start: the size of its largest variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Run a graph until its sources end (Ctrl-C drains; a second Ctrl-C aborts).
    Run {
        /// Graph file, e.g. configs/graphs/replay.yaml.
        graph: PathBuf,
        /// Override a parameter (repeatable): name=value for one the graph exposes in its
        /// `interface:`, models.BUNDLE.KEY=value for a model file (every node running the
        /// bundle), node.param=value for any node's; also node.pacing.rate_hz,
        /// node.pacing.speed and node.on_error.
        #[arg(long = "set", value_name = "TARGET=VALUE")]
        set: Vec<String>,
        /// Write the run's metrics as JSON.
        #[arg(long, value_name = "FILE")]
        metrics: Option<PathBuf>,
        /// Hide the progress bar.
        #[arg(long)]
        no_progress: bool,
        /// Process every N-th scene starting at I (sets the graph's exposed `shard`), so one
        /// command can be spread over machines by any batch scheduler.
        #[arg(long, value_name = "I/N")]
        shard: Option<String>,
        /// Rewrite existing output files of every `export_features` node.
        #[arg(long)]
        overwrite: bool,
    },
    /// Validate a graph and print it resolved (models, exposed names, parameters with
    /// defaults, edges with policies). A graph a command runs by default is also held to that
    /// command's contract: the names it binds to must be exposed.
    Check {
        graph: PathBuf,
        #[arg(long = "set", value_name = "TARGET=VALUE")]
        set: Vec<String>,
    },
    /// Print a graph in another form.
    Graph {
        graph: PathBuf,
        /// Graphviz DOT (render with `dot -Tsvg`).
        #[arg(long)]
        dot: bool,
        #[arg(long = "set", value_name = "TARGET=VALUE")]
        set: Vec<String>,
    },
    /// List the node kinds with their ports.
    Kinds,
    /// Generate the synthetic driving world in the nuScenes layout (version v1.0-synth).
    Synth(commands::synth::SynthArgs),
    /// Draw the LiDAR into each camera image, as the nuScenes devkit projects it, to check a
    /// dataset's calibration: writes OUT/<CHANNEL>.png and OUT/<CHANNEL>.csv (u,v,depth).
    Inspect(commands::inspect::InspectArgs),
    /// Evaluate: Chamfer distance between clouds, forecasting baselines.
    #[command(subcommand)]
    Eval(commands::eval::EvalCommand),
    /// Train a model: the tokenizer or the world model.
    #[command(subcommand)]
    Train(commands::train::TrainCommand),
    /// Tokenizer tools: latent statistics.
    #[command(subcommand)]
    Tokenizer(commands::tokenizer::TokenizerCommand),
    /// Show the Burn device that BURN_DEVICE selects and measure its matmul rate.
    Device {
        /// Matrix size for the measurement.
        #[arg(long, default_value_t = 512)]
        size: usize,
    },
}

fn main() -> ExitCode {
    bevworld_device::keep_freed_memory();
    init_tracing();
    let cli = Cli::parse();
    if let Some(threads) = cli.threads {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(usize::from(threads))
            .build_global();
        if let Err(error) = pool {
            eprintln!("error: --threads {threads}: {error}");
            return ExitCode::from(2);
        }
    }
    match dispatch(cli.command) {
        Ok(code) => code,
        // One exit-code rule for every command (`commands::Refused`).
        Err(error) => match error.downcast_ref::<commands::Refused>() {
            Some(commands::Refused::Graph(diagnostics)) => {
                eprintln!("{diagnostics}");
                ExitCode::from(2)
            }
            Some(commands::Refused::Flag(_)) => {
                eprintln!("error: {}", describe_chain(&error));
                ExitCode::from(2)
            }
            None => {
                eprintln!("error: {}", describe_chain(&error));
                ExitCode::from(1)
            }
        },
    }
}

/// `--threads`: a whole number of threads, at least 1. Negative values reach this parser
/// (`allow_negative_numbers`), so that they are refused with the reason, not as an unknown
/// flag.
fn thread_count(text: &str) -> Result<u16, String> {
    match text.trim().parse::<i64>() {
        Ok(n) if (1..=i64::from(u16::MAX)).contains(&n) => Ok(n as u16),
        Ok(n) => Err(format!(
            "{n} threads: the tensor ops need at least 1 thread (and at most {})",
            u16::MAX
        )),
        Err(_) => Err(format!("'{text}' is not a whole number of threads")),
    }
}

/// An error and its causes, joined by ": ", each said once. Libraries put their cause in
/// their own message (a path, an OS error) and also return it as the source; printed as a
/// chain, it would read twice ("not found (os error 2): not found (os error 2)").
fn describe_chain(error: &anyhow::Error) -> String {
    let mut text = error.to_string();
    for cause in error.chain().skip(1) {
        let cause = cause.to_string();
        if text.contains(&cause) {
            continue;
        }
        // "opening DIR" then "DIR: no such folder": the cause names the path once more.
        let cause = match cause.split_once(": ") {
            Some((head, rest)) if head.contains(['/', '.']) && text.contains(head) => rest,
            _ => &cause,
        };
        text.push_str(": ");
        text.push_str(cause);
    }
    text
}

fn init_tracing() {
    let filter = tracing_subscriber::EnvFilter::try_from_default_env()
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    let _ = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .try_init();
}

fn dispatch(command: Command) -> Result<ExitCode> {
    match command {
        Command::Run {
            graph,
            mut set,
            metrics,
            no_progress,
            shard,
            overwrite,
        } => {
            if let Some(shard) = shard {
                bevworld_sensors::source::parse_shard(&shard).context("--shard")?;
                set.push(format!("shard={shard}"));
            }
            if overwrite {
                set.extend(
                    export_nodes(&graph)?
                        .into_iter()
                        .map(|id| format!("{id}.overwrite=true")),
                );
            }
            run(&graph, &set, metrics.as_deref(), !no_progress)
        }
        Command::Check { graph, set } => {
            let Some(validated) = load(&graph, &set)? else {
                return Ok(ExitCode::from(2));
            };
            print!("{}", validated.spec.describe());
            let mut refused = false;
            for contract in commands::contracts::of_default_graph(&graph) {
                match validated.spec.check_contract(&contract) {
                    Ok(()) => println!("  serves `{}`", contract.command),
                    Err(diagnostics) => {
                        eprintln!("{diagnostics}");
                        refused = true;
                    }
                }
            }
            if refused {
                return Ok(ExitCode::from(2));
            }
            println!("ok");
            Ok(ExitCode::SUCCESS)
        }
        Command::Graph { graph, dot, set } => {
            let Some(validated) = load(&graph, &set)? else {
                return Ok(ExitCode::from(2));
            };
            if dot {
                print!("{}", bevworld_graph::dot::to_dot(&validated.spec));
            } else {
                print!("{}", validated.spec.describe());
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Kinds => {
            for kind in registry::registry().kinds() {
                println!("{} [{}]: {}", kind.name, kind.role.as_str(), kind.summary);
                for port in &kind.inputs {
                    println!(
                        "    in  {}: {}{}",
                        port.name,
                        port.ty.name(),
                        if port.required { "" } else { " (optional)" }
                    );
                }
                for port in &kind.outputs {
                    println!("    out {}: {}", port.name, port.ty.name());
                }
            }
            Ok(ExitCode::SUCCESS)
        }
        Command::Synth(args) => commands::synth::run(&args),
        Command::Inspect(args) => commands::inspect::run(&args),
        Command::Eval(command) => commands::eval::run(&command),
        Command::Tokenizer(command) => commands::tokenizer::run(&command),
        Command::Train(command) => commands::train::run(&command),
        Command::Device { size } => {
            let (kind, device) = bevworld_device::from_env()?;
            println!("backend: {} ({device:?})", kind.name());
            println!(
                "cpu: {}; vector instructions: {}; host kernels dispatch to {}",
                bevworld_device::cpu_model(),
                bevworld_device::simd_features().join(" "),
                bevworld_blocks::host::dispatch_level()
            );
            let rate = bevworld_device::matmul_gflops(&device, size, 5)?;
            println!("matmul {size}x{size}: {rate:.1} GFLOP/s");
            Ok(ExitCode::SUCCESS)
        }
    }
}

/// The ids of a graph's `export_features` nodes, for `--overwrite`.
fn export_nodes(path: &Path) -> Result<Vec<String>> {
    let Some(graph) = load(path, &[])? else {
        bail!("{} has validation problems (see above)", path.display())
    };
    Ok(graph
        .spec
        .nodes
        .iter()
        .filter(|n| n.kind.name == "export_features")
        .map(|n| n.id.clone())
        .collect())
}

/// Validates a graph (building nothing); prints every problem and returns None when there are
/// any.
fn load(path: &Path, set: &[String]) -> Result<Option<bevworld_graph::ValidatedGraph>> {
    let overrides = set
        .iter()
        .map(|text| Override::parse(text).map_err(|e| commands::refuse(format!("--set {e}"))))
        .collect::<Result<Vec<_>>>()?;
    match bevworld_graph::load(path, &registry::registry(), &overrides) {
        Ok(graph) => Ok(Some(graph)),
        Err(diagnostics) => {
            eprintln!("{diagnostics}");
            Ok(None)
        }
    }
}

fn run(path: &Path, set: &[String], metrics: Option<&Path>, progress: bool) -> Result<ExitCode> {
    let Some(validated) = load(path, set)? else {
        return Ok(ExitCode::from(2));
    };
    let show_progress = progress && validated.spec.settings.progress;
    let name = validated.spec.name.clone();
    let graph = match validated.build() {
        Ok(graph) => graph,
        Err(diagnostics) => {
            eprintln!("{diagnostics}");
            return Ok(ExitCode::from(2));
        }
    };
    let stop = StopHandle::new();
    let handler_stop = stop.clone();
    static PRESSES: AtomicUsize = AtomicUsize::new(0);
    ctrlc::set_handler(move || {
        if PRESSES.fetch_add(1, Ordering::SeqCst) == 0 {
            eprintln!("\ninterrupt: draining (press Ctrl-C again to abort)");
            handler_stop.drain();
        } else {
            handler_stop.abort();
        }
    })
    .context("installing the Ctrl-C handler")?;

    let observer = show_progress
        .then(|| Arc::new(ProgressBar::new(&name)) as Arc<dyn bevworld_graph::RunObserver>);
    let outcome = bevworld_graph::run(graph, RunOptions { stop, observer });
    print!("{}", outcome.report.table());
    if let Some(file) = metrics {
        if let Some(parent) = file.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("creating {}", parent.display()))?;
        }
        bevworld_graph::io::write_atomic_now(file, outcome.report.to_json().as_bytes())
            .with_context(|| format!("writing metrics to {}", file.display()))?;
    }
    match outcome.error {
        // A second Ctrl-C: the shell's convention for a run ended by SIGINT.
        Some(error @ bevworld_graph::RunError::Aborted { .. }) => {
            eprintln!("error: {error}");
            Ok(ExitCode::from(130))
        }
        Some(error) => bail!(error),
        None => Ok(ExitCode::SUCCESS),
    }
}

/// The run's progress bar: items released by the sources against the totals they announce,
/// shown when stderr is a terminal.
struct ProgressBar(indicatif::ProgressBar);

impl ProgressBar {
    fn new(graph: &str) -> Self {
        let bar = indicatif::ProgressBar::new(0);
        bar.set_style(
            indicatif::ProgressStyle::with_template(
                "{spinner} {msg} [{bar:30}] {pos}/{len} items, {per_sec}, eta {eta}",
            )
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        bar.set_message(graph.to_string());
        Self(bar)
    }
}

impl bevworld_graph::RunObserver for ProgressBar {
    fn expect_items(&self, items: u64) {
        self.0.inc_length(items);
    }

    fn item_released(&self) {
        self.0.inc(1);
    }

    fn finished(&self) {
        self.0.finish_and_clear();
    }
}
