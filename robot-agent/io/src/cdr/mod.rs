//! ROS 2 message encoding: plain CDR (XCDR1) as rmw/DDS put it on the wire, a 4-byte
//! encapsulation header (`00 01` little-endian, `00 00` big-endian, two option bytes), then the
//! fields, each primitive aligned to its own size counted from the end of the header.
//!
//! Why not the `cdr` crate: its deserializer allocates a sequence's or string's stated length
//! before checking that the bytes are there, so a four-byte garbage length asks for up to 4 GiB;
//! input from the network must not be able to do that. This reader checks every length against
//! the bytes left before it allocates, and every failure is a [`CdrError`].

mod msgs;
mod pointcloud;

pub use msgs::*;
pub use pointcloud::{decode_point_cloud2, encode_point_cloud2};

/// Why a message could not be decoded.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum CdrError {
    /// The message ends before a field.
    #[error("truncated at byte {at}: {what} needs {need} bytes")]
    Truncated {
        /// Offset (after the header) where the field starts.
        at: usize,
        /// The field.
        what: &'static str,
        /// Bytes needed.
        need: usize,
    },
    /// Fewer than 4 bytes, or an encapsulation other than plain CDR LE/BE.
    #[error("unsupported CDR encapsulation {0:#06x}")]
    Encapsulation(u16),
    /// A string without its NUL terminator, or not UTF-8.
    #[error("bad string at byte {0}")]
    BadString(usize),
    /// A message that is well-formed CDR but not a usable message of its type.
    #[error("invalid {what}: {why}")]
    Invalid {
        /// The message or field.
        what: &'static str,
        /// Why.
        why: String,
    },
}

/// Encapsulation header of little-endian plain CDR (what every ROS 2 rmw on x86/ARM sends).
pub const CDR_LE_HEADER: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A bounds-checked cursor over one CDR message.
pub struct Reader<'a> {
    /// The body after the encapsulation header (alignment is relative to its start).
    body: &'a [u8],
    pos: usize,
    little: bool,
}

impl<'a> Reader<'a> {
    /// Starts reading a message that begins with its encapsulation header.
    pub fn new(message: &'a [u8]) -> Result<Self, CdrError> {
        if message.len() < 4 {
            return Err(CdrError::Encapsulation(0xffff));
        }
        let kind = u16::from_be_bytes([message[0], message[1]]);
        let little = match kind {
            0x0001 => true,
            0x0000 => false,
            other => return Err(CdrError::Encapsulation(other)),
        };
        Ok(Reader {
            body: &message[4..],
            pos: 0,
            little,
        })
    }

    /// Bytes not yet read.
    pub fn remaining(&self) -> usize {
        self.body.len() - self.pos
    }

    fn align(&mut self, n: usize, what: &'static str) -> Result<(), CdrError> {
        let pad = (n - self.pos % n) % n;
        if self.remaining() < pad {
            return Err(CdrError::Truncated {
                at: self.pos,
                what,
                need: pad,
            });
        }
        self.pos += pad;
        Ok(())
    }

    fn take(&mut self, n: usize, what: &'static str) -> Result<&'a [u8], CdrError> {
        if self.remaining() < n {
            return Err(CdrError::Truncated {
                at: self.pos,
                what,
                need: n,
            });
        }
        let s = &self.body[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn fixed<const N: usize>(&mut self, what: &'static str) -> Result<[u8; N], CdrError> {
        self.align(N, what)?;
        let mut b = [0u8; N];
        b.copy_from_slice(self.take(N, what)?);
        if !self.little {
            b.reverse();
        }
        Ok(b)
    }

    /// `uint8`.
    pub fn u8(&mut self, what: &'static str) -> Result<u8, CdrError> {
        Ok(self.take(1, what)?[0])
    }
    /// `int8`.
    pub fn i8(&mut self, what: &'static str) -> Result<i8, CdrError> {
        Ok(self.u8(what)? as i8)
    }
    /// `bool` (any non-zero byte is true).
    pub fn bool(&mut self, what: &'static str) -> Result<bool, CdrError> {
        Ok(self.u8(what)? != 0)
    }
    /// `uint16`.
    pub fn u16(&mut self, what: &'static str) -> Result<u16, CdrError> {
        Ok(u16::from_le_bytes(self.fixed(what)?))
    }
    /// `uint32`.
    pub fn u32(&mut self, what: &'static str) -> Result<u32, CdrError> {
        Ok(u32::from_le_bytes(self.fixed(what)?))
    }
    /// `int32`.
    pub fn i32(&mut self, what: &'static str) -> Result<i32, CdrError> {
        Ok(i32::from_le_bytes(self.fixed(what)?))
    }
    /// `float64`.
    pub fn f64(&mut self, what: &'static str) -> Result<f64, CdrError> {
        Ok(f64::from_le_bytes(self.fixed(what)?))
    }
    /// `float64[N]`.
    pub fn f64s<const N: usize>(&mut self, what: &'static str) -> Result<[f64; N], CdrError> {
        let mut out = [0.0; N];
        for v in &mut out {
            *v = self.f64(what)?;
        }
        Ok(out)
    }
    /// `string`: u32 length including the NUL, the bytes, the NUL.
    pub fn string(&mut self, what: &'static str) -> Result<String, CdrError> {
        let len = self.u32(what)? as usize;
        let at = self.pos;
        let bytes = self.take(len, what)?;
        match bytes.split_last() {
            Some((0, text)) => std::str::from_utf8(text)
                .map(str::to_owned)
                .map_err(|_| CdrError::BadString(at)),
            // Some writers send an empty string as length 0.
            None => Ok(String::new()),
            Some(_) => Err(CdrError::BadString(at)),
        }
    }
    /// A sequence length, checked against the bytes left (each element needs at least
    /// `min_element_bytes`), so a garbage length cannot make the caller allocate.
    pub fn seq_len(
        &mut self,
        min_element_bytes: usize,
        what: &'static str,
    ) -> Result<usize, CdrError> {
        let n = self.u32(what)? as usize;
        if n.saturating_mul(min_element_bytes.max(1)) > self.remaining() {
            return Err(CdrError::Truncated {
                at: self.pos,
                what,
                need: n.saturating_mul(min_element_bytes.max(1)),
            });
        }
        Ok(n)
    }
    /// `sequence<uint8>` as a slice of the message.
    pub fn bytes(&mut self, what: &'static str) -> Result<&'a [u8], CdrError> {
        let n = self.seq_len(1, what)?;
        self.take(n, what)
    }
}

/// Builds one CDR message (little-endian, with its encapsulation header).
pub struct Writer {
    buf: Vec<u8>,
}

impl Default for Writer {
    fn default() -> Self {
        Self::new()
    }
}

impl Writer {
    /// An empty little-endian message.
    pub fn new() -> Self {
        Writer {
            buf: CDR_LE_HEADER.to_vec(),
        }
    }
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }
    /// `uint8`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// `int8`.
    pub fn i8(&mut self, v: i8) {
        self.buf.push(v as u8);
    }
    /// `bool`.
    pub fn bool(&mut self, v: bool) {
        self.buf.push(v as u8);
    }
    /// `uint16`.
    pub fn u16(&mut self, v: u16) {
        self.align(2);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend_from_slice(&v.to_le_bytes());
    }
    /// `float64[N]`.
    pub fn f64s(&mut self, v: &[f64]) {
        for x in v {
            self.f64(*x);
        }
    }
    /// `string`.
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend_from_slice(s.as_bytes());
        self.buf.push(0);
    }
    /// `sequence<uint8>`.
    pub fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
    }
    /// The finished message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn big_endian_and_alignment() {
        // BE header, then u8 1, pad to 4, u32 0x01020304, pad to 8, f64 1.5.
        let mut m = vec![0, 0, 0, 0, 7, 0, 0, 0, 1, 2, 3, 4];
        m.extend_from_slice(&1.5f64.to_be_bytes());
        let mut r = Reader::new(&m).unwrap();
        assert_eq!(r.u8("a").unwrap(), 7);
        assert_eq!(r.u32("b").unwrap(), 0x01020304);
        assert_eq!(r.f64("c").unwrap(), 1.5);
        assert_eq!(r.remaining(), 0);
    }

    #[test]
    fn huge_lengths_are_errors_not_allocations() {
        let mut m = CDR_LE_HEADER.to_vec();
        m.extend_from_slice(&u32::MAX.to_le_bytes());
        assert!(matches!(
            Reader::new(&m).unwrap().string("s"),
            Err(CdrError::Truncated { .. })
        ));
        assert!(matches!(
            Reader::new(&m).unwrap().seq_len(8, "q"),
            Err(CdrError::Truncated { .. })
        ));
        assert!(matches!(
            Reader::new(&[1, 2]),
            Err(CdrError::Encapsulation(_))
        ));
        assert!(matches!(
            Reader::new(&[0, 2, 0, 0]),
            Err(CdrError::Encapsulation(2))
        ));
    }
}
