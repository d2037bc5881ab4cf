//! Little-endian plain CDR (XCDR version 1, encapsulation `CDR_LE`), the serialisation ROS 2
//! messages travel in over rmw_zenoh (and DDS).
//!
//! A payload is the 4-byte encapsulation header [`CDR_LE_HEADER`] (`00 01` = CDR, little
//! endian; `00 00` = options) followed by the body. In the body every primitive is aligned to
//! its own size (1, 2, 4 or 8 bytes) counted from the first byte *after* the header; the
//! writer pads with zeros, the reader skips padding whatever its value. Strings are a `u32`
//! length that counts the terminating NUL, the bytes, then the NUL; sequences are a `u32`
//! element count then the elements; fixed arrays are the elements alone. Structures have no
//! alignment of their own (XCDR1 plain, "final" types): their first member aligns itself.
//!
//! [`CdrReader`] never panics: truncated or malformed input gives a [`CdrError`]. It accepts at
//! most 3 bytes after the last member when they only pad the body to a multiple of 4 (some
//! serialisers, e.g. Fast-CDR, append them); rosbags accepts the same.

/// Encapsulation header of a little-endian plain CDR payload (`CDR_LE`, options 0).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// Bytes in the encapsulation header.
pub const HEADER_LEN: usize = 4;

/// Why a CDR payload could not be written or read. Byte offsets (`at_byte`) count from the
/// start of the payload, header included.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum CdrError {
    /// Fewer than 4 bytes: not even an encapsulation header.
    #[error("payload of {len_bytes} bytes has no 4-byte CDR encapsulation header")]
    MissingHeader {
        /// Length of the payload.
        len_bytes: usize,
    },
    /// The header is not `CDR_LE` (big-endian, XCDR2, parameter lists, ... are not supported).
    #[error("encapsulation header {found:02x?} is not CDR_LE (00 01 00 00)")]
    UnsupportedEncapsulation {
        /// The four header bytes.
        found: [u8; 4],
    },
    /// The payload ends inside a value.
    #[error("truncated at byte {at_byte}: {needed_bytes} bytes needed, {available_bytes} left")]
    Truncated {
        /// Where the value starts.
        at_byte: usize,
        /// Bytes the value needs.
        needed_bytes: usize,
        /// Bytes left in the payload.
        available_bytes: usize,
    },
    /// A string length of 0: a CDR string always counts its terminating NUL.
    #[error("string at byte {at_byte} has length 0 (CDR counts the terminating NUL)")]
    StringLengthZero {
        /// Where the length is.
        at_byte: usize,
    },
    /// The last byte of a string is not NUL, or a NUL occurs before it.
    #[error("string at byte {at_byte} is not a NUL-terminated string without inner NULs")]
    StringNotTerminated {
        /// Where the string's bytes start.
        at_byte: usize,
    },
    /// A string's bytes are not UTF-8.
    #[error("string at byte {at_byte} is not UTF-8")]
    StringNotUtf8 {
        /// Where the string's bytes start.
        at_byte: usize,
    },
    /// A boolean other than 0 or 1.
    #[error("boolean at byte {at_byte} is {value}, not 0 or 1")]
    InvalidBool {
        /// Where the boolean is.
        at_byte: usize,
        /// Its value.
        value: u8,
    },
    /// A sequence count larger than the rest of the payload could hold (checked before
    /// anything is allocated).
    #[error(
        "sequence at byte {at_byte} claims {count} elements of at least {min_element_bytes} bytes; \
         only {available_bytes} bytes are left"
    )]
    SequenceTooLong {
        /// Where the count is.
        at_byte: usize,
        /// The count.
        count: u32,
        /// Smallest encoded size of one element.
        min_element_bytes: usize,
        /// Bytes left after the count.
        available_bytes: usize,
    },
    /// Bytes left after the last member that are not just padding to a multiple of 4.
    #[error("{trailing_bytes} unexpected bytes after the message, from byte {at_byte}")]
    TrailingBytes {
        /// Where they start.
        at_byte: usize,
        /// How many.
        trailing_bytes: usize,
    },
    /// The writer was given a string with a NUL inside (ROS strings are C strings).
    #[error("cannot write a string containing NUL")]
    NulInString,
    /// The writer was given a string or sequence longer than a `u32` count can describe.
    #[error("cannot write {len} elements: more than a u32 count")]
    TooLong {
        /// The length.
        len: usize,
    },
}

/// Writes one CDR_LE payload into a `Vec<u8>`.
///
/// The write methods never fail; the first error (a string with a NUL, a length beyond
/// `u32`) is kept and returned by [`CdrWriter::finish`], which also hands the buffer back.
#[derive(Debug)]
pub struct CdrWriter {
    buf: Vec<u8>,
    error: Option<CdrError>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        Self::new()
    }
}

impl CdrWriter {
    /// A writer with the encapsulation header already written.
    pub fn new() -> Self {
        Self::reusing(Vec::with_capacity(128))
    }

    /// A writer that reuses `buf`'s allocation: it is cleared and the header written.
    pub fn reusing(mut buf: Vec<u8>) -> Self {
        buf.clear();
        buf.extend_from_slice(&CDR_LE_HEADER);
        CdrWriter { buf, error: None }
    }

    /// Bytes written to the body so far (the position alignment counts from).
    pub fn body_len(&self) -> usize {
        self.buf.len().saturating_sub(HEADER_LEN)
    }

    /// The payload, or the first error a write ran into.
    pub fn finish(self) -> Result<Vec<u8>, CdrError> {
        match self.error {
            Some(e) => Err(e),
            None => Ok(self.buf),
        }
    }

    fn fail(&mut self, e: CdrError) {
        if self.error.is_none() {
            self.error = Some(e);
        }
    }

    fn align(&mut self, size: usize) {
        let rem = self.body_len() % size;
        if rem != 0 {
            self.buf.resize(self.buf.len() + (size - rem), 0);
        }
    }

    /// Writes a `u8` (`uint8`, `byte`, `char`).
    pub fn write_u8(&mut self, v: u8) {
        self.buf.push(v);
    }

    /// Writes an `i8`.
    pub fn write_i8(&mut self, v: i8) {
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a `bool` as one byte, 0 or 1.
    pub fn write_bool(&mut self, v: bool) {
        self.buf.push(u8::from(v));
    }

    /// Writes a `u16`, aligned to 2.
    pub fn write_u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an `i16`, aligned to 2.
    pub fn write_i16(&mut self, v: i16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a `u32`, aligned to 4.
    pub fn write_u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an `i32`, aligned to 4.
    pub fn write_i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a `u64`, aligned to 8.
    pub fn write_u64(&mut self, v: u64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an `i64`, aligned to 8.
    pub fn write_i64(&mut self, v: i64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an `f32`, aligned to 4.
    pub fn write_f32(&mut self, v: f32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes an `f64`, aligned to 8.
    pub fn write_f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }

    /// Writes a sequence's element count (`u32`, aligned to 4); the caller writes the
    /// elements.
    pub fn write_sequence_len(&mut self, len: usize) {
        match u32::try_from(len) {
            Ok(n) => self.write_u32(n),
            Err(_) => self.fail(CdrError::TooLong { len }),
        }
    }

    /// Writes a string: `u32` length including the NUL, the bytes, the NUL.
    pub fn write_string(&mut self, s: &str) {
        if s.as_bytes().contains(&0) {
            self.fail(CdrError::NulInString);
            return;
        }
        let Some(len_with_nul) = s.len().checked_add(1) else {
            self.fail(CdrError::TooLong { len: s.len() });
            return;
        };
        match u32::try_from(len_with_nul) {
            Ok(n) => {
                self.write_u32(n);
                self.buf.extend_from_slice(s.as_bytes());
                self.buf.push(0);
            }
            Err(_) => self.fail(CdrError::TooLong { len: s.len() }),
        }
    }

    /// Writes a `float32[]` sequence.
    pub fn write_f32_sequence(&mut self, values: &[f32]) {
        self.write_sequence_len(values.len());
        for &v in values {
            self.write_f32(v);
        }
    }

    /// Writes a `float64[]` sequence.
    pub fn write_f64_sequence(&mut self, values: &[f64]) {
        self.write_sequence_len(values.len());
        for &v in values {
            self.write_f64(v);
        }
    }

    /// Writes an `int32[]` sequence.
    pub fn write_i32_sequence(&mut self, values: &[i32]) {
        self.write_sequence_len(values.len());
        for &v in values {
            self.write_i32(v);
        }
    }

    /// Writes a fixed `float64[N]` array (no count).
    pub fn write_f64_array(&mut self, values: &[f64]) {
        for &v in values {
            self.write_f64(v);
        }
    }
}

/// Reads one CDR_LE payload. Every method checks the bounds first and never panics.
#[derive(Clone, Debug)]
pub struct CdrReader<'a> {
    body: &'a [u8],
    pos: usize,
}

impl<'a> CdrReader<'a> {
    /// A reader over `payload`, after checking its encapsulation header: `00 01` (CDR, little
    /// endian), then options `00 00` to `00 03` (the low bits may count end padding; the
    /// padding rule of [`CdrReader::finish`] covers it either way).
    pub fn new(payload: &'a [u8]) -> Result<Self, CdrError> {
        let (Some(header), Some(body)) = (payload.get(..HEADER_LEN), payload.get(HEADER_LEN..))
        else {
            return Err(CdrError::MissingHeader {
                len_bytes: payload.len(),
            });
        };
        let found = [header[0], header[1], header[2], header[3]];
        if found[0] != 0x00 || found[1] != 0x01 || found[2] != 0x00 || found[3] > 0x03 {
            return Err(CdrError::UnsupportedEncapsulation { found });
        }
        Ok(CdrReader { body, pos: 0 })
    }

    /// Byte offset in the payload (header included) of the next read.
    pub fn at_byte(&self) -> usize {
        self.pos + HEADER_LEN
    }

    /// Bytes not yet read.
    pub fn remaining_bytes(&self) -> usize {
        self.body.len().saturating_sub(self.pos)
    }

    /// Checks that the message ended here: nothing left but at most 3 bytes padding the body
    /// to a multiple of 4.
    pub fn finish(self) -> Result<(), CdrError> {
        let trailing_bytes = self.remaining_bytes();
        if trailing_bytes == 0 || (trailing_bytes < 4 && self.body.len().is_multiple_of(4)) {
            Ok(())
        } else {
            Err(CdrError::TrailingBytes {
                at_byte: self.at_byte(),
                trailing_bytes,
            })
        }
    }

    fn align(&mut self, size: usize) -> Result<(), CdrError> {
        let rem = self.pos % size;
        if rem != 0 {
            let pad = size - rem;
            if self.remaining_bytes() < pad {
                return Err(self.truncated(pad));
            }
            self.pos += pad;
        }
        Ok(())
    }

    fn truncated(&self, needed_bytes: usize) -> CdrError {
        CdrError::Truncated {
            at_byte: self.at_byte(),
            needed_bytes,
            available_bytes: self.remaining_bytes(),
        }
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], CdrError> {
        let body: &'a [u8] = self.body;
        let end = self.pos.checked_add(n).ok_or_else(|| self.truncated(n))?;
        let bytes = body.get(self.pos..end).ok_or_else(|| self.truncated(n))?;
        self.pos = end;
        Ok(bytes)
    }

    fn take_array<const N: usize>(&mut self) -> Result<[u8; N], CdrError> {
        self.align(N)?;
        let bytes = self.take(N)?;
        let mut out = [0u8; N];
        out.copy_from_slice(bytes);
        Ok(out)
    }

    /// Reads a `u8`.
    pub fn read_u8(&mut self) -> Result<u8, CdrError> {
        Ok(self.take_array::<1>()?[0])
    }

    /// Reads an `i8`.
    pub fn read_i8(&mut self) -> Result<i8, CdrError> {
        Ok(i8::from_le_bytes(self.take_array::<1>()?))
    }

    /// Reads a `bool`; anything but 0 or 1 is an error.
    pub fn read_bool(&mut self) -> Result<bool, CdrError> {
        let at_byte = self.at_byte();
        match self.read_u8()? {
            0 => Ok(false),
            1 => Ok(true),
            value => Err(CdrError::InvalidBool { at_byte, value }),
        }
    }

    /// Reads a `u16`.
    pub fn read_u16(&mut self) -> Result<u16, CdrError> {
        Ok(u16::from_le_bytes(self.take_array::<2>()?))
    }

    /// Reads an `i16`.
    pub fn read_i16(&mut self) -> Result<i16, CdrError> {
        Ok(i16::from_le_bytes(self.take_array::<2>()?))
    }

    /// Reads a `u32`.
    pub fn read_u32(&mut self) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.take_array::<4>()?))
    }

    /// Reads an `i32`.
    pub fn read_i32(&mut self) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.take_array::<4>()?))
    }

    /// Reads a `u64`.
    pub fn read_u64(&mut self) -> Result<u64, CdrError> {
        Ok(u64::from_le_bytes(self.take_array::<8>()?))
    }

    /// Reads an `i64`.
    pub fn read_i64(&mut self) -> Result<i64, CdrError> {
        Ok(i64::from_le_bytes(self.take_array::<8>()?))
    }

    /// Reads an `f32` (any bit pattern; check finiteness where it matters).
    pub fn read_f32(&mut self) -> Result<f32, CdrError> {
        Ok(f32::from_le_bytes(self.take_array::<4>()?))
    }

    /// Reads an `f64` (any bit pattern; check finiteness where it matters).
    pub fn read_f64(&mut self) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.take_array::<8>()?))
    }

    /// Reads a sequence's element count and checks that `count` elements of at least
    /// `min_element_bytes` each fit in what is left, so a corrupt count never makes the
    /// caller allocate.
    pub fn read_sequence_len(&mut self, min_element_bytes: usize) -> Result<usize, CdrError> {
        let at_byte = self.at_byte();
        let count = self.read_u32()?;
        let count_usize = usize::try_from(count).unwrap_or(usize::MAX);
        let available_bytes = self.remaining_bytes();
        let needed = count_usize.checked_mul(min_element_bytes.max(1));
        match needed {
            Some(n) if n <= available_bytes => Ok(count_usize),
            _ => Err(CdrError::SequenceTooLong {
                at_byte,
                count,
                min_element_bytes,
                available_bytes,
            }),
        }
    }

    /// Reads a string, borrowed from the payload.
    pub fn read_str(&mut self) -> Result<&'a str, CdrError> {
        let len_at_byte = self.at_byte();
        let len = self.read_u32()?;
        if len == 0 {
            return Err(CdrError::StringLengthZero {
                at_byte: len_at_byte,
            });
        }
        let at_byte = self.at_byte();
        let len = usize::try_from(len).unwrap_or(usize::MAX);
        let bytes = self.take(len)?;
        let Some((&last, text)) = bytes.split_last() else {
            return Err(CdrError::StringLengthZero {
                at_byte: len_at_byte,
            });
        };
        if last != 0 || text.contains(&0) {
            return Err(CdrError::StringNotTerminated { at_byte });
        }
        std::str::from_utf8(text).map_err(|_| CdrError::StringNotUtf8 { at_byte })
    }

    /// Reads a string into an owned `String`.
    pub fn read_string(&mut self) -> Result<String, CdrError> {
        self.read_str().map(str::to_owned)
    }

    /// Reads a `float32[]` sequence.
    pub fn read_f32_sequence(&mut self) -> Result<Vec<f32>, CdrError> {
        let n = self.read_sequence_len(4)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(self.read_f32()?);
        }
        Ok(out)
    }

    /// Reads a `float64[]` sequence.
    pub fn read_f64_sequence(&mut self) -> Result<Vec<f64>, CdrError> {
        let n = self.read_sequence_len(8)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(self.read_f64()?);
        }
        Ok(out)
    }

    /// Reads an `int32[]` sequence.
    pub fn read_i32_sequence(&mut self) -> Result<Vec<i32>, CdrError> {
        let n = self.read_sequence_len(4)?;
        let mut out = Vec::with_capacity(n);
        for _ in 0..n {
            out.push(self.read_i32()?);
        }
        Ok(out)
    }

    /// Reads a fixed `float64[N]` array (no count).
    pub fn read_f64_array<const N: usize>(&mut self) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.read_f64()?;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)]
    use super::*;

    #[test]
    fn alignment_counts_from_after_the_header() {
        let mut w = CdrWriter::new();
        w.write_u8(7);
        w.write_f64(1.0);
        w.write_u16(0x0102);
        w.write_u32(0x0304_0506);
        let bytes = w.finish().unwrap();
        let mut want = CDR_LE_HEADER.to_vec();
        want.extend_from_slice(&[7, 0, 0, 0, 0, 0, 0, 0]);
        want.extend_from_slice(&1.0f64.to_le_bytes());
        want.extend_from_slice(&[0x02, 0x01, 0, 0, 0x06, 0x05, 0x04, 0x03]);
        assert_eq!(bytes, want);

        let mut r = CdrReader::new(&bytes).unwrap();
        assert_eq!(r.read_u8().unwrap(), 7);
        assert_eq!(r.read_f64().unwrap(), 1.0);
        assert_eq!(r.read_u16().unwrap(), 0x0102);
        assert_eq!(r.read_u32().unwrap(), 0x0304_0506);
        r.finish().unwrap();
    }

    #[test]
    fn strings_count_their_nul() {
        let mut w = CdrWriter::new();
        w.write_string("abc");
        w.write_string("");
        let bytes = w.finish().unwrap();
        assert_eq!(
            &bytes[4..],
            &[4, 0, 0, 0, b'a', b'b', b'c', 0, 1, 0, 0, 0, 0][..]
        );
        let mut r = CdrReader::new(&bytes).unwrap();
        assert_eq!(r.read_str().unwrap(), "abc");
        assert_eq!(r.read_str().unwrap(), "");
        r.finish().unwrap();
    }

    #[test]
    fn writer_refuses_nul_in_strings() {
        let mut w = CdrWriter::new();
        w.write_string("a\0b");
        assert_eq!(w.finish(), Err(CdrError::NulInString));
    }

    #[test]
    fn header_is_checked() {
        assert_eq!(
            CdrReader::new(&[0, 1, 0]).err(),
            Some(CdrError::MissingHeader { len_bytes: 3 })
        );
        assert!(matches!(
            CdrReader::new(&[0, 0, 0, 0, 1, 2, 3, 4]),
            Err(CdrError::UnsupportedEncapsulation { .. })
        ));
        assert!(CdrReader::new(&CDR_LE_HEADER).is_ok());
    }

    #[test]
    fn truncation_is_an_error_everywhere() {
        let mut w = CdrWriter::new();
        w.write_string("frame");
        w.write_f64(2.5);
        w.write_f32_sequence(&[1.0, 2.0]);
        let bytes = w.finish().unwrap();
        for cut in 0..bytes.len() {
            let r = CdrReader::new(&bytes[..cut]).and_then(|mut r| {
                r.read_str()?;
                r.read_f64()?;
                r.read_f32_sequence()?;
                r.finish()
            });
            assert!(r.is_err(), "cut at {cut} accepted");
        }
    }

    #[test]
    fn malformed_values_are_rejected() {
        let mut bad_bool = CDR_LE_HEADER.to_vec();
        bad_bool.push(2);
        assert_eq!(
            CdrReader::new(&bad_bool).unwrap().read_bool(),
            Err(CdrError::InvalidBool {
                at_byte: 4,
                value: 2
            })
        );

        let mut zero_len = CDR_LE_HEADER.to_vec();
        zero_len.extend_from_slice(&0u32.to_le_bytes());
        assert!(matches!(
            CdrReader::new(&zero_len).unwrap().read_str(),
            Err(CdrError::StringLengthZero { .. })
        ));

        let mut no_nul = CDR_LE_HEADER.to_vec();
        no_nul.extend_from_slice(&[2, 0, 0, 0, b'a', b'b']);
        assert!(matches!(
            CdrReader::new(&no_nul).unwrap().read_str(),
            Err(CdrError::StringNotTerminated { .. })
        ));

        let mut not_utf8 = CDR_LE_HEADER.to_vec();
        not_utf8.extend_from_slice(&[2, 0, 0, 0, 0xff, 0]);
        assert!(matches!(
            CdrReader::new(&not_utf8).unwrap().read_str(),
            Err(CdrError::StringNotUtf8 { .. })
        ));

        let mut huge_seq = CDR_LE_HEADER.to_vec();
        huge_seq.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            CdrReader::new(&huge_seq).unwrap().read_f64_sequence(),
            Err(CdrError::SequenceTooLong { .. })
        ));
    }

    #[test]
    fn end_padding_up_to_a_multiple_of_four_is_accepted_more_is_not() {
        let mut padded = CDR_LE_HEADER.to_vec();
        padded.extend_from_slice(&[1, 0, 0, 0]);
        let mut r = CdrReader::new(&padded).unwrap();
        assert!(r.read_bool().unwrap());
        r.finish().unwrap();

        let mut extra = CDR_LE_HEADER.to_vec();
        extra.extend_from_slice(&[1, 0, 0, 0, 0]);
        let mut r = CdrReader::new(&extra).unwrap();
        assert!(r.read_bool().unwrap());
        assert_eq!(
            r.finish(),
            Err(CdrError::TrailingBytes {
                at_byte: 5,
                trailing_bytes: 4
            })
        );
    }
}
