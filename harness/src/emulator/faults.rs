//! The emulated faults' machinery: what the link does to the frames of one direction, and the
//! repeatable noise of the sensor channels.

use std::net::SocketAddr;

use crate::bench_protocol::LinkDirection;

/// What the emulated link does to the next frames of one direction.
#[derive(Debug, Default)]
pub(super) struct LinkFault {
    pub(super) duplicate: u32,
    pub(super) corrupt: u32,
    pub(super) reorder: bool,
    held: Option<(Vec<u8>, SocketAddr)>,
}

impl LinkFault {
    /// The datagrams the link delivers for `bytes` (none, one or two, the held one after);
    /// counts the frames it changed in `applied`.
    pub(super) fn pass(
        &mut self,
        mut bytes: Vec<u8>,
        to: SocketAddr,
        applied: &mut u64,
    ) -> Vec<(Vec<u8>, SocketAddr)> {
        if self.corrupt > 0 && !bytes.is_empty() {
            self.corrupt -= 1;
            *applied += 1;
            let middle = bytes.len() / 2;
            bytes[middle] ^= 0xFF;
        }
        let mut out = Vec::with_capacity(2);
        if self.reorder {
            *applied += 1;
            match self.held.take() {
                None => {
                    self.held = Some((bytes, to));
                    return out;
                }
                Some(first) => {
                    self.reorder = false;
                    out.push((bytes, to));
                    out.push(first);
                }
            }
        } else {
            out.push((bytes, to));
        }
        if self.duplicate > 0 {
            self.duplicate -= 1;
            *applied += 1;
            out.insert(1, out[0].clone());
        }
        out
    }
}

pub(super) fn direction_index(d: LinkDirection) -> usize {
    match d {
        LinkDirection::ToClient => 0,
        LinkDirection::ToServer => 1,
    }
}

/// A standard normal deviate from a xorshift64* generator (Box-Muller): repeatable noise.
pub(super) fn gaussian(state: &mut u64) -> f64 {
    let mut uniform = || {
        *state ^= *state >> 12;
        *state ^= *state << 25;
        *state ^= *state >> 27;
        let x = state.wrapping_mul(0x2545_F491_4F6C_DD1D);
        // 53 random bits in (0, 1].
        ((x >> 11) as f64 + 1.0) / (1u64 << 53) as f64
    };
    let (u1, u2) = (uniform(), uniform());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// A noise generator's state from its seed (SplitMix64: nonzero and well mixed, so seeds 0,
/// 1, 2, ... give unrelated sequences).
pub(super) fn noise_state(seed: u32) -> u64 {
    let mut z = u64::from(seed).wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    (z ^ (z >> 31)) | 1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn addr() -> SocketAddr {
        "127.0.0.1:9".parse().unwrap()
    }

    #[test]
    fn the_link_duplicates_swaps_and_corrupts_as_told() {
        let mut applied = 0;
        let mut link = LinkFault {
            duplicate: 1,
            ..LinkFault::default()
        };
        let out = link.pass(vec![1, 2, 3], addr(), &mut applied);
        assert_eq!(out.len(), 2);
        assert_eq!(out[0].0, out[1].0);
        assert_eq!(link.pass(vec![4], addr(), &mut applied).len(), 1);
        link.reorder = true;
        assert!(link.pass(vec![5], addr(), &mut applied).is_empty());
        let out = link.pass(vec![6], addr(), &mut applied);
        assert_eq!(out.iter().map(|o| o.0[0]).collect::<Vec<_>>(), [6, 5]);
        link.corrupt = 1;
        assert_eq!(
            link.pass(vec![0, 0, 0, 0], addr(), &mut applied)[0].0,
            [0, 0, 0xFF, 0]
        );
        assert_eq!(link.pass(vec![0, 0], addr(), &mut applied)[0].0, [0, 0]);
        assert_eq!(applied, 4);
    }

    #[test]
    fn the_noise_is_standard_normal_and_repeatable() {
        let draw = |seed| {
            let mut s = noise_state(seed);
            (0..20_000).map(|_| gaussian(&mut s)).collect::<Vec<f64>>()
        };
        let a = draw(1);
        assert_eq!(a, draw(1));
        assert_ne!(a, draw(2));
        let n = a.len() as f64;
        let mean = a.iter().sum::<f64>() / n;
        let var = a.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n;
        // Standard errors: 1/sqrt(n) = 0.007 for the mean, sqrt(2/n) = 0.01 for the variance.
        assert!(mean.abs() < 0.03, "{mean}");
        assert!((var - 1.0).abs() < 0.05, "{var}");
        let beyond = a.iter().filter(|x| x.abs() > 1.0).count() as f64 / n;
        assert!((beyond - 0.3173).abs() < 0.02, "{beyond}");
    }
}
