//! Reading an input file: a size limit, what the bytes are (UTF-8 text or not), and
//! line numbers found in one pass.
//!
//! Every loader reads through [`read_input`] (the file whole) or, for the survey
//! readers' CSV files, a `TextStream` (record by record, the same checks block by
//! block): at most [`MAX_INPUT_BYTES`] are read (an
//! endless stream such as `/dev/zero` stops at the first block that holds a NUL byte,
//! an endless text stream at the limit), and the bytes must be UTF-8 text with LF or
//! CRLF line ends: UTF-16 and UTF-32 (with or without a byte-order mark), CR-only
//! line ends and binary data are named as what they are.

use std::io::Read;
use std::path::Path;

use super::{DatasetError, Result};

/// Largest input file read \[bytes\] (1 GiB: a 13.9-hour 100 Hz ground truth, the
/// longest span synthesized, is about 0.7 GB of CSV).
pub const MAX_INPUT_BYTES: u64 = 1 << 30;

/// Size of the blocks read; the first one is examined before reading on.
const BLOCK: usize = 64 * 1024;

/// Read everything from `reader`, at most `limit` bytes; `path` names the source in
/// errors. The first block is examined before the rest is read, so a binary stream
/// fails after one block.
///
/// # Errors
/// [`DatasetError::Io`], [`DatasetError::TooLarge`] beyond `limit`,
/// [`DatasetError::NotText`] for bytes that are not UTF-8 text with LF line ends.
pub fn read_limited(reader: impl Read, path: &Path, limit: u64) -> Result<Vec<u8>> {
    let io = |error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    };
    let mut reader = reader.take(limit.saturating_add(1));
    let mut bytes = Vec::new();
    let mut block = vec![0u8; BLOCK];
    let mut examined = false;
    loop {
        let n = match reader.read(&mut block) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(io(e)),
        };
        bytes.extend_from_slice(&block[..n]);
        if !examined && bytes.len() >= BLOCK {
            check_text(&bytes, path, false)?;
            examined = true;
        }
        if bytes.len() as u64 > limit {
            return Err(DatasetError::TooLarge {
                path: path.to_path_buf(),
                limit,
            });
        }
    }
    check_text(&bytes, path, true)?;
    Ok(bytes)
}

/// [`read_limited`] with [`MAX_INPUT_BYTES`].
///
/// # Errors
/// As [`read_limited`].
pub fn read_input(reader: impl Read, path: &Path) -> Result<Vec<u8>> {
    read_limited(reader, path, MAX_INPUT_BYTES)
}

/// Open and read a file with [`read_input`].
///
/// # Errors
/// As [`read_limited`].
pub(crate) fn read_file(path: &Path) -> Result<Vec<u8>> {
    let file = std::fs::File::open(path).map_err(|error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    read_input(std::io::BufReader::with_capacity(BLOCK, file), path)
}

/// Open and read a text file (a TOML or JSON setting) with [`read_input`]'s limit and
/// checks.
///
/// # Errors
/// As [`read_limited`].
pub fn read_text_file(path: &Path) -> Result<String> {
    let bytes = read_file(path)?;
    String::from_utf8(bytes).map_err(|e| DatasetError::NotText {
        path: path.to_path_buf(),
        line: None,
        what: format!("not UTF-8 text ({e})"),
    })
}

/// Read a PD0 recording of at most `limit` bytes with [`estim_dvl::read_pd0_from`],
/// in bounded memory (the reader's window, the decoded ensembles and the report): a
/// regular file larger than `limit` is refused before reading, an endless stream
/// (`/dev/zero`) once `limit` bytes were read.
///
/// # Errors
/// [`DatasetError::Io`], [`DatasetError::TooLarge`].
pub fn read_pd0_input(path: &Path, limit: u64) -> Result<estim_dvl::Pd0Read> {
    let io = |error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let too_large = || DatasetError::TooLarge {
        path: path.to_path_buf(),
        limit,
    };
    if file
        .metadata()
        .is_ok_and(|m| m.is_file() && m.len() > limit)
    {
        return Err(too_large());
    }
    let read = estim_dvl::read_pd0_from(file.take(limit.saturating_add(1))).map_err(io)?;
    if read.report.input_bytes as u64 > limit {
        return Err(too_large());
    }
    Ok(read)
}

/// A text input read block by block, with the checks of [`read_limited`] made as it
/// goes, so that a CSV reader can stream its records in bounded memory: the first
/// block is read and examined at once (encoding, binary data; everything, the end of
/// the file included, when the file fits in it), each later block for binary bytes
/// and invalid UTF-8 (offset and line), and the total against the cap. A failure is
/// kept and surfaces as an I/O error of the reader: take it with
/// [`TextStream::take_failure`]. What a table needs at the end (a cut last line, a
/// blank file) is answered by [`TextStream::truncated_line`] and
/// [`TextStream::blank`] once the end has been read.
pub(crate) struct TextStream<R> {
    inner: R,
    path: std::path::PathBuf,
    limit: u64,
    head: Vec<u8>,
    served: usize,
    read: u64,
    newlines: u64,
    seen_lf: bool,
    seen_cr: bool,
    carry: Vec<u8>,
    tail_blank: bool,
    content: bool,
    end: bool,
    failure: Option<DatasetError>,
}

impl<R: Read> TextStream<R> {
    /// Read and examine the first block of `inner`.
    ///
    /// # Errors
    /// As [`read_limited`] for that block.
    pub(crate) fn new(mut inner: R, path: &Path, limit: u64) -> Result<Self> {
        let mut head = vec![0u8; BLOCK];
        let mut filled = 0;
        let mut end = false;
        while filled < BLOCK {
            match inner.read(&mut head[filled..]) {
                Ok(0) => {
                    end = true;
                    break;
                }
                Ok(n) => filled += n,
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(error) => {
                    return Err(DatasetError::Io {
                        path: path.to_path_buf(),
                        error,
                    })
                }
            }
        }
        head.truncate(filled);
        if filled as u64 > limit {
            return Err(DatasetError::TooLarge {
                path: path.to_path_buf(),
                limit,
            });
        }
        check_text(&head, path, end)?;
        if !end && !head.contains(&b'\n') && head.contains(&b'\r') {
            // A whole block without a line feed but with carriage returns.
            check_text(&head, path, true)?;
        }
        let mut stream = Self {
            inner,
            path: path.to_path_buf(),
            limit,
            head: Vec::new(),
            served: 0,
            read: filled as u64,
            newlines: 0,
            seen_lf: false,
            seen_cr: false,
            carry: Vec::new(),
            tail_blank: true,
            content: false,
            end,
            failure: None,
        };
        stream.scan(&head, 0)?;
        stream.head = head;
        Ok(stream)
    }

    /// Track lines, the last line's content and UTF-8 across blocks; check a later
    /// block's bytes (`offset`: the block's first byte in the file).
    fn scan(&mut self, block: &[u8], offset: u64) -> Result<()> {
        let line_at = |newlines: u64, i: usize| {
            1 + newlines + block[..i].iter().filter(|&&b| b == b'\n').count() as u64
        };
        if offset > 0 {
            if let Some(i) = block
                .iter()
                .position(|&b| b < 0x20 && !matches!(b, b'\n' | b'\r' | b'\t' | 0x0c))
            {
                let (at, line) = (offset + i as u64, line_at(self.newlines, i));
                let what = if block[i] == 0 {
                    format!(
                        "binary data, not a CSV text file (a NUL byte at offset {at}, line {line})"
                    )
                } else {
                    format!(
                        "binary data, not a CSV text file (control byte 0x{:02x} at offset {at}, line {line})",
                        block[i]
                    )
                };
                return Err(DatasetError::NotText {
                    path: self.path.clone(),
                    line: Some(line),
                    what,
                });
            }
            let mut joined = std::mem::take(&mut self.carry);
            let carried = joined.len();
            joined.extend_from_slice(block);
            if let Err(e) = std::str::from_utf8(&joined) {
                let i = e.valid_up_to();
                if e.error_len().is_some() {
                    let in_block = i.saturating_sub(carried);
                    let line = line_at(self.newlines, in_block);
                    return Err(DatasetError::NotText {
                        path: self.path.clone(),
                        line: Some(line),
                        what: format!(
                            "not UTF-8 text (invalid byte 0x{:02x} at offset {}, line {line}; \
                             Latin-1 or Windows-1252? save it as UTF-8)",
                            joined[i],
                            offset + in_block as u64
                        ),
                    });
                }
                self.carry = joined[i..].to_vec();
            }
        } else if let Err(e) = std::str::from_utf8(block) {
            // The first block was examined whole; keep a sequence cut at its end.
            self.carry = block[e.valid_up_to()..].to_vec();
        }
        for &b in block {
            match b {
                b'\n' => {
                    self.newlines += 1;
                    self.seen_lf = true;
                    self.tail_blank = true;
                }
                b' ' | b'\t' => {}
                _ => {
                    self.seen_cr |= b == b'\r';
                    self.tail_blank = false;
                    self.content |= !b.is_ascii_whitespace();
                }
            }
        }
        Ok(())
    }

    /// The checks at the end of the input.
    fn finish(&mut self) -> Result<()> {
        if !self.carry.is_empty() {
            let at = self.read - self.carry.len() as u64;
            let line = 1 + self.newlines;
            return Err(DatasetError::NotText {
                path: self.path.clone(),
                line: Some(line),
                what: format!(
                    "not UTF-8 text (invalid byte 0x{:02x} at offset {at}, line {line}; \
                     Latin-1 or Windows-1252? save it as UTF-8)",
                    self.carry[0]
                ),
            });
        }
        Ok(())
    }

    /// At the end: the line of a last line without its line end (a cut file), as
    /// [`super::akit`]'s check of a whole file says.
    pub(crate) fn truncated_line(&self) -> Option<u64> {
        (self.end && !self.tail_blank).then_some(1 + self.newlines)
    }

    /// At the end: the input holds nothing but white space.
    pub(crate) fn blank(&self) -> bool {
        self.end && !self.content
    }

    /// The failure that ended reading, if any.
    pub(crate) fn take_failure(&mut self) -> Option<DatasetError> {
        self.failure.take()
    }

    fn fail(&mut self, e: DatasetError) -> std::io::Error {
        let message = e.to_string();
        self.failure = Some(e);
        std::io::Error::other(message)
    }
}

impl<R: Read> Read for TextStream<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        if self.served < self.head.len() {
            let n = buf.len().min(self.head.len() - self.served);
            buf[..n].copy_from_slice(&self.head[self.served..self.served + n]);
            self.served += n;
            if self.served == self.head.len() {
                self.head = Vec::new();
                self.served = 0;
            }
            return Ok(n);
        }
        if self.end {
            return Ok(0);
        }
        let n = loop {
            match self.inner.read(buf) {
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                other => break other?,
            }
        };
        if n == 0 {
            self.end = true;
            return match self.finish() {
                Ok(()) => Ok(0),
                Err(e) => Err(self.fail(e)),
            };
        }
        let offset = self.read;
        self.read += n as u64;
        if self.read > self.limit {
            let e = DatasetError::TooLarge {
                path: self.path.clone(),
                limit: self.limit,
            };
            return Err(self.fail(e));
        }
        match self.scan(&buf[..n], offset) {
            Ok(()) => Ok(n),
            Err(e) => Err(self.fail(e)),
        }
    }
}

/// Open a file to stream it (see [`TextStream`]): a regular file above the cap is
/// refused before it is read.
///
/// # Errors
/// [`DatasetError::Io`], [`DatasetError::TooLarge`].
pub(crate) fn open_text(path: &Path) -> Result<std::io::BufReader<std::fs::File>> {
    let file = std::fs::File::open(path).map_err(|error| DatasetError::Io {
        path: path.to_path_buf(),
        error,
    })?;
    if file
        .metadata()
        .is_ok_and(|m| m.is_file() && m.len() > MAX_INPUT_BYTES)
    {
        return Err(DatasetError::TooLarge {
            path: path.to_path_buf(),
            limit: MAX_INPUT_BYTES,
        });
    }
    Ok(std::io::BufReader::with_capacity(BLOCK, file))
}

/// What the bytes are, when they are not UTF-8 text with LF (or CRLF) line ends.
/// `complete`: the whole file (CR-only line ends are only judged then).
pub(crate) fn check_text(bytes: &[u8], path: &Path, complete: bool) -> Result<()> {
    let not_text = |what: String| DatasetError::NotText {
        path: path.to_path_buf(),
        line: None,
        what,
    };
    let not_text_at = |line: u64, what: String| DatasetError::NotText {
        path: path.to_path_buf(),
        line: Some(line),
        what,
    };
    let boms: [(&[u8], &str); 4] = [
        (
            &[0x00, 0x00, 0xfe, 0xff],
            "UTF-32 big-endian text (byte-order mark 00 00 FE FF)",
        ),
        (
            &[0xff, 0xfe, 0x00, 0x00],
            "UTF-32 little-endian text (byte-order mark FF FE 00 00)",
        ),
        (
            &[0xff, 0xfe],
            "UTF-16 little-endian text (byte-order mark FF FE)",
        ),
        (
            &[0xfe, 0xff],
            "UTF-16 big-endian text (byte-order mark FE FF)",
        ),
    ];
    if let Some((_, what)) = boms.iter().find(|(bom, _)| bytes.starts_with(bom)) {
        return Err(not_text(format!("{what}; save it as UTF-8")));
    }
    if let Some(first) = bytes.iter().position(|&b| b == 0) {
        // UTF-16 without a mark: ASCII characters with a NUL on every other byte.
        let head = &bytes[..bytes.len().min(4096)];
        let nul_at = |parity: usize| {
            head.iter()
                .enumerate()
                .filter(|&(i, &b)| i % 2 == parity && b == 0)
                .count()
        };
        let pairs = head.len() / 2;
        let (even, odd) = (nul_at(0), nul_at(1));
        let what = if pairs >= 2 && odd * 10 >= pairs * 9 && even * 10 < pairs {
            "UTF-16 little-endian text without a byte-order mark (a NUL after every character)"
                .to_string()
        } else if pairs >= 2 && even * 10 >= pairs * 9 && odd * 10 < pairs {
            "UTF-16 big-endian text without a byte-order mark (a NUL before every character)"
                .to_string()
        } else {
            let line = 1 + count_newlines(&bytes[..first]);
            return Err(not_text_at(
                line,
                format!(
                    "binary data, not a CSV text file (a NUL byte at offset {first}, line {line})"
                ),
            ));
        };
        return Err(not_text(format!("{what}; save it as UTF-8")));
    }
    // Other control bytes (an executable, an image, compressed data).
    if let Some(i) = bytes
        .iter()
        .position(|&b| b < 0x20 && !matches!(b, b'\n' | b'\r' | b'\t' | 0x0c))
    {
        let line = 1 + count_newlines(&bytes[..i]);
        return Err(not_text_at(
            line,
            format!(
                "binary data, not a CSV text file (control byte 0x{:02x} at offset {i}, line {line})",
                bytes[i]
            ),
        ));
    }
    if complete && !bytes.contains(&b'\n') && bytes.contains(&b'\r') {
        let lines = bytes.iter().filter(|&&b| b == b'\r').count();
        return Err(not_text(format!(
            "CR-only line ends (classic Mac OS; {lines} CR, no LF); convert them to LF or CRLF"
        )));
    }
    if let Err(e) = std::str::from_utf8(bytes) {
        let i = e.valid_up_to();
        // A block boundary may cut a multi-byte character: only judged on the whole file.
        if complete || e.error_len().is_some() {
            let line = 1 + count_newlines(&bytes[..i]);
            return Err(not_text_at(
                line,
                format!(
                    "not UTF-8 text (invalid byte 0x{:02x} at offset {i}, line {line}; \
                     Latin-1 or Windows-1252? save it as UTF-8)",
                    bytes[i]
                ),
            ));
        }
    }
    Ok(())
}

fn count_newlines(bytes: &[u8]) -> u64 {
    bytes.iter().filter(|&&c| c == b'\n').count() as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn what(bytes: &[u8]) -> String {
        match read_limited(bytes, Path::new("f.csv"), 1 << 20) {
            Err(DatasetError::NotText { what, .. }) => what,
            other => format!("{other:?}"),
        }
    }

    fn utf16(text: &str, big_endian: bool, bom: bool) -> Vec<u8> {
        let mut out = Vec::new();
        if bom {
            out.extend(if big_endian {
                [0xfe, 0xff]
            } else {
                [0xff, 0xfe]
            });
        }
        for unit in text.encode_utf16() {
            out.extend(if big_endian {
                unit.to_be_bytes()
            } else {
                unit.to_le_bytes()
            });
        }
        out
    }

    #[test]
    fn encodings_and_line_ends_are_named() {
        let csv = "time,x,y,z\n0,1,2,3\n1,1,2,3\n";
        assert!(read_limited(csv.as_bytes(), Path::new("f"), 1 << 20).is_ok());
        assert!(what(&utf16(csv, false, true)).starts_with("UTF-16 little-endian"));
        assert!(what(&utf16(csv, true, true)).starts_with("UTF-16 big-endian"));
        let w = what(&utf16(csv, false, false));
        assert!(w.contains("UTF-16 little-endian text without"), "{w}");
        let w = what(&utf16(csv, true, false));
        assert!(w.contains("UTF-16 big-endian text without"), "{w}");
        let w = what(csv.replace('\n', "\r").as_bytes());
        assert!(w.starts_with("CR-only line ends"), "{w}");
        let w = what(b"\x7fELF\x02\x01\x01\x00\x00");
        assert!(
            w.starts_with("binary data") && w.contains("offset 7"),
            "{w}"
        );
        let w = what(b"t,x\n0,1\n\x1f\x8b\x08\n");
        assert!(w.contains("0x1f") && w.contains("line 3"), "{w}");
        let w = what(b"t,x\n0,\xe9\n");
        assert!(w.contains("not UTF-8") && w.contains("line 2"), "{w}");
        // CRLF, a UTF-8 BOM and non-ASCII UTF-8 are text.
        assert!(read_limited("\u{feff}t [°],x\r\n0,1\r\n".as_bytes(), Path::new("f"), 99).is_ok());
    }

    #[test]
    fn endless_streams_stop_at_the_first_block_or_the_limit() {
        // /dev/zero: one block read, then NotText.
        let zeros = std::io::repeat(0).take(u64::MAX);
        let e = read_limited(zeros, Path::new("/dev/zero"), MAX_INPUT_BYTES).unwrap_err();
        assert!(e.to_string().contains("binary data"), "{e}");
        // An endless text stream: TooLarge at the limit.
        let text = std::io::repeat(b'1').take(u64::MAX);
        let e = read_limited(text, Path::new("yes"), 1 << 20).unwrap_err();
        assert!(
            matches!(e, DatasetError::TooLarge { limit, .. } if limit == 1 << 20),
            "{e}"
        );
        assert!(e.to_string().contains("1048576"), "{e}");
    }
}
