//! Encoding and decoding of one section payload: a 16-byte sub-header, a directory of named
//! typed arrays, postcard metadata, then the arrays, each 16-byte aligned.
//!
//! ```text
//! 0   u32 meta_offset   (from the section start)
//! 4   u32 meta_len
//! 8   u32 array_count
//! 12  u32 reserved (0)
//! 16  array_count × 48 B: name[24] NUL-padded, u32 format, u32 components, u64 count, u64 offset
//! ..  metadata (postcard), then arrays (offset from the section start, multiple of 16)
//! ```

use super::{Section, align_up, decode_meta, encode_meta, get_u32, get_u64, put_u32, put_u64};
use crate::error::ParseError;
use serde::{Serialize, de::DeserializeOwned};

/// Size of the section sub-header.
pub const SUB_HEADER: usize = 16;
/// Size of one array directory entry.
pub const DIR_ENTRY: usize = 48;
/// Bytes reserved for an array name.
pub const ARRAY_NAME_LEN: usize = 24;
/// Alignment of each array inside a section.
pub const ARRAY_ALIGN: usize = 16;

/// Scalar type of an array's components.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ArrayFormat {
    /// Unsigned 8-bit.
    U8 = 1,
    /// Unsigned 16-bit.
    U16 = 2,
    /// Unsigned 32-bit.
    U32 = 3,
    /// Signed 32-bit.
    I32 = 4,
    /// 32-bit float.
    F32 = 5,
    /// IEEE half floats stored as u16 bits.
    F16 = 6,
    /// Unsigned 64-bit.
    U64 = 7,
}

impl ArrayFormat {
    /// Bytes of one component.
    pub fn size(self) -> usize {
        match self {
            ArrayFormat::U8 => 1,
            ArrayFormat::U16 | ArrayFormat::F16 => 2,
            ArrayFormat::U32 | ArrayFormat::I32 | ArrayFormat::F32 => 4,
            ArrayFormat::U64 => 8,
        }
    }
    /// The format of its code in a section directory.
    pub fn from_u32(v: u32) -> Option<Self> {
        Some(match v {
            1 => ArrayFormat::U8,
            2 => ArrayFormat::U16,
            3 => ArrayFormat::U32,
            4 => ArrayFormat::I32,
            5 => ArrayFormat::F32,
            6 => ArrayFormat::F16,
            7 => ArrayFormat::U64,
            _ => return None,
        })
    }
    /// Its name in the docs and dumps (`u8`, `f32`, ...).
    pub fn name(self) -> &'static str {
        match self {
            ArrayFormat::U8 => "u8",
            ArrayFormat::U16 => "u16",
            ArrayFormat::U32 => "u32",
            ArrayFormat::I32 => "i32",
            ArrayFormat::F32 => "f32",
            ArrayFormat::F16 => "f16",
            ArrayFormat::U64 => "u64",
        }
    }
}

/// An array's bytes: copied in, or written straight into the encoded payload by a closure
/// (so a large array is never held twice).
enum PendingBytes<'a> {
    Copied(Vec<u8>),
    Fill(Filler<'a>),
    /// Filled together with the other deferred arrays by [`SectionBuilder::finish_with`].
    Deferred,
}

/// Writes an array's bytes into its place in the payload.
type Filler<'a> = Box<dyn FnOnce(&mut [u8]) + 'a>;

struct PendingArray<'a> {
    name: String,
    format: ArrayFormat,
    components: u32,
    count: u64,
    len: usize,
    bytes: PendingBytes<'a>,
}

/// Builds one section: metadata plus named POD arrays.
pub struct SectionBuilder<'a> {
    kind: String,
    name: String,
    meta: Vec<u8>,
    arrays: Vec<PendingArray<'a>>,
}

impl<'a> SectionBuilder<'a> {
    /// A section of kind `kind` named `name`, with no metadata or arrays yet.
    pub fn new(kind: &str, name: &str) -> Self {
        Self {
            kind: kind.to_string(),
            name: name.to_string(),
            meta: Vec::new(),
            arrays: Vec::new(),
        }
    }

    /// Sets the metadata (postcard).
    pub fn meta<T: Serialize>(&mut self, meta: &T) -> &mut Self {
        self.meta = encode_meta(meta);
        self
    }

    /// Adds an array of `T`, each element being `components` scalars of `format`.
    ///
    /// Panics if the element size does not match: that is a programming error, not bad input.
    pub fn array<T: bytemuck::NoUninit>(
        &mut self,
        name: &str,
        format: ArrayFormat,
        components: u32,
        data: &[T],
    ) -> &mut Self {
        let bytes = bytemuck::cast_slice::<T, u8>(data).to_vec();
        self.push::<T>(
            name,
            format,
            components,
            data.len(),
            PendingBytes::Copied(bytes),
        )
    }

    /// Adds an array of `count` elements of `T` that `fill` writes in place when the section is
    /// encoded (the slice it gets is zeroed and 16-byte aligned): for arrays too large to build
    /// beside their encoding. Panics as [`SectionBuilder::array`] does.
    pub fn array_fill<T: bytemuck::Pod>(
        &mut self,
        name: &str,
        format: ArrayFormat,
        components: u32,
        count: usize,
        fill: impl FnOnce(&mut [T]) + 'a,
    ) -> &mut Self {
        let fill = move |out: &mut [u8]| fill(bytemuck::cast_slice_mut(out));
        self.push::<T>(
            name,
            format,
            components,
            count,
            PendingBytes::Fill(Box::new(fill)),
        )
    }

    /// Adds an array of `count` elements of `T` left for [`SectionBuilder::finish_with`] to fill
    /// in place, together with the section's other deferred arrays (zeroed and 16-byte aligned):
    /// for arrays computed side by side and too large to be held beside their encoding (the
    /// terrain light map's `irradiance` and `indirect`). Panics as [`SectionBuilder::array`] does.
    pub fn array_deferred<T: bytemuck::Pod>(
        &mut self,
        name: &str,
        format: ArrayFormat,
        components: u32,
        count: usize,
    ) -> &mut Self {
        self.push::<T>(name, format, components, count, PendingBytes::Deferred)
    }

    fn push<T>(
        &mut self,
        name: &str,
        format: ArrayFormat,
        components: u32,
        count: usize,
        bytes: PendingBytes<'a>,
    ) -> &mut Self {
        assert_eq!(
            size_of::<T>(),
            format.size() * components as usize,
            "array {name}: element size mismatch"
        );
        assert!(
            name.len() <= ARRAY_NAME_LEN && !name.contains('\0'),
            "array name {name:?} too long"
        );
        self.arrays.push(PendingArray {
            name: name.to_string(),
            format,
            components,
            count: count as u64,
            len: count * size_of::<T>(),
            bytes,
        });
        self
    }

    /// Encodes the section (deferred arrays, if any, stay zero).
    pub fn finish(self) -> Section {
        self.finish_with(|_| {})
    }

    /// Encodes the section, then lets `fill` write the deferred arrays
    /// ([`SectionBuilder::array_deferred`]) in place: it gets their byte slices in the order
    /// they were added.
    pub fn finish_with(self, fill: impl FnOnce(Vec<&mut [u8]>)) -> Section {
        let dir_end = SUB_HEADER + self.arrays.len() * DIR_ENTRY;
        let meta_offset = dir_end;
        let mut cursor = meta_offset + self.meta.len();
        let mut offsets = Vec::with_capacity(self.arrays.len());
        for a in &self.arrays {
            cursor = align_up(cursor, ARRAY_ALIGN);
            offsets.push(cursor);
            cursor += a.len;
        }
        let mut buf = vec![0u128; cursor.div_ceil(16)];
        let out = &mut bytemuck::cast_slice_mut::<u128, u8>(&mut buf)[..cursor];
        put_u32(out, 0, meta_offset as u32);
        put_u32(out, 4, self.meta.len() as u32);
        put_u32(out, 8, self.arrays.len() as u32);
        let mut deferred = Vec::new();
        for (k, (a, &off)) in self.arrays.into_iter().zip(&offsets).enumerate() {
            let d = SUB_HEADER + k * DIR_ENTRY;
            out[d..d + a.name.len()].copy_from_slice(a.name.as_bytes());
            put_u32(out, d + 24, a.format as u32);
            put_u32(out, d + 28, a.components);
            put_u64(out, d + 32, a.count);
            put_u64(out, d + 40, off as u64);
            match a.bytes {
                PendingBytes::Copied(b) => out[off..off + a.len].copy_from_slice(&b),
                PendingBytes::Fill(f) => f(&mut out[off..off + a.len]),
                PendingBytes::Deferred => deferred.push((off, a.len)),
            }
        }
        out[meta_offset..meta_offset + self.meta.len()].copy_from_slice(&self.meta);
        // The deferred arrays' slices, split off in ascending order (their offsets increase).
        let mut slices = Vec::with_capacity(deferred.len());
        let mut rest: &mut [u8] = out;
        let mut at = 0;
        for (off, len) in deferred {
            let (_, tail) = std::mem::take(&mut rest).split_at_mut(off - at);
            let (mine, tail) = tail.split_at_mut(len);
            slices.push(mine);
            rest = tail;
            at = off + len;
        }
        fill(slices);
        Section {
            kind: self.kind,
            name: self.name,
            payload: super::Payload::from_aligned(buf, cursor),
        }
    }
}

/// Directory entry of one array.
#[derive(Debug, Clone, PartialEq)]
pub struct ArrayInfo {
    /// The array's name.
    pub name: String,
    /// Its component format.
    pub format: ArrayFormat,
    /// Components per element.
    pub components: u32,
    /// Elements.
    pub count: u64,
    /// Byte offset of its data in the payload.
    pub offset: u64,
}

impl ArrayInfo {
    /// Bytes of its data.
    pub fn byte_len(&self) -> u64 {
        self.count * self.components as u64 * self.format.size() as u64
    }
}

/// A parsed section borrowed from its pack.
#[derive(Debug, Clone)]
pub struct SectionView<'a> {
    bytes: &'a [u8],
    /// Absolute file offset of the section, for error messages.
    base: usize,
    meta: &'a [u8],
    /// The arrays, in directory order.
    pub arrays: Vec<ArrayInfo>,
}

impl<'a> SectionView<'a> {
    /// Parses a payload; `base` is its file offset (used in messages only).
    pub fn parse(bytes: &'a [u8], base: usize) -> Result<Self, ParseError> {
        if bytes.len() < SUB_HEADER {
            return Err(ParseError::at_byte(
                base,
                "section shorter than its 16-byte sub-header",
            ));
        }
        let meta_offset = get_u32(bytes, 0) as usize;
        let meta_len = get_u32(bytes, 4) as usize;
        let count = get_u32(bytes, 8) as usize;
        let dir_end = count
            .checked_mul(DIR_ENTRY)
            .and_then(|n| n.checked_add(SUB_HEADER));
        if dir_end.is_none_or(|e| e > bytes.len()) {
            return Err(ParseError::at_byte(
                base + 8,
                format!("array directory of {count} entries runs past the section end"),
            ));
        }
        if meta_offset
            .checked_add(meta_len)
            .is_none_or(|e| e > bytes.len())
        {
            return Err(ParseError::at_byte(
                base,
                "section metadata runs past the section end",
            ));
        }
        let mut arrays = Vec::with_capacity(count);
        for k in 0..count {
            let d = SUB_HEADER + k * DIR_ENTRY;
            let name_bytes = &bytes[d..d + ARRAY_NAME_LEN];
            let end = name_bytes
                .iter()
                .position(|&c| c == 0)
                .unwrap_or(ARRAY_NAME_LEN);
            let name = String::from_utf8(name_bytes[..end].to_vec())
                .map_err(|_| ParseError::at_byte(base + d, "array name is not UTF-8"))?;
            let format = ArrayFormat::from_u32(get_u32(bytes, d + 24)).ok_or_else(|| {
                ParseError::at_byte(
                    base + d + 24,
                    format!("array {name:?}: unknown format code"),
                )
            })?;
            let info = ArrayInfo {
                name,
                format,
                components: get_u32(bytes, d + 28),
                count: get_u64(bytes, d + 32),
                offset: get_u64(bytes, d + 40),
            };
            let len = info
                .count
                .checked_mul(info.components as u64)
                .and_then(|n| n.checked_mul(format.size() as u64));
            let fits = len
                .and_then(|l| l.checked_add(info.offset))
                .is_some_and(|e| e <= bytes.len() as u64);
            if !fits || !info.offset.is_multiple_of(ARRAY_ALIGN as u64) {
                return Err(ParseError::at_byte(
                    base + d,
                    format!(
                        "array {:?} (offset {}, {} elements) is misaligned or runs past the section end",
                        info.name, info.offset, info.count
                    ),
                ));
            }
            arrays.push(info);
        }
        Ok(Self {
            bytes,
            base,
            meta: &bytes[meta_offset..meta_offset + meta_len],
            arrays,
        })
    }

    /// Decodes the metadata.
    pub fn meta<T: DeserializeOwned>(&self) -> Result<T, ParseError> {
        decode_meta(self.meta, self.base)
    }

    /// The array named `name`'s directory entry.
    pub fn info(&self, name: &str) -> Option<&ArrayInfo> {
        self.arrays.iter().find(|a| a.name == name)
    }

    /// The raw bytes of an array.
    pub fn array_bytes(&self, name: &str) -> Result<&'a [u8], ParseError> {
        let a = self.info(name).ok_or_else(|| {
            ParseError::at_byte(self.base, format!("section has no array {name:?}"))
        })?;
        Ok(&self.bytes[a.offset as usize..(a.offset + a.byte_len()) as usize])
    }

    /// An array read in place as `&[T]`; its element size must be `size_of::<T>()`.
    pub fn array<T: bytemuck::AnyBitPattern>(&self, name: &str) -> Result<&'a [T], ParseError> {
        let a = self.info(name).ok_or_else(|| {
            ParseError::at_byte(self.base, format!("section has no array {name:?}"))
        })?;
        let elem = a.format.size() * a.components as usize;
        if elem != size_of::<T>() {
            return Err(ParseError::at_byte(
                self.base + a.offset as usize,
                format!(
                    "array {name:?} has {elem}-byte elements, the reader expects {}",
                    size_of::<T>()
                ),
            ));
        }
        let bytes = self.array_bytes(name)?;
        bytemuck::try_cast_slice(bytes).map_err(|e| {
            ParseError::at_byte(
                self.base + a.offset as usize,
                format!("array {name:?}: {e}"),
            )
        })
    }

    /// An array copied out as `Vec<T>` (no alignment requirement).
    pub fn array_vec<T: bytemuck::Pod>(&self, name: &str) -> Result<Vec<T>, ParseError> {
        let a = self.info(name).ok_or_else(|| {
            ParseError::at_byte(self.base, format!("section has no array {name:?}"))
        })?;
        let elem = a.format.size() * a.components as usize;
        if elem != size_of::<T>() {
            return Err(ParseError::at_byte(
                self.base + a.offset as usize,
                format!(
                    "array {name:?} has {elem}-byte elements, the reader expects {}",
                    size_of::<T>()
                ),
            ));
        }
        Ok(bytemuck::pod_collect_to_vec(self.array_bytes(name)?))
    }
}
