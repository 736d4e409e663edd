//! Writing a dataset: the runs validated as loading would, then written atomically.

use super::*;

/// Checks an in-memory run as [`load`] would check its file (lengths, finite values, time).
fn validate_run(run: &Run, path: &Path, sample_rate_hz: f64) -> Result<(), DatasetError> {
    let n = run.time_s.len();
    if n == 0 {
        return Err(DatasetError::NoSamples {
            path: path.to_path_buf(),
            line: 2,
        });
    }
    let mut columns: Vec<(&str, &[f64])> = vec![
        (COL_TIME, &run.time_s),
        (COL_DISPLACEMENT, &run.displacement_m),
        (COL_FORCE, &run.force_n),
    ];
    if let Some(v) = &run.velocity_m_s {
        columns.push((COL_VELOCITY, v));
    }
    if let Some(a) = &run.alpha {
        columns.push((COL_ALPHA, a));
    }
    for (name, values) in &columns {
        if values.len() != n {
            return Err(DatasetError::LengthMismatch {
                path: path.to_path_buf(),
                column: (*name).to_string(),
                expected: n,
                found: values.len(),
            });
        }
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(DatasetError::NonFinite {
                path: path.to_path_buf(),
                line: sample_line(i),
                column: (*name).to_string(),
                value: values[i].to_string(),
            });
        }
    }
    if let Some(a) = &run.alpha {
        for (i, &value) in a.iter().enumerate() {
            check_alpha(value, path, sample_line(i))?;
        }
    }
    for (i, w) in run.time_s.windows(2).enumerate() {
        check_increasing(w[0], w[1], path, sample_line(i + 1))?;
    }
    check_time_grid(&run.time_s, sample_rate_hz, path, sample_line)?;
    Ok(())
}

/// [`crate::atomic_file::write_atomic`] with the dataset's error type (naming the file).
fn write_atomic(
    path: &Path,
    fill: impl FnOnce(&mut dyn std::io::Write) -> std::io::Result<()>,
) -> Result<(), DatasetError> {
    crate::atomic_file::write_atomic(path, fill).map_err(|error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    })
}

/// Writes one run as CSV (`time_s,displacement_m,force_n[,velocity_m_s][,alpha]`).
fn write_run_csv(run: &Run, w: &mut dyn std::io::Write) -> std::io::Result<()> {
    let mut line = String::with_capacity(128);
    line.push_str("time_s,displacement_m,force_n");
    if run.velocity_m_s.is_some() {
        line.push_str(",velocity_m_s");
    }
    if run.alpha.is_some() {
        line.push_str(",alpha");
    }
    line.push('\n');
    w.write_all(line.as_bytes())?;
    for i in 0..run.time_s.len() {
        line.clear();
        // `{}` on f64 prints the shortest decimal that parses back to the same value.
        let _ = write!(
            line,
            "{},{},{}",
            run.time_s[i], run.displacement_m[i], run.force_n[i]
        );
        if let Some(v) = &run.velocity_m_s {
            let _ = write!(line, ",{}", v[i]);
        }
        if let Some(a) = &run.alpha {
            let _ = write!(line, ",{}", a[i]);
        }
        line.push('\n');
        w.write_all(line.as_bytes())?;
    }
    Ok(())
}

/// Writes `dataset` to the folder `dir` (created if needed): every run CSV at its manifest
/// path, then `manifest.toml`. Each file is written atomically; the dataset is validated
/// first with the same rules as [`load`], so whatever `write` accepts, `load` reads back
/// exactly. Existing files of the same names are replaced; other files are left alone.
pub fn write(dir: &Path, dataset: &Dataset) -> Result<(), DatasetError> {
    use rayon::prelude::*;
    let manifest = dataset.manifest();
    let manifest_path = dir.join(MANIFEST_FILE);
    validate_manifest(&manifest, &manifest_path, None)?;
    for run in &dataset.runs {
        validate_run(run, &dir.join(&run.entry.file), dataset.sample_rate_hz)?;
    }
    dataset
        .runs
        .par_iter()
        .map(|run| write_atomic(&dir.join(&run.entry.file), |w| write_run_csv(run, w)))
        .collect::<Result<Vec<()>, _>>()?;
    let text = toml::to_string(&manifest).map_err(|e| DatasetError::ManifestValue {
        path: manifest_path.clone(),
        line: None,
        key: "(manifest)".into(),
        message: format!("cannot be encoded as TOML: {e}"),
    })?;
    write_atomic(&manifest_path, |w| w.write_all(text.as_bytes()))
}
