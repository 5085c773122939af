//! The attachment rmw_zenoh puts on every sample, in Zenoh's own serialisation (zenoh-ext:
//! strings and byte buffers as a LEB128 length then the bytes, integers little-endian):
//!
//! - Jazzy/Kilted form: `"sequence_number"`, i64, `"source_timestamp"`, i64, `"source_gid"`,
//!   16-byte buffer (the keys are written out);
//! - the later compact form: i64, i64, 16-byte buffer (33 bytes, no keys).
//!
//! We write the keyed form (what Jazzy reads) and read both.

/// Sample metadata of the rmw form.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Attachment {
    /// Per-publisher sequence number, from 1.
    pub sequence_number: i64,
    /// Send time, nanoseconds since the Unix epoch.
    pub source_timestamp_ns: i64,
    /// The publisher's GID.
    pub source_gid: [u8; 16],
}

/// Why an attachment could not be read.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("bad rmw_zenoh attachment: {0}")]
pub struct AttachmentError(pub &'static str);

fn put_len(out: &mut Vec<u8>, mut n: usize) {
    loop {
        let b = (n & 0x7f) as u8;
        n >>= 7;
        if n == 0 {
            out.push(b);
            return;
        }
        out.push(b | 0x80);
    }
}

fn put_buf(out: &mut Vec<u8>, b: &[u8]) {
    put_len(out, b.len());
    out.extend_from_slice(b);
}

struct Cursor<'a>(&'a [u8]);

impl<'a> Cursor<'a> {
    fn len(&mut self) -> Result<usize, AttachmentError> {
        let mut n = 0usize;
        for shift in (0..64).step_by(7) {
            let (&b, rest) = self
                .0
                .split_first()
                .ok_or(AttachmentError("truncated length"))?;
            self.0 = rest;
            n |= ((b & 0x7f) as usize) << shift;
            if b & 0x80 == 0 {
                return Ok(n);
            }
        }
        Err(AttachmentError("length too long"))
    }
    fn buf(&mut self) -> Result<&'a [u8], AttachmentError> {
        let n = self.len()?;
        if n > self.0.len() {
            return Err(AttachmentError("truncated buffer"));
        }
        let (b, rest) = self.0.split_at(n);
        self.0 = rest;
        Ok(b)
    }
    fn i64(&mut self) -> Result<i64, AttachmentError> {
        if self.0.len() < 8 {
            return Err(AttachmentError("truncated integer"));
        }
        let (b, rest) = self.0.split_at(8);
        self.0 = rest;
        Ok(i64::from_le_bytes(
            b.try_into().map_err(|_| AttachmentError("integer"))?,
        ))
    }
    fn key(&mut self, want: &str) -> Result<(), AttachmentError> {
        if self.buf()? == want.as_bytes() {
            Ok(())
        } else {
            Err(AttachmentError("unexpected key"))
        }
    }
}

impl Attachment {
    /// The keyed (Jazzy) serialisation.
    pub fn encode(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(80);
        put_buf(&mut out, b"sequence_number");
        out.extend_from_slice(&self.sequence_number.to_le_bytes());
        put_buf(&mut out, b"source_timestamp");
        out.extend_from_slice(&self.source_timestamp_ns.to_le_bytes());
        put_buf(&mut out, b"source_gid");
        put_buf(&mut out, &self.source_gid);
        out
    }

    /// Reads either form.
    pub fn decode(bytes: &[u8]) -> Result<Self, AttachmentError> {
        let gid = |b: &[u8]| -> Result<[u8; 16], AttachmentError> {
            b.try_into()
                .map_err(|_| AttachmentError("source_gid is not 16 bytes"))
        };
        let mut c = Cursor(bytes);
        if bytes.len() == 33 && bytes[16] == 16 {
            let sequence_number = c.i64()?;
            let source_timestamp_ns = c.i64()?;
            let source_gid = gid(c.buf()?)?;
            return Ok(Attachment {
                sequence_number,
                source_timestamp_ns,
                source_gid,
            });
        }
        c.key("sequence_number")?;
        let sequence_number = c.i64()?;
        c.key("source_timestamp")?;
        let source_timestamp_ns = c.i64()?;
        c.key("source_gid")?;
        let source_gid = gid(c.buf()?)?;
        if !c.0.is_empty() {
            return Err(AttachmentError("trailing bytes"));
        }
        Ok(Attachment {
            sequence_number,
            source_timestamp_ns,
            source_gid,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_forms_decode() {
        let a = Attachment {
            sequence_number: 42,
            source_timestamp_ns: 1_700_000_000_123_456_789,
            source_gid: [7; 16],
        };
        let keyed = a.encode();
        assert_eq!(keyed[0], 15);
        assert_eq!(&keyed[1..16], b"sequence_number");
        assert_eq!(Attachment::decode(&keyed).unwrap(), a);
        let mut compact = Vec::new();
        compact.extend_from_slice(&42i64.to_le_bytes());
        compact.extend_from_slice(&a.source_timestamp_ns.to_le_bytes());
        put_buf(&mut compact, &a.source_gid);
        assert_eq!(Attachment::decode(&compact).unwrap(), a);
        for n in 0..keyed.len() {
            assert!(Attachment::decode(&keyed[..n]).is_err());
        }
    }
}
