//! The manifest (`manifest.toml`): its TOML, its validation with file, line and column, and the
//! condition it declares.

use crate::{io_err, line_col, ConditionSpec, DatasetError, Manifest, RunEntry, MANIFEST_FILE};
use nemm_core::Direction;
use serde::Deserialize;
use std::collections::HashMap;
use std::path::{Component, Path, PathBuf};
use toml::Spanned;
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawManifest {
    name: String,
    sample_rate_hz: Spanned<f64>,
    #[serde(default)]
    condition: Option<RawCondition>,
    #[serde(default)]
    runs: Vec<RawRun>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawCondition {
    name: Spanned<String>,
    #[serde(default)]
    unit: Option<Spanned<String>>,
    #[serde(default)]
    at_alpha_0: Option<Spanned<f64>>,
    #[serde(default)]
    at_alpha_1: Option<Spanned<f64>>,
    #[serde(default)]
    b_fl: Option<Spanned<String>>,
    #[serde(default)]
    b_pr: Option<Spanned<String>>,
    #[serde(default)]
    k_pr: Option<Spanned<String>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawRun {
    file: Spanned<PathBuf>,
    #[serde(alias = "alpha")]
    oil_loss: Spanned<f64>,
    #[serde(default)]
    amplitude_m: Option<Spanned<f64>>,
    #[serde(default)]
    target_velocity_m_s: Option<Spanned<f64>>,
}

/// Spans of the manifest values, for error lines (`None` for in-memory manifests).
pub(super) struct ManifestLines {
    sample_rate_hz: usize,
    condition: Option<ConditionLines>,
    pub(super) runs: Vec<RunLines>,
}

/// Lines of the `[condition]` values (the table's name line where a key is absent).
#[derive(Clone, Copy)]
pub(super) struct ConditionLines {
    name: usize,
    unit: usize,
    at_alpha_0: usize,
    at_alpha_1: usize,
}

pub(super) struct RunLines {
    pub(super) file: usize,
    oil_loss: usize,
    amplitude_m: Option<usize>,
    target_velocity_m_s: Option<usize>,
}

/// Checks the values of a manifest (ranges, file names, duplicates).
pub(super) fn validate_manifest(
    m: &Manifest,
    path: &Path,
    lines: Option<&ManifestLines>,
) -> Result<(), DatasetError> {
    if !(m.sample_rate_hz.is_finite() && m.sample_rate_hz > 0.0) {
        return Err(value_error(
            path,
            lines.map(|l| l.sample_rate_hz),
            "sample_rate_hz",
            format!("{} is not a positive finite rate in Hz", m.sample_rate_hz),
        ));
    }
    if let Some(c) = &m.condition {
        validate_condition(c, path, lines.and_then(|l| l.condition.as_ref()))?;
    }
    if m.runs.is_empty() {
        return Err(value_error(
            path,
            None,
            "runs",
            "no runs listed (add [[runs]] tables)".into(),
        ));
    }
    let mut seen: HashMap<PathBuf, usize> = HashMap::new();
    for (i, r) in m.runs.iter().enumerate() {
        let rl = lines.and_then(|l| l.runs.get(i));
        let file_line = rl.map(|l| l.file);
        let key = format!("runs[{i}].file");
        let normalised = normalise_relative(&r.file).map_err(|message| {
            value_error(path, file_line, &key, format!("{:?}: {message}", r.file))
        })?;
        if let Some(&first) = seen.get(&normalised) {
            return Err(DatasetError::DuplicateRunFile {
                path: path.to_path_buf(),
                line: file_line,
                key,
                first_key: format!("runs[{first}].file"),
                file: r.file.clone(),
            });
        }
        seen.insert(normalised, i);
        validate_run_values(r, i, path, rl)?;
    }
    Ok(())
}

/// A [`DatasetError::ManifestValue`] of the manifest at `path`.
fn value_error(
    path: &Path,
    line: Option<usize>,
    key: impl Into<String>,
    message: String,
) -> DatasetError {
    DatasetError::ManifestValue {
        path: path.to_path_buf(),
        line,
        key: key.into(),
        message,
    }
}

/// Checks the `[condition]` table: the lengths of name and unit (what the weights blob
/// holds), finite and distinct values at alpha 0 and 1.
fn validate_condition(
    c: &ConditionSpec,
    path: &Path,
    cl: Option<&ConditionLines>,
) -> Result<(), DatasetError> {
    let limits = [
        (
            "condition.name",
            c.name.len(),
            1,
            nemm_core::MAX_CONDITION_NAME,
            cl.map(|l| l.name),
        ),
        (
            "condition.unit",
            c.unit.len(),
            0,
            nemm_core::MAX_CONDITION_UNIT,
            cl.map(|l| l.unit),
        ),
    ];
    for (key, len, lo, hi, line) in limits {
        if !(lo..=hi).contains(&len) {
            return Err(value_error(
                path,
                line,
                key,
                format!("{len} bytes; must be {lo} to {hi} bytes"),
            ));
        }
    }
    for (key, text, line) in [
        ("condition.name", &c.name, cl.map(|l| l.name)),
        ("condition.unit", &c.unit, cl.map(|l| l.unit)),
    ] {
        if let Some(message) = control_character(text) {
            return Err(value_error(path, line, key, message));
        }
    }
    if let Some((key, message)) = condition_values_error(c.at_alpha_0, c.at_alpha_1) {
        let line = cl.map(|l| {
            if key.ends_with('0') {
                l.at_alpha_0
            } else {
                l.at_alpha_1
            }
        });
        return Err(value_error(path, line, key, message));
    }
    Ok(())
}

/// What is wrong with a condition name or unit `text` that holds a control character (a
/// line break, an escape): names travel into the blob and onto terminals.
pub fn control_character(text: &str) -> Option<String> {
    text.chars().find(|ch| ch.is_control()).map(|ch| {
        format!("{text:?} holds the control character {ch:?}; give a name of printable characters")
    })
}

/// What is wrong with a condition's values at alpha 0 (`a0`) and 1 (`a1`), as the key and
/// the message: each finite in the blob's single precision, and distinct there.
pub fn condition_values_error(a0: f64, a1: f64) -> Option<(&'static str, String)> {
    for (key, v) in [("condition.at_alpha_0", a0), ("condition.at_alpha_1", a1)] {
        if !(v.is_finite() && (v as f32).is_finite()) {
            return Some((
                key,
                format!(
                    "{} is not a finite number in the blob's single precision (at most {:e} \
                     in magnitude)",
                    short_number(v),
                    f32::MAX
                ),
            ));
        }
    }
    if a0 as f32 != a1 as f32 {
        return None;
    }
    let message = if a0 == a1 {
        format!(
            "{} equals at_alpha_0: the condition needs distinct values at alpha 0 and 1",
            short_number(a1)
        )
    } else {
        format!(
            "{} and at_alpha_0 {} are one number in the blob's single precision ({}): the \
             condition needs values at alpha 0 and 1 that differ there; give them in another \
             unit",
            short_number(a1),
            short_number(a0),
            short_number(f64::from(a1 as f32))
        )
    };
    Some(("condition.at_alpha_1", message))
}

/// `v` as text of a readable length: plain between 1e-4 and 1e9 in magnitude (and 0), else
/// in scientific notation (`1e300`, not 301 digits).
pub fn short_number(v: f64) -> String {
    if v == 0.0 || (1e-4..1e9).contains(&v.abs()) || !v.is_finite() {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Checks the values of run `i` (its level and optional metadata; lines `rl`).
fn validate_run_values(
    r: &RunEntry,
    i: usize,
    path: &Path,
    rl: Option<&RunLines>,
) -> Result<(), DatasetError> {
    let key = |k: &str| format!("runs[{i}].{k}");
    if !(r.oil_loss.is_finite() && (0.0..=1.0).contains(&r.oil_loss)) {
        return Err(value_error(
            path,
            rl.map(|l| l.oil_loss),
            key("oil_loss"),
            format!(
                "{} is outside [0, 1] (condition level alpha, e.g. the fraction of oil \
                 volume lost)",
                r.oil_loss
            ),
        ));
    }
    let positive = |v: Option<f64>, k: &str, line: Option<usize>| match v {
        Some(v) if !(v.is_finite() && v > 0.0) => Err(value_error(
            path,
            line,
            key(k),
            format!("{v} is not a positive finite number"),
        )),
        _ => Ok(()),
    };
    positive(r.amplitude_m, "amplitude_m", rl.and_then(|l| l.amplitude_m))?;
    positive(
        r.target_velocity_m_s,
        "target_velocity_m_s",
        rl.and_then(|l| l.target_velocity_m_s),
    )
}

/// The run file path without `.` components; refuses empty, absolute and `..` paths.
fn normalise_relative(file: &Path) -> Result<PathBuf, &'static str> {
    let mut out = PathBuf::new();
    for c in file.components() {
        match c {
            Component::Normal(p) => out.push(p),
            Component::CurDir => {}
            Component::ParentDir => {
                return Err("must stay inside the dataset folder (no `..`)");
            }
            Component::RootDir | Component::Prefix(_) => {
                return Err("must be relative to the manifest, not absolute");
            }
        }
    }
    if out.as_os_str().is_empty() {
        return Err("is not a file name");
    }
    Ok(out)
}

/// Reads and validates `DIR/manifest.toml` (without opening the run files).
pub fn read_manifest(dir: &Path) -> Result<Manifest, DatasetError> {
    Ok(read_manifest_with_lines(dir)?.0)
}

pub(super) fn read_manifest_with_lines(
    dir: &Path,
) -> Result<(Manifest, ManifestLines), DatasetError> {
    let path = dir.join(MANIFEST_FILE);
    let text = std::fs::read_to_string(&path).map_err(io_err(&path))?;
    let raw: RawManifest = toml::from_str(&text).map_err(|e| {
        let (line, column) = line_col(&text, e.span().map_or(0, |s| s.start));
        DatasetError::ManifestSyntax {
            path: path.clone(),
            line,
            column,
            message: e.message().trim().to_string(),
        }
    })?;
    let line_of = |span: std::ops::Range<usize>| line_col(&text, span.start).0;
    let condition = raw
        .condition
        .map(|c| raw_condition(c, &text, &path))
        .transpose()?;
    let lines = ManifestLines {
        sample_rate_hz: line_of(raw.sample_rate_hz.span()),
        condition: condition.as_ref().map(|c| c.1),
        runs: raw
            .runs
            .iter()
            .map(|r| RunLines {
                file: line_of(r.file.span()),
                oil_loss: line_of(r.oil_loss.span()),
                amplitude_m: r.amplitude_m.as_ref().map(|s| line_of(s.span())),
                target_velocity_m_s: r.target_velocity_m_s.as_ref().map(|s| line_of(s.span())),
            })
            .collect(),
    };
    let manifest = Manifest {
        name: raw.name,
        sample_rate_hz: raw.sample_rate_hz.into_inner(),
        condition: condition.map(|c| c.0),
        runs: raw
            .runs
            .into_iter()
            .map(|r| RunEntry {
                file: r.file.into_inner(),
                oil_loss: r.oil_loss.into_inner(),
                amplitude_m: r.amplitude_m.map(Spanned::into_inner),
                target_velocity_m_s: r.target_velocity_m_s.map(Spanned::into_inner),
            })
            .collect(),
    };
    validate_manifest(&manifest, &path, Some(&lines))?;
    Ok((manifest, lines))
}

/// The `[condition]` table with its lines; a direction that is none of the accepted names
/// is refused with its line.
fn raw_condition(
    c: RawCondition,
    text: &str,
    path: &Path,
) -> Result<(ConditionSpec, ConditionLines), DatasetError> {
    let line_of = |span: std::ops::Range<usize>| line_col(text, span.start).0;
    let name_line = line_of(c.name.span());
    let line = |s: &Option<Spanned<f64>>| s.as_ref().map_or(name_line, |s| line_of(s.span()));
    let lines = ConditionLines {
        name: name_line,
        unit: c.unit.as_ref().map_or(name_line, |s| line_of(s.span())),
        at_alpha_0: line(&c.at_alpha_0),
        at_alpha_1: line(&c.at_alpha_1),
    };
    let direction = |s: Option<Spanned<String>>, key: &str| -> Result<Direction, DatasetError> {
        match s {
            None => Ok(Direction::default()),
            Some(s) => {
                let l = line_of(s.span());
                s.into_inner()
                    .parse::<Direction>()
                    .map_err(|e| DatasetError::ManifestValue {
                        path: path.to_path_buf(),
                        line: Some(l),
                        key: format!("condition.{key}"),
                        message: format!("{e}"),
                    })
            }
        }
    };
    let spec = ConditionSpec {
        name: c.name.into_inner(),
        unit: c
            .unit
            .map_or_else(ConditionSpec::default_unit, Spanned::into_inner),
        at_alpha_0: c.at_alpha_0.map_or(0.0, Spanned::into_inner),
        at_alpha_1: c.at_alpha_1.map_or(1.0, Spanned::into_inner),
        b_fl: direction(c.b_fl, "b_fl")?,
        b_pr: direction(c.b_pr, "b_pr")?,
        k_pr: direction(c.k_pr, "k_pr")?,
    };
    Ok((spec, lines))
}
