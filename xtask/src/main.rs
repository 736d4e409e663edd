//! Project automation. Run `cargo xtask help`.
//!
//! - `cargo xtask test`: everything: the firmware and the STM32F407 image for the target
//!   (found or installed toolchain, see [`toolchain`]), their lint, the host workspace tests
//!   (release, then the default debug profile for the crates that do not depend on the
//!   trainer), the
//!   QEMU tests (`tests/tests/qemu_*.rs`, ignored by a plain `cargo test`) pointed at the
//!   images, the firmware library's host unit tests, `nemm sweep` through a one-node Slurm
//!   ([`slurm`]), nemm-kernels' and nemm-core's feature sets on the host and the target (`features`), the
//!   `rust-version` check (`msrv`), a short `bench-target`, and the C interface: the host C
//!   unit test and the C example on the Cortex-M4F against the firmware ([`c_interface`]).
//! - `cargo xtask build-board`: the STM32F407 image (`boards/nemm-stm32f407`), as flashed and
//!   for QEMU's netduinoplus2 ([`board`]).
//! - `cargo xtask bench-target`: instructions per estimator step on the emulated Cortex-M4
//!   and Cortex-M7, per model kind and integrator, and the cycles the cycle model
//!   ([`cycles`]) estimates from the traced instruction mix.
//! - `cargo xtask firmware-model`: trains the model the firmware embeds ([`model`]).
//! - `cargo xtask e2e`: held-out runs through the firmware in QEMU, its force error against
//!   the trainer's ([`model`]).
//! - `cargo xtask results`: the target figures (instructions per step, flash, RAM, stack)
//!   written into `docs/results.md`; `--training DIR` copies a training report's tables
//!   there, `--host` writes the host criterion benches' figures ([`results`],
//!   [`host_bench`]), `--observer` the alpha observer's accuracy on the virtual bench, `--c`
//!   the C interface's figures (the C example on the Cortex-M4F, as `c-test` runs it).
//! - `cargo xtask bench-slurm`: the overhead of `nemm sweep`'s Slurm engine against the local
//!   one on a one-node cluster ([`slurm`]).
//! - `cargo xtask c-lib`, `c-test`, `c-header`: the C interface (`nemm-c`): its static
//!   libraries, its tests, its generated header ([`c_interface`]).

mod board;
mod c_interface;
mod checks;
mod cycles;
mod firmware;
mod host_bench;
mod model;
mod results;
mod slurm;
mod target_bench;
use nemm_slot as slot;
mod toolchain;

use clap::{CommandFactory, Parser, Subcommand, ValueEnum};
use nemm_elf::Elf;
use std::path::PathBuf;
use std::process::{Command, ExitCode};
use std::time::Instant;
use toolchain::Toolchain;

/// Project automation for NEMM.
#[derive(Debug, Parser)]
#[command(name = "cargo xtask", bin_name = "cargo xtask", version, about)]
struct Cli {
    #[command(subcommand)]
    command: Option<Cmd>,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// Every test: the firmware (target build, lint), the host workspace (release, and the
    /// default debug profile for the crates that do not depend on the trainer), the QEMU tests,
    /// nemm-kernels' and nemm-core's feature sets (`features`), the rust-version check (`msrv`), a short
    /// bench-target, the C interface (`c-test`), `nemm sweep` through a one-node Slurm
    /// (skipped with a message without root or slurm-wlm and munge).
    Test {
        /// Skip everything that needs the embedded toolchain (no firmware, no QEMU tests).
        #[arg(long)]
        host_only: bool,
    },
    /// Instructions and estimated cycles per estimator step in QEMU, per board, model kind
    /// and integrator; and per step of the alpha observer.
    ///
    /// QEMU counts instructions (-icount shift=0); N steps of the bench trace after 200
    /// warm-up steps. Each line reads
    ///
    /// `target-step model=<kind> integrator=<rk4|rk3> mode=<mode> instructions_per_step=<N>`
    ///
    /// and mode=table adds segments=, table_bytes= (RAM), max_rel_error_ppb=, kinks= and
    /// build_instructions= (building the tables at boot). Then, per chip (m4f on
    /// mps2-an386, m7 on mps2-an500), one line per model kind and integrator:
    ///
    /// `target-cycles chip=<m4f|m7> board=<machine> model=<kind> integrator=<rk4|rk3>
    /// mode=<mode> instructions_per_step=<N> est_cycles_per_step=<C>
    /// cycles_per_instruction=<x> budget_<f>mhz=<fraction of the 10 kHz period>`
    ///
    /// from the instruction mix of two traced steps priced by the cycle model
    /// (nemm-firmware/README.md, "Cycle model").
    ///
    /// With the NEMM among the models, the firmware's alpha observer (the bench-controller
    /// mode; exact mode whatever --mode, the example NEMM, the model's own force as the
    /// measurement):
    ///
    /// `target-observer model=nemm integrator=<rk4|rk3> levels=<n> model_steps=<n>
    /// instructions_per_step=<N> ram_bytes=<B>`
    ///
    /// and its `target-cycles` line per chip (model `nemm-observer`, from one traced observer
    /// step).
    BenchTarget {
        /// The estimator's evaluation: the exact scalers or the tabulated fast path.
        #[arg(long, value_enum, default_value_t = Mode::Exact)]
        mode: Mode,
        /// Measured steps of the bench trace.
        #[arg(long, default_value_t = 4000)]
        steps: u32,
        /// Model to benchmark (repeatable; default: every kind without the element): a kind
        /// (sem, linear-emm, nemm-light, nemm), or an EMM-family kind with the example
        /// lost-motion element, `<kind>+lm` (e.g. nemm+lm).
        #[arg(long = "model", value_parser = Variant::parse, value_name = "KIND[+lm]")]
        models: Vec<Variant>,
        /// Board to benchmark (repeatable; default: both).
        #[arg(long = "board", value_enum, value_name = "BOARD")]
        boards: Vec<firmware::Board>,
        /// Instructions only: no traced mix, no cycle estimate.
        #[arg(long)]
        no_cycles: bool,
    },
    /// Build the firmware images, print their flash and RAM use, and run the application in
    /// QEMU to print its stack at the end of the boot (`boot-stack bytes=<n>`, by stack
    /// painting) and its boot time in each evaluation mode.
    ///
    /// The boot time: `boot board=<machine> mode=<mode> instructions=<n>
    /// est_ms_at_<f>mhz=<t>`, instructions from reset to the estimator ready (QEMU's
    /// instruction count; the first step follows one 100 us period later), and the time they
    /// take at the chip's stated clocks at the cycles per instruction of the cycle model for
    /// the exact NEMM step.
    BuildTarget {
        /// Board to build (repeatable; default: both).
        #[arg(long = "board", value_enum, value_name = "BOARD")]
        boards: Vec<firmware::Board>,
    },
    /// Build and link the STM32F407 image (boards/nemm-stm32f407), as flashed and for QEMU's
    /// netduinoplus2, and print their flash and RAM use.
    BuildBoard,
    /// Run the firmware in QEMU with firmware options.
    ///
    /// e.g. `cargo xtask run-target -- period_ticks=100000 fault=bus@3000+20
    /// fault=nan@5000+40 samples=2000`
    RunTarget {
        /// Firmware options (`key=value`, see nemm-firmware/src/options.rs).
        #[arg(
            trailing_var_arg = true,
            allow_hyphen_values = true,
            value_name = "OPTION"
        )]
        options: Vec<String>,
    },
    /// Write the target figures (instructions per step, flash, RAM, stack) into
    /// docs/results.md.
    ///
    /// With --training DIR, fill its training block from a finished `nemm compare` / `nemm demo`
    /// report directory instead (table4.md, table5.md and degradation.md if present, report.json).
    /// With --table3 DIR, fill the table3 block from a collected `nemm sweep --grid table3`
    /// report directory (table3.md, sweep-jobs.json). With --state-priors DIR, fill the
    /// state-priors block (the ablation of the priors in the state: held by construction
    /// against the physics penalty at each lambda_ph) from a collected `nemm sweep --grid
    /// state-priors` report directory (state-priors.md, sweep-jobs.json).
    /// With --tables, fill the tables block: the fast path's error against the exact one on the
    /// firmware's trained model and the example models (host, minutes). With --host, run the host
    /// criterion benches (nemm-core's `step` with libm and micromath, nemm-train's `gradient`;
    /// minutes) and fill the host block. With --observer, run `nemm diagnose` on out/bench
    /// (generate it first with `nemm bench generate --out out/bench`) with the firmware's trained
    /// model and fill the observer block and docs/img/level_step.png (minutes). With --c, run the
    /// C example on the emulated Cortex-M4F as `cargo xtask c-test` does (the firmware's blob)
    /// and fill the c block: instructions per step, stack peak, image sections.
    Results {
        /// A report directory of `nemm compare` or `nemm demo`.
        #[arg(long, value_name = "DIR", conflicts_with_all = ["table3", "state_priors", "tables", "host", "observer", "c"])]
        training: Option<PathBuf>,
        /// A collected `nemm sweep --grid table3` report directory (the `table3` block).
        #[arg(long, value_name = "DIR", conflicts_with_all = ["state_priors", "tables", "host", "observer", "c"])]
        table3: Option<PathBuf>,
        /// A collected `nemm sweep --grid state-priors` report directory (the `state-priors`
        /// block).
        #[arg(long, value_name = "DIR", conflicts_with_all = ["tables", "host", "observer", "c"])]
        state_priors: Option<PathBuf>,
        /// Measure the tabulated fast path instead (the `tables` block).
        #[arg(long, conflicts_with_all = ["host", "observer", "c"])]
        tables: bool,
        /// Run the host criterion benches instead (the `host` block).
        #[arg(long, conflicts_with_all = ["observer", "c"])]
        host: bool,
        /// Run `nemm diagnose` on out/bench with the firmware's trained model instead (the
        /// `observer` block and docs/img/level_step.png).
        #[arg(long, conflicts_with = "c")]
        observer: bool,
        /// Run the C example on the emulated Cortex-M4F instead (the `c` block: the C
        /// interface's figures).
        #[arg(long)]
        c: bool,
        /// With --host: do not run the benches, write the block from the results of the last
        /// complete --host run (in `<target>/criterion-host`).
        #[arg(long, requires = "host")]
        no_run: bool,
        /// Measured steps of the bench trace.
        #[arg(long, default_value_t = 4000)]
        steps: u32,
        /// Write the block although the work tree (or, with --training, the code that trained
        /// the report) has uncommitted changes; the block then names the commit `+dirty`.
        #[arg(long)]
        allow_dirty: bool,
    },
    /// The overhead of `nemm sweep --engine slurm` against the local engine on a one-node
    /// Slurm cluster (started as root; Debian's slurm-wlm and munge): submission, time from
    /// submission to each task's start, wall time, collection. One `slurm-overhead` line.
    BenchSlurm {
        /// Tiny configurations of the sweep (two at a time).
        #[arg(long, default_value_t = 4)]
        tasks: usize,
    },
    /// Say which toolchain route builds the firmware (install it if root).
    Toolchain,
    /// Build the C interface's static libraries (`libnemm_c.a`) for the host and the
    /// Cortex-M4F, and print their paths and the header's.
    CLib {
        /// The host library only (no embedded toolchain needed).
        #[arg(long)]
        host_only: bool,
    },
    /// Test the C interface: the host C unit test (`examples/c/test_host.c`), then the C
    /// example (`examples/c/replay.c`, arm-none-eabi-gcc) in QEMU, whose forces must be
    /// bit-identical to the Rust firmware's on the same trace, blob, alpha and mode.
    CTest {
        /// The host C unit test only.
        #[arg(long)]
        host_only: bool,
    },
    /// Regenerate the C header `nemm-c/include/nemm.h` from nemm-c (cbindgen).
    CHeader,
    /// nemm-kernels' and nemm-core's tests with every valid feature set on the host, and their
    /// libraries built for the target with every `no_std` set.
    Features,
    /// Check that every workspace package's `rust-version` is at least what every crate it
    /// compiles declares (one `rust-version package=..` line each).
    Msrv,
    /// Train the model the firmware images embed (nemm-firmware/data/trained-nemm.nemm).
    ///
    /// One `nemm train` on the default virtual bench (seed 1, generated into
    /// out/firmware-bench if absent): the NEMM at the demo's budget, 15 % oil loss held out.
    /// The blob records the command, the dataset and the commit (`nemm inspect` prints them).
    FirmwareModel {
        /// Velocity preprocessing: `causal` trains on the firmware's online velocity estimate
        /// (`nemm train --velocity causal`); default: the trainer's zero-phase filter.
        #[arg(long, value_parser = ["causal"])]
        velocity: Option<String>,
        /// Output blob (relative to the workspace root).
        #[arg(long, default_value = model::FIRMWARE_MODEL)]
        out: String,
    },
    /// End-to-end accuracy: held-out runs (nemm-firmware/data/e2e) through the firmware's SPI
    /// sensor path in QEMU.
    ///
    /// One line per run: `e2e run=<file> firmware_rmse_n=<x> host_rmse_n=<y>`, where
    /// host_rmse_n is the trainer's whole-run evaluation of the same model on the same run.
    /// Fails if the firmware is worse than 1.10 x host + 2 N on a run.
    E2e {
        /// A weights blob to run instead of the embedded one (patched into the slot).
        #[arg(long, value_name = "FILE")]
        weights: Option<PathBuf>,
    },
}

/// The estimator's evaluation mode (the firmware's `mode=` option).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Mode {
    /// The scalers evaluated as they are.
    Exact,
    /// Scalers tabulated at boot, then interpolated.
    Table,
}

impl Mode {
    /// The firmware's name of the mode.
    pub fn name(self) -> &'static str {
        match self {
            Mode::Exact => "exact",
            Mode::Table => "table",
        }
    }
}

/// A model kind (an example blob `nemm-firmware/data/example-<kind>.nemm`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Kind {
    /// Static empirical model: force-velocity map per oil-loss level.
    Sem,
    /// EMM with constant parameters.
    LinearEmm,
    /// EMM with a neural `b_fl(v_st, alpha)`.
    NemmLight,
    /// EMM with neural `b_fl`, `b_pr` and `k_pr`.
    Nemm,
}

impl Kind {
    /// Every kind, in the order of the paper's tables.
    pub const ALL: [Kind; 4] = [Kind::Sem, Kind::LinearEmm, Kind::NemmLight, Kind::Nemm];

    /// The name in the blobs' file names and in the firmware's output.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Sem => "sem",
            Kind::LinearEmm => "linear-emm",
            Kind::NemmLight => "nemm-light",
            Kind::Nemm => "nemm",
        }
    }
}

/// A benchmarked model: an example model of a kind, with or without the example
/// lost-motion element (`nemm_core::testing::EXAMPLE_LOST_MOTION`, which the benchmark adds
/// with `lost-motion=1`). Its name is the kind's, plus [`Variant::LOST_MOTION_SUFFIX`] with
/// the element: `nemm`, `nemm+lm` (`--model` of `bench-target`, `model=` of its lines).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Variant {
    /// The model kind (its example blob in the weights slot).
    pub kind: Kind,
    /// With the example lost-motion element.
    pub lost_motion: bool,
}

impl Variant {
    /// What the name of a model with the element appends to the kind's (the benchmark's
    /// `kind=` appends the same).
    pub const LOST_MOTION_SUFFIX: &'static str = "+lm";

    /// Every kind without the element, in the order of [`Kind::ALL`].
    pub const ALL: [Variant; 4] = [
        Variant::plain(Kind::Sem),
        Variant::plain(Kind::LinearEmm),
        Variant::plain(Kind::NemmLight),
        Variant::plain(Kind::Nemm),
    ];

    /// The EMM-family kinds with the element (the SEM refuses it).
    pub const WITH_LOST_MOTION: [Variant; 3] = [
        Variant::with_lost_motion(Kind::LinearEmm),
        Variant::with_lost_motion(Kind::NemmLight),
        Variant::with_lost_motion(Kind::Nemm),
    ];

    /// `kind` without the element.
    pub const fn plain(kind: Kind) -> Self {
        Self {
            kind,
            lost_motion: false,
        }
    }

    /// `kind` with the element.
    pub const fn with_lost_motion(kind: Kind) -> Self {
        Self {
            kind,
            lost_motion: true,
        }
    }

    /// `<kind>` or `<kind>+lm`.
    pub fn name(self) -> String {
        let suffix = if self.lost_motion {
            Self::LOST_MOTION_SUFFIX
        } else {
            ""
        };
        format!("{}{suffix}", self.kind.name())
    }

    /// The variant of a name ([`Variant::name`]); `sem+lm` is refused.
    pub fn parse(name: &str) -> Result<Self, String> {
        let (kind, lost_motion) = match name.strip_suffix(Self::LOST_MOTION_SUFFIX) {
            Some(kind) => (kind, true),
            None => (name, false),
        };
        let kind = Kind::from_str(kind, false).map_err(|_| {
            let names: Vec<String> = Kind::ALL
                .iter()
                .map(|k| format!("{}[{}]", k.name(), Self::LOST_MOTION_SUFFIX))
                .collect();
            format!("unknown model `{name}` (one of {})", names.join(", "))
        })?;
        if lost_motion && kind == Kind::Sem {
            return Err(format!("`{name}`: the SEM has no lost-motion element"));
        }
        Ok(Self { kind, lost_motion })
    }

    /// The benchmark's options for this variant (besides mode, steps, ...).
    pub fn bench_args(self) -> Vec<String> {
        if self.lost_motion {
            vec!["lost-motion=1".to_string()]
        } else {
            Vec::new()
        }
    }
}

/// Workspace locations.
pub struct Paths {
    /// Workspace root.
    pub root: PathBuf,
    /// Cargo's target directory of the workspace.
    pub target: PathBuf,
}

impl Paths {
    fn find() -> Result<Self, String> {
        // `cargo run` (the `cargo xtask` alias) sets CARGO_MANIFEST_DIR for the process: the
        // checkout being worked on, even when a target directory shared by several checkouts
        // hands out a binary built in another one. The compile-time value is the fallback.
        let manifest_dir = std::env::var_os("CARGO_MANIFEST_DIR")
            .map(PathBuf::from)
            .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")));
        let root = manifest_dir
            .parent()
            .ok_or("xtask has no parent directory")?
            .to_path_buf();
        let target = match std::env::var_os("CARGO_TARGET_DIR") {
            Some(t) => root.join(t),
            None => cargo_metadata::MetadataCommand::new()
                .cargo_path(toolchain::host_cargo())
                .current_dir(&root)
                .no_deps()
                .exec()
                .map_err(|e| format!("cargo metadata: {e}"))?
                .target_directory
                .into_std_path_buf(),
        };
        Ok(Self { root, target })
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.command {
        Some(Cmd::Test { host_only }) => test(host_only),
        Some(Cmd::BenchTarget {
            mode,
            steps,
            models,
            boards,
            no_cycles,
        }) => bench_target(mode, steps, &models, &boards, !no_cycles),
        Some(Cmd::BuildTarget { boards }) => build_target(&boards),
        Some(Cmd::Features) => Paths::find().and_then(|paths| {
            let tc = toolchain::detect(&paths.root, true)?;
            checks::features(Some(&tc), &paths)
        }),
        Some(Cmd::Msrv) => Paths::find().and_then(|paths| checks::msrv(&paths)),
        Some(Cmd::BuildBoard) => build_board(),
        Some(Cmd::RunTarget { options }) => run_target(&options),
        Some(Cmd::Results {
            training,
            table3,
            state_priors,
            tables,
            host,
            observer,
            c,
            no_run,
            steps,
            allow_dirty,
        }) => match (training, table3, state_priors) {
            (Some(dir), _, _) => {
                Paths::find().and_then(|p| results::training(&p, &dir, allow_dirty))
            }
            (None, Some(dir), _) => Paths::find()
                .and_then(|p| results::sweep_block(&p, &dir, allow_dirty, &results::TABLE3)),
            (None, None, Some(dir)) => Paths::find()
                .and_then(|p| results::sweep_block(&p, &dir, allow_dirty, &results::STATE_PRIORS)),
            _ if tables => Paths::find().and_then(|p| results::tables(&p, allow_dirty)),
            _ if host => Paths::find().and_then(|p| results::host(&p, no_run, allow_dirty)),
            _ if observer => Paths::find().and_then(|p| results::observer(&p, allow_dirty)),
            _ if c => setup().and_then(|(tc, p)| results::c_example(&tc, &p, allow_dirty)),
            _ => setup().and_then(|(tc, paths)| results::target(&tc, &paths, steps, allow_dirty)),
        },
        Some(Cmd::BenchSlurm { tasks }) => Paths::find().and_then(|p| slurm::bench(&p, tasks)),
        Some(Cmd::Toolchain) => setup().map(|(tc, _)| println!("{}", tc.describe())),
        Some(Cmd::CLib { host_only: true }) => {
            Paths::find().and_then(|p| c_interface::libs(&p, None))
        }
        Some(Cmd::CLib { host_only: false }) => {
            setup().and_then(|(tc, p)| c_interface::libs(&p, Some(&tc)))
        }
        Some(Cmd::CTest { host_only }) => c_test(host_only),
        Some(Cmd::CHeader) => Paths::find().and_then(|p| c_interface::header(&p)),
        Some(Cmd::FirmwareModel { velocity, out }) => {
            Paths::find().and_then(|p| model::firmware_model(&p, velocity.as_deref(), &out))
        }
        Some(Cmd::E2e { weights }) => {
            setup().and_then(|(tc, p)| model::e2e(&tc, &p, weights.as_deref()))
        }
        None => Cli::command()
            .print_help()
            .map_err(|e| format!("cannot print the help: {e}")),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("xtask: error: {e}");
            ExitCode::FAILURE
        }
    }
}

/// Runs `cmd`, echoing it; fails with its exit status.
pub fn run(cmd: &mut Command) -> Result<(), String> {
    eprintln!("xtask: running {}", show(cmd));
    let status = cmd
        .status()
        .map_err(|e| format!("cannot start {}: {e}", show(cmd)))?;
    if status.success() {
        Ok(())
    } else {
        Err(format!("{} failed with {status}", show(cmd)))
    }
}

/// A command as a shell line (environment changes first).
fn show(cmd: &Command) -> String {
    let mut s = String::new();
    if let Some(dir) = cmd.get_current_dir() {
        s += &format!("(in {}) ", dir.display());
    }
    for (k, v) in cmd.get_envs() {
        if let (Some(v), false) = (v, k == "PATH") {
            s += &format!("{}={} ", k.to_string_lossy(), v.to_string_lossy());
        }
    }
    s += &cmd.get_program().to_string_lossy();
    for a in cmd.get_args() {
        s += " ";
        s += &a.to_string_lossy();
    }
    s
}

fn cargo() -> Command {
    Command::new(toolchain::host_cargo())
}

fn setup() -> Result<(Toolchain, Paths), String> {
    let paths = Paths::find()?;
    let tc = toolchain::detect(&paths.root, true)?;
    eprintln!("xtask: firmware toolchain: {}", tc.describe());
    Ok((tc, paths))
}

/// The integration tests that run the firmware in QEMU (`tests/tests/qemu_*.rs`), ignored by
/// a plain `cargo test`: all of them on the mps2-an386 images.
const QEMU_TESTS: [&str; 8] = [
    "qemu_board",
    "qemu_e2e",
    "qemu_faults",
    "qemu_model",
    "qemu_no_panic",
    "qemu_observer",
    "qemu_parity",
    "qemu_weights",
];

/// The QEMU tests run on the mps2-an500 (Cortex-M7) images too: bit-identity with the host,
/// end-to-end accuracy, faults, no panic path, the weights errors and the alpha observer
/// (about two minutes).
/// Not `qemu_board` (the STM32F407 image) nor `qemu_model` (it trains a model to check the
/// embedded blob, which does not depend on the core).
const QEMU_TESTS_AN500: [&str; 6] = [
    "qemu_e2e",
    "qemu_faults",
    "qemu_no_panic",
    "qemu_observer",
    "qemu_parity",
    "qemu_weights",
];

/// The crates whose tests `cargo xtask test` also runs in the default (debug) profile: those
/// compiled into a user's firmware, whose debug builds users ship.
const DEBUG_PROFILE_CRATES: [&str; 4] = ["nemm-kernels", "nemm-core", "nemm-c", "nemm-slot"];

fn test(host_only: bool) -> Result<(), String> {
    let started = Instant::now();
    let mut clock = StageClock::start();
    let paths = Paths::find()?;
    let firmware = if host_only {
        eprintln!("xtask: --host-only: no firmware build, no QEMU tests");
        None
    } else {
        // Fails here, before the long host build, if the toolchain is missing.
        let (tc, paths) = setup()?;
        clock.lap("toolchain set-up");
        let images = firmware::build_all(&tc, &paths, &firmware::Board::ALL)?;
        clock.lap("firmware images");
        let board_images = board::build(&tc, &paths)?;
        clock.lap("board image");
        match tc.clippy_gap() {
            None => {
                firmware::clippy(&tc, &paths)?;
                board::clippy(&tc, &paths)?;
                c_interface::target_clippy(&tc, &paths)?;
            }
            Some(what) => eprintln!("xtask: firmware lint skipped: no {what}"),
        }
        clock.lap("firmware, board and C target lint");
        Some((tc, paths, images, board_images))
    };
    run(cargo()
        .args(["test", "--workspace", "--release", "--no-fail-fast"])
        .current_dir(&paths.root))?;
    clock.lap("host tests (release)");
    c_interface::host_test(&paths)?;
    clock.lap("C interface host test");
    slurm::test(&paths)?;
    clock.lap("Slurm test");
    if let Some((tc, _, images, board_images)) = &firmware {
        // The QEMU tests, with the images; `--workspace` keeps the features (and so the
        // build) of the run above.
        for im in images {
            let tests: &[&str] = match im.board {
                firmware::Board::An386 => &QEMU_TESTS,
                firmware::Board::An500 => &QEMU_TESTS_AN500,
            };
            let mut qemu_tests = cargo();
            qemu_tests.args(["test", "--workspace", "--release", "--no-fail-fast"]);
            for t in tests {
                qemu_tests.args(["--test", t]);
            }
            qemu_tests.args(["--", "--ignored"]);
            im.test_env(&mut qemu_tests, tc);
            run(qemu_tests
                .env("NEMM_BOARD_ELF", &board_images.board)
                .env("NEMM_BOARD_QEMU_ELF", &board_images.qemu)
                .current_dir(&paths.root))?;
            clock.lap(&format!("QEMU tests ({})", im.board.machine()));
        }
        // The C example against the firmware, on the Cortex-M4F image.
        if let Some(an386) = images.iter().find(|im| im.board == firmware::Board::An386) {
            c_interface::target_example(tc, &paths, an386)?;
            clock.lap("C example on the target");
        }
    }
    // The firmware library's own unit tests, on the host.
    run(cargo()
        .args(["test", "--release", "-p", "nemm-firmware", "--lib"])
        .current_dir(&paths.root))?;
    clock.lap("firmware library host tests");
    // The default (debug) profile: debug assertions and overflow checks on, nemm-core at
    // opt-level 0 (as its users' debug builds have it), the rest as the dev profile of
    // Cargo.toml sets it; the tests on the default 2 MiB test threads. The crates compiled
    // into a user's firmware: the kernels, nemm-core (the no_std runtime whose debug build
    // users ship in debug firmware), the C interface and the slot. The host tools (the ELF
    // helper, xtask), nemm-train and nemm-tests run in release above: in this profile the
    // trainer would build burn a second time and repeat the training runs, the longest
    // tests of the workspace.
    run(cargo()
        .args(["test", "--no-fail-fast"])
        .args(DEBUG_PROFILE_CRATES.iter().flat_map(|c| ["-p", c]))
        .current_dir(&paths.root))?;
    clock.lap("debug-profile tests");
    checks::example(&paths)?;
    clock.lap("example");
    checks::features(firmware.as_ref().map(|f| &f.0), &paths)?;
    clock.lap("feature sets");
    checks::msrv(&paths)?;
    clock.lap("rust-version check");
    if let Some((tc, paths, images, board_images)) = firmware {
        for im in &images {
            let steps = target_bench::run(&tc, &paths, im, Mode::Exact, 50, &Variant::ALL)?;
            for f in &steps {
                eprintln!(
                    "xtask: (smoke, 50 steps, {}) {}",
                    im.board.machine(),
                    f.line()
                );
            }
            let observer = target_bench::observer(&tc, im, 50)?;
            eprintln!(
                "xtask: (smoke, 50 steps, {}) {}",
                im.board.machine(),
                observer.line()
            );
            // The cycle model's trace, on the smallest model.
            let sem: Vec<_> = steps.into_iter().filter(|f| f.model == "sem").collect();
            for c in cycles::estimate(&tc, &paths, im, Mode::Exact, &sem)? {
                eprintln!("xtask: (smoke) {}", c.line());
            }
        }
        let named: Vec<(String, &std::path::Path)> = images
            .iter()
            .flat_map(|im| {
                [
                    (im.named()[0].0.clone(), im.app_release.as_path()),
                    (im.named()[1].0.clone(), im.app.as_path()),
                ]
            })
            .chain(
                board_images
                    .named()
                    .into_iter()
                    .map(|(n, p)| (n.to_string(), p)),
            )
            .collect();
        for (name, path) in named {
            eprintln!(
                "xtask: {}",
                firmware::memory_report(&name, &Elf::read(path)?)
            );
        }
        clock.lap("target benchmark smoke test and memory report");
    }
    clock.summary();
    eprintln!(
        "xtask: all tests passed in {:.0} s",
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The wall time of each stage of `cargo xtask test`, printed as each stage ends (so a
/// failed run still shows where its time went) and as a table at the end.
struct StageClock {
    /// The stages so far: name and seconds.
    stages: Vec<(String, f64)>,
    /// When the running stage began.
    since: Instant,
}

impl StageClock {
    /// A clock whose first stage begins now.
    fn start() -> Self {
        Self {
            stages: Vec::new(),
            since: Instant::now(),
        }
    }

    /// Ends the running stage under `name` and starts the next.
    fn lap(&mut self, name: &str) {
        let now = Instant::now();
        let secs = now.duration_since(self.since).as_secs_f64();
        eprintln!("xtask: stage '{name}' took {secs:.0} s");
        self.stages.push((name.to_string(), secs));
        self.since = now;
    }

    /// Prints every stage's time.
    fn summary(&self) {
        eprintln!("xtask: stage times:");
        for (name, secs) in &self.stages {
            eprintln!("xtask:   {secs:>6.0} s  {name}");
        }
    }
}

/// `boards`, or both if empty.
fn boards_or_all(boards: &[firmware::Board]) -> &[firmware::Board] {
    if boards.is_empty() {
        &firmware::Board::ALL
    } else {
        boards
    }
}

fn bench_target(
    mode: Mode,
    steps: u32,
    models: &[Variant],
    boards: &[firmware::Board],
    with_cycles: bool,
) -> Result<(), String> {
    let kinds = if models.is_empty() {
        &Variant::ALL[..]
    } else {
        models
    };
    let (tc, paths) = setup()?;
    let images = firmware::build_all(&tc, &paths, boards_or_all(boards))?;
    for im in &images {
        let figures = target_bench::run(&tc, &paths, im, mode, steps, kinds)?;
        // The alpha observer (exact mode whatever `mode`), on the example NEMM.
        let observer = if kinds.contains(&Variant::plain(Kind::Nemm)) {
            Some(target_bench::observer(&tc, im, steps)?)
        } else {
            None
        };
        if im.board == firmware::Board::An386 {
            for f in &figures {
                println!("{}", f.line());
            }
            if let Some(o) = &observer {
                println!("{}", o.line());
            }
        }
        if with_cycles {
            for c in cycles::estimate(&tc, &paths, im, mode, &figures)? {
                println!("{}", c.line());
            }
            if let Some(o) = &observer {
                println!("{}", cycles::estimate_observer(&tc, &paths, im, o)?.line());
            }
        }
        eprintln!(
            "xtask: {}",
            firmware::memory_report(
                &format!("firmware ({})", im.named()[0].0),
                &Elf::read(&im.app_release)?
            )
        );
    }
    Ok(())
}

/// Boot figures of one image and mode: instructions from reset to the estimator ready (the
/// first step follows one sample period later), and the estimated time at the chip's clocks.
#[derive(Debug, Clone)]
pub struct BootFigures {
    /// The board.
    pub board: firmware::Board,
    /// `exact` or `table`.
    pub mode: &'static str,
    /// Instructions from reset to the estimator ready.
    pub instructions: u64,
    /// Cycles per instruction the estimate uses (the exact NEMM step's, by the cycle model).
    pub cycles_per_instruction: f64,
}

impl BootFigures {
    /// Estimated milliseconds at `mhz`.
    pub fn ms_at(&self, mhz: u32) -> f64 {
        self.instructions as f64 * self.cycles_per_instruction / (f64::from(mhz) * 1000.0)
    }

    /// `boot board=<machine> mode=<mode> instructions=<n> est_ms_at_<f>mhz=<t>` (one per
    /// stated clock of the chip).
    pub fn line(&self) -> String {
        let mut l = format!(
            "boot board={} mode={} instructions={}",
            self.board.machine(),
            self.mode,
            self.instructions
        );
        for &mhz in crate::cycles::Chip::of(self.board).clocks_mhz() {
            l += &format!(" est_ms_at_{mhz}mhz={:.1}", self.ms_at(mhz));
        }
        l
    }
}

/// Runs the application of `images` in each mode of [`firmware::STACK_RUNS`]: stack and boot
/// figures. The boot's cycles per instruction are those of the exact NEMM RK4 step (the
/// network kernels, which also build the tables in table mode).
pub fn boot_figures(
    tc: &Toolchain,
    paths: &Paths,
    images: &firmware::Images,
) -> Result<Vec<(firmware::StackFigures, BootFigures)>, String> {
    let nemm = target_bench::image_with_example(paths, images, Kind::Nemm)?;
    let mix = cycles::trace_mix(
        tc,
        images.board,
        (&nemm, Variant::plain(Kind::Nemm)),
        Mode::Exact,
        "rk4",
    )?;
    let cpi = mix.cycles_per_instruction(cycles::Chip::of(images.board));
    let mut out = Vec::new();
    for (mode, options) in firmware::STACK_RUNS {
        let s = firmware::stack_figures(tc, images, options)?;
        let b = BootFigures {
            board: images.board,
            mode,
            instructions: s.boot_instructions,
            cycles_per_instruction: cpi,
        };
        out.push((s, b));
    }
    Ok(out)
}

fn build_target(boards: &[firmware::Board]) -> Result<(), String> {
    let (tc, paths) = setup()?;
    let images = firmware::build_all(&tc, &paths, boards_or_all(boards))?;
    for im in &images {
        let named = im.named();
        print_memory(
            &named
                .iter()
                .map(|(n, p)| (n.as_str(), *p))
                .collect::<Vec<_>>(),
        )?;
    }
    for im in &images {
        for (stack, boot) in boot_figures(&tc, &paths, im)? {
            println!("{} board={}", stack.line(boot.mode), im.board.machine());
            println!("{} tables={}", boot.line(), stack.tables());
        }
    }
    Ok(())
}

/// Prints each image's sections and its memory report.
fn print_memory(named: &[(&str, &std::path::Path)]) -> Result<(), String> {
    for (name, path) in named {
        let elf = Elf::read(path)?;
        println!("{}\n{}", path.display(), elf.memory_use().table());
        println!("{}\n", firmware::memory_report(name, &elf));
    }
    Ok(())
}

fn build_board() -> Result<(), String> {
    let (tc, paths) = setup()?;
    let images = board::build(&tc, &paths)?;
    print_memory(&images.named())?;
    eprintln!(
        "xtask: flash with `probe-rs run --chip STM32F407VGTx {}` ({}/README.md)",
        images.board.display(),
        board::DIR
    );
    Ok(())
}

/// `cargo xtask c-test`: the host C unit test, then (unless `host_only`) the C example on
/// the Cortex-M4F against the firmware's mps2-an386 build.
fn c_test(host_only: bool) -> Result<(), String> {
    let paths = Paths::find()?;
    c_interface::host_test(&paths)?;
    if !host_only {
        let (tc, paths) = setup()?;
        let images = firmware::build(&tc, &paths, firmware::Board::An386)?;
        c_interface::target_example(&tc, &paths, &images)?;
    }
    Ok(())
}

fn run_target(options: &[String]) -> Result<(), String> {
    let (tc, paths) = setup()?;
    let images = firmware::build(&tc, &paths, firmware::Board::An386)?;
    let status = firmware::qemu_command(&tc, images.board, &images.app, options)
        .status()
        .map_err(|e| format!("cannot run {}: {e}", tc.qemu.display()))?;
    match status.code() {
        Some(0) => Ok(()),
        code => Err(format!("the firmware exited with {code:?}")),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_command_line_is_consistent() {
        Cli::command().debug_assert();
    }

    #[test]
    fn parses_every_command_and_option() {
        let parse = |args: &[&str]| {
            Cli::try_parse_from(std::iter::once("xtask").chain(args.iter().copied()))
                .map(|c| c.command)
        };
        assert!(matches!(
            parse(&["test", "--host-only"]),
            Ok(Some(Cmd::Test { host_only: true }))
        ));
        assert!(matches!(
            parse(&["test"]),
            Ok(Some(Cmd::Test { host_only: false }))
        ));
        assert!(matches!(
            parse(&["bench-slurm", "--tasks", "6"]),
            Ok(Some(Cmd::BenchSlurm { tasks: 6 }))
        ));
        match parse(&["bench-target"]) {
            Ok(Some(Cmd::BenchTarget {
                mode: Mode::Exact,
                steps: 4000,
                models,
                boards,
                no_cycles: false,
            })) => assert!(models.is_empty() && boards.is_empty()),
            other => panic!("{other:?}"),
        }
        match parse(&[
            "bench-target",
            "--mode",
            "table",
            "--steps",
            "50",
            "--model",
            "linear-emm",
            "--model",
            "nemm",
            "--model",
            "nemm-light+lm",
            "--board",
            "an500",
            "--no-cycles",
        ]) {
            Ok(Some(Cmd::BenchTarget {
                mode: Mode::Table,
                steps: 50,
                models,
                boards,
                no_cycles: true,
            })) => {
                assert_eq!(
                    models,
                    [
                        Variant::plain(Kind::LinearEmm),
                        Variant::plain(Kind::Nemm),
                        Variant::with_lost_motion(Kind::NemmLight)
                    ]
                );
                assert_eq!(boards, [firmware::Board::An500]);
            }
            other => panic!("{other:?}"),
        }
        assert!(parse(&["bench-target", "--model", "lstm"]).is_err());
        assert!(parse(&["bench-target", "--model", "sem+lm"]).is_err());
        assert!(parse(&["bench-target", "--model", "nemm+lx"]).is_err());
        assert!(parse(&["bench-target", "--model", "+lm"]).is_err());
        assert!(parse(&["bench-target", "--mode", "fast"]).is_err());
        match parse(&["run-target", "--", "samples=2000", "fault=bus@3000+20"]) {
            Ok(Some(Cmd::RunTarget { options })) => {
                assert_eq!(options, ["samples=2000", "fault=bus@3000+20"]);
            }
            other => panic!("{other:?}"),
        }
        match parse(&["results", "--training", "runs/compare"]) {
            Ok(Some(Cmd::Results { training, .. })) => {
                assert_eq!(training, Some(PathBuf::from("runs/compare")));
            }
            other => panic!("{other:?}"),
        }
        match parse(&["results", "--table3", "t3"]) {
            Ok(Some(Cmd::Results {
                table3: Some(dir),
                training: None,
                ..
            })) => assert_eq!(dir, PathBuf::from("t3")),
            other => panic!("{other:?}"),
        }
        assert!(parse(&["results", "--table3", "t3", "--training", "c"]).is_err());
        match parse(&["results", "--state-priors", "sp", "--allow-dirty"]) {
            Ok(Some(Cmd::Results {
                state_priors: Some(dir),
                table3: None,
                training: None,
                tables: false,
                host: false,
                observer: false,
                c: false,
                allow_dirty: true,
                ..
            })) => assert_eq!(dir, PathBuf::from("sp")),
            other => panic!("{other:?}"),
        }
        for other in [
            &["--training", "c"][..],
            &["--table3", "t3"],
            &["--tables"],
            &["--host"],
            &["--observer"],
            &["--c"],
        ] {
            let mut args = vec!["results", "--state-priors", "sp"];
            args.extend_from_slice(other);
            assert!(parse(&args).is_err(), "{args:?}");
        }
        match parse(&["results", "--host", "--no-run"]) {
            Ok(Some(Cmd::Results {
                host: true,
                no_run: true,
                tables: false,
                training: None,
                ..
            })) => {}
            other => panic!("{other:?}"),
        }
        assert!(parse(&["results", "--no-run"]).is_err());
        assert!(parse(&["results", "--host", "--tables"]).is_err());
        assert!(parse(&["results", "--observer", "--host"]).is_err());
        match parse(&["results", "--observer"]) {
            Ok(Some(Cmd::Results {
                observer: true,
                host: false,
                tables: false,
                training: None,
                ..
            })) => {}
            other => panic!("{other:?}"),
        }
        match parse(&["results", "--c", "--allow-dirty"]) {
            Ok(Some(Cmd::Results {
                c: true,
                allow_dirty: true,
                observer: false,
                host: false,
                tables: false,
                training: None,
                table3: None,
                state_priors: None,
                ..
            })) => {}
            other => panic!("{other:?}"),
        }
        assert!(parse(&["results", "--c", "--observer"]).is_err());
        assert!(parse(&["results", "--c", "--tables"]).is_err());
        assert!(parse(&["results", "--c", "--training", "d"]).is_err());
        match parse(&["build-target"]) {
            Ok(Some(Cmd::BuildTarget { boards })) => assert!(boards.is_empty()),
            other => panic!("{other:?}"),
        }
        match parse(&["build-target", "--board", "an500"]) {
            Ok(Some(Cmd::BuildTarget { boards })) => assert_eq!(boards, [firmware::Board::An500]),
            other => panic!("{other:?}"),
        }
        assert!(parse(&["build-target", "--board", "an999"]).is_err());
        assert!(matches!(parse(&["build-board"]), Ok(Some(Cmd::BuildBoard))));
        assert!(matches!(parse(&["toolchain"]), Ok(Some(Cmd::Toolchain))));
        assert!(matches!(
            parse(&["c-lib", "--host-only"]),
            Ok(Some(Cmd::CLib { host_only: true }))
        ));
        assert!(matches!(
            parse(&["c-test"]),
            Ok(Some(Cmd::CTest { host_only: false }))
        ));
        assert!(matches!(parse(&["c-header"]), Ok(Some(Cmd::CHeader))));
        match parse(&["firmware-model", "--velocity", "causal", "--out", "m.nemm"]) {
            Ok(Some(Cmd::FirmwareModel { velocity, out })) => {
                assert_eq!(
                    (velocity.as_deref(), out.as_str()),
                    (Some("causal"), "m.nemm")
                );
            }
            other => panic!("{other:?}"),
        }
        assert!(parse(&["firmware-model", "--velocity", "acausal"]).is_err());
        match parse(&["e2e"]) {
            Ok(Some(Cmd::E2e { weights })) => assert_eq!(weights, None),
            other => panic!("{other:?}"),
        }
        assert!(matches!(parse(&[]), Ok(None)));
        assert!(parse(&["build-target", "extra"]).is_err());
        assert!(parse(&["frobnicate"]).is_err());
    }

    #[test]
    fn kind_names_are_the_blob_names() {
        for k in Kind::ALL {
            let value = k.to_possible_value().expect("a value");
            assert_eq!(value.get_name(), k.name());
        }
        assert_eq!(Mode::Table.to_possible_value().unwrap().get_name(), "table");
        for v in Variant::ALL.into_iter().chain(Variant::WITH_LOST_MOTION) {
            assert_eq!(Variant::parse(&v.name()), Ok(v));
        }
        assert_eq!(Variant::with_lost_motion(Kind::Nemm).name(), "nemm+lm");
        assert_eq!(
            Variant::with_lost_motion(Kind::LinearEmm).bench_args(),
            ["lost-motion=1"]
        );
        assert!(Variant::plain(Kind::Nemm).bench_args().is_empty());
    }

    #[test]
    fn frames_a_weights_slot() {
        let s = firmware::slot(b"NEMM1234", 32).unwrap();
        assert_eq!(&s[..8], b"NWSL\x08\x00\x00\x00");
        assert_eq!(&s[8..16], b"NEMM1234");
        assert!(s[16..].iter().all(|&b| b == 0xFF));
        assert!(firmware::slot(&[0; 30], 32).is_err());
    }
}
