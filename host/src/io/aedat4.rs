//! iniVation DV AEDAT 4.0 reader (placeholder; being written).

use std::io::Read;

use super::{Batch, EventReader, ReadError, StreamInfo};

/// Streaming AEDAT 4.0 reader.
pub struct Aedat4Reader<R> {
    _inner: R,
    info: StreamInfo,
}

impl<R: Read> Aedat4Reader<R> {
    /// Parses the header.
    pub fn new(_inner: R) -> Result<Self, ReadError> {
        Err(ReadError::Unsupported(
            "AEDAT 4 reader not yet written".into(),
        ))
    }
}

impl<R: Read> EventReader for Aedat4Reader<R> {
    fn info(&self) -> &StreamInfo {
        &self.info
    }
    fn read_batch(&mut self, _batch: &mut Batch) -> Result<bool, ReadError> {
        Ok(false)
    }
}
