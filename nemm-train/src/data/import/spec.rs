//! The import spec: read from TOML with line and column in its errors, units, and its
//! validation.

use super::*;

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
pub fn unit_factor(role: &str, unit: &str) -> Option<f64> {
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
    for (k, v) in [("rate_hz", spec.rate_hz), ("resample_hz", spec.resample_hz)] {
        if let Some(v) = v {
            if !(v.is_finite() && v > 0.0) {
                return Err(spec_err(k, format!("{v} is not a positive rate in Hz")));
            }
        }
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
    if !(c.gain.is_finite() && c.gain != 0.0) {
        return Err(spec_err(
            key("gain"),
            format!("{} is not a non-zero number", c.gain),
        ));
    }
    if !c.offset.is_finite() {
        return Err(spec_err(key("offset"), "is not finite"));
    }
    Ok(())
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
