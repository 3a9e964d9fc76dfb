//! Reading a measurement file a block of rows at a time, so that a fit of 10⁸ observations
//! never holds them all. Every line goes through the same header and cell parsing as
//! [`read`](fn@super::read) (the reader of `read.rs`); only the whole-file text and the whole-file
//! columns are replaced by one line and one block.
//!
//! Errors are those of [`read_file`](super::read_file), found at the same lines: a file with
//! problems is read to its end first so that the list is the whole file's, and the block in
//! which a problem was found is never handed out.

use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};

use kin_compiler::ir::Machine;

use super::read::{dialect_of, not_utf8, skipped, Cell, Reader};
use super::{Observations, Problem, ReadError, ReadOptions, MAX_PROBLEMS};

/// The rows of one file, `rows` at a time (see [`chunks`]).
pub struct Chunks<'m> {
    path: PathBuf,
    input: BufReader<File>,
    reader: Reader<'m>,
    rows: usize,
    /// 1-based number of the last line read.
    line: usize,
    buffer: Vec<u8>,
    cells: Vec<Cell>,
    /// Scratch for a line whose quotes are removed.
    unquoted: String,
    done: bool,
}

/// Opens `path` for reading `rows` rows at a time. The header is read and checked here; the
/// blocks come from the iterator, each an [`Observations`] of the file's kind with at most
/// `rows` rows, their own line numbers, and run and artifact ids of the whole file.
pub fn chunks<'m>(
    path: &Path,
    machine: &'m Machine,
    options: &ReadOptions,
    rows: usize,
) -> Result<Chunks<'m>, ReadError> {
    let io = |source| ReadError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut input = BufReader::new(File::open(path).map_err(io)?);
    let mut buffer = Vec::new();
    let mut line = 0usize;
    let header = loop {
        buffer.clear();
        if input.read_until(b'\n', &mut buffer).map_err(io)? == 0 {
            return Err(invalid(path, vec![Problem::NoHeader], 0));
        }
        line += 1;
        let text = text_of(&buffer, line, path)?;
        if !skipped(text) {
            break text.to_string();
        }
    };
    let reader = Reader::new(
        machine,
        options,
        dialect_of(options, &header),
        line,
        &header,
    );
    Ok(Chunks {
        path: path.to_path_buf(),
        input,
        reader,
        rows: rows.max(1),
        line,
        buffer,
        cells: Vec::new(),
        unquoted: String::new(),
        done: false,
    })
}

fn invalid(path: &Path, problems: Vec<Problem>, omitted: usize) -> ReadError {
    ReadError::Invalid {
        path: path.to_path_buf(),
        problems,
        omitted,
    }
}

/// One line without its line end (and, on the first line, a spreadsheet's byte order mark),
/// or the error `read` gives for text that is not UTF-8, at its line and column.
fn text_of<'b>(bytes: &'b [u8], line: usize, path: &Path) -> Result<&'b str, ReadError> {
    let bytes = bytes.strip_suffix(b"\n").unwrap_or(bytes);
    let bytes = bytes.strip_suffix(b"\r").unwrap_or(bytes);
    let text = std::str::from_utf8(bytes).map_err(|e| {
        let problem = match not_utf8(bytes, e.valid_up_to()) {
            Problem::NotUtf8 { column, .. } => Problem::NotUtf8 { line, column },
            other => other,
        };
        invalid(path, vec![problem], 0)
    })?;
    Ok(if line == 1 {
        text.strip_prefix('\u{feff}').unwrap_or(text)
    } else {
        text
    })
}

impl Chunks<'_> {
    /// Reads up to `rows` more data lines; false at the end of the file.
    fn fill(&mut self) -> Result<bool, ReadError> {
        let start = self.reader.data_lines();
        while self.reader.data_lines() - start < self.rows {
            self.buffer.clear();
            let read = self
                .input
                .read_until(b'\n', &mut self.buffer)
                .map_err(|source| ReadError::Io {
                    path: self.path.clone(),
                    source,
                })?;
            if read == 0 {
                return Ok(false);
            }
            self.line += 1;
            let text = text_of(&self.buffer, self.line, &self.path)?;
            if skipped(text) {
                continue;
            }
            self.reader
                .line(self.line, text, &mut self.cells, &mut self.unquoted);
        }
        Ok(true)
    }

    fn next_block(&mut self) -> Result<Option<Observations>, ReadError> {
        let more = self.fill()?;
        if !more && self.reader.data_lines() == 0 {
            // After the header's own problems, as `read` lists them.
            let (problems, mut omitted) = self.reader.problems();
            let mut problems = problems.to_vec();
            if problems.len() < MAX_PROBLEMS {
                problems.push(Problem::NoRows);
            } else {
                omitted += 1;
            }
            return Err(invalid(&self.path, problems, omitted));
        }
        if !self.reader.problems().0.is_empty() {
            // The whole file's problems, as `read` lists them; the rows are dropped as read.
            let mut more = more;
            while more {
                drop(self.reader.take());
                more = self.fill()?;
            }
            let (problems, omitted) = self.reader.problems();
            return Err(invalid(&self.path, problems.to_vec(), omitted));
        }
        if !more {
            self.done = true;
        }
        let block = self.reader.take();
        Ok((!block.is_empty()).then_some(block))
    }
}

impl Iterator for Chunks<'_> {
    type Item = Result<Observations, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.done {
            return None;
        }
        match self.next_block() {
            Ok(Some(block)) => Some(Ok(block)),
            Ok(None) => {
                self.done = true;
                None
            }
            Err(e) => {
                self.done = true;
                Some(Err(e))
            }
        }
    }
}
