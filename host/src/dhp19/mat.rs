//! Reader for DHP19's Vicon ground truth: MATLAB Level 5 MAT-files (`save -v6` and the default
//! `save -v7`, whose variables are zlib-compressed Level 5 elements) holding a struct variable
//! `XYZPOS` with one `(T, 3)` field per joint (millimetres, 100 Hz).
//!
//! What is read: the 128-byte header in either byte order ("IM" little-endian, "MI" big-endian),
//! data elements in the full and the packed small-element form, `miCOMPRESSED` (zlib),
//! `miMATRIX` of the struct class and of every numeric class (double, single, int8..uint64; the
//! stored mi type may be any numeric type, as MATLAB narrows integral doubles on save), complex
//! parts included. Cell, char, sparse, object, function and opaque arrays are skipped whole and
//! reported as [`Value::Unsupported`]. MATLAB v7.3 files (HDF5) are refused with
//! [`MatError::Hdf5`]; Level 4 files are refused as not Level 5.
//!
//! Robustness: no input makes this module panic; every length read from the file is checked
//! against the bytes that remain before anything is allocated from it; decompressed data is
//! capped (see [`decompression_limit`]); struct nesting is capped at [`MAX_DEPTH`].
//!
//! DHP19 facts this module relies on (from SensorsINI/DHP19 `generate_DHP19/*.m`): the fields of
//! `XYZPOS` are named `head shoulderR shoulderL elbowR elbowL hipR hipL handR handL kneeR kneeL
//! footR footL`; row `k` (0-based) of every field is the Vicon sample taken
//! `k * 10 ms` after the recording's start trigger (see [`vicon_index`]).

#![deny(missing_docs)]

use std::fmt;

/// Joint names of evpose's (and DHP19's MATLAB code's) joint order, as spelled in `XYZPOS`.
pub use evpose_core::skeleton::JOINT_NAMES as DHP19_JOINTS;

/// Vicon sampling period in DAVIS timestamp units (µs): DHP19's Vicon runs at 100 Hz.
pub const VICON_PERIOD_US: u64 = 10_000;

/// Deepest struct-in-struct nesting accepted before the input is called corrupt.
pub const MAX_DEPTH: usize = 32;

/// Hard ceiling on the bytes all `miCOMPRESSED` elements of one file may inflate to (1 GiB).
pub const MAX_DECOMPRESSED_BYTES: usize = 1 << 30;

/// Decompressed bytes allowed per byte of input, before the 1 GiB ceiling.
pub const MAX_DECOMPRESSION_RATIO: usize = 64;

/// Decompressed bytes allowed whatever the input size (16 MiB), before the 1 GiB ceiling.
pub const MIN_DECOMPRESSION_ALLOWANCE: usize = 16 << 20;

/// The total number of bytes the compressed elements of an `input_len`-byte file may inflate
/// to: `min(1 GiB, max(16 MiB, 64 × input_len))`. Exceeding it gives [`MatError::TooLarge`].
pub fn decompression_limit(input_len: usize) -> usize {
    input_len
        .saturating_mul(MAX_DECOMPRESSION_RATIO)
        .clamp(MIN_DECOMPRESSION_ALLOWANCE, MAX_DECOMPRESSED_BYTES)
}

/// 0-based row of the `XYZPOS` fields that holds the Vicon sample for an event at `t_us`, given
/// the recording's start time `start_us` (the DAVIS "special" trigger event), both in µs: the
/// nearest sample, `round((t_us − start_us) / 10_000)` (halves up); `None` before the start.
/// DHP19's MATLAB code writes the 1-based `k = floor((t - startTime) * 0.0001) + 1`, but its
/// times are int64: MATLAB's int64 × double rounds to the nearest integer before the `floor`,
/// which then does nothing, so its row is the nearest one (the `floor` reading, used here
/// through stop 42, was up to half a sample early). The caller must still check the row against
/// `T` (DHP19 stops cutting windows once it passes the last sample).
pub fn vicon_index(t_us: u64, start_us: u64) -> Option<usize> {
    let d = t_us.checked_sub(start_us)?;
    usize::try_from(d / VICON_PERIOD_US + u64::from(d % VICON_PERIOD_US >= VICON_PERIOD_US / 2))
        .ok()
}

/// Where in the input something was found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Location {
    /// Byte offset: into the file, or, when `compressed_element` is set, into the data inflated
    /// from that compressed element.
    pub offset: usize,
    /// File offset of the `miCOMPRESSED` element whose inflated data `offset` points into.
    pub compressed_element: Option<usize>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.compressed_element {
            None => write!(f, "byte {}", self.offset),
            Some(z) => write!(
                f,
                "byte {} of the data inflated from the compressed element at file byte {}",
                self.offset, z
            ),
        }
    }
}

/// Everything that can go wrong reading a MAT-file or its `XYZPOS` variable.
#[derive(Debug, thiserror::Error)]
pub enum MatError {
    /// The input ends (or an element's declared size runs) past the available bytes.
    #[error("truncated MAT-file at {at}: {what} needs {needed} bytes, {available} available")]
    Truncated {
        /// Where the incomplete item starts.
        at: Location,
        /// What was being read.
        what: &'static str,
        /// Bytes the item needs.
        needed: usize,
        /// Bytes that remain.
        available: usize,
    },
    /// The bytes are there but do not form a valid Level 5 structure.
    #[error("corrupt MAT-file at {at}: {reason}")]
    Corrupt {
        /// Where the problem was found.
        at: Location,
        /// What is wrong.
        reason: String,
    },
    /// The header is not a MATLAB Level 5 header.
    #[error("not a MATLAB Level 5 MAT-file: {0}")]
    NotLevel5(String),
    /// A MATLAB v7.3 file (HDF5 container), which this reader does not parse.
    #[error(
        "MATLAB v7.3 (HDF5) MAT-files are not supported; re-save with `save(file, '-v7')` or \
         `-v6`"
    )]
    Hdf5,
    /// Compressed elements inflate to more than [`decompression_limit`] allows.
    #[error("compressed element at file byte {at} inflates past the limit of {limit} bytes")]
    TooLarge {
        /// File offset of the compressed element.
        at: usize,
        /// The limit in bytes.
        limit: usize,
    },
    /// No variable of that name in the file.
    #[error("variable `{0}` not found in the MAT-file")]
    MissingVariable(String),
    /// A variable or field has the wrong class or shape.
    #[error("`{name}`: expected {expected}, found {found}")]
    WrongType {
        /// Variable or field name.
        name: String,
        /// What was expected.
        expected: &'static str,
        /// What was found.
        found: String,
    },
    /// A joint needed for evpose's joint order is not a field of `XYZPOS`.
    #[error("joint `{0}` is missing from XYZPOS")]
    MissingJoint(String),
    /// Joints differ in their number of samples.
    #[error("joint `{joint}` has {len} samples but `{first}` has {first_len}")]
    LengthMismatch {
        /// The joint that disagrees.
        joint: String,
        /// Its number of samples.
        len: usize,
        /// The joint it was compared with.
        first: String,
        /// That joint's number of samples.
        first_len: usize,
    },
}

/// MATLAB array class (`mxCLASS`), from the array-flags sub-element.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ArrayClass {
    /// mxCELL_CLASS (1).
    Cell,
    /// mxSTRUCT_CLASS (2).
    Struct,
    /// mxOBJECT_CLASS (3).
    Object,
    /// mxCHAR_CLASS (4).
    Char,
    /// mxSPARSE_CLASS (5).
    Sparse,
    /// mxDOUBLE_CLASS (6).
    Double,
    /// mxSINGLE_CLASS (7).
    Single,
    /// mxINT8_CLASS (8).
    Int8,
    /// mxUINT8_CLASS (9); also logical arrays.
    UInt8,
    /// mxINT16_CLASS (10).
    Int16,
    /// mxUINT16_CLASS (11).
    UInt16,
    /// mxINT32_CLASS (12).
    Int32,
    /// mxUINT32_CLASS (13).
    UInt32,
    /// mxINT64_CLASS (14).
    Int64,
    /// mxUINT64_CLASS (15).
    UInt64,
    /// mxFUNCTION_CLASS (16).
    Function,
    /// mxOPAQUE_CLASS (17).
    Opaque,
    /// Any other class code.
    Other(u8),
}

impl ArrayClass {
    fn from_code(c: u8) -> Self {
        use ArrayClass::*;
        match c {
            1 => Cell,
            2 => Struct,
            3 => Object,
            4 => Char,
            5 => Sparse,
            6 => Double,
            7 => Single,
            8 => Int8,
            9 => UInt8,
            10 => Int16,
            11 => UInt16,
            12 => Int32,
            13 => UInt32,
            14 => Int64,
            15 => UInt64,
            16 => Function,
            17 => Opaque,
            o => Other(o),
        }
    }

    fn is_numeric(self) -> bool {
        use ArrayClass::*;
        matches!(
            self,
            Double | Single | Int8 | UInt8 | Int16 | UInt16 | Int32 | UInt32 | Int64 | UInt64
        )
    }
}

/// A numeric array, converted to `f64`, in MATLAB's column-major order.
#[derive(Debug, Clone, PartialEq)]
pub struct NumericArray {
    /// The MATLAB class it had.
    pub class: ArrayClass,
    /// Whether the logical flag was set.
    pub logical: bool,
    /// Dimensions (at least two).
    pub dims: Vec<usize>,
    /// Real parts, column-major: element `(r, c)` of a 2-D array is `real[r + c * dims[0]]`.
    pub real: Vec<f64>,
    /// Imaginary parts, same layout, for complex arrays.
    pub imag: Option<Vec<f64>>,
}

impl NumericArray {
    /// Element `(row, col)` (0-based) of a 2-D array's real part, `None` outside it.
    pub fn get(&self, row: usize, col: usize) -> Option<f64> {
        if self.dims.len() != 2 || row >= self.dims[0] || col >= self.dims[1] {
            return None;
        }
        self.real.get(row + col * self.dims[0]).copied()
    }
}

/// A struct array: `len()` elements (column-major over `dims`), each with every field.
#[derive(Debug, Clone, PartialEq)]
pub struct StructArray {
    /// Dimensions (at least two).
    pub dims: Vec<usize>,
    /// Field names in file order.
    pub field_names: Vec<String>,
    /// Field values, element-major: field `f` of element `e` is `values[e * nfields + f]`.
    pub values: Vec<Value>,
}

impl StructArray {
    /// Number of elements (product of `dims`).
    pub fn len(&self) -> usize {
        self.dims
            .iter()
            .try_fold(1usize, |a, &d| a.checked_mul(d))
            .unwrap_or(usize::MAX)
    }

    /// Whether the struct array has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Field `name` (exact match) of element `element`.
    pub fn field(&self, element: usize, name: &str) -> Option<&Value> {
        let f = self.field_names.iter().position(|n| n == name)?;
        let i = element
            .checked_mul(self.field_names.len())?
            .checked_add(f)?;
        self.values.get(i)
    }
}

/// The value of a variable or struct field.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// Numeric array of any numeric class.
    Numeric(NumericArray),
    /// Struct array.
    Struct(StructArray),
    /// A zero-byte `miMATRIX` element (some writers use these for empty struct fields or cells).
    Empty,
    /// A class this reader skips (cell, char, sparse, object, function, opaque, unknown).
    Unsupported {
        /// Its class.
        class: ArrayClass,
        /// Its dimensions.
        dims: Vec<usize>,
    },
}

impl Value {
    fn describe(&self) -> String {
        match self {
            Value::Numeric(a) => format!("{:?} array of size {}", a.class, dims_str(&a.dims)),
            Value::Struct(s) => format!("struct array of size {}", dims_str(&s.dims)),
            Value::Empty => "empty matrix".to_string(),
            Value::Unsupported { class, dims } => {
                format!("{:?} array of size {}", class, dims_str(dims))
            }
        }
    }
}

fn dims_str(d: &[usize]) -> String {
    d.iter()
        .map(|x| x.to_string())
        .collect::<Vec<_>>()
        .join("x")
}

/// One top-level variable of a MAT-file.
#[derive(Debug, Clone, PartialEq)]
pub struct Variable {
    /// Variable name.
    pub name: String,
    /// Its value.
    pub value: Value,
}

/// DHP19 Vicon ground truth: the fields of `XYZPOS` in file order, each a list of `T` samples
/// `[x, y, z]` in mm (NaN where Vicon lost the marker; DHP19 averages with `nanmean`).
#[derive(Debug, Clone, PartialEq)]
pub struct Vicon {
    /// `(field name, samples)` in the file's field order.
    pub joints: Vec<(String, Vec<[f64; 3]>)>,
}

impl Vicon {
    fn find(&self, name: &str) -> Option<&(String, Vec<[f64; 3]>)> {
        self.joints.iter().find(|(n, _)| n == name).or_else(|| {
            self.joints
                .iter()
                .find(|(n, _)| n.eq_ignore_ascii_case(name))
        })
    }

    /// Samples of the joints in [`DHP19_JOINTS`] order, matched by field name (exact match
    /// preferred, else case-insensitive), never by position. Fails naming the first missing
    /// joint, or when the 13 joints differ in length.
    pub fn dhp19_order(&self) -> Result<Vec<Vec<[f64; 3]>>, MatError> {
        let mut out: Vec<Vec<[f64; 3]>> = Vec::with_capacity(DHP19_JOINTS.len());
        let mut first: Option<(&str, usize)> = None;
        for name in DHP19_JOINTS {
            let (_, s) = self
                .find(name)
                .ok_or_else(|| MatError::MissingJoint(name.to_string()))?;
            match first {
                None => first = Some((name, s.len())),
                Some((f, n)) if n != s.len() => {
                    return Err(MatError::LengthMismatch {
                        joint: name.to_string(),
                        len: s.len(),
                        first: f.to_string(),
                        first_len: n,
                    })
                }
                Some(_) => {}
            }
            out.push(s.clone());
        }
        Ok(out)
    }

    /// The same as [`Vicon::dhp19_order`], transposed to one `[joint][xyz]` pose per sample.
    pub fn dhp19_frames(&self) -> Result<Vec<[[f64; 3]; 13]>, MatError> {
        let joints = self.dhp19_order()?;
        let t = joints.first().map_or(0, Vec::len);
        Ok((0..t)
            .map(|i| std::array::from_fn(|j| joints[j][i]))
            .collect())
    }
}

/// Reads the `XYZPOS` struct variable of a DHP19 Vicon MAT-file. Every field must be a numeric
/// `(T, 3)` array (any `T`, zero included); the first element of a struct array is used and the
/// struct must have exactly one element.
pub fn read_xyzpos(bytes: &[u8]) -> Result<Vicon, MatError> {
    let vars = read_variables(bytes)?;
    let var = vars
        .iter()
        .find(|v| v.name == "XYZPOS")
        .or_else(|| vars.iter().find(|v| v.name.eq_ignore_ascii_case("XYZPOS")))
        .ok_or_else(|| MatError::MissingVariable("XYZPOS".to_string()))?;
    let s = match &var.value {
        Value::Struct(s) if s.len() == 1 => s,
        other => {
            return Err(MatError::WrongType {
                name: var.name.clone(),
                expected: "a 1x1 struct",
                found: other.describe(),
            })
        }
    };
    let mut joints = Vec::with_capacity(s.field_names.len());
    for (name, value) in s.field_names.iter().zip(&s.values) {
        let a = match value {
            Value::Numeric(a) if a.dims.len() == 2 && a.dims[1] == 3 => a,
            other => {
                return Err(MatError::WrongType {
                    name: format!("XYZPOS.{name}"),
                    expected: "a numeric (T, 3) array",
                    found: other.describe(),
                })
            }
        };
        let t = a.dims[0];
        // Column-major: x is rows 0..t, y is t..2t, z is 2t..3t.
        let samples = (0..t)
            .map(|r| [a.real[r], a.real[r + t], a.real[r + 2 * t]])
            .collect();
        joints.push((name.clone(), samples));
    }
    Ok(Vicon { joints })
}

/// Reads every top-level variable of a Level 5 MAT-file (v6, or v7 with compression), in file
/// order. Elements that are neither `miMATRIX` nor `miCOMPRESSED` are skipped.
pub fn read_variables(bytes: &[u8]) -> Result<Vec<Variable>, MatError> {
    read_variables_limited(bytes, decompression_limit(bytes.len()))
}

// ---------------------------------------------------------------------------------------------
// Implementation.

const MI_INT8: u32 = 1;
const MI_UINT8: u32 = 2;
const MI_INT16: u32 = 3;
const MI_UINT16: u32 = 4;
const MI_INT32: u32 = 5;
const MI_UINT32: u32 = 6;
const MI_SINGLE: u32 = 7;
const MI_DOUBLE: u32 = 9;
const MI_INT64: u32 = 12;
const MI_UINT64: u32 = 13;
const MI_MATRIX: u32 = 14;
const MI_COMPRESSED: u32 = 15;
const MI_UTF8: u32 = 16;

const HEADER_LEN: usize = 128;
const HDF5_SIGNATURE: &[u8; 8] = b"\x89HDF\r\n\x1a\n";

/// A view of a byte buffer with its place in the input, for offsets in errors.
#[derive(Clone, Copy)]
struct Buf<'a> {
    data: &'a [u8],
    /// Offset of `data[0]` in the file or in the inflated stream.
    base: usize,
    /// File offset of the compressed element the data was inflated from.
    zsrc: Option<usize>,
    big: bool,
}

impl<'a> Buf<'a> {
    fn loc(&self, pos: usize) -> Location {
        Location {
            offset: self.base.saturating_add(pos),
            compressed_element: self.zsrc,
        }
    }

    fn truncated(&self, pos: usize, what: &'static str, needed: usize) -> MatError {
        MatError::Truncated {
            at: self.loc(pos),
            what,
            needed,
            available: self.data.len().saturating_sub(pos),
        }
    }

    fn corrupt(&self, pos: usize, reason: impl Into<String>) -> MatError {
        MatError::Corrupt {
            at: self.loc(pos),
            reason: reason.into(),
        }
    }

    fn sub(&self, start: usize, len: usize) -> Buf<'a> {
        Buf {
            data: &self.data[start..start + len],
            base: self.base.saturating_add(start),
            zsrc: self.zsrc,
            big: self.big,
        }
    }

    fn u32_at(&self, pos: usize) -> Option<u32> {
        let b: [u8; 4] = self.data.get(pos..pos.checked_add(4)?)?.try_into().ok()?;
        Some(if self.big {
            u32::from_be_bytes(b)
        } else {
            u32::from_le_bytes(b)
        })
    }
}

/// One data element: its type and the sub-buffer holding its data.
struct Element<'a> {
    mi_type: u32,
    data: Buf<'a>,
    /// Offset of the tag within the parent buffer.
    tag_pos: usize,
}

/// Reads the element at `*pos` of `buf` and advances `*pos` past it (and past its padding to
/// 8 bytes when `pad`; missing padding at the very end of `buf` is tolerated).
fn next_element<'a>(buf: &Buf<'a>, pos: &mut usize, pad: bool) -> Result<Element<'a>, MatError> {
    let p = *pos;
    let avail = buf.data.len().saturating_sub(p);
    if avail < 4 {
        return Err(buf.truncated(p, "data element tag", 8));
    }
    let w = buf
        .u32_at(p)
        .ok_or_else(|| buf.truncated(p, "data element tag", 8))?;
    if w >> 16 != 0 {
        // Small data element: type in the low half, size in the high half, data in bytes 4..8.
        let n = (w >> 16) as usize;
        if n > 4 {
            return Err(buf.corrupt(p, format!("small data element declares {n} bytes (max 4)")));
        }
        if avail < 8 {
            return Err(buf.truncated(p, "small data element", 8));
        }
        *pos = p + 8;
        return Ok(Element {
            mi_type: w & 0xffff,
            data: buf.sub(p + 4, n),
            tag_pos: p,
        });
    }
    if avail < 8 {
        return Err(buf.truncated(p, "data element tag", 8));
    }
    let n = buf
        .u32_at(p + 4)
        .ok_or_else(|| buf.truncated(p, "data element tag", 8))? as usize;
    let start = p + 8;
    if n > buf.data.len() - start {
        return Err(buf.truncated(start, "data element", n));
    }
    let end = start + n;
    let padded = if pad {
        end.saturating_add((8 - n % 8) % 8)
    } else {
        end
    };
    *pos = padded.min(buf.data.len());
    Ok(Element {
        mi_type: w,
        data: buf.sub(start, n),
        tag_pos: p,
    })
}

fn read_variables_limited(bytes: &[u8], limit: usize) -> Result<Vec<Variable>, MatError> {
    let big = check_header(bytes)?;
    let file = Buf {
        data: bytes,
        base: 0,
        zsrc: None,
        big,
    };
    let mut budget = limit;
    let mut vars = Vec::new();
    let mut pos = HEADER_LEN;
    while pos < bytes.len() {
        // Compressed elements are not padded; matrices are, in practice, multiples of 8 already.
        let el = next_element(&file, &mut pos, true)?;
        match el.mi_type {
            MI_MATRIX => {
                if let Some(v) = parse_variable(&el.data)? {
                    vars.push(v);
                }
            }
            MI_COMPRESSED => {
                // Undo the padding `next_element` added: compressed elements are packed.
                pos = el.tag_pos + 8 + el.data.data.len();
                let inflated = inflate(el.data.data, el.tag_pos, &mut budget, limit)?;
                let ibuf = Buf {
                    data: &inflated,
                    base: 0,
                    zsrc: Some(el.tag_pos),
                    big,
                };
                let mut ipos = 0;
                while ipos < inflated.len() {
                    let inner = next_element(&ibuf, &mut ipos, true)?;
                    match inner.mi_type {
                        MI_MATRIX => {
                            if let Some(v) = parse_variable(&inner.data)? {
                                vars.push(v);
                            }
                        }
                        MI_COMPRESSED => {
                            return Err(ibuf.corrupt(inner.tag_pos, "nested compressed element"))
                        }
                        _ => {}
                    }
                }
            }
            _ => {}
        }
    }
    Ok(vars)
}

/// Validates the header; returns whether the file is big-endian.
fn check_header(bytes: &[u8]) -> Result<bool, MatError> {
    if bytes.len() >= 10 && bytes.starts_with(b"MATLAB 7.3") {
        return Err(MatError::Hdf5);
    }
    if bytes.len() >= 520 && &bytes[512..520] == HDF5_SIGNATURE {
        return Err(MatError::Hdf5);
    }
    if bytes.starts_with(HDF5_SIGNATURE) {
        return Err(MatError::Hdf5);
    }
    if bytes.len() < HEADER_LEN {
        return Err(MatError::Truncated {
            at: Location {
                offset: 0,
                compressed_element: None,
            },
            what: "128-byte header",
            needed: HEADER_LEN,
            available: bytes.len(),
        });
    }
    let big = match &bytes[126..128] {
        b"IM" => false,
        b"MI" => true,
        other => {
            return Err(MatError::NotLevel5(format!(
                "endian indicator at byte 126 is {other:?}, expected \"IM\" or \"MI\""
            )))
        }
    };
    let vb = [bytes[124], bytes[125]];
    let version = if big {
        u16::from_be_bytes(vb)
    } else {
        u16::from_le_bytes(vb)
    };
    match version {
        0x0100 => Ok(big),
        0x0200 => Err(MatError::Hdf5),
        v => Err(MatError::NotLevel5(format!(
            "version 0x{v:04x} at byte 124, expected 0x0100"
        ))),
    }
}

/// Inflates one zlib stream, charging its output against `budget`.
fn inflate(src: &[u8], at: usize, budget: &mut usize, limit: usize) -> Result<Vec<u8>, MatError> {
    use flate2::{Decompress, FlushDecompress, Status};
    let corrupt = |r: String| MatError::Corrupt {
        at: Location {
            offset: at,
            compressed_element: None,
        },
        reason: r,
    };
    let mut d = Decompress::new(true);
    let mut out: Vec<u8> = Vec::new();
    loop {
        if out.len() == out.capacity() {
            if out.len() >= *budget {
                return Err(MatError::TooLarge { at, limit });
            }
            let room = *budget - out.len();
            // Grow geometrically, never past the remaining budget (+1 to detect overflow).
            let grow = out
                .capacity()
                .max(src.len().saturating_mul(4))
                .max(4096)
                .min(room);
            out.reserve_exact(grow);
        }
        let consumed = usize::try_from(d.total_in())
            .unwrap_or(usize::MAX)
            .min(src.len());
        let (in_before, out_before) = (d.total_in(), out.len());
        let status = d
            .decompress_vec(&src[consumed..], &mut out, FlushDecompress::None)
            .map_err(|e| corrupt(format!("zlib stream: {e}")))?;
        if out.len() > *budget {
            return Err(MatError::TooLarge { at, limit });
        }
        match status {
            Status::StreamEnd => break,
            Status::Ok | Status::BufError => {
                let progressed = d.total_in() != in_before || out.len() != out_before;
                if !progressed && out.len() < out.capacity() {
                    return Err(MatError::Truncated {
                        at: Location {
                            offset: at,
                            compressed_element: None,
                        },
                        what: "zlib stream of compressed element",
                        needed: src.len() + 1,
                        available: src.len(),
                    });
                }
            }
        }
    }
    *budget -= out.len();
    Ok(out)
}

/// Parses a top-level `miMATRIX` element's data into a named variable (`None` if empty).
fn parse_variable(buf: &Buf<'_>) -> Result<Option<Variable>, MatError> {
    if buf.data.is_empty() {
        return Ok(None);
    }
    let (name, value) = parse_matrix(buf, 0)?;
    Ok(Some(Variable { name, value }))
}

fn read_numeric(el: &Element<'_>) -> Result<Vec<f64>, MatError> {
    let b = &el.data;
    let size = match el.mi_type {
        MI_INT8 | MI_UINT8 => 1,
        MI_INT16 | MI_UINT16 => 2,
        MI_INT32 | MI_UINT32 | MI_SINGLE => 4,
        MI_DOUBLE | MI_INT64 | MI_UINT64 => 8,
        MI_UTF8 => 1, // some writers store uint8/logical data as miUTF8
        t => return Err(b.corrupt(0, format!("numeric data has non-numeric type {t}"))),
    };
    let n = b.data.len();
    if !n.is_multiple_of(size) {
        return Err(b.corrupt(0, format!("{n} data bytes are not a multiple of {size}")));
    }
    let big = b.big;
    let chunks = b.data.chunks_exact(size);
    let mut out = Vec::with_capacity(n / size);
    macro_rules! conv {
        ($t:ty, $n:expr) => {
            for c in chunks {
                let a: [u8; $n] = c.try_into().expect("chunk size");
                let v = if big {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                };
                out.push(v as f64);
            }
        };
    }
    match el.mi_type {
        MI_INT8 => conv!(i8, 1),
        MI_UINT8 | MI_UTF8 => conv!(u8, 1),
        MI_INT16 => conv!(i16, 2),
        MI_UINT16 => conv!(u16, 2),
        MI_INT32 => conv!(i32, 4),
        MI_UINT32 => conv!(u32, 4),
        MI_SINGLE => conv!(f32, 4),
        MI_DOUBLE => conv!(f64, 8),
        MI_INT64 => conv!(i64, 8),
        _ => conv!(u64, 8),
    }
    Ok(out)
}

/// Parses the sub-elements of one `miMATRIX` (non-empty) into `(name, value)`.
fn parse_matrix(buf: &Buf<'_>, depth: usize) -> Result<(String, Value), MatError> {
    if depth > MAX_DEPTH {
        return Err(buf.corrupt(0, format!("structs nested deeper than {MAX_DEPTH}")));
    }
    let mut pos = 0;

    // Array flags.
    let flags_el = next_element(buf, &mut pos, true)?;
    if flags_el.mi_type != MI_UINT32 || flags_el.data.data.len() < 4 {
        return Err(buf.corrupt(
            flags_el.tag_pos,
            "array flags: expected miUINT32 of 8 bytes",
        ));
    }
    let flags = flags_el.data.u32_at(0).unwrap_or(0);
    let class = ArrayClass::from_code((flags & 0xff) as u8);
    let complex = flags & 0x0800 != 0;
    let logical = flags & 0x0200 != 0;

    // Dimensions.
    let dims_el = next_element(buf, &mut pos, true)?;
    if dims_el.mi_type != MI_INT32 || dims_el.data.data.len() % 4 != 0 {
        return Err(buf.corrupt(dims_el.tag_pos, "dimensions: expected miINT32 array"));
    }
    let nd = dims_el.data.data.len() / 4;
    if nd < 2 {
        return Err(buf.corrupt(
            dims_el.tag_pos,
            format!("{nd} dimensions (at least 2 needed)"),
        ));
    }
    let mut dims = Vec::with_capacity(nd);
    for i in 0..nd {
        let d = dims_el.data.u32_at(4 * i).unwrap_or(0) as i32;
        if d < 0 {
            return Err(buf.corrupt(dims_el.tag_pos, format!("negative dimension {d}")));
        }
        dims.push(d as usize);
    }
    let count = dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));

    // Name.
    let name_el = next_element(buf, &mut pos, true)?;
    if name_el.mi_type != MI_INT8 && name_el.mi_type != MI_UINT8 && name_el.mi_type != MI_UTF8 {
        return Err(buf.corrupt(name_el.tag_pos, "array name: expected miINT8"));
    }
    let name = cstr(name_el.data.data);

    if class.is_numeric() {
        let count = count.ok_or_else(|| buf.corrupt(dims_el.tag_pos, "dimensions overflow"))?;
        let re_el = next_element(buf, &mut pos, true)?;
        let real = read_numeric(&re_el)?;
        if real.len() != count {
            return Err(buf.corrupt(
                re_el.tag_pos,
                format!(
                    "real part has {} values, dimensions {} need {count}",
                    real.len(),
                    dims_str(&dims)
                ),
            ));
        }
        let imag = if complex {
            let im_el = next_element(buf, &mut pos, true)?;
            let imag = read_numeric(&im_el)?;
            if imag.len() != count {
                return Err(buf.corrupt(
                    im_el.tag_pos,
                    format!("imaginary part has {} values, expected {count}", imag.len()),
                ));
            }
            Some(imag)
        } else {
            None
        };
        return Ok((
            name,
            Value::Numeric(NumericArray {
                class,
                logical,
                dims,
                real,
                imag,
            }),
        ));
    }

    if class != ArrayClass::Struct {
        // Cell, char, sparse, object, ...: the element's size is known, skip it whole.
        return Ok((name, Value::Unsupported { class, dims }));
    }

    // Struct: field name length, field names, then one miMATRIX per field per element.
    let len_el = next_element(buf, &mut pos, true)?;
    if len_el.mi_type != MI_INT32 || len_el.data.data.len() != 4 {
        return Err(buf.corrupt(len_el.tag_pos, "field name length: expected one miINT32"));
    }
    let name_len = len_el.data.u32_at(0).unwrap_or(0) as usize;
    let names_el = next_element(buf, &mut pos, true)?;
    if names_el.mi_type != MI_INT8 && names_el.mi_type != MI_UINT8 {
        return Err(buf.corrupt(names_el.tag_pos, "field names: expected miINT8"));
    }
    let nb = names_el.data.data.len();
    let nfields = match (name_len, nb) {
        (_, 0) => 0,
        (0, _) => return Err(buf.corrupt(len_el.tag_pos, "field name length 0 with field names")),
        (l, n) if n % l != 0 => {
            return Err(buf.corrupt(
                names_el.tag_pos,
                format!("{n} name bytes not a multiple of {l}"),
            ))
        }
        (l, n) => n / l,
    };
    let field_names: Vec<String> = (0..nfields)
        .map(|f| cstr(&names_el.data.data[f * name_len..(f + 1) * name_len]))
        .collect();
    let count = count.ok_or_else(|| buf.corrupt(dims_el.tag_pos, "dimensions overflow"))?;
    let nvalues = count.saturating_mul(nfields);
    // Each value needs at least an 8-byte tag: check before allocating.
    let remaining = buf.data.len().saturating_sub(pos);
    if nvalues > remaining / 8 {
        return Err(buf.truncated(pos, "struct field values", nvalues.saturating_mul(8)));
    }
    let mut values = Vec::with_capacity(nvalues);
    for _ in 0..nvalues {
        let el = next_element(buf, &mut pos, true)?;
        if el.mi_type != MI_MATRIX {
            return Err(buf.corrupt(
                el.tag_pos,
                format!("struct field: expected miMATRIX, found type {}", el.mi_type),
            ));
        }
        if el.data.data.is_empty() {
            values.push(Value::Empty);
        } else {
            values.push(parse_matrix(&el.data, depth + 1)?.1);
        }
    }
    Ok((
        name,
        Value::Struct(StructArray {
            dims,
            field_names,
            values,
        }),
    ))
}

/// Bytes up to the first NUL, as text.
fn cstr(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).into_owned()
}

// ---------------------------------------------------------------------------------------------
#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    /// Builds MAT-file bytes in either byte order.
    struct W {
        big: bool,
        /// Use the packed small-element form where the data fits in 4 bytes.
        small: bool,
    }

    impl W {
        fn u32b(&self, v: u32) -> [u8; 4] {
            if self.big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        }

        /// A data element with padding to 8 bytes.
        fn elem(&self, ty: u32, data: &[u8]) -> Vec<u8> {
            let mut out = Vec::new();
            if self.small && data.len() <= 4 && !data.is_empty() {
                out.extend(self.u32b(((data.len() as u32) << 16) | ty));
                out.extend(data);
                out.resize(8, 0);
                return out;
            }
            out.extend(self.u32b(ty));
            out.extend(self.u32b(data.len() as u32));
            out.extend(data);
            while out.len() % 8 != 0 {
                out.push(0);
            }
            out
        }

        fn i32s(&self, v: &[i32]) -> Vec<u8> {
            v.iter().flat_map(|&x| self.u32b(x as u32)).collect()
        }

        fn f64s(&self, v: &[f64]) -> Vec<u8> {
            v.iter()
                .flat_map(|&x| {
                    if self.big {
                        x.to_be_bytes()
                    } else {
                        x.to_le_bytes()
                    }
                })
                .collect()
        }

        fn i16s(&self, v: &[f64]) -> Vec<u8> {
            v.iter()
                .flat_map(|&x| {
                    let x = x as i16;
                    if self.big {
                        x.to_be_bytes()
                    } else {
                        x.to_le_bytes()
                    }
                })
                .collect()
        }

        fn f32s(&self, v: &[f64]) -> Vec<u8> {
            v.iter()
                .flat_map(|&x| {
                    let x = x as f32;
                    if self.big {
                        x.to_be_bytes()
                    } else {
                        x.to_le_bytes()
                    }
                })
                .collect()
        }

        /// A full miMATRIX element.
        fn matrix(&self, class: u8, dims: &[i32], name: &str, body: &[u8]) -> Vec<u8> {
            let mut c = Vec::new();
            let flags = [class as u32, 0];
            c.extend(self.elem(
                MI_UINT32,
                &flags.iter().flat_map(|&f| self.u32b(f)).collect::<Vec<_>>(),
            ));
            c.extend(self.elem(MI_INT32, &self.i32s(dims)));
            c.extend(self.elem(MI_INT8, name.as_bytes()));
            c.extend(body);
            assert_eq!(c.len() % 8, 0);
            let mut out = Vec::new();
            out.extend(self.u32b(MI_MATRIX));
            out.extend(self.u32b(c.len() as u32));
            out.extend(c);
            out
        }

        fn double(&self, name: &str, rows: usize, cols: usize, colmajor: &[f64]) -> Vec<u8> {
            self.matrix(
                6,
                &[rows as i32, cols as i32],
                name,
                &self.elem(MI_DOUBLE, &self.f64s(colmajor)),
            )
        }

        fn structure(&self, name: &str, fields: &[(&str, Vec<u8>)]) -> Vec<u8> {
            let l = 32;
            let mut names = vec![0u8; l * fields.len()];
            for (i, (n, _)) in fields.iter().enumerate() {
                names[i * l..i * l + n.len()].copy_from_slice(n.as_bytes());
            }
            let mut body = self.elem(MI_INT32, &self.i32s(&[l as i32]));
            body.extend(self.elem(MI_INT8, &names));
            for (_, m) in fields {
                body.extend(m);
            }
            self.matrix(2, &[1, 1], name, &body)
        }

        fn header(&self, text: &str) -> Vec<u8> {
            let mut h = vec![b' '; 116];
            h[..text.len()].copy_from_slice(text.as_bytes());
            h.extend([0u8; 8]);
            h.extend(if self.big { [1u8, 0] } else { [0u8, 1] });
            h.extend(if self.big { *b"MI" } else { *b"IM" });
            h
        }

        fn file(&self, elements: &[Vec<u8>]) -> Vec<u8> {
            let mut f = self.header("MATLAB 5.0 MAT-file, Platform: test, Created on: today");
            for e in elements {
                f.extend(e);
            }
            f
        }

        fn compressed(&self, element: &[u8]) -> Vec<u8> {
            let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
            z.write_all(element).unwrap();
            let z = z.finish().unwrap();
            let mut out = Vec::new();
            out.extend(self.u32b(MI_COMPRESSED));
            out.extend(self.u32b(z.len() as u32));
            out.extend(z);
            out
        }
    }

    /// Value of joint `j`, sample `t`, axis `a`.
    fn val(j: usize, t: usize, a: usize) -> f64 {
        (j * 1000 + t * 10 + a) as f64 + 0.25
    }

    /// Column-major (T, 3) data for joint `j`.
    fn joint_data(j: usize, t: usize) -> Vec<f64> {
        (0..3)
            .flat_map(|a| (0..t).map(move |s| val(j, s, a)))
            .collect()
    }

    fn xyzpos(w: &W, order: &[usize], t: usize) -> Vec<u8> {
        let fields: Vec<(&str, Vec<u8>)> = order
            .iter()
            .map(|&j| (DHP19_JOINTS[j], w.double("", t, 3, &joint_data(j, t))))
            .collect();
        w.structure("XYZPOS", &fields)
    }

    fn check_all(v: &Vicon, t: usize) {
        let joints = v.dhp19_order().unwrap();
        assert_eq!(joints.len(), 13);
        for (j, s) in joints.iter().enumerate() {
            assert_eq!(s.len(), t);
            for (i, p) in s.iter().enumerate() {
                assert_eq!(
                    *p,
                    [val(j, i, 0), val(j, i, 1), val(j, i, 2)],
                    "joint {j} sample {i}"
                );
            }
        }
        let frames = v.dhp19_frames().unwrap();
        assert_eq!(frames.len(), t);
        assert_eq!(
            frames[t - 1][12],
            [val(12, t - 1, 0), val(12, t - 1, 1), val(12, t - 1, 2)]
        );
    }

    fn variants() -> Vec<(W, bool)> {
        let mut v = Vec::new();
        for big in [false, true] {
            for small in [false, true] {
                for z in [false, true] {
                    v.push((W { big, small }, z));
                }
            }
        }
        v
    }

    #[test]
    fn roundtrip_all_byte_orders_forms_and_compression() {
        let order: Vec<usize> = (0..13).collect();
        for (w, z) in variants() {
            let m = xyzpos(&w, &order, 5);
            let f = w.file(&[if z { w.compressed(&m) } else { m }]);
            let v = read_xyzpos(&f)
                .unwrap_or_else(|e| panic!("big={} small={} z={z}: {e}", w.big, w.small));
            let names: Vec<&str> = v.joints.iter().map(|(n, _)| n.as_str()).collect();
            assert_eq!(names, DHP19_JOINTS);
            check_all(&v, 5);
        }
    }

    #[test]
    fn column_major_layout() {
        let w = W {
            big: false,
            small: true,
        };
        // 2x3 matrix [[1,2,3],[4,5,6]] stored column-major as 1,4,2,5,3,6.
        let f = w.file(&[w.double("A", 2, 3, &[1.0, 4.0, 2.0, 5.0, 3.0, 6.0])]);
        let vars = read_variables(&f).unwrap();
        let Value::Numeric(a) = &vars[0].value else {
            panic!()
        };
        assert_eq!(a.dims, vec![2, 3]);
        assert_eq!(a.get(0, 1), Some(2.0));
        assert_eq!(a.get(1, 0), Some(4.0));
        assert_eq!(a.get(1, 2), Some(6.0));
        assert_eq!(a.get(2, 0), None);
    }

    #[test]
    fn maps_by_name_not_position_and_ignores_case() {
        let w = W {
            big: true,
            small: true,
        };
        // hipL before hipR, footL first, reversed; one name upper-cased.
        let order: Vec<usize> = (0..13).rev().collect();
        let fields: Vec<(String, Vec<u8>)> = order
            .iter()
            .map(|&j| {
                let n = if j == 0 {
                    "HEAD".to_string()
                } else {
                    DHP19_JOINTS[j].to_string()
                };
                (n, w.double("", 3, 3, &joint_data(j, 3)))
            })
            .collect();
        let fr: Vec<(&str, Vec<u8>)> = fields
            .iter()
            .map(|(n, m)| (n.as_str(), m.clone()))
            .collect();
        let f = w.file(&[w.compressed(&w.structure("XYZPOS", &fr))]);
        let v = read_xyzpos(&f).unwrap();
        assert_eq!(v.joints[0].0, "footL");
        assert_eq!(v.joints[12].0, "HEAD");
        check_all(&v, 3);
    }

    #[test]
    fn narrowed_storage_types_and_single_class() {
        for big in [false, true] {
            let w = W { big, small: true };
            let data = [1.0, -2.0, 300.0, 4.0, 5.0, -6.0];
            let a = w.matrix(6, &[2, 3], "a", &w.elem(MI_INT16, &w.i16s(&data)));
            let b = w.matrix(
                7,
                &[2, 3],
                "b",
                &w.elem(MI_SINGLE, &w.f32s(&[0.5, 1.5, 2.5, 3.5, 4.5, 5.5])),
            );
            let u8s: Vec<u8> = vec![1, 2, 3];
            let c = w.matrix(9, &[1, 3], "c", &w.elem(MI_UINT8, &u8s));
            let f = w.file(&[a, w.compressed(&b), c]);
            let vars = read_variables(&f).unwrap();
            assert_eq!(vars.len(), 3);
            let Value::Numeric(a) = &vars[0].value else {
                panic!()
            };
            assert_eq!(a.real, data.to_vec());
            assert_eq!(a.class, ArrayClass::Double);
            let Value::Numeric(b) = &vars[1].value else {
                panic!()
            };
            assert_eq!(b.class, ArrayClass::Single);
            assert_eq!(b.get(1, 2), Some(5.5));
            let Value::Numeric(c) = &vars[2].value else {
                panic!()
            };
            assert_eq!(c.real, vec![1.0, 2.0, 3.0]);
        }
    }

    #[test]
    fn skips_other_classes_and_keeps_nan() {
        let w = W {
            big: false,
            small: true,
        };
        let chars = w.matrix(4, &[1, 2], "s", &w.elem(MI_UINT16, &[104, 0, 105, 0]));
        let cell = w.matrix(1, &[1, 1], "c", &w.double("", 1, 1, &[7.0]));
        // A NaN as the first x of `head`.
        let mut d = joint_data(0, 2);
        d[0] = f64::NAN;
        let fields: Vec<(&str, Vec<u8>)> = (0..13)
            .map(|j| {
                (
                    DHP19_JOINTS[j],
                    w.double("", 2, 3, &if j == 0 { d.clone() } else { joint_data(j, 2) }),
                )
            })
            .collect();
        let m = w.structure("XYZPOS", &fields);
        let f = w.file(&[chars, w.compressed(&cell), m]);
        let vars = read_variables(&f).unwrap();
        assert!(matches!(
            vars[0].value,
            Value::Unsupported {
                class: ArrayClass::Char,
                ..
            }
        ));
        assert!(matches!(
            vars[1].value,
            Value::Unsupported {
                class: ArrayClass::Cell,
                ..
            }
        ));
        let v = read_xyzpos(&f).unwrap();
        let j = v.dhp19_order().unwrap();
        assert!(j[0][0][0].is_nan());
        assert_eq!(j[0][0][1], val(0, 0, 1));
    }

    #[test]
    fn missing_joint_is_named() {
        let w = W {
            big: false,
            small: false,
        };
        let order: Vec<usize> = (0..13).filter(|&j| j != 6).collect(); // no hipL
        let f = w.file(&[xyzpos(&w, &order, 4)]);
        let v = read_xyzpos(&f).unwrap();
        match v.dhp19_order() {
            Err(MatError::MissingJoint(n)) => assert_eq!(n, "hipL"),
            other => panic!("{other:?}"),
        }
        assert!(v.dhp19_order().unwrap_err().to_string().contains("hipL"));
    }

    #[test]
    fn length_mismatch_is_an_error() {
        let w = W {
            big: false,
            small: true,
        };
        let fields: Vec<(&str, Vec<u8>)> = (0..13)
            .map(|j| {
                let t = if j == 9 { 3 } else { 4 };
                (DHP19_JOINTS[j], w.double("", t, 3, &joint_data(j, t)))
            })
            .collect();
        let f = w.file(&[w.structure("XYZPOS", &fields)]);
        let e = read_xyzpos(&f).unwrap().dhp19_order().unwrap_err();
        assert!(
            matches!(e, MatError::LengthMismatch { ref joint, len: 3, .. } if joint == "kneeR"),
            "{e}"
        );
    }

    #[test]
    fn wrong_shape_and_missing_variable() {
        let w = W {
            big: false,
            small: true,
        };
        let f = w.file(&[w.structure("XYZPOS", &[("head", w.double("", 3, 2, &[0.0; 6]))])]);
        assert!(matches!(read_xyzpos(&f), Err(MatError::WrongType { .. })));
        let f = w.file(&[w.double("other", 1, 1, &[1.0])]);
        assert!(matches!(read_xyzpos(&f), Err(MatError::MissingVariable(_))));
    }

    #[test]
    fn v73_and_hdf5_are_refused() {
        let w = W {
            big: false,
            small: true,
        };
        let mut f =
            w.header("MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: x HDF5 schema 1.00 .");
        f[124] = 0;
        f[125] = 2;
        f.resize(1024, 0);
        f[512..520].copy_from_slice(HDF5_SIGNATURE);
        assert!(matches!(read_xyzpos(&f), Err(MatError::Hdf5)));
        // The signature alone, with some other header text.
        let mut g = w.header("something");
        g.resize(600, 0);
        g[512..520].copy_from_slice(HDF5_SIGNATURE);
        assert!(matches!(read_variables(&g), Err(MatError::Hdf5)));
        // Version 0x0200 alone.
        let mut h = w.header("MATLAB 5.0");
        h[124] = 0;
        h[125] = 2;
        assert!(matches!(read_variables(&h), Err(MatError::Hdf5)));
        assert!(MatError::Hdf5.to_string().contains("v7.3"));
    }

    #[test]
    fn bad_headers() {
        assert!(matches!(
            read_variables(b"short"),
            Err(MatError::Truncated { .. })
        ));
        let mut f = W {
            big: false,
            small: true,
        }
        .header("MATLAB 5.0");
        f[126] = b'X';
        assert!(matches!(read_variables(&f), Err(MatError::NotLevel5(_))));
        let w = W {
            big: false,
            small: true,
        };
        assert!(read_variables(&w.file(&[])).unwrap().is_empty());
    }

    #[test]
    fn truncation_at_every_byte_errors() {
        let order: Vec<usize> = (0..13).collect();
        for (w, z) in variants() {
            let m = xyzpos(&w, &order, 2);
            let f = w.file(&[if z { w.compressed(&m) } else { m }]);
            assert!(read_xyzpos(&f).is_ok());
            for cut in 0..f.len() {
                let r = read_xyzpos(&f[..cut]);
                assert!(
                    r.is_err(),
                    "cut at {cut} of {} (big={} small={} z={z}) gave Ok",
                    f.len(),
                    w.big,
                    w.small
                );
            }
        }
    }

    #[test]
    fn truncation_error_names_offset() {
        let w = W {
            big: false,
            small: true,
        };
        let f = w.file(&[w.double("A", 1, 1, &[1.0])]);
        let e = read_variables(&f[..f.len() - 3]).unwrap_err();
        match e {
            MatError::Truncated { at, .. } => assert_eq!(at.offset, 136),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn corrupted_bytes_never_panic() {
        let order: Vec<usize> = (0..13).collect();
        let mut seed: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut rnd = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for (w, z) in variants() {
            let m = xyzpos(&w, &order, 3);
            let f = w.file(&[if z { w.compressed(&m) } else { m }]);
            for _ in 0..400 {
                let mut g = f.clone();
                for _ in 0..(1 + rnd() % 4) {
                    let i = HEADER_LEN + (rnd() as usize) % (g.len() - HEADER_LEN);
                    g[i] = match rnd() % 4 {
                        0 => 0xff,
                        1 => 0,
                        _ => rnd() as u8,
                    };
                }
                let _ = read_xyzpos(&g).and_then(|v| v.dhp19_order());
            }
            // Every single-byte 0xff at every position.
            for i in HEADER_LEN..f.len() {
                let mut g = f.clone();
                g[i] ^= 0xff;
                let _ = read_xyzpos(&g).and_then(|v| v.dhp19_order());
            }
        }
    }

    #[test]
    fn huge_declared_sizes_do_not_allocate() {
        let w = W {
            big: false,
            small: false,
        };
        // A struct with dims 2^31-1 x 2^31-1 and one field, nothing after it.
        let names = {
            let mut n = vec![0u8; 8];
            n[..4].copy_from_slice(b"head");
            n
        };
        let mut body = w.elem(MI_INT32, &w.i32s(&[8]));
        body.extend(w.elem(MI_INT8, &names));
        let m = w.matrix(2, &[i32::MAX, i32::MAX], "XYZPOS", &body);
        assert!(read_variables(&w.file(&[m])).is_err());
        // A tag declaring 4 GiB.
        let mut f = w.file(&[]);
        f.extend(w.u32b(MI_MATRIX));
        f.extend(w.u32b(u32::MAX));
        assert!(matches!(
            read_variables(&f),
            Err(MatError::Truncated { .. })
        ));
    }

    #[test]
    fn zip_bomb_is_capped() {
        let w = W {
            big: false,
            small: false,
        };
        let big = w.double("Z", 100_000, 1, &vec![0.0; 100_000]); // 800 kB of zeros
        let f = w.file(&[w.compressed(&big)]);
        assert!(f.len() < 10_000);
        assert!(matches!(
            read_variables_limited(&f, 64 * f.len()),
            Err(MatError::TooLarge { .. })
        ));
        assert!(read_variables_limited(&f, 1 << 20).is_ok());
        assert_eq!(decompression_limit(1), MIN_DECOMPRESSION_ALLOWANCE);
        assert_eq!(decompression_limit(usize::MAX), MAX_DECOMPRESSED_BYTES);
    }

    #[test]
    fn empty_field_and_struct_array_shapes() {
        let w = W {
            big: true,
            small: true,
        };
        let empty = {
            let mut e = Vec::new();
            e.extend(w.u32b(MI_MATRIX));
            e.extend(w.u32b(0));
            e
        };
        let f = w.file(&[w.structure("S", &[("a", empty), ("b", w.double("", 1, 1, &[2.0]))])]);
        let vars = read_variables(&f).unwrap();
        let Value::Struct(s) = &vars[0].value else {
            panic!()
        };
        assert_eq!(s.field(0, "a"), Some(&Value::Empty));
        assert!(matches!(s.field(0, "b"), Some(Value::Numeric(_))));
        let empty_joint = w.structure("XYZPOS", &[("head", w.double("", 0, 3, &[]))]);
        assert_eq!(
            read_xyzpos(&w.file(&[empty_joint])).unwrap().joints[0]
                .1
                .len(),
            0
        );
    }

    /// `scipy.io.savemat(..., do_compression=True)` (SciPy 1.17.1) of `XYZPOS` (13 fields, T = 7,
    /// value `j*1000 + t*10 + axis + 0.25` for joint `j` of a list with hipL before hipR,
    /// `head[2][1]` NaN), a char `note`, a cell `cellv` and an int16 `i16`: an independent writer.
    const SCIPY_V5_ZLIB: &str = concat!(
        "4d41544c414220352e30204d41542d66696c6520506c6174666f726d3a20706f7369782c2043726561746564206f6e3a",
        "20547565204465632020312032313a30363a333320323032360000000000000000000000000000000000000000000000",
        "000000000000000000000000000000000000000000000000000000000001494d0f000000d4020000789ca5cfcd4bd371",
        "1cc0f15f6666119e2b0a1644f80744c7fc297ad046c632510f95b6c5b4e9e673e8d4296a3ea5736ee6960f9f54dc029f",
        "d283a586999ad70e115e0b82924ed1a163dbbeef5674fd0d7ebcbedb77efcff649d3342dfd94a6a5444d8d3e499a7a1d",
        "e3fd917f9ed8778a8a4b6ee4df8cdd276b27f9bc23fad86da55655d6da9df50eabadc6923899359ba3ccd96889ddc64f",
        "e6d8c95eee32ab227ab2702aadb25a122775fda0ca66b3244eeab3fb4e679d2571624cfc95167d0eb4bffba4fcb7cff1",
        "e87394ff1d7b9d883e9144fd3e238ee7a21e57bf8c5795a66cccc5eb4aed27dd25deff6a535d867a2f7442277fba24a5",
        "279ddfb9c25c1d73300ff37543fb650da9393efc8c67bcca4c2cc761cce37b213cc4f3dce7602506d0c2f7a6f1075ee0",
        "3e17ab31e835b65fe614ff1f87f1157e527a9245795af8ffdc5762005fe317ba14bab374b9dc576310b7f11b5d2add39",
        "31b49fc71556733a710ce7f10d7ec0af5883dd18c2457c8b1ff110ebb007c7711977f100bf878deda72fa93905684737",
        "7a71165f6216166205b6a20fe7701db3b1081de8413f467073c9d07e7acf6a7c8eeec3719cc3655cc75decc5119cc030",
        "bec00ddcc33ef4e32446700537f1ddaab1fd5c6b6a4e1376e2208ee134ce63353663170e61106770016bd08ddde8c510",
        "cee2e29ab1fd8a36d49c327460037ab00ffd588cf7b0121bb11dfb31802568c52a7c881d3880a31bc6f6d3b7d49c3c2c",
        "c0db68c71a7463265ec35b7807cbb1165b300bcd588877b102ebb075cbd07e26ff767c8e2988933883115cc015a5d009",
        "9dd0099dd0099dd0990218c2299cc5e7b888abdbc6f6ebd951731ea30f9fe0383ec339a5d0099dd0099dd0099dd0997a",
        "711047700c27701ac33bc6f673efa939edd88dfde8c500869442277442277442277442676ac10e7c8403388ca3f874cf",
        "d87eae7d35a71e9bb00d3bb11707954227744227744227744267aac6066c460f76611f0eedebbf0133b404be0f000000",
        "2c000000789ce3636060b000623620e600621606086085f219a16c46a04c5e7e49aa00949f919a93930fa40144e50450",
        "0f00000039000000789ce3636060d800c46c40cc01c48c0c10c08ac46782d220b1e4d49c9c3220cd07c41648faf8b0e8",
        "6344328f07cd7c72f53341f9000a2104090f0000002c000000789ce3636060b000623620e600622e06086085f299a098",
        "91819921d3d00c4842c441fc7fff5918002fb40354",
    );

    fn unhex(s: &str) -> Vec<u8> {
        (0..s.len() / 2)
            .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
            .collect()
    }

    #[test]
    fn reads_a_scipy_written_file() {
        let f = unhex(SCIPY_V5_ZLIB);
        let vars = read_variables(&f).unwrap();
        let names: Vec<&str> = vars.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names, ["XYZPOS", "note", "cellv", "i16"]);
        assert!(matches!(
            vars[1].value,
            Value::Unsupported {
                class: ArrayClass::Char,
                ..
            }
        ));
        assert!(matches!(
            vars[2].value,
            Value::Unsupported {
                class: ArrayClass::Cell,
                ..
            }
        ));
        let Value::Numeric(i) = &vars[3].value else {
            panic!()
        };
        assert_eq!(
            (i.class, i.get(0, 1), i.get(1, 0)),
            (ArrayClass::Int16, Some(-2.0), Some(3.0))
        );
        let v = read_xyzpos(&f).unwrap();
        assert_eq!(v.joints[5].0, "hipL");
        let j = v.dhp19_order().unwrap();
        // File index of each evpose joint in the fixture's list (hipL 5, hipR 6 swapped).
        let file_idx = [0, 1, 2, 3, 4, 6, 5, 7, 8, 9, 10, 11, 12];
        for (k, s) in j.iter().enumerate() {
            assert_eq!(s.len(), 7);
            for (t, p) in s.iter().enumerate() {
                for (a, &x) in p.iter().enumerate() {
                    if k == 0 && t == 2 && a == 1 {
                        assert!(x.is_nan());
                    } else {
                        assert_eq!(x, val(file_idx[k], t, a), "joint {k} t {t} axis {a}");
                    }
                }
            }
        }
        // Cutting inside XYZPOS's element fails; cutting elsewhere fails or yields a prefix of
        // the variables (a cut exactly between two elements leaves a valid, shorter file).
        let xyz_end = 128 + 8 + u32::from_le_bytes(f[132..136].try_into().unwrap()) as usize;
        for cut in 0..f.len() {
            match read_variables(&f[..cut]) {
                Err(_) => {}
                Ok(vs) => {
                    assert!((cut == 128 || cut >= xyz_end) && vs.len() < 4, "cut {cut}");
                    assert!(
                        vs.iter().zip(&vars).all(|(a, b)| a.name == b.name),
                        "cut {cut}"
                    );
                }
            }
            if cut < xyz_end {
                assert!(read_xyzpos(&f[..cut]).is_err(), "cut {cut}");
            }
        }
    }

    #[test]
    fn truncated_zlib_stream_with_consistent_tag_errors() {
        let w = W {
            big: false,
            small: true,
        };
        let m = w.double("A", 4, 3, &[1.5; 12]);
        let full = w.compressed(&m);
        for keep in 0..full.len() - 8 {
            let mut el = Vec::new();
            el.extend(w.u32b(MI_COMPRESSED));
            el.extend(w.u32b(keep as u32));
            el.extend(&full[8..8 + keep]);
            let r = read_variables(&w.file(&[el]));
            assert!(r.is_err(), "keep {keep} of {}", full.len() - 8);
        }
    }

    #[test]
    fn vicon_index_matches_dhp19() {
        // MATLAB: int64(d) * 0.0001 rounds (halves away from zero), floor() keeps it.
        assert_eq!(vicon_index(1_000, 1_000), Some(0));
        assert_eq!(vicon_index(1_000 + 4_999, 1_000), Some(0));
        assert_eq!(vicon_index(1_000 + 5_000, 1_000), Some(1));
        assert_eq!(vicon_index(1_000 + 9_999, 1_000), Some(1));
        assert_eq!(vicon_index(1_000 + 14_999, 1_000), Some(1));
        assert_eq!(vicon_index(1_000 + 15_000, 1_000), Some(2));
        assert_eq!(vicon_index(999, 1_000), None);
        // u64::MAX ends in ...1615: below half a sample; no overflow in the rounding.
        assert_eq!(
            vicon_index(u64::MAX, 0),
            usize::try_from(u64::MAX / 10_000).ok()
        );
    }
}
