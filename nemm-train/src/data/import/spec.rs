//! The import spec: read from TOML with line and column in its errors, units, and its
//! validation.

use super::{
    spec_err, ColumnSpec, CsvOptions, FileSpec, ImportCondition, ImportError, ImportSpec,
    SplitSpec, MAX_RESAMPLE_HZ, MIN_RESAMPLE_HZ,
};
use nemm_core::Direction;
use nemm_dataset as dataset;
use std::path::Path;

/// 1-based line and column of a byte offset.
fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let before = text.get(..offset.min(text.len())).unwrap_or(text);
    let line = before.matches('\n').count() + 1;
    let start = before.rfind('\n').map_or(0, |i| i + 1);
    (line, before[start..].chars().count() + 1)
}

/// Reads an import spec; file paths in it become relative to the spec's folder.
pub fn read_spec(path: &Path) -> Result<ImportSpec, ImportError> {
    let text = std::fs::read_to_string(path).map_err(|error| ImportError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    let mut spec: ImportSpec = toml::from_str(&text).map_err(|e| {
        let (line, column) = line_col(&text, e.span().map_or(0, |s| s.start));
        ImportError::SpecSyntax {
            path: path.to_path_buf(),
            line,
            column,
            message: e.message().trim().to_string(),
        }
    })?;
    let base = path.parent().unwrap_or(Path::new(""));
    for f in &mut spec.files {
        if f.path.is_relative() {
            f.path = base.join(&f.path);
        }
    }
    Ok(spec)
}

/// SI factor of a unit name (`m`, `cm`, `mm`, `um`, `in`; `N`, `kN`, `lbf`, `kgf`; `m/s`,
/// `mm/s`, `in/s`; `s`, `ms`, `us`, `min`; `1` for the level) for a column role (`time`,
/// `displacement`, `force`, `velocity`, `alpha`).
pub(crate) fn unit_factor(role: &str, unit: &str) -> Option<f64> {
    let table: &[(&str, f64)] = match role {
        "time" => &[("s", 1.0), ("ms", 1e-3), ("us", 1e-6), ("min", 60.0)],
        "displacement" => &[
            ("m", 1.0),
            ("cm", 1e-2),
            ("mm", 1e-3),
            ("um", 1e-6),
            ("in", 0.0254),
        ],
        "force" => &[
            ("N", 1.0),
            ("kN", 1e3),
            ("lbf", 4.448_221_615_260_5),
            ("kgf", 9.806_65),
        ],
        "velocity" => &[("m/s", 1.0), ("mm/s", 1e-3), ("in/s", 0.0254)],
        "alpha" => &[("1", 1.0)],
        _ => &[],
    };
    table.iter().find(|(u, _)| *u == unit).map(|(_, f)| *f)
}

/// Checks the spec's values (units, gains, levels, rates, cutting options).
pub fn validate_spec(spec: &ImportSpec) -> Result<(), ImportError> {
    for (role, c) in spec.columns.roles() {
        if let Some(c) = c {
            validate_column(role, c)?;
        }
    }
    // Each file's runs are named after its file stem (runs/STEM.csv, runs/STEM_01.csv ...).
    for (i, f) in spec.files.iter().enumerate() {
        if let Some(g) = spec.files[..i]
            .iter()
            .find(|g| g.path.file_stem() == f.path.file_stem())
        {
            return Err(spec_err(
                format!("files[{i}]"),
                format!(
                    "{} and {} have one file name stem, {:?}, and each file's runs are named \
                     after it (runs/STEM.csv): rename or copy one of them under another name",
                    g.path.display(),
                    f.path.display(),
                    f.path.file_stem().unwrap_or_default()
                ),
            ));
        }
    }
    for (k, v) in [("rate_hz", spec.rate_hz), ("resample_hz", spec.resample_hz)] {
        if let Some(v) = v {
            if !(v.is_finite() && v > 0.0) {
                return Err(spec_err(k, format!("{v} is not a positive rate in Hz")));
            }
        }
    }
    if let Some(v) = spec.resample_hz.filter(|v| *v > MAX_RESAMPLE_HZ) {
        return Err(spec_err(
            "resample_hz",
            format!("{v} Hz is above the highest model rate, {MAX_RESAMPLE_HZ} Hz"),
        ));
    }
    if let Some(v) = spec.resample_hz.filter(|v| *v < MIN_RESAMPLE_HZ) {
        return Err(spec_err(
            "resample_hz",
            format!("{v} Hz is below the lowest model rate, {MIN_RESAMPLE_HZ} Hz"),
        ));
    }
    if spec.columns.time.is_none() && spec.rate_hz.is_none() {
        return Err(spec_err(
            "rate_hz",
            "needed when there is no time column (columns.time)",
        ));
    }
    validate_csv(&spec.csv)?;
    if spec.files.is_empty() {
        return Err(spec_err("files", "no raw files given"));
    }
    validate_split("split", &spec.split)?;
    // The condition with what is known before reading: values from a range taken from the
    // data are checked once read.
    let level = spec
        .columns
        .alpha
        .as_ref()
        .map(|c| LevelMap::new(c, (0.0, 1.0)));
    let from_data = matches!(
        level,
        Some(LevelMap::Range {
            from_data: true,
            ..
        })
    );
    resolve_condition(spec, level.as_ref(), !from_data)?;
    for (i, f) in spec.files.iter().enumerate() {
        validate_file(i, f, spec.columns.alpha.is_some())?;
    }
    Ok(())
}

/// Checks the column of `role` (`columns.<role>`): named or numbered, its unit, gain and
/// offset.
fn validate_column(role: &str, c: &ColumnSpec) -> Result<(), ImportError> {
    let key = |k: &str| format!("columns.{role}.{k}");
    if c.name.is_some() == c.index.is_some() {
        return Err(spec_err(
            key("name"),
            "give exactly one of `name` and `index`",
        ));
    }
    if c.index == Some(0) {
        return Err(spec_err(key("index"), "columns are counted from 1"));
    }
    if role == "alpha" {
        return validate_level_column(c);
    }
    if c.range.is_some() {
        return Err(spec_err(
            key("range"),
            "only the level column (columns.alpha) takes a range",
        ));
    }
    if unit_factor(role, &c.unit).is_none() {
        let accepted: Vec<&str> = ["s", "ms", "us", "min", "m", "cm", "mm", "um", "in"]
            .into_iter()
            .chain(["N", "kN", "lbf", "kgf", "m/s", "mm/s", "in/s", "1"])
            .filter(|u| unit_factor(role, u).is_some())
            .collect();
        return Err(spec_err(
            key("unit"),
            format!(
                "\"{}\" is not a {role} unit (one of {}; for volts give the unit of \
                 `gain` times volts, e.g. unit = \"mm\" with gain = mm per volt)",
                c.unit,
                accepted.join(", ")
            ),
        ));
    }
    validate_gain_offset(role, c)
}

/// Checks `gain` (finite, non-zero) and `offset` (finite) of the column of `role`.
fn validate_gain_offset(role: &str, c: &ColumnSpec) -> Result<(), ImportError> {
    let key = |k: &str| format!("columns.{role}.{k}");
    if !(c.gain().is_finite() && c.gain() != 0.0) {
        return Err(spec_err(
            key("gain"),
            format!("{} is not a non-zero number", c.gain()),
        ));
    }
    if !c.offset().is_finite() {
        return Err(spec_err(key("offset"), "is not finite"));
    }
    Ok(())
}

/// Checks the level column (`columns.alpha`): `range` or `gain`/`offset` (not both), a
/// `range` of finite distinct ends, the unit `1` for `gain`/`offset` and a condition unit
/// otherwise, no `invert` with a range (swap its ends instead) and no `center`.
fn validate_level_column(c: &ColumnSpec) -> Result<(), ImportError> {
    if c.center {
        return Err(spec_err(
            "columns.alpha.center",
            "a condition level is not centred",
        ));
    }
    match LevelKind::of(c) {
        LevelKind::Linear => {
            if c.range.is_some() {
                return Err(spec_err(
                    "columns.alpha.range",
                    "give either `range` or `gain`/`offset`, not both",
                ));
            }
            if c.unit != "1" {
                return Err(spec_err(
                    "columns.alpha.unit",
                    format!(
                        "\"{}\": with `gain`/`offset` the unit is \"1\" (raw * gain + offset is \
                         alpha); to map raw values in {} give `range = [at alpha 0, at alpha 1]` \
                         instead, or neither to take the range from the data",
                        c.unit, c.unit
                    ),
                ));
            }
            validate_gain_offset("alpha", c)
        }
        LevelKind::Range(range) => {
            if let Some([a, b]) = range {
                if !(a.is_finite() && b.is_finite() && a != b) {
                    return Err(spec_err(
                        "columns.alpha.range",
                        format!(
                            "[{a}, {b}] needs two finite, distinct raw values (at alpha 0 and 1)"
                        ),
                    ));
                }
            }
            if c.invert {
                return Err(spec_err(
                    "columns.alpha.invert",
                    "not with a range: swap its ends (the raw value at alpha 0 comes first)",
                ));
            }
            let max = nemm_core::MAX_CONDITION_UNIT;
            if c.unit.is_empty() || c.unit.len() > max {
                return Err(spec_err(
                    "columns.alpha.unit",
                    format!(
                        "\"{}\" is {} bytes; the level column's unit is the condition's \
                         and must be 1 to {max} bytes",
                        c.unit,
                        c.unit.len()
                    ),
                ));
            }
            Ok(())
        }
    }
}

/// How the level column maps raw numbers to alpha, as the spec says it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) enum LevelKind {
    /// `alpha = raw * gain + offset` (unit `1`; `gain` or `offset` given, or neither with
    /// unit `1` and no `range`).
    Linear,
    /// By the raw values at alpha 0 and 1: given (`range`), or `None` to take them from the
    /// data.
    Range(Option<[f64; 2]>),
}

impl LevelKind {
    /// The mapping of level column `c`.
    pub(super) fn of(c: &ColumnSpec) -> LevelKind {
        match (c.range, c.gain.is_some() || c.offset.is_some()) {
            (Some(r), false) => LevelKind::Range(Some(r)),
            (None, false) if c.unit != "1" => LevelKind::Range(None),
            _ => LevelKind::Linear,
        }
    }
}

/// How the level column's raw numbers became alpha in an import.
#[derive(Debug, Clone, PartialEq)]
pub enum LevelMap {
    /// `alpha = sign (raw * gain + offset)`.
    Linear {
        /// Multiplier of the raw number.
        gain: f64,
        /// Added after the gain.
        offset: f64,
        /// Negated after.
        invert: bool,
    },
    /// `alpha = (raw - at_0) / (at_1 - at_0)`.
    Range {
        /// Raw value at alpha 0.
        at_0: f64,
        /// Raw value at alpha 1.
        at_1: f64,
        /// Unit of the raw values (the column's).
        unit: String,
        /// `true` if the range is the smallest and largest raw value of the data.
        from_data: bool,
    },
}

impl LevelMap {
    /// The mapping of level column `c` with the range of the data `data` (smallest and
    /// largest raw value; used when the spec gives no range).
    pub fn new(c: &ColumnSpec, data: (f64, f64)) -> LevelMap {
        match LevelKind::of(c) {
            LevelKind::Linear => LevelMap::Linear {
                gain: c.gain(),
                offset: c.offset(),
                invert: c.invert,
            },
            LevelKind::Range(r) => LevelMap::Range {
                at_0: r.map_or(data.0, |r| r[0]),
                at_1: r.map_or(data.1, |r| r[1]),
                unit: c.unit.clone(),
                from_data: r.is_none(),
            },
        }
    }

    /// The level of raw value `raw`.
    pub fn alpha(&self, raw: f64) -> f64 {
        match self {
            LevelMap::Linear {
                gain,
                offset,
                invert,
            } => (raw * gain + offset) * if *invert { -1.0 } else { 1.0 },
            LevelMap::Range { at_0, at_1, .. } => (raw - at_0) / (at_1 - at_0),
        }
    }

    /// The mapping in words: `range 0 .. 5 V (the data's)`, `raw * 0.2 + 0`.
    pub fn describe(&self) -> String {
        match self {
            LevelMap::Linear {
                gain,
                offset,
                invert,
            } => format!("{}raw * {gain} + {offset}", if *invert { "-" } else { "" }),
            LevelMap::Range {
                at_0,
                at_1,
                unit,
                from_data,
            } => format!(
                "range {at_0} .. {at_1} {unit}{}",
                if *from_data {
                    " (the smallest and largest raw value of the imported files)"
                } else {
                    ""
                }
            ),
        }
    }
}

/// The manifest's `[condition]` of an import: the spec's `[condition]` with the defaults of
/// a level column mapped by a range (`level`): its unit and its raw values at alpha 0 and 1.
/// `None` without both (alpha is then the paper's oil loss). Refuses a missing name or prior,
/// a name or unit too long for the weights blob, and values at alpha 0 and 1 that are not
/// finite and distinct.
pub(crate) fn condition_spec(
    spec: &ImportSpec,
    level: Option<&LevelMap>,
) -> Result<Option<dataset::ConditionSpec>, ImportError> {
    resolve_condition(spec, level, true)
}

/// [`condition_spec`]; `check_values: false` skips the check of the values at alpha 0 and
/// 1 (a range still to be taken from the data).
fn resolve_condition(
    spec: &ImportSpec,
    level: Option<&LevelMap>,
    check_values: bool,
) -> Result<Option<dataset::ConditionSpec>, ImportError> {
    let range = match level {
        Some(LevelMap::Range {
            at_0, at_1, unit, ..
        }) => Some((*at_0, *at_1, unit.as_str())),
        _ => None,
    };
    let c = match (&spec.condition, range) {
        (None, None) => return Ok(None),
        (Some(c), _) => c.clone(),
        (None, Some(_)) => ImportCondition::default(),
    };
    let why = match (&spec.condition, range) {
        (None, Some((_, _, unit))) => format!(
            " (the level column in {unit} makes alpha a condition: name it in [condition] or \
             with --condition-name)"
        ),
        _ => String::new(),
    };
    let name = c.name.clone().ok_or_else(|| {
        spec_err(
            "condition.name",
            format!("missing: name what alpha stands for, e.g. \"control voltage\"{why}"),
        )
    })?;
    let prior = |d: Option<Direction>, coefficient: &str| {
        d.ok_or_else(|| {
            spec_err(
                format!("condition.{coefficient}"),
                format!(
                    "missing: the prior of {coefficient} in alpha, \"decreasing\", \
                     \"increasing\" or \"none\" (--prior {coefficient}=...); it is not assumed, \
                     since oil loss's \"decreasing\" is wrong for a condition that raises damping"
                ),
            )
        })
    };
    let out = dataset::ConditionSpec {
        unit: c.unit.clone().unwrap_or_else(|| match range {
            Some((_, _, u)) if u != "1" => u.to_string(),
            _ => "-".into(),
        }),
        at_alpha_0: c.at_alpha_0.or(range.map(|r| r.0)).unwrap_or(0.0),
        at_alpha_1: c.at_alpha_1.or(range.map(|r| r.1)).unwrap_or(1.0),
        b_fl: prior(c.b_fl, "b_fl")?,
        b_pr: prior(c.b_pr, "b_pr")?,
        k_pr: prior(c.k_pr, "k_pr")?,
        name,
    };
    let (name_max, unit_max) = (nemm_core::MAX_CONDITION_NAME, nemm_core::MAX_CONDITION_UNIT);
    if out.name.is_empty() || out.name.len() > name_max {
        return Err(spec_err(
            "condition.name",
            format!(
                "\"{}\" is {} bytes; must be 1 to {name_max} bytes",
                out.name,
                out.name.len()
            ),
        ));
    }
    for (key, text) in [("condition.name", &out.name), ("condition.unit", &out.unit)] {
        if let Some(message) = dataset::control_character(text) {
            return Err(spec_err(key, message));
        }
    }
    if out.unit.len() > unit_max {
        return Err(spec_err(
            "condition.unit",
            format!(
                "\"{}\" is {} bytes; must be at most {unit_max} bytes",
                out.unit,
                out.unit.len()
            ),
        ));
    }
    if !check_values {
        return Ok(Some(out));
    }
    if let Some((key, message)) = dataset::condition_values_error(out.at_alpha_0, out.at_alpha_1) {
        return Err(spec_err(key, message));
    }
    Ok(Some(out))
}

/// Checks the CSV dialect (`[csv]`).
fn validate_csv(csv: &CsvOptions) -> Result<(), ImportError> {
    if csv.header_line == 0 {
        return Err(spec_err("csv.header_line", "lines are counted from 1"));
    }
    let delimiter = delimiter_byte(&csv.delimiter)?;
    if csv.decimal_comma && delimiter == b',' {
        return Err(spec_err(
            "csv.decimal_comma",
            "needs a delimiter other than \",\"",
        ));
    }
    if let Some(c) = &csv.comment {
        if c.len() != 1 {
            return Err(spec_err("csv.comment", "must be one ASCII character"));
        }
    }
    Ok(())
}

/// Checks cutting options at `key` (`split` or `files[i].split`).
fn validate_split(key: &str, s: &SplitSpec) -> Result<(), ImportError> {
    for (k, v) in [
        ("min_pause_s", s.min_pause_s),
        ("pause_band", s.pause_band),
        ("min_run_s", s.min_run_s),
    ] {
        if !(v.is_finite() && v > 0.0) {
            return Err(spec_err(
                format!("{key}.{k}"),
                format!("{v} is not positive"),
            ));
        }
    }
    Ok(())
}

/// Checks raw file `i` (`files[i]`): its level (required unless the spec maps a level
/// column, `level_column`), its cutting and its time ranges.
fn validate_file(i: usize, f: &FileSpec, level_column: bool) -> Result<(), ImportError> {
    let level_ok = |a: f64| (0.0..=1.0).contains(&a);
    match f.alpha {
        Some(a) if !level_ok(a) => {
            return Err(spec_err(
                format!("files[{i}].alpha"),
                format!("{a} is outside [0, 1]"),
            ))
        }
        None if !level_column => {
            return Err(spec_err(
                format!("files[{i}].alpha"),
                "missing: give the file's condition level, or a level column \
                 (columns.alpha)",
            ))
        }
        _ => {}
    }
    if let Some(s) = &f.split {
        validate_split(&format!("files[{i}].split"), s)?;
    }
    for (j, r) in f.runs.iter().enumerate() {
        if !(r.start_s.is_finite() && r.end_s.is_finite() && r.start_s < r.end_s) {
            return Err(spec_err(
                format!("files[{i}].runs[{j}]"),
                format!("start_s {} must be below end_s {}", r.start_s, r.end_s),
            ));
        }
        if let Some(a) = r.alpha.filter(|a| !level_ok(*a)) {
            return Err(spec_err(
                format!("files[{i}].runs[{j}].alpha"),
                format!("{a} is outside [0, 1]"),
            ));
        }
    }
    Ok(())
}

pub(super) fn delimiter_byte(d: &str) -> Result<u8, ImportError> {
    match d {
        "tab" | "\t" => Ok(b'\t'),
        d if d.len() == 1 => Ok(d.as_bytes()[0]),
        _ => Err(spec_err(
            "csv.delimiter",
            format!("\"{d}\" is not one ASCII character or \"tab\""),
        )),
    }
}
