//! SGI image files (`.rgb`, `.rgba`, `.bw`, `.sgi`): the texture format of Xfrog plants.
//!
//! Layout (Paul Haeberli, "The SGI Image File Format", version 1.00), all big-endian:
//! a 512-byte header `{u16 magic = 474, u8 storage (0 verbatim, 1 RLE), u8 bpc (1 or 2),
//! u16 dimension, u16 xsize, u16 ysize, u16 zsize, i32 pixmin, i32 pixmax, 4 dummy bytes,
//! char name[80], i32 colormap, 404 dummy bytes}`, then the channels one after the other
//! (planar), each channel's rows bottom-up. Verbatim files store the samples as they are; RLE
//! files store a table of `ysize·zsize` row offsets and one of row lengths (u32 each, row
//! `y` of channel `z` at entry `y + z·ysize`), then the rows as runs: a control unit `c`
//! (one sample wide), `c & 0x7f` = count (0 ends the row), high bit set = `count` literal
//! samples follow, clear = the next sample repeats `count` times.
//!
//! Decoding returns an [`Rgba8Image`] with row 0 at the top. Channels: 1 = grey, 2 = grey +
//! alpha, 3 = RGB, 4 = RGBA (more channels: the first four are used). 16-bit samples are
//! rounded to 8 bits (`(v·255 + 32767) / 65535`). Only the normal colormap mode (0) is
//! supported; dithered, screen and colormap files are rejected.

use crate::error::ParseError;
use crate::model::Rgba8Image;

/// The SGI magic number (big-endian u16 at byte 0).
pub const MAGIC: u16 = 474;
const HEADER: usize = 512;
/// The largest image decoded (8192 × 8192): a bound on what a header can make us allocate.
pub const MAX_PIXELS: usize = 1 << 26;

/// Whether `bytes` start like an SGI image.
pub fn is_sgi(bytes: &[u8]) -> bool {
    bytes.len() >= 2 && u16::from_be_bytes([bytes[0], bytes[1]]) == MAGIC
}

/// The fields of the header that decoding needs.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Header {
    rle: bool,
    bpc: usize,
    width: usize,
    height: usize,
    channels: usize,
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

fn be32(b: &[u8], at: usize) -> u32 {
    u32::from_be_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

fn read_header(bytes: &[u8]) -> Result<Header, ParseError> {
    if bytes.len() < HEADER {
        return Err(ParseError::at_byte(
            bytes.len(),
            format!(
                "file ends inside the 512-byte SGI header ({} bytes)",
                bytes.len()
            ),
        ));
    }
    if !is_sgi(bytes) {
        return Err(ParseError::at_byte(
            0,
            "not an SGI image (magic 474 expected)",
        ));
    }
    let rle = match bytes[2] {
        0 => false,
        1 => true,
        s => {
            return Err(ParseError::at_byte(
                2,
                format!("storage {s}, expected 0 (verbatim) or 1 (RLE)"),
            ));
        }
    };
    let bpc = match bytes[3] {
        b @ (1 | 2) => b as usize,
        b => {
            return Err(ParseError::at_byte(
                3,
                format!("{b} bytes per sample, expected 1 or 2"),
            ));
        }
    };
    let dimension = be16(bytes, 4);
    let (width, mut height, mut channels) = (
        be16(bytes, 6) as usize,
        be16(bytes, 8) as usize,
        be16(bytes, 10) as usize,
    );
    // Dimension 1 and 2 files may leave the unused sizes at 0; they mean 1.
    match dimension {
        1 => (height, channels) = (1, 1),
        2 => channels = 1,
        3 => {}
        d => {
            return Err(ParseError::at_byte(
                4,
                format!("dimension {d}, expected 1, 2 or 3"),
            ));
        }
    }
    if width == 0 || height == 0 || channels == 0 {
        return Err(ParseError::at_byte(
            6,
            format!("empty image {width}×{height}×{channels}"),
        ));
    }
    // RLE rows may share data, so a tiny file can claim a huge image: cap the size.
    if width * height > MAX_PIXELS {
        return Err(ParseError::at_byte(
            6,
            format!("image {width}×{height} is larger than the supported {MAX_PIXELS} pixels"),
        ));
    }
    let colormap = be32(bytes, 104);
    if colormap != 0 {
        return Err(ParseError::at_byte(
            104,
            format!("colormap mode {colormap} is not supported (only 0, normal)"),
        ));
    }
    Ok(Header {
        rle,
        bpc,
        width,
        height,
        channels,
    })
}

/// Decodes an SGI image into RGBA8, row 0 at the top.
pub fn decode(bytes: &[u8]) -> Result<Rgba8Image, ParseError> {
    let h = read_header(bytes)?;
    // Only the first four channels are used; more (rare) are ignored.
    let used = h.channels.min(4);
    let mut planes = Vec::with_capacity(used);
    for z in 0..used {
        planes.push(if h.rle {
            decode_rle_channel(bytes, &h, z)?
        } else {
            verbatim_channel(bytes, &h, z)?
        });
    }
    Ok(assemble(&h, &planes))
}

/// One channel of a verbatim file as 8-bit samples, rows bottom-up.
fn verbatim_channel(bytes: &[u8], h: &Header, z: usize) -> Result<Vec<u8>, ParseError> {
    let plane = h.width * h.height * h.bpc;
    let start = HEADER + z * plane;
    let data = bytes.get(start..start + plane).ok_or_else(|| {
        ParseError::at_byte(
            bytes.len(),
            format!("file ends inside channel {z}: {plane} bytes expected from byte {start}"),
        )
    })?;
    Ok(to_8bit(data, h.bpc))
}

fn to_8bit(data: &[u8], bpc: usize) -> Vec<u8> {
    if bpc == 1 {
        data.to_vec()
    } else {
        data.chunks_exact(2)
            .map(|c| sample16_to_8(u16::from_be_bytes([c[0], c[1]])))
            .collect()
    }
}

fn sample16_to_8(v: u16) -> u8 {
    ((v as u32 * 255 + 32767) / 65535) as u8
}

/// One channel of an RLE file as 8-bit samples, rows bottom-up.
fn decode_rle_channel(bytes: &[u8], h: &Header, z: usize) -> Result<Vec<u8>, ParseError> {
    let rows = h.height * h.channels;
    let tables_end = HEADER + 8 * rows;
    if bytes.len() < tables_end {
        return Err(ParseError::at_byte(
            bytes.len(),
            format!("file ends inside the RLE offset tables ({rows} rows need {tables_end} bytes)"),
        ));
    }
    let mut out = Vec::with_capacity(h.width * h.height);
    for y in 0..h.height {
        let entry = y + z * h.height;
        let start = be32(bytes, HEADER + 4 * entry) as usize;
        let len = be32(bytes, HEADER + 4 * rows + 4 * entry) as usize;
        let row = bytes.get(start..start.saturating_add(len)).ok_or_else(|| {
            ParseError::at_byte(
                HEADER + 4 * entry,
                format!("RLE row {y} of channel {z}: {len} bytes at offset {start} lie past the end ({} bytes)", bytes.len()),
            )
        })?;
        let before = out.len();
        expand_rle_row(row, h.bpc, h.width, &mut out).map_err(|msg| {
            ParseError::at_byte(start, format!("RLE row {y} of channel {z}: {msg}"))
        })?;
        debug_assert_eq!(out.len() - before, h.width);
    }
    Ok(out)
}

/// Expands one RLE row of exactly `width` samples into `out` (8-bit).
fn expand_rle_row(row: &[u8], bpc: usize, width: usize, out: &mut Vec<u8>) -> Result<(), String> {
    let unit = |i: usize| -> Option<u16> {
        let at = i * bpc;
        match bpc {
            1 => row.get(at).map(|&b| b as u16),
            _ => row
                .get(at..at + 2)
                .map(|c| u16::from_be_bytes([c[0], c[1]])),
        }
    };
    let sample = |v: u16| if bpc == 1 { v as u8 } else { sample16_to_8(v) };
    let (mut i, mut written) = (0usize, 0usize);
    loop {
        let control = unit(i).ok_or("row data ends before its end marker")?;
        i += 1;
        let count = (control & 0x7f) as usize;
        if count == 0 {
            break;
        }
        if written + count > width {
            return Err(format!("runs overflow the row width {width}"));
        }
        if control & 0x80 != 0 {
            for _ in 0..count {
                out.push(sample(unit(i).ok_or("literal run past the row data")?));
                i += 1;
            }
        } else {
            let v = sample(unit(i).ok_or("repeat run past the row data")?);
            i += 1;
            out.extend(std::iter::repeat_n(v, count));
        }
        written += count;
    }
    if written != width {
        return Err(format!("row holds {written} samples, expected {width}"));
    }
    Ok(())
}

/// Interleaves bottom-up planes into a top-down RGBA image.
fn assemble(h: &Header, planes: &[Vec<u8>]) -> Rgba8Image {
    let (w, ht) = (h.width, h.height);
    let mut pixels = Vec::with_capacity(w * ht);
    for row in 0..ht {
        let y = ht - 1 - row; // file row y counts from the bottom
        for x in 0..w {
            let s = |z: usize| planes[z][y * w + x];
            pixels.push(match planes.len() {
                1 => [s(0), s(0), s(0), 255],
                2 => [s(0), s(0), s(0), s(1)],
                3 => [s(0), s(1), s(2), 255],
                _ => [s(0), s(1), s(2), s(3)],
            });
        }
    }
    Rgba8Image {
        width: w as u32,
        height: ht as u32,
        pixels,
    }
}

/// Encodes an RGBA8 image (row 0 at the top) as an 8-bit, 4-channel SGI file, verbatim or RLE.
///
/// Used by the fixture generator and the tests. Images wider or taller than 65535 pixels
/// cannot be stored (the header holds u16 sizes): this panics, as it is a programming error.
pub fn encode(img: &Rgba8Image, rle: bool) -> Vec<u8> {
    assert!(
        img.width <= 0xffff && img.height <= 0xffff,
        "SGI sizes are u16"
    );
    let (w, h) = (img.width as usize, img.height as usize);
    let mut out = vec![0u8; HEADER];
    out[0..2].copy_from_slice(&MAGIC.to_be_bytes());
    out[2] = rle as u8;
    out[3] = 1;
    out[4..6].copy_from_slice(&3u16.to_be_bytes());
    out[6..8].copy_from_slice(&(w as u16).to_be_bytes());
    out[8..10].copy_from_slice(&(h as u16).to_be_bytes());
    out[10..12].copy_from_slice(&4u16.to_be_bytes());
    out[12..16].copy_from_slice(&0u32.to_be_bytes());
    out[16..20].copy_from_slice(&255u32.to_be_bytes());
    out[24..28].copy_from_slice(b"bake");
    // Rows bottom-up, channel by channel.
    let row = |z: usize, y: usize| -> Vec<u8> {
        let top = h - 1 - y;
        (0..w).map(|x| img.pixels[top * w + x][z]).collect()
    };
    if !rle {
        for z in 0..4 {
            for y in 0..h {
                out.extend(row(z, y));
            }
        }
        return out;
    }
    let rows = 4 * h;
    let mut starts = vec![0u32; rows];
    let mut lengths = vec![0u32; rows];
    let mut data = Vec::new();
    let data_start = HEADER + 8 * rows;
    for z in 0..4 {
        for y in 0..h {
            let packed = compress_rle_row(&row(z, y));
            starts[y + z * h] = (data_start + data.len()) as u32;
            lengths[y + z * h] = packed.len() as u32;
            data.extend(packed);
        }
    }
    starts.iter().for_each(|s| out.extend(s.to_be_bytes()));
    lengths.iter().for_each(|l| out.extend(l.to_be_bytes()));
    out.extend(data);
    out
}

/// Run-length encodes one row of 8-bit samples: repeats of 3 or more become repeat runs,
/// the rest literal runs; runs hold at most 127 samples; a 0 ends the row.
fn compress_rle_row(row: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < row.len() {
        let same = row[i..]
            .iter()
            .take(127)
            .take_while(|&&v| v == row[i])
            .count();
        if same >= 3 {
            out.extend([same as u8, row[i]]);
            i += same;
            continue;
        }
        // A literal run up to the next run of 3 equal samples.
        let mut j = i;
        while j < row.len() && j - i < 127 {
            if j + 2 < row.len() && row[j] == row[j + 1] && row[j] == row[j + 2] {
                break;
            }
            j += 1;
        }
        out.push(0x80 | (j - i) as u8);
        out.extend(&row[i..j]);
        i = j;
    }
    out.push(0);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn data(name: &str) -> Vec<u8> {
        let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("tests/data/sgi")
            .join(name);
        std::fs::read(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
    }

    /// The pattern as the PNG decoder of the `image` crate reads it.
    fn png(name: &str) -> Rgba8Image {
        let img = image::load_from_memory(&data(name)).unwrap().to_rgba8();
        Rgba8Image {
            width: img.width(),
            height: img.height(),
            pixels: img.pixels().map(|p| p.0).collect(),
        }
    }

    /// Files written by Pillow (verbatim) and netpbm's pnmtosgi (RLE) decode to the same
    /// pixels as the PNG they were made from (tests/data/sgi/generate.py).
    #[test]
    fn decodes_third_party_files_like_the_png() {
        let cases = [
            ("rgba_verbatim_pillow.rgb", "pattern_rgba.png", false, 4),
            ("grey_verbatim_pillow.rgb", "pattern_grey.png", false, 1),
            ("rgb_rle_netpbm.rgb", "pattern_rgb.png", true, 3),
            ("grey_rle_netpbm.rgb", "pattern_grey.png", true, 1),
            ("rgb16_rle_netpbm.rgb", "pattern_rgb.png", true, 3),
        ];
        for (file, pattern, rle, channels) in cases {
            let bytes = data(file);
            let h = read_header(&bytes).unwrap();
            assert_eq!((h.rle, h.channels), (rle, channels), "{file}");
            assert_eq!(decode(&bytes).unwrap(), png(pattern), "{file}");
        }
    }

    #[test]
    fn sixteen_bit_files_are_detected() {
        assert_eq!(read_header(&data("rgb16_rle_netpbm.rgb")).unwrap().bpc, 2);
        assert_eq!(sample16_to_8(0xffff), 255);
        assert_eq!(sample16_to_8(200 * 257), 200);
        assert_eq!(sample16_to_8(0), 0);
    }

    fn pattern(w: u32, h: u32) -> Rgba8Image {
        let pixels = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                // Runs (flat rows, long flat areas past 127) and noise (literals).
                if y % 3 == 0 {
                    [7, 7, 7, 7]
                } else {
                    [
                        (x * 13 % 251) as u8,
                        (y * 7) as u8,
                        ((x ^ y) & 0xff) as u8,
                        (x / 50) as u8,
                    ]
                }
            })
            .collect();
        Rgba8Image {
            width: w,
            height: h,
            pixels,
        }
    }

    #[test]
    fn encoder_round_trips_both_storages() {
        for (w, h) in [(1, 1), (3, 2), (300, 5), (64, 64)] {
            let img = pattern(w, h);
            for rle in [false, true] {
                let bytes = encode(&img, rle);
                assert_eq!(bytes[2], rle as u8);
                assert_eq!(decode(&bytes).unwrap(), img, "{w}×{h} rle={rle}");
            }
        }
        let img = pattern(300, 5);
        assert!(encode(&img, true).len() < encode(&img, false).len());
    }

    #[test]
    fn rle_rows_follow_the_spec() {
        assert_eq!(compress_rle_row(&[5, 5, 5, 5]), vec![4, 5, 0]);
        assert_eq!(compress_rle_row(&[1, 2, 3]), vec![0x83, 1, 2, 3, 0]);
        assert_eq!(compress_rle_row(&[1, 2, 2, 2]), vec![0x81, 1, 3, 2, 0]);
        let long = vec![9u8; 200];
        assert_eq!(compress_rle_row(&long), vec![127, 9, 73, 9, 0]);
    }

    #[test]
    fn corrupt_files_give_errors_not_panics() {
        let good = encode(&pattern(16, 8), true);
        // A row offset past the end of the file.
        let mut bad = good.clone();
        bad[HEADER..HEADER + 4].copy_from_slice(&u32::MAX.to_be_bytes());
        let e = decode(&bad).unwrap_err();
        assert!(e.message.contains("past the end"), "{e}");
        // A row length that cuts the row short (no end marker).
        let mut bad = good.clone();
        let len_at = HEADER + 4 * 32;
        bad[len_at..len_at + 4].copy_from_slice(&1u32.to_be_bytes());
        assert!(decode(&bad).is_err());
        // Bad storage, bpc, dimension, colormap.
        for (at, v, place) in [(2, 7u8, 2), (3, 3, 3), (5, 9, 4), (107, 1, 104)] {
            let mut bad = good.clone();
            bad[at] = v;
            let e = decode(&bad).unwrap_err();
            assert_eq!(e.place, format!("byte {place}"), "{e}");
        }
        // Every truncation and every single-byte corruption: an error or an image, never a panic.
        for n in 0..good.len() {
            assert!(decode(&good[..n]).is_err());
        }
        for at in 0..good.len() {
            let mut bad = good.clone();
            bad[at] ^= 0xa5;
            let _ = decode(&bad);
        }
        let verbatim = encode(&pattern(4, 4), false);
        assert!(decode(&verbatim[..verbatim.len() - 1]).is_err());
    }
}
