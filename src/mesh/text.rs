//! Shared helpers for the line-based text formats (OFF, OBJ, TOSCA `.vert`/`.tri`).
//!
//! Everything works on bytes: comments may hold any encoding, and only the tokens that are
//! parsed need to be ASCII numbers.

use std::borrow::Cow;
use std::io::Read;

use super::error::MeshError;

/// Largest amount of data a gzip stream may decompress to (1 GiB), so that a small
/// compressed "bomb" cannot exhaust memory. Real meshes of a few million vertices fit easily.
pub const MAX_DECOMPRESSED_BYTES: u64 = 1 << 30;

/// Returns `bytes` itself, or its decompressed content when it starts with the gzip magic
/// number (`1f 8b`).
pub(crate) fn gunzip_if_needed(bytes: &[u8]) -> Result<Cow<'_, [u8]>, MeshError> {
    gunzip_limited(bytes, MAX_DECOMPRESSED_BYTES)
}

/// [`gunzip_if_needed`] with a smaller cap on the decompressed size (at most
/// [`MAX_DECOMPRESSED_BYTES`]).
pub(crate) fn gunzip_limited(bytes: &[u8], limit: u64) -> Result<Cow<'_, [u8]>, MeshError> {
    if bytes.len() < 2 || bytes[0] != 0x1f || bytes[1] != 0x8b {
        return Ok(Cow::Borrowed(bytes));
    }
    let limit = limit.min(MAX_DECOMPRESSED_BYTES);
    let decoder = flate2::read::MultiGzDecoder::new(bytes);
    let mut out = Vec::with_capacity(bytes.len().saturating_mul(4).min(1 << 26).min(limit as usize));
    decoder.take(limit + 1).read_to_end(&mut out).map_err(MeshError::Decompress)?;
    if out.len() as u64 > limit {
        return Err(MeshError::TooLarge { limit });
    }
    Ok(Cow::Owned(out))
}

/// Iterates over the lines of `bytes` as `(1-based line number, content)`, with `#` comments,
/// the line terminator and surrounding whitespace removed. Blank lines are skipped.
pub(crate) struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Lines<'a> {
    pub(crate) fn new(bytes: &'a [u8]) -> Self {
        Self { bytes, pos: 0, line: 0 }
    }

    /// The next raw line (comment stripped, maybe blank), or `None` at the end.
    fn next_raw(&mut self) -> Option<&'a [u8]> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += end + 1;
        self.line += 1;
        let mut line = &rest[..end];
        if let Some(hash) = line.iter().position(|&b| b == b'#') {
            line = &line[..hash];
        }
        Some(line.trim_ascii())
    }
}

impl<'a> Iterator for Lines<'a> {
    type Item = (usize, &'a [u8]);

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            let line = self.next_raw()?;
            if !line.is_empty() {
                return Some((self.line, line));
            }
        }
    }
}

/// Whitespace-separated tokens of a line.
pub(crate) fn tokens(line: &[u8]) -> impl Iterator<Item = &[u8]> {
    line.split(|b| b.is_ascii_whitespace()).filter(|t| !t.is_empty())
}

/// A token for an error message: printable ASCII, everything else escaped, shortened to at
/// most 40 characters, quoted ([`crate::limits::excerpt`]).
pub(crate) fn show(token: &[u8]) -> String {
    crate::limits::excerpt(token, 40)
}

/// Parses a token as `f64` (accepting whatever `f64::from_str` accepts, including `nan`
/// and `inf`, which validation then rejects with a clearer message).
pub(crate) fn parse_f64(token: &[u8]) -> Option<f64> {
    std::str::from_utf8(token).ok()?.parse().ok()
}

/// Parses a token as a non-negative integer.
pub(crate) fn parse_usize(token: &[u8]) -> Option<usize> {
    std::str::from_utf8(token).ok()?.parse().ok()
}

/// Parses a token as a signed integer.
pub(crate) fn parse_i64(token: &[u8]) -> Option<i64> {
    std::str::from_utf8(token).ok()?.parse().ok()
}

/// Parses the first three tokens of `line` as coordinates; extra tokens are ignored.
pub(crate) fn parse_xyz(line_no: usize, line: &[u8]) -> Result<[f64; 3], MeshError> {
    let mut p = [0.0; 3];
    let mut found = 0;
    for token in tokens(line).take(3) {
        p[found] = parse_f64(token).ok_or_else(|| MeshError::parse_at(line_no, "a number", show(token)))?;
        found += 1;
    }
    if found < 3 {
        return Err(MeshError::parse_at(line_no, "3 coordinates", found.to_string()));
    }
    Ok(p)
}

/// A capacity for `declared` items of at least `min_bytes` each, capped by what `available`
/// bytes can possibly hold, so a forged header cannot make us pre-allocate gigabytes.
pub(crate) fn capped_capacity(declared: usize, available: usize, min_bytes: usize) -> usize {
    declared.min(available / min_bytes.max(1))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lines_strip_comments_and_blank_lines() {
        let text = b"# header\nOFF # kind\n\n  1 2 3  \r\n#\n";
        let lines: Vec<_> = Lines::new(text).collect();
        assert_eq!(lines, vec![(2, &b"OFF"[..]), (4, &b"1 2 3"[..])]);
    }

    #[test]
    fn capacity_is_capped_by_available_bytes() {
        assert_eq!(capped_capacity(999_999_999_999, 20, 6), 3);
        assert_eq!(capped_capacity(2, 1000, 6), 2);
        assert_eq!(capped_capacity(5, 10, 0), 5);
    }

    #[test]
    fn show_shortens_long_tokens() {
        let long = vec![b'a'; 100];
        assert_eq!(show(&long).chars().count(), 43);
        assert_eq!(show(b"x"), "\"x\"");
    }
}
