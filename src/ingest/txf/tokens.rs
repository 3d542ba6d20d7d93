//! The tokenizer: tokens of the text parts and the cursor that reads them and the binary arrays.

use super::*;

/// A token of the text parts.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) enum Tok<'a> {
    Open(&'a str),
    Close(&'a str),
    Text(&'a str),
    Eof,
}

pub(super) struct Cursor<'a> {
    pub(super) b: &'a [u8],
    pub(super) pos: usize,
}

pub(super) fn is_ws(c: u8) -> bool {
    matches!(c, b' ' | b'\t' | b'\r' | b'\n')
}

impl<'a> Cursor<'a> {
    /// 1-based line of a byte offset (counting every 0x0A before it, binary ones included, so
    /// that it matches what an editor shows).
    pub(super) fn line_of(&self, at: usize) -> usize {
        1 + self.b[..at.min(self.b.len())]
            .iter()
            .filter(|&&c| c == b'\n')
            .count()
    }

    pub(super) fn place(&self, at: usize) -> String {
        format!("line {}", self.line_of(at))
    }

    pub(super) fn err(&self, at: usize, msg: impl Into<String>) -> ParseError {
        ParseError::at_line(self.line_of(at), msg)
    }

    pub(super) fn unexpected(&self, at: usize, tok: &Tok, expected: &str) -> ParseError {
        let found = match tok {
            Tok::Open(n) => format!("<{n}>"),
            Tok::Close(n) => format!("</{n}>"),
            Tok::Text(t) => format!("text {:?}", t.chars().take(40).collect::<String>()),
            Tok::Eof => "the end of the file".into(),
        };
        self.err(at, format!("expected {expected}, found {found}"))
    }

    pub(super) fn skip_ws(&mut self) {
        while self.pos < self.b.len() && is_ws(self.b[self.pos]) {
            self.pos += 1;
        }
    }

    /// The next token and the byte offset where it starts.
    pub(super) fn next(&mut self) -> Result<(Tok<'a>, usize), ParseError> {
        self.skip_ws();
        let at = self.pos;
        if at >= self.b.len() {
            return Ok((Tok::Eof, at));
        }
        if self.b[at] == b'<' {
            return self.tag(at).map(|t| (t, at));
        }
        let end = self.b[at..]
            .iter()
            .position(|&c| c == b'<')
            .map_or(self.b.len(), |k| at + k);
        let text = std::str::from_utf8(&self.b[at..end])
            .map_err(|_| self.err(at, "binary data where text was expected"))?;
        self.pos = end;
        Ok((Tok::Text(text.trim_end()), at))
    }

    pub(super) fn tag(&mut self, at: usize) -> Result<Tok<'a>, ParseError> {
        const MAX_TAG: usize = 128;
        let rest = &self.b[at + 1..self.b.len().min(at + 1 + MAX_TAG)];
        let len = rest
            .iter()
            .position(|&c| c == b'>')
            .ok_or_else(|| self.err(at, "unterminated tag (no '>')"))?;
        let inner = std::str::from_utf8(&rest[..len])
            .map_err(|_| self.err(at, "tag name is not text"))?
            .trim();
        self.pos = at + 2 + len;
        let (close, name) = match inner.strip_prefix('/') {
            Some(n) => (true, n.trim()),
            None => (false, inner),
        };
        if name.is_empty() || !name.bytes().all(|c| c.is_ascii_alphanumeric() || c == b'_') {
            return Err(self.err(at, format!("bad tag <{inner}>")));
        }
        Ok(if close {
            Tok::Close(name)
        } else {
            Tok::Open(name)
        })
    }

    /// After `<name>`: the element's text up to `</name>` (empty if none).
    pub(super) fn text_element(&mut self, name: &str) -> Result<(&'a str, usize), ParseError> {
        let (tok, at) = self.next()?;
        match tok {
            Tok::Close(n) if n == name => Ok(("", at)),
            Tok::Text(t) => {
                self.expect_close(name)?;
                Ok((t, at))
            }
            t => Err(self.unexpected(at, &t, &format!("the value of <{name}>"))),
        }
    }

    pub(super) fn expect_close(&mut self, name: &str) -> Result<(), ParseError> {
        match self.next()? {
            (Tok::Close(n), _) if n == name => Ok(()),
            (t, at) => Err(self.unexpected(at, &t, &format!("</{name}>"))),
        }
    }

    /// After `<name>`: skips text and nested elements up to the matching `</name>`.
    pub(super) fn skip_element(&mut self, name: &str) -> Result<(), ParseError> {
        let mut open: Vec<&str> = vec![name];
        while let Some(&top) = open.last() {
            match self.next()? {
                (Tok::Open(n), _) => open.push(n),
                (Tok::Close(n), _) if n == top => {
                    open.pop();
                }
                (Tok::Text(_), _) => {}
                (t, at) => return Err(self.unexpected(at, &t, &format!("</{top}>"))),
            }
        }
        Ok(())
    }

    /// Whether `</name>` follows byte `at` after optional whitespace.
    pub(super) fn closes_at(&self, mut at: usize, name: &str) -> bool {
        while at < self.b.len() && is_ws(self.b[at]) {
            at += 1;
        }
        let rest = &self.b[at.min(self.b.len())..];
        let Some(r) = rest.strip_prefix(b"</") else {
            return false;
        };
        let Some(r) = r.strip_prefix(name.as_bytes()) else {
            return false;
        };
        r.iter().find(|&&c| !is_ws(c)) == Some(&b'>')
    }

    /// Reads a binary payload of `len` bytes that starts right after the tag just read or
    /// after that tag's 0x0A, and is followed by `</closing>` (see the module doc). `score`
    /// rates how plausible a candidate payload is. Leaves the cursor after the payload.
    pub(super) fn payload(
        &mut self,
        len: Option<usize>,
        what: &str,
        closing: &str,
        score: impl Fn(&[u8]) -> usize,
    ) -> Result<&'a [u8], ParseError> {
        let start = self.pos;
        let remaining = self.b.len() - start;
        let len = match len {
            Some(l) if l <= remaining => l,
            _ => {
                return Err(ParseError::at_byte(
                    start,
                    format!(
                        "{what} needs {} bytes, only {remaining} remain",
                        len.map_or("more than 2^64".into(), |l| l.to_string())
                    ),
                ));
            }
        };
        let mut candidates = vec![start];
        let nl = self.b[start..]
            .iter()
            .take(8)
            .position(|&c| !matches!(c, b' ' | b'\t' | b'\r'));
        if let Some(k) = nl.filter(|&k| self.b.get(start + k) == Some(&b'\n')) {
            candidates.push(start + k + 1);
        }
        let valid: Vec<usize> = candidates
            .into_iter()
            .filter(|&s| s + len <= self.b.len() && self.closes_at(s + len, closing))
            .collect();
        // Ties go to the later (after-newline) candidate: `max_by_key` keeps the last maximum.
        let chosen = valid
            .iter()
            .copied()
            .max_by_key(|&s| score(&self.b[s..s + len]))
            .ok_or_else(|| {
                ParseError::at_byte(
                    start + len,
                    format!("expected </{closing}> after the {len}-byte {what} that starts at byte {start}"),
                )
            })?;
        self.pos = chosen + len;
        Ok(&self.b[chosen..chosen + len])
    }
}
