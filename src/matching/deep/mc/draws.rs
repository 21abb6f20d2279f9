//! The random numbers of MC dropout, drawn from seeded streams
//! ([`crate::rng`]) as plain numbers: inverted-dropout masks (0 or
//! 1 / (1 - p)) with one unit per 32-bit draw for training and two at
//! inference, and the consensus' random node indicators.

use rand::{Rng, RngCore};
use rand_chacha::ChaCha8Rng;

/// A mask draw: the training or the inference one.
pub(crate) type MaskDraw = fn(&mut ChaCha8Rng, usize, f64) -> Vec<f32>;

/// Draws inverted-dropout masks (0 or 1 / (1 - p)) of the given shape.
pub(crate) fn dropout_mask(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    // Compare raw 32-bit draws with the keep threshold: one draw per unit.
    let threshold = (keep * 4_294_967_296.0).min(f64::from(u32::MAX)) as u32;
    let mut out = vec![0f32; len];
    for v in out.iter_mut() {
        if rng.next_u32() < threshold {
            *v = scale;
        }
    }
    out
}

/// Inference masks: [`dropout_mask`] with two units per 32-bit draw (the
/// keep probability rounded to 1/65536: 0.8 becomes 0.800003), half the
/// random numbers of the training masks.
pub(crate) fn dropout_mask_16(rng: &mut ChaCha8Rng, len: usize, p: f64) -> Vec<f32> {
    if p <= 0.0 {
        return vec![1.0; len];
    }
    let keep = 1.0 - p;
    let scale = (1.0 / keep) as f32;
    let threshold = (keep * 65_536.0).round().min(65_536.0) as u32;
    let mut words = vec![0u32; len.div_ceil(2)];
    rng.fill(&mut words[..]);
    let mut out = vec![0f32; 2 * words.len()];
    for (o, &w) in out.chunks_exact_mut(2).zip(&words) {
        o[0] = scale * f32::from(u8::from((w & 0xFFFF) < threshold));
        o[1] = scale * f32::from(u8::from((w >> 16) < threshold));
    }
    out.truncate(len);
    out
}

/// `len` standard normals, the consensus
/// indicators (`[n1, consensus_dim]` of one pair, row-major).
pub(crate) fn indicator_values(rng: &mut ChaCha8Rng, len: usize) -> Vec<f32> {
    let normal = rand_distr::StandardNormal;
    (0..len)
        .map(|_| rng.sample::<f64, _>(normal) as f32)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn dropout_masks_have_the_right_rate_and_scale() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let m = dropout_mask(&mut rng, 100_000, 0.4);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.6).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.6).abs() < 1e-6));
        assert!(dropout_mask(&mut rng, 10, 0.0).iter().all(|&v| v == 1.0));
        let m = dropout_mask_16(&mut rng, 100_001, 0.2);
        let kept = m.iter().filter(|&&v| v > 0.0).count() as f64 / m.len() as f64;
        assert!((kept - 0.8).abs() < 0.01, "{kept}");
        assert!(m.iter().all(|&v| v == 0.0 || (v - 1.0 / 0.8).abs() < 1e-6));
        assert!(dropout_mask_16(&mut rng, 7, 0.0).iter().all(|&v| v == 1.0));
    }
}
