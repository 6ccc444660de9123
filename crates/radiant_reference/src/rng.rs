//! The tracer's random numbers: a counter-based stream per (seed, kind, item, chunk), so every
//! sample is the same whatever the thread count or the order work is done in.
//!
//! The bake has a generator of its own (`radiant_radiosity::rng`); the reference keeps a
//! separate one on purpose, so that it shares no code path with what it judges.

/// A PCG-XSH-RR 32-bit generator (O'Neill 2014) with a 64-bit state; two outputs per `f64`.
#[derive(Clone, Debug)]
pub(crate) struct Rng {
    state: u64,
    inc: u64,
}

const MUL: u64 = 6_364_136_223_846_793_005;

/// Mixes four words into a well-spread 64-bit value (the MurmurHash3 finaliser per word).
fn mix(words: [u64; 4]) -> u64 {
    let mut h = 0x243F_6A88_85A3_08D3u64;
    for w in words {
        let mut k = w.wrapping_add(h);
        k ^= k >> 33;
        k = k.wrapping_mul(0xFF51_AFD7_ED55_8CCD);
        k ^= k >> 33;
        k = k.wrapping_mul(0xC4CE_B9FE_1A85_EC53);
        k ^= k >> 33;
        h = k ^ h.rotate_left(29);
    }
    h
}

impl Rng {
    /// The stream of one chunk of samples.
    pub(crate) fn for_chunk(seed: u64, kind: u64, item: u64, chunk: u64) -> Rng {
        let mut r = Rng {
            state: 0,
            inc: (mix([seed, kind, item, !chunk]) << 1) | 1,
        };
        r.state = r.state.wrapping_add(mix([chunk, item, kind, seed]));
        r.next_u32();
        r
    }

    #[inline]
    fn next_u32(&mut self) -> u32 {
        let old = self.state;
        self.state = old.wrapping_mul(MUL).wrapping_add(self.inc);
        let xorshifted = (((old >> 18) ^ old) >> 27) as u32;
        let rot = (old >> 59) as u32;
        xorshifted.rotate_right(rot)
    }

    /// Uniform in `[0, 1)`, 53 bits.
    #[inline]
    pub(crate) fn f64(&mut self) -> f64 {
        let hi = (self.next_u32() as u64) << 21;
        let lo = (self.next_u32() >> 11) as u64;
        (hi | lo) as f64 * (1.0 / (1u64 << 53) as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn streams_are_uniform_and_distinct() {
        let mut a = Rng::for_chunk(1, 0, 0, 0);
        let mut b = Rng::for_chunk(1, 0, 0, 1);
        let n = 100_000;
        let (mut mean, mut same) = (0.0, 0);
        for _ in 0..n {
            let (x, y) = (a.f64(), b.f64());
            assert!((0.0..1.0).contains(&x));
            mean += x / n as f64;
            same += usize::from(x == y);
        }
        assert!((mean - 0.5).abs() < 0.005, "{mean}");
        assert_eq!(same, 0);
    }
}
