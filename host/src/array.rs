//! NumPy `.npy` array files: read any numeric array as f64, stream it, write f32/f64/i32 arrays.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read};
use std::path::Path;

use anyhow::{bail, Context, Result};
use npyz::{NpyFile, Order, WriterBuilder};

/// A stream of numbers from an `.npy` file, converted to f64 whatever the stored dtype.
pub type Values = Box<dyn Iterator<Item = io::Result<f64>> + Send>;

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

/// Opens an `.npy` stream after checking its header: at most [`MAX_HEADER_BYTES`] long and
/// [`MAX_HEADER_DEPTH`] deep.
fn open_npy<R: Read>(mut reader: R) -> io::Result<NpyFile<io::Chain<io::Cursor<Vec<u8>>, R>>> {
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
    NpyFile::new(io::Cursor::new(pre).chain(reader))
}

/// Opens an `.npy` stream: returns its shape and an iterator over its values in C order.
pub fn stream_f64<R: Read + Send + 'static>(reader: R) -> io::Result<(Vec<u64>, Values)> {
    let npy = open_npy(reader)?;
    if npy.order() == Order::Fortran && npy.shape().len() > 1 {
        return Err(io::Error::new(
            io::ErrorKind::InvalidData,
            "Fortran-order arrays are not supported; save with np.ascontiguousarray",
        ));
    }
    let shape = npy.shape().to_vec();
    let dtype = npy.dtype().descr();
    macro_rules! try_types {
        ($npy:ident; $($t:ty),*) => {{
            let npy = $npy;
            $(
                let npy = match npy.try_data::<$t>() {
                    Ok(r) => {
                        let it: Values = Box::new(r.map(|v| v.map(|v| v as f64)));
                        return Ok((shape, it));
                    }
                    Err(npy) => npy,
                };
            )*
            drop(npy);
        }};
    }
    try_types!(npy; f64, f32, i64, i32, i16, i8, u64, u32, u16, u8);
    Err(io::Error::new(
        io::ErrorKind::InvalidData,
        format!("unsupported npy dtype {dtype}; expected a numeric array"),
    ))
}

/// Reads a whole `.npy` file as f64 values with its shape.
pub fn read_f64(path: &Path) -> Result<(Vec<u64>, Vec<f64>)> {
    let file = File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
    let (shape, values) =
        stream_f64(BufReader::new(file)).with_context(|| format!("{}", path.display()))?;
    let data = values
        .collect::<io::Result<Vec<f64>>>()
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
