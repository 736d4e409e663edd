//! `nemm data check` and `nemm data prepare`: validate a bench dataset and show what the
//! preprocessing of section 5.3 makes of it.
use crate::config::{resolve_data, DataConfig};
use crate::data::check;
use crate::data::import::{self, ColumnSpec, ImportSpec, SplitMethod};
use crate::data::preprocess::{self, PrepareConfig, SignalConfig};
use crate::output_guard::{self, Inputs, Output};
use crate::report::dataset::{check_report, prepare_report};
use anyhow::{Context, Result};
use nemm_core::Direction;
use nemm_dataset::{self as dataset, Dataset};
use std::fmt::Write as _;
use std::io::{IsTerminal, Write as _};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// `nemm data ...`
#[derive(Debug, Clone, clap::Subcommand)]
pub enum DataCmd {
    /// Load and validate a dataset folder; print a per-run table (condition level alpha,
    /// amplitude, frequency, peak velocity, samples, duration, force range) and the levels
    /// by the condition's name and unit.
    Check {
        /// Dataset folder (with manifest.toml).
        dir: PathBuf,
        /// Data options.
        #[command(flatten)]
        data: DataConfig,
    },
    /// Convert raw dyno CSV files (any column names and units, sign flips, offsets, long
    /// records cut into runs) into a dataset folder. Column flags take `NAME:UNIT` or
    /// `#INDEX:UNIT`; an import spec (`--spec`, TOML) covers the rest (gains, per-file
    /// levels, time ranges). See docs/data-format.md, "Importing raw dyno files".
    Import(Box<ImportArgs>),
    /// Split, cut into sequences, scale and extract quasi-static points; print the counts.
    Prepare {
        /// Dataset folder (with manifest.toml).
        dir: PathBuf,
        /// Also write a JSON summary (configuration, counts, scales, per-run facts).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Write the resolved data options to DIR/nemm-data.toml, which every command reading
        /// this dataset then uses (options given on a command line still override it).
        #[arg(long)]
        save_options: bool,
        /// Quasi-static window half-width, as a fraction of the amplitude.
        #[arg(long, default_value_t = preprocess::DEFAULT_QS_WINDOW)]
        qs_window: f64,
        /// Low-pass the training force as well (default: raw force).
        #[arg(long)]
        filter_force: bool,
        /// Data options.
        #[command(flatten)]
        data: DataConfig,
    },
}

/// Options of `nemm data import` (flags override the spec's values).
#[derive(Debug, Clone, clap::Args)]
pub struct ImportArgs {
    /// Raw CSV files (not with a spec that lists `[[files]]`).
    pub files: Vec<PathBuf>,
    /// Output dataset folder (created; the dataset is built in a sibling folder and swapped
    /// in, so a kill leaves the old or the new dataset complete).
    #[arg(long)]
    pub out: PathBuf,
    /// Replace the dataset `--out` already holds, as a whole (its run files are removed;
    /// `--force` names the force column). An input file is never overwritten, even with
    /// `--replace`.
    #[arg(long)]
    pub replace: bool,
    /// Import spec (TOML): columns, units, gains, signs, per-file levels, cutting.
    #[arg(long)]
    pub spec: Option<PathBuf>,
    /// Dataset name (default: the spec's, else the output folder's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Time column and unit (s, ms, us, min), e.g. `"Time [ms]:ms"`.
    #[arg(long, value_parser = ColumnSpec::parse_flag)]
    pub time: Option<ColumnSpec>,
    /// Displacement column and unit (m, cm, mm, um, in).
    #[arg(long, value_parser = ColumnSpec::parse_flag)]
    pub displacement: Option<ColumnSpec>,
    /// Force column and unit (N, kN, lbf, kgf).
    #[arg(long, value_parser = ColumnSpec::parse_flag)]
    pub force: Option<ColumnSpec>,
    /// Measured velocity column and unit (m/s, mm/s, in/s), optional.
    #[arg(long, value_parser = ColumnSpec::parse_flag)]
    pub velocity: Option<ColumnSpec>,
    /// Condition level alpha of the files: one for all, or one per file (comma-separated).
    /// Optional with `--alpha-column` (each run is then labelled with its mean level).
    #[arg(long, value_delimiter = ',')]
    pub alpha: Vec<f64>,
    /// Condition level per sample: column and unit, e.g. `U_ctrl:V`. Unit `1`: the values
    /// are alpha in [0, 1]. Any other unit: mapped to alpha by `--alpha-range`, else by the
    /// smallest and largest value over all files (printed); the condition then defaults to
    /// that unit and range.
    #[arg(long, value_parser = ColumnSpec::parse_flag)]
    pub(crate) alpha_column: Option<ColumnSpec>,
    /// Raw values of the level column at alpha 0 and at alpha 1, e.g. `0,5` for a 0-5 V
    /// control voltage (`5,0` when the level falls as the value rises).
    #[arg(long, value_name = "AT0,AT1", value_parser = parse_pair, allow_hyphen_values = true)]
    pub(crate) alpha_range: Option<[f64; 2]>,
    /// Name of the condition alpha stands for, e.g. `control voltage` (written to the
    /// manifest's `[condition]`; default: oil loss, without a level column range).
    #[arg(long)]
    pub(crate) condition_name: Option<String>,
    /// Unit of the condition value, e.g. `V` (default: the level column's unit).
    #[arg(long)]
    pub(crate) condition_unit: Option<String>,
    /// Condition values at alpha 0 and at alpha 1, e.g. `0,5` (default: the level column's
    /// range).
    #[arg(long, value_name = "AT0,AT1", value_parser = parse_pair, allow_hyphen_values = true)]
    pub(crate) condition_range: Option<[f64; 2]>,
    /// Prior of a coefficient in alpha, `COEF=DIRECTION` with COEF one of b_fl, b_pr, k_pr and
    /// DIRECTION one of decreasing, increasing, none; comma-separated or repeated, e.g.
    /// `b_fl=increasing,b_pr=increasing,k_pr=none`. A named condition needs all three.
    #[arg(long, value_name = "COEF=DIRECTION", value_delimiter = ',', value_parser = parse_prior)]
    pub prior: Vec<(Coefficient, Direction)>,
    /// Negate the displacement (stroke positive in compression).
    #[arg(long)]
    pub(crate) invert_displacement: bool,
    /// Negate the force (compression force positive).
    #[arg(long)]
    pub(crate) invert_force: bool,
    /// Subtract the mid-range of each run's displacement (arbitrary zero).
    #[arg(long)]
    pub(crate) center_displacement: bool,
    /// Field delimiter (one character or `tab`).
    #[arg(long)]
    pub delimiter: Option<String>,
    /// Line of the header (lines before it are skipped).
    #[arg(long)]
    pub header_line: Option<usize>,
    /// Sample rate (Hz): needed without a time column; else checked against the stamps.
    #[arg(long)]
    pub rate_hz: Option<f64>,
    /// Resample every run onto a uniform grid at this rate (Hz), by linear interpolation.
    #[arg(long)]
    pub resample_hz: Option<f64>,
    /// Cut each file into runs: at pauses of the excitation or at gaps in the time stamps.
    #[arg(long, value_enum)]
    pub split: Option<SplitMethod>,
    /// Shortest pause for `--split pauses` (s).
    #[arg(long)]
    pub min_pause_s: Option<f64>,
    /// Segments shorter than this are dropped and listed (s).
    #[arg(long)]
    pub(crate) min_run_s: Option<f64>,
}

/// A coefficient with a prior in alpha (`--prior`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Coefficient {
    /// Flow damping.
    BFl,
    /// Pressure-force damping.
    BPr,
    /// Pressure-force stiffness.
    KPr,
}

impl Coefficient {
    /// The coefficient's name in `--prior` and the manifest.
    pub fn name(self) -> &'static str {
        match self {
            Coefficient::BFl => "b_fl",
            Coefficient::BPr => "b_pr",
            Coefficient::KPr => "k_pr",
        }
    }
}

/// Parses `LO,HI` (two finite numbers).
fn parse_pair(text: &str) -> Result<[f64; 2], String> {
    let (a, b) = text
        .split_once(',')
        .ok_or_else(|| format!("\"{text}\": expected two numbers AT0,AT1, e.g. 0,5"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("\"{v}\" is not a finite number"))
    };
    Ok([num(a)?, num(b)?])
}

/// Parses `COEF=DIRECTION` of `--prior`.
fn parse_prior(text: &str) -> Result<(Coefficient, Direction), String> {
    let (c, d) = text
        .split_once('=')
        .ok_or_else(|| format!("\"{text}\": expected COEF=DIRECTION, e.g. b_fl=increasing"))?;
    let coefficient = match c.trim() {
        "b_fl" => Coefficient::BFl,
        "b_pr" => Coefficient::BPr,
        "k_pr" => Coefficient::KPr,
        other => return Err(format!("\"{other}\" is not b_fl, b_pr or k_pr")),
    };
    let direction = d.trim().parse::<Direction>().map_err(|e| e.to_string())?;
    Ok((coefficient, direction))
}

/// Sets the condition flags of `a` on the spec's `[condition]`; a coefficient given two
/// directions in `--prior` is refused.
fn apply_condition_flags(a: &ImportArgs, spec: &mut ImportSpec) -> Result<()> {
    for (k, &(coefficient, direction)) in a.prior.iter().enumerate() {
        if let Some(&(_, other)) = a.prior[..k]
            .iter()
            .find(|(c, d)| *c == coefficient && *d != direction)
        {
            anyhow::bail!(
                "--prior gives {} two directions, {} and {}: give one",
                coefficient.name(),
                other.name(),
                direction.name()
            );
        }
    }
    let given = a.condition_name.is_some()
        || a.condition_unit.is_some()
        || a.condition_range.is_some()
        || !a.prior.is_empty();
    if !given {
        return Ok(());
    }
    let c = spec.condition.get_or_insert_with(Default::default);
    if a.condition_name.is_some() {
        c.name.clone_from(&a.condition_name);
    }
    if a.condition_unit.is_some() {
        c.unit.clone_from(&a.condition_unit);
    }
    if let Some([lo, hi]) = a.condition_range {
        c.at_alpha_0 = Some(lo);
        c.at_alpha_1 = Some(hi);
    }
    for &(coefficient, direction) in &a.prior {
        *match coefficient {
            Coefficient::BFl => &mut c.b_fl,
            Coefficient::BPr => &mut c.b_pr,
            Coefficient::KPr => &mut c.k_pr,
        } = Some(direction);
    }
    Ok(())
}

/// The import spec from `--spec` and the flags.
pub(crate) fn import_spec(a: &ImportArgs) -> Result<ImportSpec> {
    let mut spec = match &a.spec {
        Some(p) => import::read_spec(p)?,
        None => {
            let missing = |f: &str| anyhow::anyhow!("without --spec, --{f} NAME:UNIT is required");
            ImportSpec {
                name: None,
                csv: import::CsvOptions::default(),
                columns: import::Columns {
                    time: None,
                    displacement: a
                        .displacement
                        .clone()
                        .ok_or_else(|| missing("displacement"))?,
                    force: a.force.clone().ok_or_else(|| missing("force"))?,
                    velocity: None,
                    alpha: None,
                },
                rate_hz: None,
                resample_hz: None,
                split: import::SplitSpec::default(),
                condition: None,
                files: Vec::new(),
            }
        }
    };
    let c = &mut spec.columns;
    if let Some(t) = &a.time {
        c.time = Some(t.clone());
    }
    if let Some(x) = &a.displacement {
        c.displacement = x.clone();
    }
    if let Some(f) = &a.force {
        c.force = f.clone();
    }
    if let Some(v) = &a.velocity {
        c.velocity = Some(v.clone());
    }
    if let Some(l) = &a.alpha_column {
        c.alpha = Some(l.clone());
    }
    if let Some(r) = a.alpha_range {
        match c.alpha.as_mut() {
            Some(l) => l.range = Some(r),
            None => anyhow::bail!(
                "--alpha-range maps a level column: give it with --alpha-column (or the spec's \
                 columns.alpha)"
            ),
        }
    }
    c.displacement.invert |= a.invert_displacement;
    c.force.invert |= a.invert_force;
    c.displacement.center |= a.center_displacement;
    if a.name.is_some() {
        spec.name.clone_from(&a.name);
    }
    if let Some(d) = &a.delimiter {
        spec.csv.delimiter.clone_from(d);
    }
    if let Some(h) = a.header_line {
        spec.csv.header_line = h;
    }
    apply_condition_flags(a, &mut spec)?;
    spec.rate_hz = a.rate_hz.or(spec.rate_hz);
    spec.resample_hz = a.resample_hz.or(spec.resample_hz);
    if let Some(m) = a.split {
        spec.split.method = m;
    }
    if let Some(p) = a.min_pause_s {
        spec.split.min_pause_s = p;
    }
    if let Some(r) = a.min_run_s {
        spec.split.min_run_s = r;
    }
    if !a.files.is_empty() {
        if !spec.files.is_empty() {
            anyhow::bail!("the spec lists [[files]]; give no files on the command line");
        }
        let alphas: Vec<Option<f64>> = match a.alpha.len() {
            1 => vec![Some(a.alpha[0]); a.files.len()],
            n if n == a.files.len() => a.alpha.iter().copied().map(Some).collect(),
            0 if spec.columns.alpha.is_some() => vec![None; a.files.len()],
            0 => anyhow::bail!(
                "give the condition level of the files with --alpha (or a level column with \
                 --alpha-column)"
            ),
            n => anyhow::bail!(
                "--alpha has {n} values for {} files (give one, or one per file)",
                a.files.len()
            ),
        };
        spec.files = a
            .files
            .iter()
            .zip(alphas)
            .map(|(p, alpha)| import::FileSpec {
                path: p.clone(),
                alpha,
                split: None,
                runs: Vec::new(),
            })
            .collect();
    } else if !a.alpha.is_empty() {
        anyhow::bail!("--alpha applies to files given on the command line");
    }
    Ok(spec)
}

/// The report of `nemm data import`.
pub(crate) fn import_report(out: &Path, imported: &import::Imported) -> String {
    let ds = &imported.dataset;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "imported {} runs, {} samples at {} Hz into {}",
        ds.runs.len(),
        ds.total_samples(),
        ds.sample_rate_hz,
        out.display()
    );
    let condition = ds.condition.clone().unwrap_or_default();
    if let Some(c) = &ds.condition {
        let _ = writeln!(
            s,
            "condition: {} ({}); priors in alpha: b_fl {}, b_pr {}, k_pr {}",
            c.name,
            condition_map(c),
            c.b_fl.name(),
            c.b_pr.name(),
            c.k_pr.name()
        );
    }
    if let Some(
        map @ import::LevelMap::Range {
            from_data: true, ..
        },
    ) = &imported.level
    {
        let _ = writeln!(
            s,
            "level column: {}; give columns.alpha.range (--alpha-range) to fix it otherwise",
            map.describe()
        );
    }
    for (run, acc) in ds.runs.iter().zip(&imported.runs) {
        let stamps = if acc.resampled {
            format!(
                "resampled at {} Hz by linear interpolation (source: fitted {:.1} Hz, max deviation {:.1} us)",
                ds.sample_rate_hz,
                acc.grid.rate_hz(),
                acc.grid.max_deviation_s * 1e6
            )
        } else if acc.grid.is_exact() {
            format!("uniform time stamps at {:.1} Hz", acc.grid.rate_hz())
        } else {
            format!(
                "time stamps rounded/jittered: max deviation {:.1} us from the fitted {:.1} Hz grid, accepted",
                acc.grid.max_deviation_s * 1e6,
                acc.grid.rate_hz()
            )
        };
        let _ = writeln!(
            s,
            "  {}: {}{}, {} samples from {}:{}..{} (t = {}..{} s); {stamps}",
            run.entry.file.display(),
            condition.level(run.entry.oil_loss),
            if run.alpha.is_some() {
                " on average"
            } else {
                ""
            },
            run.len(),
            acc.source.display(),
            acc.lines.0,
            acc.lines.1,
            acc.time_s.0,
            acc.time_s.1
        );
    }
    for (file, a, b) in &imported.dropped {
        let _ = writeln!(
            s,
            "  dropped: {} t = {a}..{b} s (shorter than min_run_s)",
            file.display()
        );
    }
    let _ = writeln!(s, "next: nemm data check {}", out.display());
    s
}

/// The map from alpha to the condition value: `alpha 0 = 0 V, alpha 1 = 5 V`.
pub(crate) fn condition_map(c: &dataset::ConditionSpec) -> String {
    let u = if c.unit == "-" {
        String::new()
    } else {
        format!(" {}", c.unit)
    };
    format!(
        "alpha 0 = {}{u}, alpha 1 = {}{u}",
        c.value_text(c.at_alpha_0),
        c.value_text(c.at_alpha_1)
    )
}

fn import_cmd(a: &ImportArgs) -> Result<()> {
    let spec = import_spec(a)?;
    let inputs = Inputs::new()
        .paths("a raw file", spec.files.iter().map(|f| f.path.as_path()))
        .paths("--spec", a.spec.as_deref());
    output_guard::check(&[Output::dataset("--out", &a.out)], &inputs, false, "")?;
    let default_name = output_guard::resolve(&a.out)?
        .file_name()
        .map_or("imported dyno data".into(), |n| {
            n.to_string_lossy().into_owned()
        });
    let manifest = a.out.join(dataset::MANIFEST_FILE);
    if manifest.exists() && !a.replace {
        anyhow::bail!(
            "{} already holds a dataset ({}); give --replace to replace it as a whole, or \
             choose another --out folder",
            a.out.display(),
            manifest.display()
        );
    }
    let imported = import::import(&spec, &default_name)?;
    let stale_options = a.out.join(crate::config::DATA_OPTIONS_FILE);
    let stale_options = (manifest.exists() && stale_options.exists()).then_some(stale_options);
    dataset::write(&a.out, &imported.dataset)
        .with_context(|| format!("cannot write the dataset to {}", a.out.display()))?;
    print!("{}", import_report(&a.out, &imported));
    if let Some(p) = stale_options {
        println!(
            "removed {}: the data options saved for the replaced dataset",
            p.display()
        );
    }
    Ok(())
}

/// Runs a `nemm data` subcommand.
pub fn run(cmd: DataCmd) -> Result<()> {
    match cmd {
        DataCmd::Check { dir, data } => {
            let resolved = resolve_data(&data.in_dir(&dir))?;
            let mut signal = resolved.config.prepare_config().signal;
            signal.filter_force = false;
            check(&dir, &signal)
        }
        DataCmd::Import(args) => import_cmd(&args),
        DataCmd::Prepare {
            dir,
            out,
            save_options,
            qs_window,
            filter_force,
            data,
        } => {
            if let Some(out) = &out {
                let inputs = Inputs::new().dataset("the dataset", &dir);
                output_guard::check(&[Output::file("--out", out)], &inputs, false, "")?;
            }
            let resolved = resolve_data(&data.in_dir(&dir))?;
            let mut config = resolved.config.prepare_config();
            config.signal.filter_force = filter_force;
            config.quasi_static_window = Some(qs_window);
            prepare(&dir, &config, out.as_deref())?;
            if save_options {
                let path = resolved.config.save_options_file(&dir)?;
                println!("data options written to {}", path.display());
            }
            Ok(())
        }
    }
}

/// Loads a dataset, showing progress on a terminal.
pub(crate) fn load_with_progress(dir: &Path) -> Result<Dataset> {
    let tty = std::io::stderr().is_terminal();
    let start = Instant::now();
    let ds = dataset::load_with_progress(dir, |p| {
        if tty {
            eprint!(
                "\rloading: {}/{} runs, {:.2} M samples",
                p.runs_done,
                p.runs_total,
                p.samples_done as f64 / 1e6
            );
            let _ = std::io::stderr().flush();
        }
    });
    if tty {
        eprint!("\r\x1b[K");
    }
    let ds = ds.with_context(|| format!("dataset {} is not valid", dir.display()))?;
    eprintln!(
        "loaded {} runs, {} samples in {:.2} s",
        ds.runs.len(),
        ds.total_samples(),
        start.elapsed().as_secs_f64()
    );
    Ok(ds)
}

/// `nemm data check`: every readable run is checked; runs that cannot be read are listed
/// with their errors and make the command fail after the report of the rest.
fn check(dir: &Path, cfg: &SignalConfig) -> Result<()> {
    let (ds, unreadable) = dataset::load_readable(dir)
        .with_context(|| format!("dataset {} is not valid", dir.display()))?;
    eprintln!(
        "loaded {} runs, {} samples{}",
        ds.runs.len(),
        ds.total_samples(),
        if unreadable.is_empty() {
            String::new()
        } else {
            format!("; {} could not be read", unreadable.len())
        }
    );
    let (runs, findings) = check::check_dataset(&ds, cfg)?;
    print!("{}", check_report(&ds, &runs, &findings));
    if unreadable.is_empty() {
        return Ok(());
    }
    println!("runs that could not be read (skipped):");
    for e in &unreadable {
        println!("  {e}");
    }
    anyhow::bail!(
        "{} of {} runs could not be read (listed above); the other {} were checked",
        unreadable.len(),
        unreadable.len() + ds.runs.len(),
        ds.runs.len()
    )
}

fn prepare(dir: &Path, config: &PrepareConfig, out: Option<&Path>) -> Result<()> {
    let ds = load_with_progress(dir)?;
    let prepared = preprocess::prepare(&ds, config).context("preprocessing failed")?;
    print!("{}", prepare_report(&ds, &prepared));
    if let Some(out) = out {
        let json = serde_json::to_string_pretty(&prepared.summary(&ds.name))?;
        std::fs::write(out, json + "\n")
            .with_context(|| format!("cannot write {}", out.display()))?;
        println!("summary written to {}", out.display());
    }
    Ok(())
}
