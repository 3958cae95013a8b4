//! Counter-based random numbers: every draw is a pure function of
//! (seed, iteration, batch, index, draw number), so thread count, chunking and resume can never
//! change a result, and any single photon can be replayed.
//!
//! Written by hand because the `rand` generators are sequential streams; what we need is a
//! keyed hash (SplitMix64 finalizer over the key), which is a dozen lines.

/// A small generator whose state is derived from a key; draws advance a counter.
#[derive(Debug, Clone)]
pub struct Rng {
    key: u64,
    counter: u64,
}

#[inline]
fn mix(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58476d1ce4e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d049bb133111eb);
    z ^ (z >> 31)
}

impl Rng {
    /// The stream for (seed, iteration, batch, index).
    pub fn new(seed: u64, iteration: u64, batch: u64, index: u64) -> Rng {
        let mut k = mix(seed ^ 0x9e3779b97f4a7c15);
        k = mix(k ^ iteration.wrapping_mul(0xd1b54a32d192ed03));
        k = mix(k ^ batch.wrapping_mul(0xabc98388fb8fac03));
        k = mix(k ^ index.wrapping_mul(0x8cb92ba72f3d8dd7));
        Rng { key: k, counter: 0 }
    }

    #[inline]
    pub fn u64(&mut self) -> u64 {
        self.counter += 1;
        mix(self
            .key
            .wrapping_add(self.counter.wrapping_mul(0x9e3779b97f4a7c15)))
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn f32(&mut self) -> f32 {
        (self.u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }

    /// Uniform in [0, 1) with 53 bits.
    #[inline]
    pub fn f64(&mut self) -> f64 {
        (self.u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal, from two draws (Box-Muller): test noise, and the projection's noise
    /// probe.
    pub fn normal(&mut self) -> f32 {
        let (u, v) = (1.0 - self.f64(), self.f64());
        ((-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()) as f32
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn same_key_same_stream_and_keys_differ() {
        let a: Vec<u64> = {
            let mut r = Rng::new(1, 2, 3, 4);
            (0..8).map(|_| r.u64()).collect()
        };
        let b: Vec<u64> = {
            let mut r = Rng::new(1, 2, 3, 4);
            (0..8).map(|_| r.u64()).collect()
        };
        assert_eq!(a, b);
        for key in [(2, 2, 3, 4), (1, 3, 3, 4), (1, 2, 4, 4), (1, 2, 3, 5)] {
            let mut r = Rng::new(key.0, key.1, key.2, key.3);
            assert_ne!(r.u64(), a[0], "{key:?}");
        }
    }

    #[test]
    fn uniform_moments() {
        let mut r = Rng::new(42, 0, 0, 0);
        let n = 200_000;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for _ in 0..n {
            let x = r.f32() as f64;
            assert!((0.0..1.0).contains(&x));
            s += x;
            s2 += x * x;
        }
        let m = s / n as f64;
        let v = s2 / n as f64 - m * m;
        assert!((m - 0.5).abs() < 0.005, "mean {m}");
        assert!((v - 1.0 / 12.0).abs() < 0.002, "var {v}");
    }
}
