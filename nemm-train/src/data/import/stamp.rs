//! Date-time stamps as loggers write them, read as seconds.
//!
//! Accepted forms: `YYYY-MM-DD HH:MM:SS` or `YYYY-MM-DDTHH:MM:SS` (ISO 8601), each with an
//! optional fraction of a second (`.107472`, up to nanoseconds and beyond, which are
//! ignored) and an optional offset (`Z`, `+01:00`, `-0530`, `+01`). A stamp with an offset
//! is taken in UTC; stamps without one are taken as they are (the same clock for the file).

/// A date-time stamp: whole seconds since 1970-01-01 00:00:00 (UTC when the stamp has an
/// offset) and the fraction of the second.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Stamp {
    /// Whole seconds.
    pub(super) seconds: i64,
    /// Fraction of a second, in \[0, 1).
    pub(super) fraction: f64,
}

impl Stamp {
    /// Seconds from `origin` to `self`.
    pub(super) fn since(&self, origin: &Stamp) -> f64 {
        (self.seconds - origin.seconds) as f64 + (self.fraction - origin.fraction)
    }
}

/// `true` when `text` starts like a date (`NNNN-`): a cell meant as a date-time stamp.
pub(super) fn looks_like_date(text: &str) -> bool {
    let b = text.as_bytes();
    b.len() >= 5 && b[..4].iter().all(u8::is_ascii_digit) && b[4] == b'-'
}

/// Days from 1970-01-01 to the civil date `y-m-d` (proleptic Gregorian calendar).
fn days_from_civil(y: i64, m: i64, d: i64) -> i64 {
    let y = if m <= 2 { y - 1 } else { y };
    let era = y.div_euclid(400);
    let yoe = y - era * 400;
    let doy = (153 * (m + if m > 2 { -3 } else { 9 }) + 2) / 5 + d - 1;
    let doe = yoe * 365 + yoe / 4 - yoe / 100 + doy;
    era * 146_097 + doe - 719_468
}

/// Days in month `m` of year `y`.
fn days_in_month(y: i64, m: i64) -> i64 {
    match m {
        4 | 6 | 9 | 11 => 30,
        2 if (y % 4 == 0 && y % 100 != 0) || y % 400 == 0 => 29,
        2 => 28,
        _ => 31,
    }
}

/// A cursor over the stamp's bytes.
struct Cursor<'a> {
    b: &'a [u8],
    at: usize,
}

impl Cursor<'_> {
    /// Exactly `n` digits, within `lo..=hi`, named `what` in the error.
    fn digits(&mut self, n: usize, lo: i64, hi: i64, what: &str) -> Result<i64, String> {
        let s = self.b.get(self.at..self.at + n).unwrap_or_default();
        if s.len() != n || !s.iter().all(u8::is_ascii_digit) {
            return Err(format!("expected {n} digits of the {what}"));
        }
        self.at += n;
        let v = s.iter().fold(0i64, |v, d| v * 10 + i64::from(d - b'0'));
        if !(lo..=hi).contains(&v) {
            return Err(format!("{what} {v} is outside {lo}..{hi}"));
        }
        Ok(v)
    }

    /// The byte `c` (one of `cs`).
    fn one_of(&mut self, cs: &[u8], what: &str) -> Result<u8, String> {
        match self.b.get(self.at) {
            Some(c) if cs.contains(c) => {
                self.at += 1;
                Ok(*c)
            }
            _ => Err(format!("expected {what}")),
        }
    }
}

/// Parses a date-time stamp (see the module documentation for the forms); the error says
/// what is wrong.
pub(super) fn parse(text: &str) -> Result<Stamp, String> {
    let mut c = Cursor {
        b: text.as_bytes(),
        at: 0,
    };
    let y = c.digits(4, 0, 9999, "year")?;
    c.one_of(b"-", "'-' after the year")?;
    let mo = c.digits(2, 1, 12, "month")?;
    c.one_of(b"-", "'-' after the month")?;
    let d = c.digits(2, 1, days_in_month(y, mo), "day")?;
    c.one_of(b"T t", "'T' or a space between the date and the time")?;
    let h = c.digits(2, 0, 23, "hour")?;
    c.one_of(b":", "':' after the hour")?;
    let mi = c.digits(2, 0, 59, "minute")?;
    c.one_of(b":", "':' after the minute")?;
    let s = c.digits(2, 0, 59, "second")?;
    let mut fraction = 0.0;
    if c.b.get(c.at) == Some(&b'.') {
        c.at += 1;
        let start = c.at;
        while c.b.get(c.at).is_some_and(u8::is_ascii_digit) {
            c.at += 1;
        }
        if c.at == start {
            return Err("expected digits after the '.' of the seconds".into());
        }
        // At most 18 digits (attoseconds) count; more are below any logger's resolution.
        let digits = &text[start..c.at.min(start + 18)];
        fraction = digits.parse::<u64>().map_err(|e| e.to_string())? as f64
            / 10f64.powi(digits.len() as i32);
    }
    let mut offset_s = 0;
    match c.b.get(c.at) {
        None => {}
        Some(b'Z' | b'z') => c.at += 1,
        Some(b'+' | b'-') => {
            let sign = if c.one_of(b"+-", "an offset sign")? == b'-' {
                -1
            } else {
                1
            };
            let oh = c.digits(2, 0, 23, "offset hours")?;
            let mut om = 0;
            if c.b.get(c.at) == Some(&b':') {
                c.at += 1;
                om = c.digits(2, 0, 59, "offset minutes")?;
            } else if c.at < c.b.len() {
                om = c.digits(2, 0, 59, "offset minutes")?;
            }
            offset_s = sign * (oh * 3600 + om * 60);
        }
        Some(_) => {
            return Err("expected a fraction '.', an offset (Z, +HH:MM) or the end".into());
        }
    }
    if c.at != c.b.len() {
        return Err("unexpected text after the offset".into());
    }
    let seconds = days_from_civil(y, mo, d) * 86_400 + h * 3600 + mi * 60 + s - offset_s;
    Ok(Stamp { seconds, fraction })
}

/// The accepted forms, for error messages.
pub(super) const FORMS: &str =
    "YYYY-MM-DD HH:MM:SS[.ffffff][Z|+HH:MM] or YYYY-MM-DDTHH:MM:SS[.ffffff][Z|+HH:MM]";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn logger_and_iso_forms_parse_to_the_same_instant() {
        let a = parse("2025-11-14 19:25:35.107472").expect("space");
        let b = parse("2025-11-14T19:25:35.107472Z").expect("iso");
        let c = parse("2025-11-14T20:25:35.107472+01:00").expect("offset");
        let d = parse("2025-11-14T14:25:35.107472-0500").expect("offset without colon");
        assert_eq!(a, b);
        assert_eq!(b, c);
        assert_eq!(c, d);
        // 2025-11-14 is day 20406 since 1970-01-01.
        assert_eq!(a.seconds, 20_406 * 86_400 + 19 * 3600 + 25 * 60 + 35);
        assert!((a.fraction - 0.107_472).abs() < 1e-15);
        let whole = parse("2025-11-14 19:25:36").expect("no fraction");
        assert!((whole.since(&a) - 0.892_528).abs() < 1e-12);
        // Across midnight and a leap day.
        let e = parse("2024-02-29 23:59:59.5").expect("leap day");
        let f = parse("2024-03-01 00:00:00.25").expect("next day");
        assert!((f.since(&e) - 0.75).abs() < 1e-12);
    }

    #[test]
    fn malformed_stamps_say_what_is_wrong() {
        for (text, want) in [
            ("2025-13-14 19:25:35", "month 13"),
            ("2025-02-29 19:25:35", "day 29"),
            ("2025-11-14 24:00:00", "hour 24"),
            ("2025-11-14 19:25", "':' after the minute"),
            ("2025-11-14/19:25:35", "'T' or a space"),
            ("2025-11-14 19:25:35.", "digits after the '.'"),
            ("2025-11-14 19:25:35 UTC", "an offset"),
        ] {
            let e = parse(text).expect_err(text);
            assert!(e.contains(want), "{text}: {e}");
        }
        assert!(looks_like_date("2025-11-14 19:25"));
        assert!(!looks_like_date("1.5e-3"));
    }
}
