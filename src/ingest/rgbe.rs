//! Radiance RGBE (`.hdr`, `.pic`) decoding: the header, then every scanline located in one cheap
//! sequential pass and decoded in parallel, straight into the float image.
//!
//! Written here (the `image` crate decodes the same files, and is this decoder's oracle in the
//! tests) because its decoder reads byte by byte through `Read` on one thread, a fifth of
//! `bake sky` on a 2048×1024 sky. The same files are accepted and decode to the same bits:
//! - the header: a first line starting with `#?`, `KEY=VALUE` and comment lines up to an empty
//!   line; `FORMAT` must be `32-bit_rle_rgbe` if given; then the resolution line `-Y H +X W`
//!   (the standard orientation; others are refused);
//! - scanlines, each in one of three encodings: per-component run-length (starts `2 2 h l` with
//!   `h < 128`; per component, a count byte above 128 is a run of count − 128 copies of the next
//!   byte, else that many literal bytes), flat RGBE quadruples, or flat with the old run markers
//!   (`1 1 1 n`: repeat the previous pixel n times, n × 256ᵏ for the k-th marker in a row);
//! - a value is `c · 2^(e − 136)`, `e = 0` is black.

use crate::error::ParseError;
use crate::model::FloatImage;
use rayon::prelude::*;

/// Where a scanline starts and how it is encoded.
#[derive(Debug, Clone, Copy)]
enum Line {
    /// Per-component run-length encoding; the offset of its first run (after `2 2 h l`).
    Components(usize),
    /// RGBE quadruples from this offset; `plain`: without old run markers (exactly 4 bytes a
    /// pixel, so the pixels can be read in place).
    Flat { at: usize, plain: bool },
}

/// The header: width, height, and the offset of the first scanline.
pub fn header(bytes: &[u8]) -> Result<(u32, u32, usize), ParseError> {
    let mut at = 0;
    let mut line_no = 0;
    let mut next_line = |at: &mut usize| -> Result<(usize, &[u8]), ParseError> {
        let start = *at;
        let rest = &bytes[start..];
        let len = rest.iter().position(|&b| b == b'\n').ok_or_else(|| {
            ParseError::new(
                format!("Radiance header, byte {start}"),
                "a line ended by a newline (the header ends with an empty line, then the resolution line)",
            )
        })?;
        *at = start + len + 1;
        line_no += 1;
        Ok((line_no, &rest[..len]))
    };
    let (_, first) = next_line(&mut at)?;
    if !first.starts_with(b"#?") {
        return Err(ParseError::new(
            "Radiance header, line 1",
            "the signature `#?RADIANCE` (or another `#?` program name)",
        ));
    }
    loop {
        let start = at;
        let (n, line) = next_line(&mut at)?;
        if line.is_empty() {
            break;
        }
        if let Some(format) = line.strip_prefix(b"FORMAT=") {
            let format = String::from_utf8_lossy(format);
            if format.trim() != "32-bit_rle_rgbe" {
                return Err(ParseError::new(
                    format!("Radiance header, line {n} (byte {start})"),
                    format!("FORMAT=32-bit_rle_rgbe, got FORMAT={}", format.trim()),
                ));
            }
        }
    }
    let start = at;
    let (n, res) = next_line(&mut at)?;
    let text = String::from_utf8_lossy(res);
    let words: Vec<&str> = text.split_ascii_whitespace().collect();
    let size = |w: &str| w.parse::<u32>().ok().filter(|&v| v > 0);
    match words.as_slice() {
        ["-Y", h, "+X", w] if size(h).is_some() && size(w).is_some() => {
            Ok((size(w).unwrap(), size(h).unwrap(), at))
        }
        _ => Err(ParseError::new(
            format!("Radiance resolution line, line {n} (byte {start})"),
            format!(
                "`-Y HEIGHT +X WIDTH` (the standard orientation, sizes above 0), got `{}`",
                text.trim()
            ),
        )),
    }
}

/// Pass 1, sequential: where each scanline starts, every length checked (runs are skipped, not
/// expanded). Needs no pixel buffer, so a truncated file fails before one is allocated.
fn locate(bytes: &[u8], (width, height): (u32, u32), data: usize) -> Result<Vec<Line>, ParseError> {
    let w = width as usize;
    // (Every scanline takes at least 4 bytes: the capacity is bounded by the file, not the header.)
    let mut lines = Vec::with_capacity((height as usize).min(bytes.len() / 4 + 1));
    let mut at = data;
    for row in 0..height as usize {
        let line = match bytes.get(at..at + 4) {
            Some([2, 2, h, _]) if *h < 128 => Line::Components(at + 4),
            Some(_) => Line::Flat { at, plain: true },
            None => return Err(ended(row, at)),
        };
        let line = match line {
            Line::Components(from) => {
                at = skip_components(bytes, w, from, row)?;
                line
            }
            Line::Flat { at: from, .. } => {
                let (end, plain) = skip_flat(bytes, w, from, row)?;
                at = end;
                Line::Flat { at: from, plain }
            }
        };
        lines.push(line);
    }
    Ok(lines)
}

/// Pass 2, parallel: each located (checked) scanline into its row of `pixels`.
fn expand(bytes: &[u8], width: usize, lines: Vec<Line>, pixels: &mut [[f32; 3]]) {
    pixels.par_chunks_mut(width).zip(lines).for_each_init(
        || vec![[0u8; 4]; width],
        |rgbe, (out, line)| match line {
            Line::Components(from) => {
                expand_components(bytes, from, rgbe);
                for (o, p) in out.iter_mut().zip(rgbe.iter()) {
                    *o = to_float(*p);
                }
            }
            Line::Flat { at, .. } => decode_flat(bytes, at, out),
        },
    );
}

/// Pass 2 for [`RgbeImage`], parallel: each located (checked) scanline into its row of `quads`.
fn expand_quads(bytes: &[u8], width: usize, lines: Vec<Line>, quads: &mut [[u8; 4]]) {
    quads
        .par_chunks_mut(width)
        .zip(lines)
        .for_each(|(out, line)| match line {
            Line::Components(from) => expand_components(bytes, from, out),
            Line::Flat { at, .. } => expand_flat(bytes, at, out),
        });
}

fn ended(row: usize, at: usize) -> ParseError {
    ParseError::new(
        format!("Radiance scanline {row}, byte {at}"),
        "more scanline data: the file ends before the last scanline",
    )
}

fn too_long(row: usize, at: usize, reach: usize, width: usize) -> ParseError {
    ParseError::new(
        format!("Radiance scanline {row}, byte {at}"),
        format!("runs that fill the width of {width} pixels, got one reaching pixel {reach}"),
    )
}

/// The offset after a per-component scanline whose runs start at `at`, checked.
fn skip_components(
    bytes: &[u8],
    width: usize,
    mut at: usize,
    row: usize,
) -> Result<usize, ParseError> {
    for _ in 0..4 {
        let mut pos = 0;
        while pos < width {
            let count = *bytes.get(at).ok_or_else(|| ended(row, at))? as usize;
            let (len, skip) = if count > 128 {
                (count - 128, 2)
            } else {
                (count, 1 + count)
            };
            if pos + len > width {
                return Err(too_long(row, at, pos + len, width));
            }
            if at + skip > bytes.len() {
                return Err(ended(row, at));
            }
            pos += len;
            at += skip;
        }
    }
    Ok(at)
}

/// Expands a checked per-component scanline into its RGBE quadruples.
fn expand_components(bytes: &[u8], mut at: usize, rgbe: &mut [[u8; 4]]) {
    let width = rgbe.len();
    for component in 0..4 {
        let mut pos = 0;
        while pos < width {
            let count = bytes[at] as usize;
            if count > 128 {
                let value = bytes[at + 1];
                for p in &mut rgbe[pos..pos + count - 128] {
                    p[component] = value;
                }
                pos += count - 128;
                at += 2;
            } else {
                for (p, &value) in rgbe[pos..pos + count].iter_mut().zip(&bytes[at + 1..]) {
                    p[component] = value;
                }
                pos += count;
                at += 1 + count;
            }
        }
    }
}

fn is_marker(p: &[u8]) -> bool {
    p[0] == 1 && p[1] == 1 && p[2] == 1
}

/// The offset after a flat scanline (old run markers counted), checked, and whether it had no
/// run marker.
fn skip_flat(
    bytes: &[u8],
    width: usize,
    mut at: usize,
    row: usize,
) -> Result<(usize, bool), ParseError> {
    let (mut pos, mut mult, mut plain) = (0usize, 1usize, true);
    while pos < width {
        let p = bytes.get(at..at + 4).ok_or_else(|| ended(row, at))?;
        if is_marker(p) {
            if pos == 0 {
                return Err(first_marker(row, at));
            }
            let len = (p[3] as usize).saturating_mul(mult);
            if pos.saturating_add(len) > width {
                return Err(too_long(row, at, pos.saturating_add(len), width));
            }
            pos += len;
            mult = mult.saturating_mul(256);
            plain = false;
        } else {
            pos += 1;
            mult = 1;
        }
        at += 4;
    }
    Ok((at, plain))
}

fn first_marker(row: usize, at: usize) -> ParseError {
    ParseError::new(
        format!("Radiance scanline {row}, byte {at}"),
        "a pixel to start the scanline, got a run marker (1 1 1 n)",
    )
}

/// Expands a checked flat scanline.
fn decode_flat(bytes: &[u8], mut at: usize, out: &mut [[f32; 3]]) {
    let width = out.len();
    let (mut pos, mut mult) = (0usize, 1usize);
    let mut prev = [0.0f32; 3];
    while pos < width {
        let p = &bytes[at..at + 4];
        if is_marker(p) {
            // (Saturating as in `skip_flat`, which checked that the run fits.)
            let len = (p[3] as usize).saturating_mul(mult);
            out[pos..pos + len].fill(prev);
            pos += len;
            mult = mult.saturating_mul(256);
        } else {
            prev = to_float([p[0], p[1], p[2], p[3]]);
            out[pos] = prev;
            pos += 1;
            mult = 1;
        }
        at += 4;
    }
}

/// Expands a checked flat scanline into its RGBE quadruples (a run repeats the pixel before it).
fn expand_flat(bytes: &[u8], mut at: usize, out: &mut [[u8; 4]]) {
    let width = out.len();
    let (mut pos, mut mult) = (0usize, 1usize);
    let mut prev = [0u8; 4];
    while pos < width {
        let p = [bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]];
        if is_marker(&p) {
            let len = (p[3] as usize).saturating_mul(mult);
            out[pos..pos + len].fill(prev);
            pos += len;
            mult = mult.saturating_mul(256);
        } else {
            prev = p;
            out[pos] = p;
            pos += 1;
            mult = 1;
        }
        at += 4;
    }
}

/// 2^(e − 136) for every exponent byte e; 0 for e = 0 (2^(e − 128) built from its bits, a
/// subnormal for e = 1, then the exact division by 256).
const SCALE: [f32; 256] = {
    let mut t = [0.0f32; 256];
    let mut e = 0;
    while e < 256 {
        let bits = if e > 1 { (e - 1) << 23 } else { e << 22 };
        t[e as usize] = f32::from_bits(bits) * (1.0 / 256.0);
        e += 1;
    }
    t
};

/// `c · 2^(e − 136)`; e = 0 is black.
#[inline]
fn to_float(p: [u8; 4]) -> [f32; 3] {
    let scale = SCALE[p[3] as usize];
    [
        scale * p[0] as f32,
        scale * p[1] as f32,
        scale * p[2] as f32,
    ]
}

/// A Radiance image kept as its RGBE quadruples, 4 bytes a pixel (a third of the float image),
/// for readers that decode only the pixels they read, as the sky's resampling does: a pixel
/// decodes ([`RgbeImage::pixel`]) to the same bits as in [`parse`]'s float image. A file of flat
/// scanlines without run markers (what most writers, bake's included, produce) is used in
/// place, without a copy.
#[derive(Clone)]
pub struct RgbeImage {
    pub width: u32,
    pub height: u32,
    /// The file's bytes (pixels in place from `offset`) or the expanded pixels (`offset` 0).
    bytes: std::sync::Arc<RgbeBytes>,
    offset: usize,
}

/// The bytes of a Radiance file: read into memory, or mapped.
pub enum RgbeBytes {
    Owned(Vec<u8>),
    /// A read-only map of the file (its pixels are only ever read in place: a run-length
    /// encoded file is copied before its runs are expanded, so a file changed under the map
    /// cannot change the scanline structure that [`locate`] checked).
    Mapped(memmap2::Mmap),
}

impl std::ops::Deref for RgbeBytes {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            RgbeBytes::Owned(v) => v,
            RgbeBytes::Mapped(m) => m,
        }
    }
}

impl std::fmt::Debug for RgbeImage {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RgbeImage")
            .field("width", &self.width)
            .field("height", &self.height)
            .finish_non_exhaustive()
    }
}

impl PartialEq for RgbeImage {
    fn eq(&self, other: &Self) -> bool {
        (self.width, self.height) == (other.width, other.height) && self.quads() == other.quads()
    }
}

impl RgbeImage {
    /// The pixels' RGBE bytes, 4 a pixel, row-major.
    fn quads(&self) -> &[u8] {
        let len = 4 * self.width as usize * self.height as usize;
        &self.bytes[self.offset..self.offset + len]
    }

    /// The RGBE quadruple of pixel `i` (row-major, row 0 at the top).
    #[inline]
    pub fn quad(&self, i: usize) -> [u8; 4] {
        let at = self.offset + 4 * i;
        let p = &self.bytes[at..at + 4];
        [p[0], p[1], p[2], p[3]]
    }

    /// Pixel `i` as linear float RGB: `c · 2^(e − 136)`, the bits [`parse`] gives.
    #[inline]
    pub fn pixel(&self, i: usize) -> [f32; 3] {
        to_float(self.quad(i))
    }

    /// The whole image as floats (the same bits as [`parse`]).
    pub fn to_float_image(&self) -> FloatImage {
        let pixels = self
            .quads()
            .par_chunks(4)
            .map(|p| to_float([p[0], p[1], p[2], p[3]]))
            .collect();
        FloatImage {
            width: self.width,
            height: self.height,
            pixels,
        }
    }
}

impl crate::cube::LatLongPixels for RgbeImage {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    #[inline]
    fn pixel(&self, i: usize) -> [f32; 3] {
        RgbeImage::pixel(self, i)
    }

    fn row_below(&self, row: u32, below: f32) -> bool {
        self.view().row_below(row, below)
    }
}

/// An [`RgbeImage`]'s pixels borrowed as quadruples: what the resampling's inner loop reads
/// (one bounds check a pixel).
#[derive(Clone, Copy)]
pub struct RgbeView<'a> {
    width: u32,
    height: u32,
    quads: &'a [[u8; 4]],
}

impl RgbeImage {
    pub fn view(&self) -> RgbeView<'_> {
        RgbeView {
            width: self.width,
            height: self.height,
            quads: self.quads().as_chunks::<4>().0,
        }
    }
}

impl crate::cube::LatLongPixels for RgbeView<'_> {
    fn size(&self) -> (u32, u32) {
        (self.width, self.height)
    }

    #[inline]
    fn pixel(&self, i: usize) -> [f32; 3] {
        to_float(self.quads[i])
    }

    /// First from the row's largest exponent (a pixel is at most 255 · 2^(e − 136), and the
    /// luminance weights sum to 1), pixel by pixel only where that bound is not enough.
    fn row_below(&self, row: u32, below: f32) -> bool {
        let w = self.width as usize;
        let line = &self.quads[row as usize * w..(row as usize + 1) * w];
        let e = line.iter().fold(0u8, |m, p| m.max(p[3]));
        let bound = to_float([255, 255, 255, e])[0];
        bound * 1.0001 < below
            || line
                .iter()
                .all(|&p| crate::color::luminance(to_float(p)) < below)
    }
}

/// Reads a whole file as an [`RgbeImage`]: header, size check (`check`), every scanline located
/// and checked (the same errors as [`parse`]); the pixels are then used in place (flat scanlines
/// without run markers) or expanded in parallel.
pub fn parse_rgbe(
    bytes: RgbeBytes,
    check: impl FnOnce(u32, u32) -> Result<(), ParseError>,
) -> Result<RgbeImage, ParseError> {
    let (width, height, data) = header(&bytes)?;
    check(width, height)?;
    let mut lines = locate(&bytes, (width, height), data)?;
    let row = 4 * width as usize;
    let in_place = lines
        .iter()
        .enumerate()
        .all(|(r, l)| matches!(*l, Line::Flat { at, plain: true } if at == data + r * row));
    if in_place {
        return Ok(RgbeImage {
            width,
            height,
            bytes: std::sync::Arc::new(bytes),
            offset: data,
        });
    }
    // Runs are expanded from bytes that cannot change after `locate` checked them.
    let bytes = match bytes {
        RgbeBytes::Mapped(m) => {
            let owned = m.to_vec();
            lines = locate(&owned, (width, height), data)?;
            owned
        }
        RgbeBytes::Owned(v) => v,
    };
    let mut quads = vec![[0u8; 4]; width as usize * height as usize];
    expand_quads(&bytes, width as usize, lines, &mut quads);
    Ok(RgbeImage {
        width,
        height,
        bytes: std::sync::Arc::new(RgbeBytes::Owned(quads.into_flattened())),
        offset: 0,
    })
}

/// Decodes a whole file: header, size check (`check`), pixels.
pub fn parse(
    bytes: &[u8],
    check: impl FnOnce(u32, u32) -> Result<(), ParseError>,
) -> Result<FloatImage, ParseError> {
    let (width, height, data) = header(bytes)?;
    check(width, height)?;
    let lines = locate(bytes, (width, height), data)?;
    let mut pixels = vec![[0.0f32; 3]; width as usize * height as usize];
    expand(bytes, width as usize, lines, &mut pixels);
    Ok(FloatImage {
        width,
        height,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Oracle: the `image` crate's Radiance decoder.
    fn oracle(bytes: &[u8]) -> Result<Vec<[f32; 3]>, String> {
        let img = image::load_from_memory_with_format(bytes, image::ImageFormat::Hdr)
            .map_err(|e| e.to_string())?;
        Ok(img.to_rgb32f().pixels().map(|p| p.0).collect())
    }

    fn ours(bytes: &[u8]) -> Result<Vec<[f32; 3]>, ParseError> {
        parse(bytes, |_, _| Ok(())).map(|i| i.pixels)
    }

    fn head(w: usize, h: usize) -> Vec<u8> {
        format!(
            "#?RADIANCE\n# made by a test\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n\n-Y {h} +X {w}\n"
        )
        .into_bytes()
    }

    /// Pseudo-random RGBE pixels with long runs in some components (so the encoder makes both
    /// runs and literals), every exponent from 0 to 255 somewhere.
    fn pixels(w: usize, h: usize) -> Vec<[u8; 4]> {
        let mut x = 0x2545_f491_4f6c_dd1du64;
        (0..w * h)
            .map(|i| {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
                let row = i / w;
                let run = (i % w) / 37;
                [
                    (x & 0xff) as u8,
                    if row.is_multiple_of(3) {
                        200
                    } else {
                        (x >> 8) as u8
                    },
                    (run * 11) as u8,
                    ((i * 7) % 256) as u8,
                ]
            })
            .collect()
    }

    /// Per-component run-length encoding of one scanline (runs of ≥ 3 as runs, else literals).
    fn encode_components(line: &[[u8; 4]]) -> Vec<u8> {
        let w = line.len();
        let mut out = vec![2, 2, (w >> 8) as u8, (w & 0xff) as u8];
        for c in 0..4 {
            let v: Vec<u8> = line.iter().map(|p| p[c]).collect();
            let mut i = 0;
            while i < w {
                let mut run = 1;
                while i + run < w && run < 127 && v[i + run] == v[i] {
                    run += 1;
                }
                if run >= 3 {
                    out.extend([128 + run as u8, v[i]]);
                    i += run;
                } else {
                    let mut j = i;
                    while j < w
                        && j - i < 128
                        && !(j + 2 < w && v[j] == v[j + 1] && v[j] == v[j + 2])
                    {
                        j += 1;
                    }
                    let j = j.max(i + 1);
                    out.push((j - i) as u8);
                    out.extend(&v[i..j]);
                    i = j;
                }
            }
        }
        out
    }

    /// A w×h file of [`pixels`] twice: as flat quadruples (no pixel may look like a marker or a
    /// component header) and as per-component runs (readers take them from width 8 on; ours and
    /// the oracle both accept narrower ones, so they are tested too).
    fn flat_and_runs(w: usize, h: usize) -> (Vec<u8>, Vec<u8>) {
        let px = pixels(w, h);
        let mut flat = head(w, h);
        for p in &px {
            let mut p = *p;
            if (p[0], p[1]) == (2, 2) || (p[0], p[1], p[2]) == (1, 1, 1) {
                p[0] = 9;
            }
            flat.extend(p);
        }
        let mut runs = head(w, h);
        for line in px.chunks(w) {
            runs.extend(encode_components(line));
        }
        (flat, runs)
    }

    #[test]
    fn every_encoding_decodes_to_the_image_crates_bits() {
        for (w, h) in [(1, 1), (7, 3), (64, 5), (300, 9)] {
            let (flat, runs) = flat_and_runs(w, h);
            for bytes in [&flat, &runs] {
                let want = oracle(bytes).unwrap();
                let got = ours(bytes).unwrap();
                assert_eq!(got.len(), w * h);
                for (a, b) in got.iter().zip(&want) {
                    assert_eq!(a.map(f32::to_bits), b.map(f32::to_bits), "{w}×{h}");
                }
            }
        }
        // Old run markers: a pixel, a run of 3, a run of 2 + 1·256 (two markers), a pixel.
        let w = 3 + 1 + 258 + 2;
        let mut old = head(w, 2);
        for _ in 0..2 {
            old.extend([10, 20, 30, 130]);
            old.extend([1, 1, 1, 3]);
            old.extend([40, 50, 60, 128]);
            old.extend([1, 1, 1, 1]);
            old.extend([1, 1, 1, 1]);
            old.extend([70, 80, 90, 127]);
            old.extend([5, 5, 5, 0]);
        }
        let want = oracle(&old).unwrap();
        assert_eq!(ours(&old).unwrap(), want);
        assert_eq!(want[5..5 + 257], vec![want[4]; 257][..]);
        assert_eq!(want[1..4], vec![want[0]; 3][..]);
    }

    #[test]
    fn rgbe_images_decode_to_the_float_images_bits() {
        // Oracle: `parse` (itself checked against the `image` crate above). Flat files are used
        // in place; run-length and old-marker files are expanded.
        let (w, h) = (300, 9);
        let (flat, runs) = flat_and_runs(w, h);
        let mut old = head(4, 1);
        old.extend([10, 20, 30, 130, 1, 1, 1, 2, 40, 50, 60, 128]);
        for (bytes, in_place) in [(&flat, true), (&runs, false), (&old, false)] {
            let want = ours(bytes).unwrap();
            let img = parse_rgbe(RgbeBytes::Owned(bytes.clone()), |_, _| Ok(())).unwrap();
            assert_eq!(img.offset != 0, in_place);
            for (i, p) in want.iter().enumerate() {
                assert_eq!(img.pixel(i).map(f32::to_bits), p.map(f32::to_bits));
            }
            assert_eq!(img.to_float_image().pixels, want);
        }
        // Broken files fail as in `parse`, with the same message.
        for bytes in [
            &runs[..runs.len() - 1],
            &runs[..runs.len() / 2],
            &flat[..flat.len() - 3],
        ] {
            let want = ours(bytes).unwrap_err().to_string();
            let got = parse_rgbe(RgbeBytes::Owned(bytes.to_vec()), |_, _| Ok(()));
            assert_eq!(got.unwrap_err().to_string(), want);
        }
    }

    #[test]
    fn broken_files_name_the_scanline_and_byte() {
        let px = pixels(16, 4);
        let mut runs = head(16, 4);
        let data = runs.len();
        for line in px.chunks(16) {
            runs.extend(encode_components(line));
        }
        // Every truncation is an error (the oracle agrees), naming the place.
        for cut in [data + 1, data + 10, runs.len() - 1] {
            let e = ours(&runs[..cut]).unwrap_err();
            assert!(oracle(&runs[..cut]).is_err());
            assert!(e.place.starts_with("Radiance scanline"), "{e}");
            assert!(
                e.to_string().contains("ends before the last scanline"),
                "{e}"
            );
        }
        // A run past the width.
        let mut bad = head(16, 1);
        let at = bad.len() + 4;
        bad.extend([2, 2, 0, 16, 128 + 20, 7]);
        let e = ours(&bad).unwrap_err();
        assert!(oracle(&bad).is_err());
        assert_eq!(e.place, format!("Radiance scanline 0, byte {at}"));
        assert!(e.to_string().contains("reaching pixel 20"), "{e}");
        // An old run marker first in its scanline, and one that overruns.
        let mut first = head(4, 1);
        first.extend([1, 1, 1, 2, 0, 0, 0, 0]);
        assert!(
            ours(&first)
                .unwrap_err()
                .to_string()
                .contains("got a run marker")
        );
        assert!(oracle(&first).is_err());
        let mut over = head(4, 1);
        over.extend([9, 9, 9, 9, 1, 1, 1, 200]);
        assert!(
            ours(&over)
                .unwrap_err()
                .to_string()
                .contains("reaching pixel 201")
        );
        assert!(oracle(&over).is_err());
        // Ten zero-length run markers in a row (the multiplier passes 256⁸): no overflow, no run.
        let mut zeros = head(4, 1);
        zeros.extend([9, 9, 9, 130]);
        for _ in 0..10 {
            zeros.extend([1, 1, 1, 0]);
        }
        zeros.extend([8, 8, 8, 130, 7, 7, 7, 130, 6, 6, 6, 130]);
        let px = ours(&zeros).unwrap();
        assert_eq!(
            px[1..].iter().map(|p| p[0] * 64.0).collect::<Vec<_>>(),
            [8.0, 7.0, 6.0]
        );
        // Headers.
        for (bytes, place) in [
            (&b"RADIANCE\n\n-Y 1 +X 1\n"[..], "line 1"),
            (
                b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n-Y 1 +X 1\n",
                "line 2",
            ),
            (b"#?RADIANCE\n\n+Y 1 +X 1\n", "resolution line, line 3"),
            (b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe", "byte 11"),
        ] {
            let e = ours(bytes).unwrap_err();
            assert!(e.place.contains(place), "{place}: {e}");
            assert!(oracle(bytes).is_err(), "{place}");
        }
        // An empty image (the oracle decodes it to nothing): refused here.
        let e = ours(b"#?RADIANCE\n\n-Y 0 +X 1\n").unwrap_err();
        assert!(e.to_string().contains("sizes above 0"), "{e}");
    }

    #[test]
    fn a_large_file_decodes_alike_on_any_thread_count() {
        let (w, h) = (512, 64);
        let mut runs = head(w, h);
        for line in pixels(w, h).chunks(w) {
            runs.extend(encode_components(line));
        }
        let one = rayon::ThreadPoolBuilder::new()
            .num_threads(1)
            .build()
            .unwrap();
        let a = one.install(|| ours(&runs).unwrap());
        let b = ours(&runs).unwrap();
        assert_eq!(a, b);
        assert_eq!(a, oracle(&runs).unwrap());
    }
}
