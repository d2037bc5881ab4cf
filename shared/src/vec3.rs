//! The two small vector helpers every crate needs on plain arrays (no nalgebra types on
//! the wire or in the 1 kHz steps' records).

/// Euclidean norm of the first three components (a force or translation part of a
/// 4-vector `[x, y, z, θ]`); fewer components count as zero.
#[inline]
pub fn norm3(v: &[f64]) -> f64 {
    v.iter().take(3).map(|x| x * x).sum::<f64>().sqrt()
}

/// Dot product of two 3-vectors.
#[inline]
pub fn dot3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn norm_uses_the_translation_part_only() {
        assert_eq!(norm3(&[3.0, 4.0, 12.0, 100.0]), 13.0);
        assert_eq!(norm3(&[3.0, 4.0]), 5.0);
        assert_eq!(dot3(&[1.0, 2.0, 3.0], &[4.0, -5.0, 6.0]), 12.0);
    }
}
