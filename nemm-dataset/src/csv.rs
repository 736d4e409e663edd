//! The CSV reader of the dataset's run files ([`crate::load`]) and of the raw logger files
//! `nemm data import` converts.
//!
//! It strips a UTF-8 byte-order mark, accepts LF, CRLF and CR line ends, trims the spaces
//! around cells and header names, skips blank lines, comment lines and the lines before the
//! header, and numbers every record with the 1-based line it starts on, as an editor shows it
//! (the `csv` crate's own record position is where the previous record ended, which after a
//! CRLF line end, a blank line or a comment line is an earlier line). Cells parse as finite
//! `f64` numbers, optionally with a decimal comma. Errors name the file and the line, and a
//! cell's errors its column.

use std::path::{Path, PathBuf};

/// The dialect of a CSV file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Dialect {
    /// Field delimiter.
    pub delimiter: u8,
    /// Lines starting with this byte are skipped.
    pub comment: Option<u8>,
    /// 1-based line of the header: records that start before it (a logger's preamble) are
    /// skipped.
    pub header_line: usize,
    /// Every row must have as many fields as the header ([`CsvError::FieldCount`]).
    pub same_field_count: bool,
    /// Numbers use a decimal comma (`1,5`).
    pub decimal_comma: bool,
}

impl Dialect {
    /// The dataset's run files: comma-separated, the header on line 1, no comments, every
    /// row as wide as the header.
    pub const RUN_FILE: Dialect = Dialect {
        delimiter: b',',
        comment: None,
        header_line: 1,
        same_field_count: true,
        decimal_comma: false,
    };
}

/// Why a CSV file could not be read.
#[derive(Debug)]
pub enum CsvError {
    /// The `csv` crate refused the text.
    Malformed {
        /// The file.
        path: PathBuf,
        /// The line of the record it stopped at.
        line: usize,
        /// Its message.
        message: String,
    },
    /// A row has a different number of fields than the header.
    FieldCount {
        /// The file.
        path: PathBuf,
        /// The row's line.
        line: usize,
        /// Fields in the header.
        expected: usize,
        /// Fields in the row.
        found: usize,
    },
}

/// What is wrong with a cell that should hold a number.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CellProblem {
    /// Not a number at all (empty, text, not UTF-8).
    NotANumber,
    /// NaN or infinite.
    NonFinite,
}

/// A cell that is not a finite number, with its place.
#[derive(Debug)]
pub struct CellError {
    /// The file.
    pub path: PathBuf,
    /// The row's line.
    pub line: usize,
    /// The field (0-based).
    pub field: usize,
    /// The column's header name (empty for a field beyond the header).
    pub column: String,
    /// The cell as found.
    pub value: String,
    /// What is wrong with it.
    pub problem: CellProblem,
}

/// The header of a file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// Its line.
    pub line: usize,
    /// The column names.
    pub names: Vec<String>,
}

/// Reads a CSV file held in memory: [`CsvReader::read_header`], then
/// [`CsvReader::next_row`] until it returns `None`.
pub struct CsvReader<'a> {
    path: &'a Path,
    /// The text without its byte-order mark.
    text: &'a [u8],
    dialect: Dialect,
    reader: ::csv::Reader<&'a [u8]>,
    record: ::csv::ByteRecord,
    lines: LineCounter,
    /// Line of the current record.
    line: usize,
    /// The header's column names (empty before [`CsvReader::read_header`]).
    names: Vec<String>,
}

impl<'a> CsvReader<'a> {
    /// A reader of `bytes`, the content of the file at `path` (used in errors only).
    pub fn new(bytes: &'a [u8], path: &'a Path, dialect: Dialect) -> Self {
        // Spreadsheet exports often start with a UTF-8 byte-order mark.
        let text = bytes.strip_prefix(b"\xEF\xBB\xBF").unwrap_or(bytes);
        let reader = ::csv::ReaderBuilder::new()
            .has_headers(false)
            .flexible(true)
            .trim(::csv::Trim::All)
            .delimiter(dialect.delimiter)
            .comment(dialect.comment)
            .from_reader(text);
        CsvReader {
            path,
            text,
            dialect,
            reader,
            record: ::csv::ByteRecord::new(),
            lines: LineCounter::default(),
            line: 0,
            names: Vec::new(),
        }
    }

    /// Reads the header: the first record that starts at or after the dialect's
    /// `header_line` (`None` when there is none).
    pub fn read_header(&mut self) -> Result<Option<Header>, CsvError> {
        while self.read_record()? {
            if self.line >= self.dialect.header_line {
                self.names = (0..self.record.len()).map(|i| self.text_of(i)).collect();
                return Ok(Some(Header {
                    line: self.line,
                    names: self.names.clone(),
                }));
            }
        }
        Ok(None)
    }

    /// The next row after the header (`None` at the end of the file).
    pub fn next_row(&mut self) -> Result<Option<Row<'_, 'a>>, CsvError> {
        if !self.read_record()? {
            return Ok(None);
        }
        if self.dialect.same_field_count && self.record.len() != self.names.len() {
            return Err(CsvError::FieldCount {
                path: self.path.to_path_buf(),
                line: self.line,
                expected: self.names.len(),
                found: self.record.len(),
            });
        }
        Ok(Some(Row { reader: self }))
    }

    /// Reads the next record and its line; `false` at the end of the file.
    fn read_record(&mut self) -> Result<bool, CsvError> {
        match self.reader.read_byte_record(&mut self.record) {
            Ok(false) => Ok(false),
            Ok(true) => {
                self.line = match self.record.position() {
                    Some(p) => self.line_from(p.byte()),
                    None => self.line + 1,
                };
                Ok(true)
            }
            Err(e) => Err(CsvError::Malformed {
                path: self.path.to_path_buf(),
                line: match e.position() {
                    Some(p) => self.line_from(p.byte()),
                    None => self.line + 1,
                },
                message: e.to_string(),
            }),
        }
    }

    /// The line of the record the `csv` crate places at byte `at`: its position is where the
    /// previous record ended, before the blank and comment lines it skips.
    fn line_from(&mut self, at: u64) -> usize {
        let mut at = usize::try_from(at)
            .unwrap_or(usize::MAX)
            .min(self.text.len());
        loop {
            match self.text.get(at) {
                Some(b'\r' | b'\n') => at += 1,
                Some(&c) if Some(c) == self.dialect.comment => {
                    // A comment runs to the next LF.
                    at += self.text[at..]
                        .iter()
                        .position(|&b| b == b'\n')
                        .map_or(self.text.len() - at, |n| n + 1);
                }
                _ => break,
            }
        }
        self.lines.line_at(self.text, at)
    }

    /// Field `i` of the current record as text (spaces trimmed; empty beyond its end).
    fn text_of(&self, i: usize) -> String {
        String::from_utf8_lossy(self.record.get(i).unwrap_or_default())
            .trim()
            .to_string()
    }
}

/// A row of a file.
pub struct Row<'r, 'a> {
    reader: &'r CsvReader<'a>,
}

impl Row<'_, '_> {
    /// Its line (1-based).
    pub fn line(&self) -> usize {
        self.reader.line
    }

    /// The number of fields of the row.
    pub fn field_count(&self) -> usize {
        self.reader.record.len()
    }

    /// `true` if every field is empty.
    pub fn is_blank(&self) -> bool {
        self.reader.record.iter().all(<[u8]>::is_empty)
    }

    /// Field `i` as text (spaces trimmed; empty beyond the row's end).
    pub fn text(&self, i: usize) -> String {
        self.reader.text_of(i)
    }

    /// The header name of column `i` (empty beyond the header).
    pub fn column(&self, i: usize) -> String {
        self.reader.names.get(i).cloned().unwrap_or_default()
    }

    /// Field `i` as a finite number (a field beyond the row's end is empty, so not a number).
    pub fn number(&self, i: usize) -> Result<f64, CellError> {
        let raw = self.reader.record.get(i).unwrap_or_default();
        let text = std::str::from_utf8(raw).ok().map(str::trim);
        let parsed = text.and_then(|t| {
            if self.reader.dialect.decimal_comma {
                t.replace(',', ".").parse::<f64>().ok()
            } else {
                t.parse::<f64>().ok()
            }
        });
        let problem = match parsed {
            Some(v) if v.is_finite() => return Ok(v),
            Some(_) => CellProblem::NonFinite,
            None => CellProblem::NotANumber,
        };
        Err(CellError {
            path: self.reader.path.to_path_buf(),
            line: self.line(),
            field: i,
            column: self.column(i),
            value: self.text(i),
            problem,
        })
    }
}

/// Line numbers of byte offsets, counted on from the last offset asked for.
#[derive(Debug, Clone, Copy)]
struct LineCounter {
    /// The last offset asked for.
    offset: usize,
    /// Its line.
    line: usize,
}

impl Default for LineCounter {
    fn default() -> Self {
        LineCounter { offset: 0, line: 1 }
    }
}

impl LineCounter {
    /// The 1-based line of byte `at` of `text`; LF, CRLF and a lone CR end a line.
    fn line_at(&mut self, text: &[u8], at: usize) -> usize {
        if at < self.offset {
            *self = LineCounter::default();
        }
        let at = at.min(text.len());
        for i in self.offset..at {
            match text[i] {
                b'\n' => self.line += 1,
                b'\r' if text.get(i + 1) != Some(&b'\n') => self.line += 1,
                _ => {}
            }
        }
        self.offset = at;
        self.line
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `(line, fields)` of every row of `text` read with `dialect`, after the header's line.
    fn rows(text: &str, dialect: Dialect) -> (usize, Vec<(usize, Vec<String>)>) {
        let path = Path::new("x.csv");
        let mut r = CsvReader::new(text.as_bytes(), path, dialect);
        let header = r.read_header().expect("read").expect("header");
        let mut out = Vec::new();
        while let Some(row) = r.next_row().expect("row") {
            let n = row.reader.record.len();
            out.push((row.line(), (0..n).map(|i| row.text(i)).collect()));
        }
        (header.line, out)
    }

    /// The header's line and the rows' lines.
    fn lines_of(text: &str, dialect: Dialect) -> (usize, Vec<usize>) {
        let (h, rows) = rows(text, dialect);
        (h, rows.into_iter().map(|r| r.0).collect())
    }

    #[test]
    fn lines_are_those_an_editor_shows() {
        let d = Dialect::RUN_FILE;
        assert_eq!(lines_of("a,b\n1,2\n3,4\n", d), (1, vec![2, 3]));
        assert_eq!(lines_of("a,b\r\n1,2\r\n3,4\r\n", d), (1, vec![2, 3]));
        assert_eq!(lines_of("a,b\r1,2\r3,4", d), (1, vec![2, 3]));
        assert_eq!(lines_of("\na,b\n\n1,2\r\n\r\n\r\n3,4", d), (2, vec![4, 7]));
        // A quoted field spanning lines: the record's first line.
        assert_eq!(lines_of("a,b\n\"1\n2\",2\n3,4\n", d), (1, vec![2, 4]));
        let logger = Dialect {
            comment: Some(b'#'),
            header_line: 3,
            same_field_count: false,
            ..d
        };
        assert_eq!(
            lines_of(
                "preamble\r\n# note\r\nt;x\r\n# note\r\n1;2\r\n\r\n3;4\r\n",
                Dialect {
                    delimiter: b';',
                    ..logger
                }
            ),
            (3, vec![5, 7])
        );
        // Records before the header line are skipped, whatever their width.
        assert_eq!(
            lines_of("v2\r\nop: me, you\r\nt,x\r\n1,2\r\n", logger),
            (3, vec![4])
        );
    }

    #[test]
    fn byte_order_mark_and_spaces_are_dropped() {
        let (_, r) = rows("\u{feff} a , b \n 1 ,\t2\n", Dialect::RUN_FILE);
        assert_eq!(r, vec![(2, vec!["1".to_string(), "2".to_string()])]);
        let mut reader = CsvReader::new(
            "\u{feff} a , b \n".as_bytes(),
            Path::new("x"),
            Dialect::RUN_FILE,
        );
        let h = reader.read_header().expect("read").expect("header");
        assert_eq!(h.names, ["a", "b"]);
    }

    #[test]
    fn cells_name_their_line_and_column() {
        let text = "t,x\r\n0,1\r\n0.1,NaN\r\n0.2,abc\r\n";
        let mut r = CsvReader::new(text.as_bytes(), Path::new("x.csv"), Dialect::RUN_FILE);
        r.read_header().expect("read");
        let row = r.next_row().expect("read").expect("row");
        assert_eq!(row.number(1).expect("number"), 1.0);
        let row = r.next_row().expect("read").expect("row");
        let e = row.number(1).expect_err("NaN");
        assert_eq!(
            (
                e.line,
                e.field,
                e.column.as_str(),
                e.value.as_str(),
                e.problem
            ),
            (3, 1, "x", "NaN", CellProblem::NonFinite)
        );
        let row = r.next_row().expect("read").expect("row");
        let e = row.number(1).expect_err("text");
        assert_eq!((e.line, e.problem), (4, CellProblem::NotANumber));
        assert!(r.next_row().expect("end").is_none());
    }

    #[test]
    fn a_decimal_comma_parses() {
        let d = Dialect {
            delimiter: b';',
            decimal_comma: true,
            ..Dialect::RUN_FILE
        };
        let mut r = CsvReader::new(b"t;x\n0;1,5\n", Path::new("x.csv"), d);
        r.read_header().expect("read");
        let row = r.next_row().expect("read").expect("row");
        assert_eq!(row.number(1).expect("number"), 1.5);
    }

    #[test]
    fn rows_as_wide_as_the_header_when_asked() {
        let text = "t,x\r\n0,1\r\n0.1\r\n";
        let mut r = CsvReader::new(text.as_bytes(), Path::new("x.csv"), Dialect::RUN_FILE);
        r.read_header().expect("read");
        assert!(r.next_row().expect("row").is_some());
        match r.next_row() {
            Err(CsvError::FieldCount {
                line: 3,
                expected: 2,
                found: 1,
                ..
            }) => {}
            other => panic!("{:?}", other.map(|r| r.map(|r| r.line()))),
        }
        let flexible = Dialect {
            same_field_count: false,
            ..Dialect::RUN_FILE
        };
        assert_eq!(lines_of(text, flexible), (1, vec![2, 3]));
    }
}
