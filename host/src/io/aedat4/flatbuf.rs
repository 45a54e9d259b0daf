//! The bounds-checked flatbuffer reader AEDAT 4.0's headers and packets need.

use super::super::ReadError;

/// A flatbuffer in memory; `offset` is the file offset named in errors.
#[derive(Clone, Copy)]
pub(super) struct Flatbuffer<'a> {
    pub(super) buf: &'a [u8],
    pub(super) offset: u64,
    pub(super) what: &'static str,
}

impl<'a> Flatbuffer<'a> {
    pub(super) fn corrupt(&self, message: String) -> ReadError {
        ReadError::Corrupt {
            offset: self.offset,
            message: format!("{}: {message}", self.what),
        }
    }

    pub(super) fn bytes(&self, pos: usize, len: usize) -> Result<&'a [u8], ReadError> {
        pos.checked_add(len)
            .and_then(|end| self.buf.get(pos..end))
            .ok_or_else(|| {
                self.corrupt(format!(
                    "{len} bytes at {pos} are outside the {}-byte buffer",
                    self.buf.len()
                ))
            })
    }

    pub(super) fn array<const N: usize>(&self, pos: usize) -> Result<[u8; N], ReadError> {
        let mut out = [0u8; N];
        out.copy_from_slice(self.bytes(pos, N)?);
        Ok(out)
    }

    pub(super) fn u16(&self, pos: usize) -> Result<u16, ReadError> {
        self.array(pos).map(u16::from_le_bytes)
    }

    pub(super) fn u32(&self, pos: usize) -> Result<u32, ReadError> {
        self.array(pos).map(u32::from_le_bytes)
    }

    pub(super) fn i32(&self, pos: usize) -> Result<i32, ReadError> {
        self.array(pos).map(i32::from_le_bytes)
    }

    pub(super) fn i64(&self, pos: usize) -> Result<i64, ReadError> {
        self.array(pos).map(i64::from_le_bytes)
    }

    /// The position `pos` plus the unsigned offset stored there.
    pub(super) fn follow(&self, pos: usize) -> Result<usize, ReadError> {
        let target = usize::try_from(self.u32(pos)?)
            .ok()
            .and_then(|d| pos.checked_add(d))
            .filter(|&t| t < self.buf.len());
        target.ok_or_else(|| self.corrupt(format!("offset at {pos} points outside the buffer")))
    }

    /// Checks the 4-byte file identifier.
    pub(super) fn expect_identifier(&self, id: &[u8; 4]) -> Result<(), ReadError> {
        let found = self.bytes(4, 4)?;
        if found == id {
            Ok(())
        } else {
            Err(self.corrupt(format!(
                "file identifier is {:?}, expected {:?}",
                String::from_utf8_lossy(found),
                String::from_utf8_lossy(id)
            )))
        }
    }

    pub(super) fn root(&self) -> Result<Table<'a>, ReadError> {
        Table::at(*self, self.follow(0)?)
    }
}

/// A flatbuffer table with its vtable.
pub(super) struct Table<'a> {
    pub(super) fb: Flatbuffer<'a>,
    pub(super) pos: usize,
    pub(super) vtable: usize,
    pub(super) vtable_len: usize,
    pub(super) table_len: usize,
}

impl<'a> Table<'a> {
    pub(super) fn at(fb: Flatbuffer<'a>, pos: usize) -> Result<Self, ReadError> {
        let soffset = i64::from(fb.i32(pos)?);
        let vtable = i64::try_from(pos)
            .ok()
            .map(|p| p - soffset)
            .and_then(|v| usize::try_from(v).ok())
            .ok_or_else(|| fb.corrupt(format!("vtable of the table at {pos} is out of range")))?;
        let vtable_len = usize::from(fb.u16(vtable)?);
        let table_len = usize::from(fb.u16(vtable + 2)?);
        if vtable_len < 4 || vtable_len % 2 != 0 || table_len < 4 {
            return Err(fb.corrupt(format!("vtable at {vtable} has bad sizes")));
        }
        fb.bytes(vtable, vtable_len)?;
        fb.bytes(pos, table_len)?;
        Ok(Self {
            fb,
            pos,
            vtable,
            vtable_len,
            table_len,
        })
    }

    /// Buffer position of field `index` (`size` bytes inline), or `None` when absent.
    pub(super) fn field(&self, index: usize, size: usize) -> Result<Option<usize>, ReadError> {
        let entry = 4 + 2 * index;
        if entry + 2 > self.vtable_len {
            return Ok(None);
        }
        let at = usize::from(self.fb.u16(self.vtable + entry)?);
        if at == 0 {
            return Ok(None);
        }
        if at < 4 || at + size > self.table_len {
            return Err(self
                .fb
                .corrupt(format!("field {index} lies outside its table")));
        }
        Ok(Some(self.pos + at))
    }

    pub(super) fn i32_or(&self, index: usize, default: i32) -> Result<i32, ReadError> {
        self.field(index, 4)?
            .map_or(Ok(default), |p| self.fb.i32(p))
    }

    pub(super) fn i64_or(&self, index: usize, default: i64) -> Result<i64, ReadError> {
        self.field(index, 8)?
            .map_or(Ok(default), |p| self.fb.i64(p))
    }

    pub(super) fn string(&self, index: usize) -> Result<Option<&'a str>, ReadError> {
        let Some(p) = self.field(index, 4)? else {
            return Ok(None);
        };
        let at = self.fb.follow(p)?;
        let len = self.fb.u32(at)? as usize;
        let bytes = self.fb.bytes(at + 4, len)?;
        std::str::from_utf8(bytes).map(Some).map_err(|e| {
            self.fb
                .corrupt(format!("string field {index} is not UTF-8: {e}"))
        })
    }

    /// Start and length of the vector in field `index` with `elem`-byte elements.
    pub(super) fn vector(
        &self,
        index: usize,
        elem: usize,
    ) -> Result<Option<(usize, usize)>, ReadError> {
        let Some(p) = self.field(index, 4)? else {
            return Ok(None);
        };
        let at = self.fb.follow(p)?;
        let count = self.fb.u32(at)? as usize;
        let bytes = count.checked_mul(elem).ok_or_else(|| {
            self.fb
                .corrupt(format!("vector of {count} elements overflows"))
        })?;
        self.fb.bytes(at + 4, bytes)?;
        Ok(Some((at + 4, count)))
    }
}

// ---------------------------------------------------------------------------------------------
// The infoNode XML.
