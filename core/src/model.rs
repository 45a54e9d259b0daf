//! The model blob (`.evq`): a PointNet-SimDR network read in place from `&[u8]` (flash on an MCU).
//!
//! # The network family
//! Per point: a DAG of 1×1 layers, each reading the concatenation of the input features and/or
//! earlier layers' outputs (the paper: conv1 → conv2 → conv3 → conv4, conv5 on their
//! concatenation); the last point layer is pooled over all points by max and by mean,
//! concatenated `[max, mean]`; then a chain of fully connected layers; the last one's output is
//! read as `J × D`, and two heads shared by all joints map each `D`-vector to `W` x-logits and `H`
//! y-logits.
//!
//! # Layout (little-endian)
//! ```text
//! 0   magic "EVPQ"          4   version u16         6   dtype u8 (0 f32, 1 int8)   7 reserved
//! 8   total length u32      12  CRC-32 (ISO-HDLC) of bytes 16..total
//! 16  layer count u16       18  point layers u16    20  joints u16   22 width u16  24 height u16
//! 26  head dim u16          28  input shifts [u8; 5] + 3 reserved
//! 36  average-pool constant f32 (int8)             40  table offset u32   44  data offset u32
//! 48  points N u32 (0: any)   52  window events u32 (0: unstated)   56  time slices K u8
//!     (0: unstated)           57  reserved (7 bytes)          (version 2; version 1: all 0)
//! 64  layer table: one 32-byte entry per layer, in order: point layers, FC layers, head x, head y
//!     0 kind u8 (0 point, 1 fc, 2 head x, 3 head y)   1 flags u8 (bit 0 LeakyReLU)
//!     2 weight type u8 (0 f32, 1 i8, 2 i16)           3 reserved
//!     4 in dim u32   8 out dim u32   12 sources u32 (point layers: bit 0 = input features,
//!       bit i = point layer i − 1)   16 weights offset   20 bias offset   24 scales offset
//!       (0: none)   28 LeakyReLU alpha f32
//! data: arrays at 16-byte-aligned offsets: weights `[out][in]`, bias `[out]` (f32 or i32),
//!       scales `[out]` f32 (int8 requantization multipliers; on int8 heads, version 3, the
//!       dequantization multipliers: logit = accumulator × scale)
//! ```
//! [`Model::parse`] checks the magic, version, checksum, every offset, size and alignment, and
//! that the dimensions chain; after that, reading the model cannot fail. The offsets are named
//! once, in [`header`] and [`entry`], for the parser and the host's writer.
//!
//! Bytes 48–56 carry the preprocessing the model was trained for ([`Preprocessing`]: points per
//! input, events per window, time slices), so the contract travels with the weights. Version 1
//! blobs (before these fields) still parse, with the fields unstated. Version 3 lets int8 heads
//! carry the scale of their logits ([`Model::head_scales`]), which joint confidences need;
//! version 1 and 2 blobs parse without it.

use core::fmt;

use bytemuck::Pod;

/// Byte offsets of the header fields.
pub mod header {
    /// Magic, 4 bytes.
    pub const MAGIC: usize = 0;
    /// Version, u16.
    pub const VERSION: usize = 4;
    /// Number format, u8.
    pub const DTYPE: usize = 6;
    /// Reserved, u8 (zero).
    pub const RESERVED: usize = 7;
    /// Total length, u32.
    pub const TOTAL: usize = 8;
    /// CRC-32 of bytes `CRC_FROM..total`, u32.
    pub const CRC: usize = 12;
    /// First byte the CRC covers.
    pub const CRC_FROM: usize = 16;
    /// Layer count, u16.
    pub const LAYERS: usize = 16;
    /// Point layer count, u16.
    pub const POINT_LAYERS: usize = 18;
    /// Joints, u16.
    pub const JOINTS: usize = 20;
    /// SimDR width, u16.
    pub const WIDTH: usize = 22;
    /// SimDR height, u16.
    pub const HEIGHT: usize = 24;
    /// Head dimension, u16.
    pub const HEAD_DIM: usize = 26;
    /// Input shifts, `[u8; 5]`.
    pub const INPUT_SHIFTS: usize = 28;
    /// Average-pool constant, f32.
    pub const AVG_SCALE: usize = 36;
    /// Layer table offset, u32.
    pub const TABLE: usize = 40;
    /// Data offset, u32.
    pub const DATA: usize = 44;
    /// Points per input, u32 (version 2).
    pub const POINTS: usize = 48;
    /// Events per window, u32 (version 2).
    pub const WINDOW_EVENTS: usize = 52;
    /// Time slices, u8 (version 2).
    pub const SLICES: usize = 56;
}

/// Byte offsets of the fields of a layer-table entry.
pub mod entry {
    /// Kind, u8.
    pub const KIND: usize = 0;
    /// Flags, u8 (bit 0: LeakyReLU).
    pub const FLAGS: usize = 1;
    /// Weight type, u8.
    pub const WEIGHT_TYPE: usize = 2;
    /// Input width, u32.
    pub const IN_DIM: usize = 4;
    /// Output width, u32.
    pub const OUT_DIM: usize = 8;
    /// Sources bitmask, u32.
    pub const SOURCES: usize = 12;
    /// Weights offset, u32.
    pub const WEIGHTS: usize = 16;
    /// Bias offset, u32.
    pub const BIAS: usize = 20;
    /// Scales offset, u32 (0: none).
    pub const SCALES: usize = 24;
    /// LeakyReLU slope, f32.
    pub const ALPHA: usize = 28;
}

/// The preprocessing a model expects, recorded in its blob (0: unstated, the caller's default
/// applies).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Preprocessing {
    /// Points per network input, `N` (0: any).
    pub points: u32,
    /// Events per window (0: unstated).
    pub window_events: u32,
    /// Time slices `K` of the rasterization (0: unstated).
    pub slices: u8,
}

/// First bytes of a blob.
pub const MAGIC: [u8; 4] = *b"EVPQ";
/// Format version this crate writes (2: with [`Preprocessing`]; 3: int8 heads may carry
/// their logit scale); it reads versions 1 to 3.
pub const VERSION: u16 = 3;
/// Size of the fixed header.
pub const HEADER_LEN: usize = 64;
/// Size of one layer-table entry.
pub const ENTRY_LEN: usize = 32;
/// Alignment of every array in the data section.
pub const ALIGN: usize = 16;
/// Most layers a blob may hold.
pub const MAX_LAYERS: usize = 32;
/// Most point layers (the sources bitmask has 32 bits, bit 0 is the input).
pub const MAX_POINT_LAYERS: usize = 16;
/// Point features per point: `[x, y, t_avg, p_acc, cnt]`.
pub const FEATURES: usize = 5;

/// The CRC used for the checksum (CRC-32/ISO-HDLC, the zlib one), with [`CrcTable`]'s tables.
pub const CRC: crc::Crc<u32, CrcTable> = crc::Crc::<u32, CrcTable>::new(&crc::CRC_32_ISO_HDLC);

/// The lookup tables of [`CRC`]: 1 KiB, a byte per step, by default (an MCU's flash); 16 KiB,
/// 16 bytes per step, with the feature `fast-crc` (hosts: [`Model::parse`] of the paper model's
/// 4.6 MB int8 blob took 8.7 ms with the first, 0.9 ms with the second, on a Zen 5). The same
/// checksum either way.
pub type CrcTable = crc::Table<
    {
        if cfg!(feature = "fast-crc") {
            16
        } else {
            1
        }
    },
>;

/// Number format of a blob.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DType {
    /// f32 weights and arithmetic (the float reference path).
    F32 = 0,
    /// int8 weights and activations, int32 accumulators.
    I8 = 1,
}

impl fmt::Display for DType {
    /// `f32` or `int8`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Self::F32 => "f32",
            Self::I8 => "int8",
        })
    }
}

/// Role of a layer.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LayerKind {
    /// A 1×1 layer applied to every point.
    Point = 0,
    /// A fully connected layer after pooling.
    Fc = 1,
    /// The x head (`D → W`, shared by all joints).
    HeadX = 2,
    /// The y head (`D → H`).
    HeadY = 3,
}

/// Element type of a weight array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WeightType {
    /// f32.
    F32 = 0,
    /// i8.
    I8 = 1,
    /// i16 (the int8 model's first layer).
    I16 = 2,
}

impl WeightType {
    /// Bytes per element.
    pub const fn size(self) -> usize {
        match self {
            Self::F32 => 4,
            Self::I8 => 1,
            Self::I16 => 2,
        }
    }
}

/// A blob the core refuses, with what is wrong.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum ModelError {
    /// Shorter than its header or its stated length.
    Truncated {
        /// Bytes needed.
        needed: usize,
        /// Bytes present.
        got: usize,
    },
    /// Not an evpose model.
    BadMagic,
    /// A format version this build does not read.
    Version(u16),
    /// The checksum does not match: the blob is corrupt.
    Checksum {
        /// CRC stored in the header.
        stored: u32,
        /// CRC of the bytes.
        computed: u32,
    },
    /// The blob does not start at a 16-byte-aligned address (weights are read in place).
    Misaligned,
    /// A header field is invalid.
    Header(&'static str),
    /// Layer `index` is invalid.
    Layer {
        /// Index in the layer table.
        index: u8,
        /// What is wrong.
        reason: &'static str,
    },
}

impl fmt::Display for ModelError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match *self {
            Self::Truncated { needed, got } => {
                write!(f, "model blob truncated: needs {needed} bytes, has {got}")
            }
            Self::BadMagic => write!(f, "not an evpose model blob (bad magic)"),
            Self::Version(v) => {
                write!(f, "model blob version {v}, this build reads 1 to {VERSION}")
            }
            Self::Checksum { stored, computed } => write!(
                f,
                "model blob corrupt: checksum {computed:08x}, header says {stored:08x}"
            ),
            Self::Misaligned => write!(f, "model blob must start at a 16-byte-aligned address"),
            Self::Header(what) => write!(f, "model blob header: {what}"),
            Self::Layer { index, reason } => write!(f, "model blob layer {index}: {reason}"),
        }
    }
}

impl core::error::Error for ModelError {}

/// A validated layer-table entry.
#[derive(Clone, Copy, Debug, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LayerDesc {
    /// Role.
    pub kind: LayerKind,
    /// Input width.
    pub in_dim: u32,
    /// Output width.
    pub out_dim: u32,
    /// Point layers: bit 0 = input features, bit `i` = point layer `i − 1`.
    pub sources: u32,
    /// LeakyReLU slope, when the layer has one.
    pub leaky: Option<f32>,
    /// Weight element type.
    pub weight_type: WeightType,
    weights: u32,
    bias: u32,
    scales: u32,
}

/// Weights of one layer, `[out][in]`, borrowed from the blob.
#[derive(Clone, Copy, Debug)]
pub enum Weights<'a> {
    /// f32 weights.
    F32(&'a [f32]),
    /// i8 weights.
    I8(&'a [i8]),
    /// i16 weights.
    I16(&'a [i16]),
}

/// Bias of one layer, borrowed from the blob.
#[derive(Clone, Copy, Debug)]
pub enum Bias<'a> {
    /// f32 bias (f32 models).
    F32(&'a [f32]),
    /// i32 bias in accumulator units (int8 models).
    I32(&'a [i32]),
}

/// One layer's parameters, borrowed from the blob.
#[derive(Clone, Copy, Debug)]
pub struct Layer<'a> {
    /// The table entry.
    pub desc: LayerDesc,
    /// `[out][in]` weights.
    pub weights: Weights<'a>,
    /// `[out]` bias.
    pub bias: Bias<'a>,
    /// `[out]` requantization multipliers (int8 point and FC layers), else empty.
    pub scales: &'a [f32],
}

/// A validated model blob.
#[derive(Clone, Copy, Debug)]
pub struct Model<'a> {
    blob: &'a [u8],
    version: u16,
    dtype: DType,
    layers: [Option<LayerDesc>; MAX_LAYERS],
    layer_count: usize,
    point_layers: usize,
    joints: u16,
    width: u16,
    height: u16,
    head_dim: u16,
    input_shifts: [u8; FEATURES],
    avg_scale: f32,
    preprocessing: Preprocessing,
}

// The readers below return 0 past the end of `b` instead of panicking: `parse` checks every
// length before it reads, and an image then links no panic path for them.

fn u16_at(b: &[u8], o: usize) -> u16 {
    b.get(o..)
        .and_then(<[u8]>::first_chunk)
        .map_or(0, |c| u16::from_le_bytes(*c))
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    b.get(o..)
        .and_then(<[u8]>::first_chunk)
        .map_or(0, |c| u32::from_le_bytes(*c))
}

impl<'a> Model<'a> {
    /// Validates a blob. The blob must start at a 16-byte-aligned address ([`ALIGN`]: its
    /// arrays are read in place; else [`ModelError::Misaligned`]). Embedded in flash, wrap it
    /// in a type of that alignment:
    ///
    /// ```
    /// # use evpose_core::Model;
    /// #[repr(C, align(16))]
    /// struct Aligned<T: ?Sized>(T);
    /// # const BYTES: [u8; 4] = *b"EVPQ";
    /// static BLOB: &Aligned<[u8]> = &Aligned(BYTES); // BYTES: `*include_bytes!("model.evq")`
    /// let parsed = Model::parse(&BLOB.0);
    /// # assert!(parsed.is_err()); // four bytes are no blob
    /// ```
    ///
    /// Read at run time (a host, or an MCU loading from external storage), copy it into
    /// 16-byte-aligned memory first: a buffer of that `Aligned` type, or on a host
    /// `evpose_host::model::AlignedBlob`.
    pub fn parse(blob: &'a [u8]) -> Result<Self, ModelError> {
        // The fixed header as an array: its reads below need no bounds checks.
        let Some(head) = blob.first_chunk::<HEADER_LEN>() else {
            return Err(ModelError::Truncated {
                needed: HEADER_LEN,
                got: blob.len(),
            });
        };
        use header as h;
        if head[h::MAGIC..h::MAGIC + 4] != MAGIC {
            return Err(ModelError::BadMagic);
        }
        let version = u16_at(head, h::VERSION);
        if !(1..=VERSION).contains(&version) {
            return Err(ModelError::Version(version));
        }
        let total = u32_at(head, h::TOTAL) as usize;
        let Some(blob) = blob.get(..total) else {
            return Err(ModelError::Truncated {
                needed: total,
                got: blob.len(),
            });
        };
        if total < HEADER_LEN {
            return Err(ModelError::Header("total length below the header size"));
        }
        let stored = u32_at(head, h::CRC);
        let computed = CRC.checksum(blob.get(h::CRC_FROM..).unwrap_or_default());
        if stored != computed {
            return Err(ModelError::Checksum { stored, computed });
        }
        if !(blob.as_ptr() as usize).is_multiple_of(ALIGN) {
            return Err(ModelError::Misaligned);
        }
        if head[h::RESERVED] != 0 {
            return Err(ModelError::Header("reserved byte 7 must be zero"));
        }
        let dtype = match head[h::DTYPE] {
            0 => DType::F32,
            1 => DType::I8,
            _ => return Err(ModelError::Header("unknown dtype")),
        };
        let shifts: [u8; FEATURES] = core::array::from_fn(|i| head[h::INPUT_SHIFTS + i]);
        if shifts.iter().any(|&s| s > 15) {
            return Err(ModelError::Header("input shift above 15"));
        }
        let mut m = Self {
            blob,
            version,
            dtype,
            layers: [None; MAX_LAYERS],
            layer_count: usize::from(u16_at(head, h::LAYERS)),
            point_layers: usize::from(u16_at(head, h::POINT_LAYERS)),
            joints: u16_at(head, h::JOINTS),
            width: u16_at(head, h::WIDTH),
            height: u16_at(head, h::HEIGHT),
            head_dim: u16_at(head, h::HEAD_DIM),
            input_shifts: shifts,
            avg_scale: f32::from_bits(u32_at(head, h::AVG_SCALE)),
            preprocessing: Preprocessing {
                points: u32_at(head, h::POINTS),
                window_events: u32_at(head, h::WINDOW_EVENTS),
                slices: head[h::SLICES],
            },
        };
        if version == 1 && m.preprocessing != Preprocessing::default() {
            return Err(ModelError::Header(
                "version 1 blobs have no preprocessing fields",
            ));
        }
        if m.preprocessing.slices > crate::raster::MAX_SLICES {
            return Err(ModelError::Header(
                "more time slices than the rasterizer has",
            ));
        }
        if head[h::SLICES + 1..].iter().any(|&b| b != 0) {
            return Err(ModelError::Header("reserved bytes 57..64 must be zero"));
        }
        m.check_header()?;
        let table = u32_at(head, h::TABLE) as usize;
        let outside = ModelError::Header("layer table outside the blob");
        let entries = table
            .checked_add(m.layer_count * ENTRY_LEN)
            .and_then(|end| blob.get(table..end))
            .filter(|_| table >= HEADER_LEN)
            .ok_or(outside)?;
        // `check_header` bounded the layer count by MAX_LAYERS, the length of `m.layers`.
        for (i, entry) in entries.as_chunks::<ENTRY_LEN>().0.iter().enumerate() {
            let desc = m.parse_entry(i, entry)?;
            if let Some(slot) = m.layers.get_mut(i) {
                *slot = Some(desc);
            }
        }
        m.check_chain()?;
        Ok(m)
    }

    fn check_header(&self) -> Result<(), ModelError> {
        if self.layer_count > MAX_LAYERS || self.layer_count < self.point_layers + 3 {
            return Err(ModelError::Header(
                "layer count must cover the point layers, one FC layer and two heads",
            ));
        }
        if self.point_layers == 0 || self.point_layers > MAX_POINT_LAYERS {
            return Err(ModelError::Header("point layer count outside 1..=16"));
        }
        if self.joints == 0 || self.width == 0 || self.height == 0 || self.head_dim == 0 {
            return Err(ModelError::Header(
                "joints, width, height and head dim must be non-zero",
            ));
        }
        if self.dtype == DType::I8 && !(self.avg_scale.is_finite() && self.avg_scale > 0.0) {
            return Err(ModelError::Header("average-pool constant must be positive"));
        }
        Ok(())
    }

    fn parse_entry(&self, i: usize, e: &[u8; ENTRY_LEN]) -> Result<LayerDesc, ModelError> {
        let err = |reason| ModelError::Layer {
            index: i as u8,
            reason,
        };
        use entry as f;
        let kind = match e[f::KIND] {
            0 => LayerKind::Point,
            1 => LayerKind::Fc,
            2 => LayerKind::HeadX,
            3 => LayerKind::HeadY,
            _ => return Err(err("unknown layer kind")),
        };
        let expected_kind = if i < self.point_layers {
            LayerKind::Point
        } else if i + 2 < self.layer_count {
            LayerKind::Fc
        } else if i + 2 == self.layer_count {
            LayerKind::HeadX
        } else {
            LayerKind::HeadY
        };
        if kind != expected_kind {
            return Err(err("layers must be ordered: point, FC, head x, head y"));
        }
        let weight_type = match e[f::WEIGHT_TYPE] {
            0 => WeightType::F32,
            1 => WeightType::I8,
            2 => WeightType::I16,
            _ => return Err(err("unknown weight type")),
        };
        let head = matches!(kind, LayerKind::HeadX | LayerKind::HeadY);
        let allowed = match (self.dtype, kind) {
            (DType::F32, _) => weight_type == WeightType::F32,
            (DType::I8, LayerKind::Point) => weight_type != WeightType::F32,
            // Version 3: int8 heads may keep 15-bit weights (the heads are ~0.1 % of the MACs
            // and the argmax is sensitive to their rounding).
            (DType::I8, _) if head && self.version >= 3 => weight_type != WeightType::F32,
            (DType::I8, _) => weight_type == WeightType::I8,
        };
        if !allowed {
            return Err(err("weight type does not fit the model's dtype"));
        }
        let alpha = f32::from_bits(u32_at(e, f::ALPHA));
        let leaky = match e[f::FLAGS] & 1 {
            1 if alpha.is_finite() => Some(alpha),
            1 => return Err(err("LeakyReLU slope is not finite")),
            _ => None,
        };
        let d = LayerDesc {
            kind,
            in_dim: u32_at(e, f::IN_DIM),
            out_dim: u32_at(e, f::OUT_DIM),
            sources: u32_at(e, f::SOURCES),
            leaky,
            weight_type,
            weights: u32_at(e, f::WEIGHTS),
            bias: u32_at(e, f::BIAS),
            scales: u32_at(e, f::SCALES),
        };
        if d.in_dim == 0 || d.out_dim == 0 || d.in_dim > 1 << 16 || d.out_dim > 1 << 16 {
            return Err(err("dimensions must be in 1..=65536"));
        }
        // Checked: on a 32-bit MCU, 65,536 × 65,536 weights would wrap to 0 bytes.
        let w_bytes = (d.in_dim as usize)
            .checked_mul(d.out_dim as usize)
            .and_then(|n| n.checked_mul(weight_type.size()))
            .ok_or(err("weights larger than the address space"))?;
        self.check_array(d.weights, w_bytes, i)?;
        self.check_array(d.bias, d.out_dim as usize * 4, i)?;
        let int8 = self.dtype == DType::I8;
        let wants_scales = int8 && matches!(kind, LayerKind::Point | LayerKind::Fc);
        let head_scales = int8 && self.version >= 3 && !wants_scales;
        match (wants_scales, d.scales) {
            (true, 0) => return Err(err("int8 layer without requantization scales")),
            (true, off) => {
                let n = d.out_dim as usize;
                self.check_array(off, n * 4, i)?;
                // Finite scales keep every requantized value a number (the Cortex-M7 kernel
                // relies on it; a NaN scale would otherwise saturate to -128 in the reference).
                let scale = |j: usize| f32::from_bits(u32_at(self.blob, off as usize + 4 * j));
                if !(0..n).all(|j| scale(j).is_finite()) {
                    return Err(err("requantization scale not finite"));
                }
            }
            (false, 0) => {}
            (false, off) if head_scales => {
                self.check_array(off, d.out_dim as usize * 4, i)?;
                let first = f32::from_bits(u32_at(self.blob, off as usize));
                if !(first.is_finite() && first > 0.0) {
                    return Err(err("head logit scale must be positive"));
                }
            }
            (false, _) => return Err(err("scales on a layer that takes none")),
        }
        if head && weight_type == WeightType::I16 {
            self.check_i16_head(&d, i)?;
        }
        if kind == LayerKind::Point {
            self.check_sources(&d, i)?;
            if weight_type == WeightType::I16 && d.sources != 1 {
                return Err(err(
                    "i16 weights only on layers reading the input features alone",
                ));
            }
            // The int8 engine reads the input features only through i16 weights (found by the
            // `blob` fuzz target: an int8 layer on the input indexed before the activations).
            if int8 && d.sources == 1 && weight_type != WeightType::I16 {
                return Err(err(
                    "an int8 model's layers reading the input features take i16 weights",
                ));
            }
        } else if d.sources != 0 {
            return Err(err("only point layers have sources"));
        }
        Ok(d)
    }

    /// An i16 head's accumulators must stay exact in i32: `D ≤ MAX_I16_HEAD_DIM`, weights within
    /// `±HEAD_WEIGHT_LIMIT`, biases within `±HEAD_BIAS_LIMIT` (arrays already bounds-checked).
    fn check_i16_head(&self, d: &LayerDesc, i: usize) -> Result<(), ModelError> {
        use crate::quant::{HEAD_BIAS_LIMIT, HEAD_WEIGHT_LIMIT, MAX_I16_HEAD_DIM};
        let err = |reason| ModelError::Layer {
            index: i as u8,
            reason,
        };
        if d.in_dim as usize > MAX_I16_HEAD_DIM {
            return Err(err("i16 heads take at most 256 inputs"));
        }
        let n = d.in_dim as usize * d.out_dim as usize;
        let w = self.span(d.weights, 2 * n);
        if w.as_chunks::<2>()
            .0
            .iter()
            .any(|b| i16::from_le_bytes(*b).unsigned_abs() > HEAD_WEIGHT_LIMIT as u16)
        {
            return Err(err("i16 head weight beyond the 15-bit limit"));
        }
        let b = self.span(d.bias, 4 * d.out_dim as usize);
        if b.as_chunks::<4>()
            .0
            .iter()
            .any(|b| i32::from_le_bytes(*b).unsigned_abs() > HEAD_BIAS_LIMIT as u32)
        {
            return Err(err("i16 head bias beyond its limit"));
        }
        Ok(())
    }

    fn check_array(&self, offset: u32, bytes: usize, i: usize) -> Result<(), ModelError> {
        let o = offset as usize;
        let ok = o.is_multiple_of(ALIGN)
            && o >= HEADER_LEN
            && o.checked_add(bytes)
                .is_some_and(|end| end <= self.blob.len());
        if ok {
            Ok(())
        } else {
            Err(ModelError::Layer {
                index: i as u8,
                reason: "array outside the blob or misaligned",
            })
        }
    }

    fn check_sources(&self, d: &LayerDesc, i: usize) -> Result<(), ModelError> {
        let err = |reason| ModelError::Layer {
            index: i as u8,
            reason,
        };
        // Only the input (bit 0) and earlier layers (bits 1..=i).
        if d.sources == 0 || d.sources >> (i + 1) != 0 {
            return Err(err("sources must name the input or earlier point layers"));
        }
        // The engines read sources in place: one contiguous run of layers, or the input alone.
        let run = d.sources >> d.sources.trailing_zeros();
        if run & (run + 1) != 0 || (d.sources & 1 == 1 && d.sources != 1) {
            return Err(err(
                "sources must be the input alone or a contiguous run of layers",
            ));
        }
        let mut width = 0u32;
        for bit in 0..=i {
            if d.sources >> bit & 1 == 1 {
                width += if bit == 0 {
                    FEATURES as u32
                } else {
                    self.layers
                        .get(bit - 1)
                        .copied()
                        .flatten()
                        .map_or(0, |l| l.out_dim)
                };
            }
        }
        if width != d.in_dim {
            return Err(err("input width is not the sum of its sources' widths"));
        }
        Ok(())
    }

    fn check_chain(&self) -> Result<(), ModelError> {
        let mut prev = 2 * self.pooled_width();
        for i in self.point_layers..self.layer_count - 2 {
            let l = self.desc(i);
            if l.in_dim != prev {
                return Err(ModelError::Layer {
                    index: i as u8,
                    reason: "input width does not match the previous layer",
                });
            }
            prev = l.out_dim;
        }
        if prev != u32::from(self.joints) * u32::from(self.head_dim) {
            return Err(ModelError::Header(
                "last FC layer width is not joints × head dim",
            ));
        }
        let (hx, hy) = (
            self.desc(self.layer_count - 2),
            self.desc(self.layer_count - 1),
        );
        let d = u32::from(self.head_dim);
        if hx.in_dim != d
            || hy.in_dim != d
            || hx.out_dim != u32::from(self.width)
            || hy.out_dim != u32::from(self.height)
        {
            return Err(ModelError::Header(
                "heads must map head dim to width and height",
            ));
        }
        Ok(())
    }

    fn desc(&self, i: usize) -> LayerDesc {
        // Every index below layer_count was filled by parse().
        match self.layers.get(i) {
            Some(Some(d)) => *d,
            _ => LayerDesc {
                kind: LayerKind::Point,
                in_dim: 0,
                out_dim: 0,
                sources: 0,
                leaky: None,
                weight_type: WeightType::F32,
                weights: 0,
                bias: 0,
                scales: 0,
            },
        }
    }

    /// `len` bytes of the blob from `offset` (checked in parse; empty if they were not there).
    fn span(&self, offset: u32, len: usize) -> &'a [u8] {
        self.blob
            .get(offset as usize..)
            .and_then(|b| b.get(..len))
            .unwrap_or(&[])
    }

    fn array<T: Pod>(&self, offset: u32, len: usize) -> &'a [T] {
        // One range check (parse checked the arrays, so it always passes): `span`'s two
        // checks cost 0.25 % more instructions per inference on the M7, where `run_i8` asks
        // for each layer's arrays once per block of points.
        let o = offset as usize;
        let bytes = self
            .blob
            .get(o..o.wrapping_add(len.wrapping_mul(size_of::<T>())))
            .unwrap_or(&[]);
        // Offsets are 16-byte aligned within a 16-byte-aligned blob (checked in parse).
        bytemuck::try_cast_slice(bytes).unwrap_or(&[])
    }

    /// Layer `i` of the table with its arrays.
    pub fn layer(&self, i: usize) -> Layer<'a> {
        let d = self.desc(i);
        let n = d.in_dim as usize * d.out_dim as usize;
        let out = d.out_dim as usize;
        let weights = match d.weight_type {
            WeightType::F32 => Weights::F32(self.array(d.weights, n)),
            WeightType::I8 => Weights::I8(self.array(d.weights, n)),
            WeightType::I16 => Weights::I16(self.array(d.weights, n)),
        };
        let bias = match self.dtype {
            DType::F32 => Bias::F32(self.array(d.bias, out)),
            DType::I8 => Bias::I32(self.array(d.bias, out)),
        };
        let scales = if d.scales == 0 {
            &[][..]
        } else {
            self.array(d.scales, out)
        };
        Layer {
            desc: d,
            weights,
            bias,
            scales,
        }
    }

    /// The preprocessing the model expects (fields 0 where the blob does not state them).
    pub fn preprocessing(&self) -> Preprocessing {
        self.preprocessing
    }

    /// Points per network input: the `N` the blob records, else the paper's
    /// [`DEFAULT_POINTS`](crate::pipeline::DEFAULT_POINTS).
    pub fn input_points(&self) -> usize {
        match self.preprocessing.points {
            0 => crate::pipeline::DEFAULT_POINTS,
            n => n as usize,
        }
    }

    /// Number format.
    pub fn dtype(&self) -> DType {
        self.dtype
    }
    /// Joints `J`.
    pub fn joints(&self) -> usize {
        usize::from(self.joints)
    }
    /// Width `W` of the x logits.
    pub fn width(&self) -> usize {
        usize::from(self.width)
    }
    /// Height `H` of the y logits.
    pub fn height(&self) -> usize {
        usize::from(self.height)
    }
    /// Per-joint feature width `D` read by the heads.
    pub fn head_dim(&self) -> usize {
        usize::from(self.head_dim)
    }
    /// Number of point layers.
    pub fn point_layer_count(&self) -> usize {
        self.point_layers
    }
    /// Number of layers (point, FC, heads).
    pub fn layer_count(&self) -> usize {
        self.layer_count
    }
    /// Indices of the FC layers.
    pub fn fc_range(&self) -> core::ops::Range<usize> {
        self.point_layers..self.layer_count - 2
    }
    /// Index of the x head (the y head follows).
    pub fn head_x_index(&self) -> usize {
        self.layer_count - 2
    }
    /// Width of the pooled (last) point layer.
    pub fn pooled_width(&self) -> u32 {
        self.desc(self.point_layers - 1).out_dim
    }
    /// int8 input coding exponents per feature.
    pub fn input_shifts(&self) -> [u8; FEATURES] {
        self.input_shifts
    }
    /// The factor from head outputs to logits, `[x, y]`: 1 for an f32 model; for an int8
    /// model, the heads' dequantization multipliers (blob version 3: `logit = accumulator ×
    /// scale`, one scale per head), or `None` when the blob does not carry them.
    pub fn head_scales(&self) -> Option<[f32; 2]> {
        if self.dtype == DType::F32 {
            return Some([1.0; 2]);
        }
        let hx = self.head_x_index();
        let first = |i: usize| match self.layer(i).scales {
            [s, ..] => Some(*s),
            [] => None,
        };
        Some([first(hx)?, first(hx + 1)?])
    }
    /// int8 average-pool constant `c` (see [`crate::quant::average`]).
    pub fn avg_scale(&self) -> f32 {
        self.avg_scale
    }
    /// Sum of the point layers' output widths (one point's activations).
    pub fn point_activation_width(&self) -> usize {
        (0..self.point_layers)
            .map(|i| self.desc(i).out_dim as usize)
            .sum()
    }
    /// Multiply-accumulates per point (the point layers).
    pub fn macs_per_point(&self) -> u64 {
        (0..self.point_layers).map(|i| self.macs(i)).sum()
    }
    /// Multiply-accumulates after pooling (FC layers and heads, all joints).
    pub fn macs_after_pooling(&self) -> u64 {
        let fc: u64 = self.fc_range().map(|i| self.macs(i)).sum();
        let heads = self.macs(self.head_x_index()) + self.macs(self.head_x_index() + 1);
        fc + heads * u64::from(self.joints)
    }
    /// Multiply-accumulates of layer `i` for one input vector.
    pub fn macs(&self, i: usize) -> u64 {
        let d = self.desc(i);
        u64::from(d.in_dim) * u64::from(d.out_dim)
    }
    /// Largest FC output width (scratch sizing).
    pub fn widest_fc(&self) -> usize {
        self.fc_range()
            .map(|i| self.desc(i).out_dim as usize)
            .max()
            .unwrap_or(0)
    }
    /// The blob's bytes.
    pub fn bytes(&self) -> &'a [u8] {
        self.blob
    }
    /// The blob's CRC-32 (from the header, checked by [`Model::parse`]): identifies the model.
    pub fn checksum(&self) -> u32 {
        u32_at(self.blob, 12)
    }
}

#[cfg(test)]
mod tests {
    /// Either table size ([`super::CrcTable`]) computes CRC-32/ISO-HDLC: its check value, and
    /// the byte-wise table's sums over every length up to 100 bytes (steps of 16 bytes ending
    /// anywhere). The workspace's test run (`cargo test --workspace`) builds the core with
    /// `fast-crc`, as the host asks for it, so there the comparison is between the two table
    /// sizes; a build of the core alone compares the byte-wise table with itself, and only the
    /// check value tests it.
    #[test]
    fn the_checksum_is_crc32_whatever_the_tables() {
        assert_eq!(super::CRC.checksum(b"123456789"), 0xCBF4_3926);
        let bytewise = crc::Crc::<u32, crc::Table<1>>::new(&crc::CRC_32_ISO_HDLC);
        let data: [u8; 100] = core::array::from_fn(|i| (i * 37 + 11) as u8);
        for n in 0..=data.len() {
            assert_eq!(
                super::CRC.checksum(&data[..n]),
                bytewise.checksum(&data[..n]),
                "{n}"
            );
        }
    }
}
