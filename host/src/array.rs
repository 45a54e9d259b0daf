//! NumPy `.npy` array files: read any numeric array as f64, stream it, write f32/f64/i32 arrays.

use std::fs::File;
use std::io::{self, BufReader, BufWriter, Read};
use std::path::Path;

use anyhow::{bail, Context, Result};
use npyz::{NpyFile, Order, WriterBuilder};

/// A stream of numbers from an `.npy` file, converted to f64 whatever the stored dtype.
pub type Values = Box<dyn Iterator<Item = io::Result<f64>> + Send>;

/// Opens an `.npy` stream: returns its shape and an iterator over its values in C order.
pub fn stream_f64<R: Read + Send + 'static>(reader: R) -> io::Result<(Vec<u64>, Values)> {
    let npy = NpyFile::new(reader)?;
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
    let npy = NpyFile::new(BufReader::new(file))
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
