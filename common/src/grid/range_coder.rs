//! Adaptive binary range coder (the carry-propagating LZMA scheme) and the integer models the
//! tile codec builds on it.
//!
//! Each binary decision is coded with an adaptive probability (11-bit, updated by 1/32 of the
//! error), so a decision that is almost always the same costs a small fraction of a bit: that is
//! what a general-purpose compressor cannot do on a 4096-cell tile, where its tables cost more
//! than the data. The decoder reads zeros past the end of its input, so any byte string decodes
//! to *something* without panicking; the codec's checksum decides whether it was a tile.

/// An adaptive probability of a 0 bit (15-bit) with the number of bits it has seen: it learns
/// fast at first (each of the first bits moves it by ~1/(n+2), like a frequency count) and then
/// settles to a 1/2^`RATE_MAX` moving average. A tile has a few thousand cells, so how fast a
/// model learns matters as much as where it ends up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Prob {
    p: u16,
    n: u8,
}

const PROB_BITS: u32 = 15;
const PROB_ONE: u32 = 1 << PROB_BITS;
const PROB_INIT: Prob = Prob {
    p: (PROB_ONE / 2) as u16,
    n: 0,
};
const RATE_MIN: u32 = 1;
const RATE_MAX: u32 = 5;

impl Prob {
    fn p0(self) -> u32 {
        u32::from(self.p)
    }

    fn update(&mut self, bit: bool) {
        let shift = (32 - (u32::from(self.n) + 2).leading_zeros() - 1).clamp(RATE_MIN, RATE_MAX);
        let p = u32::from(self.p);
        let p = if bit {
            p - (p >> shift)
        } else {
            p + ((PROB_ONE - p) >> shift)
        };
        // Never certain: a bit that has always been 0 must still be codable as 1.
        self.p = p.clamp(32, PROB_ONE - 32) as u16;
        self.n = self.n.saturating_add(1);
    }
}
const TOP: u32 = 1 << 24;

/// Encoder writing into a byte vector.
pub struct Encoder {
    low: u64,
    range: u32,
    cache: u8,
    cache_size: u64,
    out: Vec<u8>,
    /// The first byte the scheme emits is always 0: it is dropped, and the decoder assumes it.
    first: bool,
}

impl Default for Encoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Encoder {
    /// An empty encoder.
    pub fn new() -> Self {
        Self {
            low: 0,
            range: u32::MAX,
            cache: 0,
            cache_size: 1,
            out: Vec::new(),
            first: true,
        }
    }

    fn shift_low(&mut self) {
        if (self.low as u32) < 0xFF00_0000 || (self.low >> 32) != 0 {
            let carry = (self.low >> 32) as u8;
            let mut temp = self.cache;
            loop {
                let byte = temp.wrapping_add(carry);
                if self.first {
                    self.first = false;
                } else {
                    self.out.push(byte);
                }
                temp = 0xFF;
                self.cache_size -= 1;
                if self.cache_size == 0 {
                    break;
                }
            }
            self.cache = ((self.low >> 24) & 0xFF) as u8;
        }
        self.cache_size += 1;
        self.low = (self.low & 0x00FF_FFFF) << 8;
    }

    /// Codes one bit with the adaptive probability `p`.
    pub fn bit(&mut self, p: &mut Prob, bit: bool) {
        let bound = (self.range >> PROB_BITS) * p.p0();
        if bit {
            self.low += u64::from(bound);
            self.range -= bound;
        } else {
            self.range = bound;
        }
        p.update(bit);
        while self.range < TOP {
            self.range <<= 8;
            self.shift_low();
        }
    }

    /// Codes `n` (<= 32) bits of `v` at probability one half, most significant first.
    pub fn direct(&mut self, v: u32, n: u32) {
        for i in (0..n).rev() {
            self.range >>= 1;
            if (v >> i) & 1 == 1 {
                self.low += u64::from(self.range);
            }
            while self.range < TOP {
                self.range <<= 8;
                self.shift_low();
            }
        }
    }

    /// Flushes and returns the coded bytes.
    pub fn finish(mut self) -> Vec<u8> {
        for _ in 0..5 {
            self.shift_low();
        }
        // Trailing zero bytes carry nothing: the decoder reads zeros past the end.
        while self.out.last() == Some(&0) {
            self.out.pop();
        }
        self.out
    }
}

/// Decoder over a byte slice.
pub struct Decoder<'a> {
    range: u32,
    code: u32,
    input: &'a [u8],
    pos: usize,
}

impl<'a> Decoder<'a> {
    /// Starts decoding `input` (as produced by [`Encoder::finish`]).
    pub fn new(input: &'a [u8]) -> Self {
        let mut d = Self {
            range: u32::MAX,
            code: 0,
            input,
            pos: 0,
        };
        for _ in 0..4 {
            d.code = (d.code << 8) | u32::from(d.byte());
        }
        d
    }

    fn byte(&mut self) -> u8 {
        let b = self.input.get(self.pos).copied().unwrap_or(0);
        self.pos += 1;
        b
    }

    /// Decodes one bit with the adaptive probability `p`.
    pub fn bit(&mut self, p: &mut Prob) -> bool {
        let bound = (self.range >> PROB_BITS) * p.p0();
        let bit = if self.code < bound {
            self.range = bound;
            false
        } else {
            self.code -= bound;
            self.range -= bound;
            true
        };
        p.update(bit);
        while self.range < TOP {
            self.range <<= 8;
            self.code = (self.code << 8) | u32::from(self.byte());
        }
        bit
    }

    /// Decodes `n` (<= 32) bits at probability one half.
    pub fn direct(&mut self, n: u32) -> u32 {
        let mut v = 0u32;
        for _ in 0..n {
            self.range >>= 1;
            let bit = self.code >= self.range;
            if bit {
                self.code -= self.range;
            }
            v = (v << 1) | u32::from(bit);
            while self.range < TOP {
                self.range <<= 8;
                self.code = (self.code << 8) | u32::from(self.byte());
            }
        }
        v
    }
}

/// What the encoder and the decoder have in common, so one routine describes a format for
/// both: the encoder codes the value it is given and returns it, the decoder ignores it and
/// returns what it decodes.
pub trait BitCoder {
    /// Codes (or decodes) one bit with the adaptive probability `p`.
    fn code_bit(&mut self, p: &mut Prob, bit: bool) -> bool;
    /// Codes (or decodes) `n` (<= 32) bits of `v` at probability one half.
    fn code_direct(&mut self, v: u32, n: u32) -> u32;
    /// Names the field the next bits belong to (for [`Meter`]).
    fn field(&mut self, _k: usize) {}
}

/// A coder that only counts: the ideal cost in bits of each field (what codec tuning reads).
#[derive(Default)]
pub struct Meter {
    /// Bits per field.
    pub bits: [f64; 8],
    field: usize,
}

impl BitCoder for Meter {
    fn code_bit(&mut self, p: &mut Prob, bit: bool) -> bool {
        let p0 = f64::from(p.p0()) / f64::from(PROB_ONE);
        self.bits[self.field] -= if bit { 1.0 - p0 } else { p0 }.log2();
        p.update(bit);
        bit
    }
    fn code_direct(&mut self, v: u32, n: u32) -> u32 {
        self.bits[self.field] += f64::from(n);
        v
    }
    fn field(&mut self, k: usize) {
        self.field = k;
    }
}

impl BitCoder for Encoder {
    fn code_bit(&mut self, p: &mut Prob, bit: bool) -> bool {
        self.bit(p, bit);
        bit
    }
    fn code_direct(&mut self, v: u32, n: u32) -> u32 {
        self.direct(v, n);
        v
    }
}

impl BitCoder for Decoder<'_> {
    fn code_bit(&mut self, p: &mut Prob, _bit: bool) -> bool {
        self.bit(p)
    }
    fn code_direct(&mut self, _v: u32, n: u32) -> u32 {
        self.direct(n)
    }
}

/// An adaptive model of an `n`-bit symbol: a binary tree of `2^n - 1` probabilities, so every
/// symbol value has its own learnt frequency.
#[derive(Clone)]
pub struct TreeModel {
    bits: u32,
    probs: Vec<Prob>,
}

impl TreeModel {
    /// A model of `bits`-bit symbols, all equally likely at first.
    pub fn new(bits: u32) -> Self {
        Self {
            bits,
            probs: vec![PROB_INIT; 1 << bits],
        }
    }

    /// Codes `v` (< 2^bits), or decodes a symbol.
    pub fn code(&mut self, c: &mut impl BitCoder, v: u32) -> u32 {
        let mut m = 1usize;
        for i in (0..self.bits).rev() {
            let b = c.code_bit(&mut self.probs[m], (v >> i) & 1 == 1);
            m = (m << 1) | usize::from(b);
        }
        (m - (1 << self.bits)) as u32
    }
}

/// Longest Elias-gamma prefix: magnitudes up to 2^32 - 1.
const MAX_PREFIX: usize = 32;

/// An adaptive model of signed integers that are usually small (prediction residuals): a zero
/// flag, a sign, then an Elias-gamma code whose prefix bits and leading suffix bits adapt.
#[derive(Clone)]
pub struct ResidualModel {
    zero: Prob,
    sign: Prob,
    prefix: [Prob; MAX_PREFIX],
    /// First suffix bit per prefix length (the rest are near-uniform).
    suffix: [Prob; MAX_PREFIX],
}

impl Default for ResidualModel {
    fn default() -> Self {
        Self {
            zero: PROB_INIT,
            sign: PROB_INIT,
            prefix: [PROB_INIT; MAX_PREFIX],
            suffix: [PROB_INIT; MAX_PREFIX],
        }
    }
}

impl ResidualModel {
    /// Codes `r` (|r| < 2^31), or decodes a residual.
    pub fn code(&mut self, c: &mut impl BitCoder, r: i64) -> i64 {
        if !c.code_bit(&mut self.zero, r != 0) {
            return 0;
        }
        let neg = c.code_bit(&mut self.sign, r < 0);
        let m = self.code_magnitude(c, r.unsigned_abs().max(1)) as i64;
        if neg {
            -m
        } else {
            m
        }
    }

    /// Codes a magnitude `m` >= 1 (< 2^32), or decodes one.
    pub fn code_magnitude(&mut self, c: &mut impl BitCoder, m: u64) -> u64 {
        let k_in = 63 - m.max(1).leading_zeros() as usize; // m in [2^k, 2^(k+1))
        let mut k = 0usize;
        while k < MAX_PREFIX - 1 && c.code_bit(&mut self.prefix[k], k < k_in) {
            k += 1;
        }
        let mut out = 1u64 << k;
        if k >= 1 {
            // Only the encoder's m is meaningful here; the decoder's bits come from the stream.
            let rest = m.wrapping_sub(1 << k);
            let top = c.code_bit(&mut self.suffix[k], (rest >> (k - 1)) & 1 == 1);
            out += u64::from(top) << (k - 1);
            if k >= 2 {
                let low = (rest & ((1 << (k - 1)) - 1)) as u32;
                out += u64::from(c.code_direct(low, (k - 1) as u32));
            }
        }
        out
    }
}

/// A fresh adaptive probability.
pub fn prob() -> Prob {
    PROB_INIT
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bits_symbols_and_residuals_round_trip() {
        let mut e = Encoder::new();
        let (mut p, mut t, mut r) = (prob(), TreeModel::new(3), ResidualModel::default());
        let vals: Vec<i64> = (-300..300)
            .chain([i64::from(i32::MAX), -(1 << 31) + 1])
            .collect();
        for (i, v) in vals.iter().enumerate() {
            e.bit(&mut p, i % 7 == 0);
            t.code(&mut e, (i % 8) as u32);
            r.code(&mut e, *v);
            e.direct(i as u32 & 0xFFFF, 16);
        }
        let bytes = e.finish();
        let mut d = Decoder::new(&bytes);
        let (mut p, mut t, mut r) = (prob(), TreeModel::new(3), ResidualModel::default());
        for (i, v) in vals.iter().enumerate() {
            assert_eq!(d.bit(&mut p), i % 7 == 0);
            assert_eq!(t.code(&mut d, 0), (i % 8) as u32);
            assert_eq!(r.code(&mut d, 0), *v);
            assert_eq!(d.direct(16), i as u32 & 0xFFFF);
        }
    }

    #[test]
    fn a_predictable_bit_costs_a_fraction_of_a_bit() {
        let mut e = Encoder::new();
        let mut p = prob();
        for i in 0..8000 {
            e.bit(&mut p, i % 100 == 0);
        }
        // 8000 decisions with 1% ones: entropy ~650 bits; the adaptive model gets close.
        let n = e.finish().len();
        assert!(n < 130, "{n} bytes");
    }

    #[test]
    fn garbage_decodes_without_panicking() {
        let mut d = Decoder::new(&[0xFF; 3]);
        let mut r = ResidualModel::default();
        let mut t = TreeModel::new(8);
        for _ in 0..100 {
            let _ = r.code(&mut d, 0);
            assert!(t.code(&mut d, 0) < 256);
        }
    }
}
