//! NumPy `.npy` array files: read any numeric array as f64, stream it, write f32/f64/i32 arrays
//! (and append i64/u32/u16/u8 ones, [`NpyAppender`]).

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read};
use std::path::Path;

use anyhow::{bail, Context, Result};
use npyz::{DType, NpyFile, NpyHeader, Order, WriterBuilder};

/// The longest `.npy` header read, bytes: NumPy's own limit when it loads a file
/// (`max_header_size`, 10,000). A longer header is refused before anything is allocated for
/// it: a damaged length field must not size an allocation (found by the `read_detect` fuzz
/// target: a 4-byte field asked for 662 MB).
pub const MAX_HEADER_BYTES: u32 = 10_000;

/// The deepest bracket nesting accepted in an `.npy` header (its Python dict literal): a plain
/// array's header nests 2 levels, a structured dtype a few more. The literal parser backtracks
/// exponentially in the depth (found by the `read_npy` fuzz target: 16 nested `{` took over
/// 10 s), so deeper headers are refused before it runs.
pub const MAX_HEADER_DEPTH: usize = 6;

/// Bracket depth of a Python literal, outside quoted strings.
fn nesting_depth(header: &[u8]) -> usize {
    let (mut depth, mut max, mut quote) = (0usize, 0usize, None::<u8>);
    for &c in header {
        match (quote, c) {
            (Some(q), _) if c == q => quote = None,
            (Some(_), _) => {}
            (None, b'\'' | b'"') => quote = Some(c),
            (None, b'{' | b'[' | b'(') => {
                depth += 1;
                max = max.max(depth);
            }
            (None, b'}' | b']' | b')') => depth = depth.saturating_sub(1),
            _ => {}
        }
    }
    max
}

/// An `.npy` stream after its header.
type Data<R> = io::Chain<io::Cursor<Vec<u8>>, R>;

/// Opens an `.npy` stream after checking its header: at most [`MAX_HEADER_BYTES`] long and
/// [`MAX_HEADER_DEPTH`] deep.
fn open_npy<R: Read>(reader: R) -> io::Result<NpyFile<Data<R>>> {
    let (header, data) = open_header(reader)?;
    Ok(NpyFile::with_header(header, data))
}

/// [`open_npy`]'s header and the stream at the first value.
fn open_header<R: Read>(mut reader: R) -> io::Result<(NpyHeader, Data<R>)> {
    let invalid = |m: String| io::Error::new(io::ErrorKind::InvalidData, m);
    let mut read_up_to = |buf: &mut Vec<u8>, n: usize| -> io::Result<()> {
        let start = buf.len();
        buf.resize(start + n, 0);
        let mut got = 0;
        while got < n {
            match reader.read(&mut buf[start + got..])? {
                0 => break,
                k => got += k,
            }
        }
        buf.truncate(start + got);
        Ok(())
    };
    // Magic (6), version (2), header length (2 bytes in version 1, 4 in versions 2 and 3).
    let mut pre = Vec::with_capacity(12);
    read_up_to(&mut pre, 10)?;
    if pre.len() == 10 && pre.starts_with(b"\x93NUMPY") {
        let len = if pre[6] == 1 {
            u32::from(u16::from_le_bytes([pre[8], pre[9]]))
        } else {
            read_up_to(&mut pre, 2)?;
            match pre[..] {
                [.., a, b, c, d] if pre.len() == 12 => u32::from_le_bytes([a, b, c, d]),
                _ => 0,
            }
        };
        if len > MAX_HEADER_BYTES {
            return Err(invalid(format!(
                "npy header of {len} bytes (at most {MAX_HEADER_BYTES} are read)"
            )));
        }
        let at = pre.len();
        read_up_to(&mut pre, len as usize)?;
        let depth = nesting_depth(&pre[at..]);
        if depth > MAX_HEADER_DEPTH {
            return Err(invalid(format!(
                "npy header nests {depth} levels (at most {MAX_HEADER_DEPTH})"
            )));
        }
    }
    let mut data = io::Cursor::new(pre).chain(reader);
    let header = NpyHeader::from_reader(&mut data)?;
    Ok((header, data))
}

/// The numeric element types [`F64Values`] reads: every integer and float width NumPy saves
/// for plain arrays (`bool`, `float16`, complex and structured dtypes are refused).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Element {
    F64,
    F32,
    I64,
    I32,
    I16,
    I8,
    U64,
    U32,
    U16,
    U8,
}

impl Element {
    /// The element type and byte order (big-endian: `true`) of a plain dtype such as `<f8`,
    /// `>i4` or `|u1`.
    fn parse(dtype: &DType) -> Option<(Self, bool)> {
        let DType::Plain(ty) = dtype else {
            return None;
        };
        let ty = ty.to_string();
        let (order, code) = ty.split_at_checked(1)?;
        let big = match order {
            "<" | "|" | "=" => false,
            ">" => true,
            _ => return None,
        };
        let e = match code {
            "f8" => Self::F64,
            "f4" => Self::F32,
            "i8" => Self::I64,
            "i4" => Self::I32,
            "i2" => Self::I16,
            "i1" => Self::I8,
            "u8" => Self::U64,
            "u4" => Self::U32,
            "u2" => Self::U16,
            "u1" => Self::U8,
            _ => return None,
        };
        Some((e, big))
    }

    /// Bytes per element.
    fn size(self) -> usize {
        match self {
            Self::F64 | Self::I64 | Self::U64 => 8,
            Self::F32 | Self::I32 | Self::U32 => 4,
            Self::I16 | Self::U16 => 2,
            Self::I8 | Self::U8 => 1,
        }
    }

    /// `bytes` (whole elements) as f64 into the front of `out`.
    fn convert(self, big: bool, bytes: &[u8], out: &mut [f64]) {
        macro_rules! each {
            ($t:ty, $n:literal) => {{
                let (elements, _) = bytes.as_chunks::<$n>();
                let pairs = out.iter_mut().zip(elements);
                if big {
                    pairs.for_each(|(o, &b)| *o = <$t>::from_be_bytes(b) as f64);
                } else {
                    pairs.for_each(|(o, &b)| *o = <$t>::from_le_bytes(b) as f64);
                }
            }};
        }
        match self {
            Self::F64 => each!(f64, 8),
            Self::F32 => each!(f32, 4),
            Self::I64 => each!(i64, 8),
            Self::I32 => each!(i32, 4),
            Self::I16 => each!(i16, 2),
            Self::I8 => each!(i8, 1),
            Self::U64 => each!(u64, 8),
            Self::U32 => each!(u32, 4),
            Self::U16 => each!(u16, 2),
            Self::U8 => each!(u8, 1),
        }
    }
}

/// The values of an `.npy` stream in C order, converted to f64 whatever the stored dtype, read a
/// block of bytes at a time (no call per value).
pub struct F64Values {
    data: Box<dyn Read + Send>,
    element: Element,
    big: bool,
    /// Values the header states that are not yet read.
    remaining: u64,
    bytes: Vec<u8>,
}

/// Values per block of [`F64Values::read_all`].
const BLOCK_VALUES: usize = 4096;

impl F64Values {
    /// Fills the front of `out` with the next `min(out.len(), remaining)` values; returns how
    /// many. An `UnexpectedEof` error when the data ends before the header's count.
    pub fn read(&mut self, out: &mut [f64]) -> io::Result<usize> {
        let n = out
            .len()
            .min(usize::try_from(self.remaining).unwrap_or(usize::MAX));
        self.bytes.resize(n * self.element.size(), 0);
        self.data.read_exact(&mut self.bytes)?;
        self.element.convert(self.big, &self.bytes, &mut out[..n]);
        self.remaining -= n as u64;
        Ok(n)
    }

    /// Every remaining value.
    pub fn read_all(mut self) -> io::Result<Vec<f64>> {
        let mut v = Vec::new();
        while self.remaining > 0 {
            let at = v.len();
            v.resize(at + BLOCK_VALUES, 0.0);
            let n = self.read(&mut v[at..])?;
            v.truncate(at + n);
        }
        Ok(v)
    }
}

/// Opens an `.npy` stream: returns its shape and its values in C order.
pub fn stream_f64<R: Read + Send + 'static>(reader: R) -> io::Result<(Vec<u64>, F64Values)> {
    let (header, data) = open_header(reader)?;
    if header.order() == Order::Fortran && header.shape().len() > 1 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            "Fortran-order arrays are not supported; save with np.ascontiguousarray",
        ));
    }
    let dtype = header.dtype();
    let Some((element, big)) = Element::parse(&dtype) else {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            format!(
                "unsupported npy dtype {}; expected a numeric array",
                dtype.descr()
            ),
        ));
    };
    let values = F64Values {
        data: Box::new(data),
        element,
        big,
        remaining: header.len(),
        bytes: Vec::new(),
    };
    Ok((header.shape().to_vec(), values))
}

/// Reads a whole `.npy` file as f64 values with its shape.
pub fn read_f64(path: &Path) -> Result<(Vec<u64>, Vec<f64>)> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let (shape, values) =
        stream_f64(BufReader::new(file)).with_context(|| format!("{}", path.display()))?;
    let data = values
        .read_all()
        .with_context(|| format!("{}: reading values", path.display()))?;
    Ok((shape, data))
}

/// Reads a whole `.npy` file of a given element type (no conversion).
pub fn read_exact<T: npyz::Deserialize>(path: &Path) -> Result<(Vec<u64>, Vec<T>)> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let npy = open_npy(BufReader::new(file))
        .with_context(|| format!("{}: not an npy file", path.display()))?;
    let shape = npy.shape().to_vec();
    let data = npy
        .into_vec::<T>()
        .with_context(|| format!("{}: unexpected dtype", path.display()))?;
    Ok((shape, data))
}

/// Writes a C-order array of the given shape.
pub fn write<T: npyz::AutoSerialize + Copy>(path: &Path, shape: &[u64], data: &[T]) -> Result<()> {
    let expected: u64 = shape.iter().product();
    if expected != data.len() as u64 {
        bail!("shape {shape:?} does not match {} values", data.len());
    }
    let file = File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
    let mut w = npyz::WriteOptions::new()
        .default_dtype()
        .shape(shape)
        .writer(BufWriter::new(file))
        .begin_nd()?;
    w.extend(data.iter().copied())?;
    w.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

/// A `.npy` file written row by row when the number of rows is not known in advance: the
/// header reserves room for the leading dimension and [`NpyAppender::finish`] patches it in.
/// (npyz writes a shape known up front; streaming a dataset of unknown size needs this.)
pub struct NpyAppender<T> {
    file: BufWriter<File>,
    path: std::path::PathBuf,
    /// The shape of one row (the array's shape after the leading dimension).
    row: Vec<u64>,
    rows: u64,
    _t: std::marker::PhantomData<T>,
}

/// Element types [`NpyAppender`] writes: little-endian numbers with numpy's type string.
pub trait NpyElement: Copy {
    /// numpy's `descr`, e.g. `<f4`.
    const DESCR: &'static str;
    /// Little-endian bytes of `v`, appended to `out`.
    fn put(v: Self, out: &mut Vec<u8>);
}

macro_rules! npy_element {
    ($($t:ty => $d:literal),*) => {$(
        impl NpyElement for $t {
            const DESCR: &'static str = $d;
            fn put(v: Self, out: &mut Vec<u8>) {
                out.extend_from_slice(&v.to_le_bytes());
            }
        }
    )*};
}
npy_element!(f32 => "<f4", f64 => "<f8", i64 => "<i8", i32 => "<i4", u32 => "<u4", u16 => "<u2", u8 => "|u1");

/// Bytes of the fixed `.npy` header [`NpyAppender`] writes (format 1.0; a multiple of 64).
const APPEND_HEADER: usize = 128;

impl<T: NpyElement> NpyAppender<T> {
    /// Creates `path` for rows of shape `row` (empty for a 1-D array).
    pub fn create(path: &Path, row: &[u64]) -> Result<Self> {
        let file =
            File::create(path).with_context(|| format!("cannot create {}", path.display()))?;
        let mut w = Self {
            file: BufWriter::new(file),
            path: path.to_path_buf(),
            row: row.to_vec(),
            rows: 0,
            _t: std::marker::PhantomData,
        };
        let header = w.header()?;
        io::Write::write_all(&mut w.file, &header)?;
        Ok(w)
    }

    fn header(&self) -> Result<Vec<u8>> {
        let mut shape = format!("{}", self.rows);
        for d in &self.row {
            shape.push_str(&format!(", {d}"));
        }
        if self.row.is_empty() {
            shape.push(',');
        }
        let dict = format!(
            "{{'descr': '{}', 'fortran_order': False, 'shape': ({shape}), }}",
            T::DESCR
        );
        let mut h = b"\x93NUMPY\x01\x00".to_vec();
        let len = APPEND_HEADER - 10;
        if dict.len() + 1 > len {
            bail!("npy header too long for {}", self.path.display());
        }
        h.extend_from_slice(&(len as u16).to_le_bytes());
        h.extend_from_slice(dict.as_bytes());
        h.resize(APPEND_HEADER - 1, b' ');
        h.push(b'\n');
        Ok(h)
    }

    /// Appends rows (`values.len()` a multiple of the row size).
    pub fn append(&mut self, values: &[T]) -> Result<()> {
        let per_row: u64 = self.row.iter().product();
        if per_row == 0 || !(values.len() as u64).is_multiple_of(per_row) {
            bail!(
                "{}: {} values are not whole rows",
                self.path.display(),
                values.len()
            );
        }
        let mut bytes = Vec::with_capacity(std::mem::size_of_val(values));
        for &v in values {
            T::put(v, &mut bytes);
        }
        io::Write::write_all(&mut self.file, &bytes)
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        self.rows += values.len() as u64 / per_row;
        Ok(())
    }

    /// Patches the row count into the header and closes the file; returns the rows.
    pub fn finish(mut self) -> Result<u64> {
        use std::io::{Seek, SeekFrom, Write};
        let header = self.header()?;
        self.file.flush()?;
        let mut f = self.file.into_inner().map_err(|e| e.into_error())?;
        f.seek(SeekFrom::Start(0))?;
        f.write_all(&header)
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        Ok(self.rows)
    }
}
