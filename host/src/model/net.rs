//! The network as the importer understands it, in f32, and the blob writer.

use anyhow::{ensure, Result};
use evpose_core::model::{
    DType, LayerKind, Preprocessing, WeightType, ALIGN, CRC, ENTRY_LEN, FEATURES, HEADER_LEN,
    MAGIC, VERSION,
};
use evpose_core::{pack_layers, packed_bytes, Model, PackedLayout, PackedWeights};

/// A dense layer: `y = act(W x + b)` with `W` stored `[out][in]`.
#[derive(Clone, Debug, PartialEq)]
pub struct Dense {
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Weights, `[out][in]` row-major.
    pub w: Vec<f32>,
    /// Bias, `[out]`.
    pub b: Vec<f32>,
    /// LeakyReLU slope, if the layer has one.
    pub leaky: Option<f32>,
    /// Point layers: bit 0 = input features, bit `i` = point layer `i − 1`. 0 otherwise.
    pub sources: u32,
}

impl Dense {
    /// Row `o` of the weights.
    pub fn row(&self, o: usize) -> &[f32] {
        &self.w[o * self.in_dim..(o + 1) * self.in_dim]
    }
}

/// A PointNet-SimDR network of the paper's family, in f32.
#[derive(Clone, Debug, PartialEq)]
pub struct FloatNet {
    /// Per-point layers, in order; the last one is pooled.
    pub point: Vec<Dense>,
    /// Fully connected layers after pooling (BatchNorm folded).
    pub fc: Vec<Dense>,
    /// x head `D → W`, shared by all joints.
    pub head_x: Dense,
    /// y head `D → H`.
    pub head_y: Dense,
    /// Joints `J`.
    pub joints: usize,
    /// Fixed point count of the export, or `None` for a dynamic one.
    pub points: Option<usize>,
}

impl FloatNet {
    /// `D`, the per-joint width.
    pub fn head_dim(&self) -> usize {
        self.head_x.in_dim
    }
    /// Width of the pooled layer.
    pub fn pooled_width(&self) -> usize {
        self.point.last().map_or(0, |l| l.out_dim)
    }
    /// All layers in blob order.
    pub fn layers(&self) -> impl Iterator<Item = (LayerKind, &Dense)> {
        self.point
            .iter()
            .map(|l| (LayerKind::Point, l))
            .chain(self.fc.iter().map(|l| (LayerKind::Fc, l)))
            .chain([
                (LayerKind::HeadX, &self.head_x),
                (LayerKind::HeadY, &self.head_y),
            ])
    }
}

/// One layer's arrays as they go into a blob.
pub struct BlobLayer {
    /// Role.
    pub kind: LayerKind,
    /// Input width.
    pub in_dim: usize,
    /// Output width.
    pub out_dim: usize,
    /// Sources bitmask (point layers).
    pub sources: u32,
    /// LeakyReLU slope.
    pub leaky: Option<f32>,
    /// Weight element type.
    pub weight_type: WeightType,
    /// Weight bytes, `[out][in]`, little-endian.
    pub weights: Vec<u8>,
    /// Bias bytes (f32 or i32 LE).
    pub bias: Vec<u8>,
    /// Scale bytes (f32 LE), empty for none.
    pub scales: Vec<u8>,
}

/// Header fields of a blob.
pub struct BlobHeader {
    /// Number format.
    pub dtype: DType,
    /// Joints.
    pub joints: usize,
    /// Width of the x logits.
    pub width: usize,
    /// Height of the y logits.
    pub height: usize,
    /// Per-joint width.
    pub head_dim: usize,
    /// Number of point layers.
    pub point_layers: usize,
    /// int8 input coding exponents.
    pub input_shifts: [u8; FEATURES],
    /// int8 average-pool constant.
    pub avg_scale: f32,
    /// The preprocessing the model expects.
    pub preprocessing: Preprocessing,
}

/// Little-endian bytes of a slice of numbers.
pub fn le_bytes<T: bytemuck::Pod>(v: &[T]) -> Vec<u8> {
    // All supported hosts are little-endian (checked at compile time below).
    bytemuck::cast_slice(v).to_vec()
}

#[cfg(not(target_endian = "little"))]
compile_error!("the blob writer assumes a little-endian host");

fn put_u16(b: &mut [u8], o: usize, v: usize) -> Result<()> {
    let v = u16::try_from(v)
        .map_err(|_| anyhow::anyhow!("{v} does not fit the blob's 16-bit field"))?;
    b[o..o + 2].copy_from_slice(&v.to_le_bytes());
    Ok(())
}

fn put_u32(b: &mut [u8], o: usize, v: u32) {
    b[o..o + 4].copy_from_slice(&v.to_le_bytes());
}

/// Serializes a model blob (layout in [`evpose_core::model`]).
pub fn write_blob(h: &BlobHeader, layers: &[BlobLayer]) -> Result<Vec<u8>> {
    ensure!(
        layers.len() <= evpose_core::model::MAX_LAYERS,
        "too many layers"
    );
    let table = HEADER_LEN;
    let mut data = (table + layers.len() * ENTRY_LEN).next_multiple_of(ALIGN);
    let mut out = vec![0u8; data];
    use evpose_core::model::{entry as f, header as o};
    out[o::MAGIC..o::MAGIC + 4].copy_from_slice(&MAGIC);
    out[o::VERSION..o::VERSION + 2].copy_from_slice(&VERSION.to_le_bytes());
    out[o::DTYPE] = h.dtype as u8;
    put_u16(&mut out, o::LAYERS, layers.len())?;
    put_u16(&mut out, o::POINT_LAYERS, h.point_layers)?;
    put_u16(&mut out, o::JOINTS, h.joints)?;
    put_u16(&mut out, o::WIDTH, h.width)?;
    put_u16(&mut out, o::HEIGHT, h.height)?;
    put_u16(&mut out, o::HEAD_DIM, h.head_dim)?;
    out[o::INPUT_SHIFTS..o::INPUT_SHIFTS + FEATURES].copy_from_slice(&h.input_shifts);
    put_u32(&mut out, o::AVG_SCALE, h.avg_scale.to_bits());
    put_u32(&mut out, o::TABLE, table as u32);
    put_u32(&mut out, o::DATA, data as u32);
    put_u32(&mut out, o::POINTS, h.preprocessing.points);
    put_u32(&mut out, o::WINDOW_EVENTS, h.preprocessing.window_events);
    out[o::SLICES] = h.preprocessing.slices;
    let mut append = |out: &mut Vec<u8>, bytes: &[u8]| -> u32 {
        if bytes.is_empty() {
            return 0;
        }
        let at = data;
        out.extend_from_slice(bytes);
        data += bytes.len();
        let padded = data.next_multiple_of(ALIGN);
        out.resize(padded, 0);
        data = padded;
        at as u32
    };
    for (i, l) in layers.iter().enumerate() {
        let w = append(&mut out, &l.weights);
        let b = append(&mut out, &l.bias);
        let s = append(&mut out, &l.scales);
        let e = table + i * ENTRY_LEN;
        out[e + f::KIND] = l.kind as u8;
        out[e + f::FLAGS] = u8::from(l.leaky.is_some());
        out[e + f::WEIGHT_TYPE] = l.weight_type as u8;
        put_u32(&mut out, e + f::IN_DIM, l.in_dim as u32);
        put_u32(&mut out, e + f::OUT_DIM, l.out_dim as u32);
        put_u32(&mut out, e + f::SOURCES, l.sources);
        put_u32(&mut out, e + f::WEIGHTS, w);
        put_u32(&mut out, e + f::BIAS, b);
        put_u32(&mut out, e + f::SCALES, s);
        put_u32(&mut out, e + f::ALPHA, l.leaky.unwrap_or(0.0).to_bits());
    }
    let total = out.len() as u32;
    put_u32(&mut out, o::TOTAL, total);
    let crc = CRC.checksum(&out[o::CRC_FROM..]);
    put_u32(&mut out, o::CRC, crc);
    // Every blob written is one the core loads: what it would refuse (a non-finite scale, an
    // i16 head out of its limits) is an error now, not at the first inference.
    Model::parse(AlignedBlob::new(&out).bytes())
        .map_err(|e| anyhow::anyhow!("the model would not load: {e}"))?;
    Ok(out)
}

/// The f32 blob of a network (the float reference path runs the core on it).
pub fn f32_blob(net: &FloatNet) -> Result<Vec<u8>> {
    let layers: Vec<BlobLayer> = net
        .layers()
        .map(|(kind, l)| BlobLayer {
            kind,
            in_dim: l.in_dim,
            out_dim: l.out_dim,
            sources: l.sources,
            leaky: l.leaky,
            weight_type: WeightType::F32,
            weights: le_bytes(&l.w),
            bias: le_bytes(&l.b),
            scales: Vec::new(),
        })
        .collect();
    write_blob(
        &BlobHeader {
            dtype: DType::F32,
            joints: net.joints,
            width: net.head_x.out_dim,
            height: net.head_y.out_dim,
            head_dim: net.head_dim(),
            point_layers: net.point.len(),
            input_shifts: [0; FEATURES],
            avg_scale: 0.0,
            preprocessing: Preprocessing {
                points: net.points.unwrap_or(0) as u32,
                ..Preprocessing::default()
            },
        },
        &layers,
    )
}

/// A blob in 16-byte-aligned memory, as the core requires for reading weights in place, with
/// its int8 point layers and heads packed for the packed kernels on first use
/// ([`AlignedBlob::packed`]).
pub struct AlignedBlob {
    words: Vec<u128>,
    len: usize,
    packed: std::sync::OnceLock<Option<(PackedLayout, Vec<u8>)>>,
}

impl AlignedBlob {
    /// Copies bytes into aligned memory.
    pub fn new(bytes: &[u8]) -> Self {
        let mut words = vec![0u128; bytes.len().div_ceil(16)];
        bytemuck::cast_slice_mut::<u128, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        Self {
            words,
            len: bytes.len(),
            packed: std::sync::OnceLock::new(),
        }
    }

    /// The packed point-layer and head weights of `model` (parsed from this blob), packed once, on the
    /// first call; `None` for a model without int8 point layers.
    pub fn packed<'b>(&'b self, model: &Model<'b>) -> anyhow::Result<Option<PackedWeights<'b>>> {
        let packed = self.packed.get_or_init(|| {
            let mut buf = vec![0; packed_bytes(model)];
            (!buf.is_empty())
                .then(|| pack_layers(model, &mut buf).ok().map(|l| (l, buf)))
                .flatten()
        });
        packed
            .as_ref()
            .map(|(layout, buf)| layout.weights(model, buf))
            .transpose()
            .map_err(|e| anyhow::anyhow!("{e}"))
    }

    /// The bytes.
    pub fn bytes(&self) -> &[u8] {
        &bytemuck::cast_slice::<u128, u8>(&self.words)[..self.len]
    }
}
