//! Dense f32 matrix products on one thread, through the `gemm` crate (the
//! kernel burn's CPU backend uses): the inference path's products and the
//! matcher bench's peak are the same call.

/// `c = a b` for row-major `a` `[m, k]`, `b` `[k, n]` and `c` `[m, n]`
/// (`c` overwritten, one thread).
///
/// # Panics
/// When a buffer is shorter than its shape.
pub fn matmul(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && c.len() >= m * n,
        "matmul: buffers shorter than [{m}, {k}] x [{k}, {n}]"
    );
    // SAFETY: the assert above bounds every index gemm reads or writes
    // (row-major: column stride 1, row stride the column count); `c` does
    // not overlap `a` or `b` (a unique and two shared borrows).
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            1,
            n as isize,
            false,
            a.as_ptr(),
            1,
            k as isize,
            b.as_ptr(),
            1,
            n as isize,
            0.0,
            1.0,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matmul_gives_the_known_product() {
        // [2, 3] x [3, 2]
        let a = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0];
        let b = [7.0, 8.0, 9.0, 10.0, 11.0, 12.0];
        let mut c = [f32::NAN; 4];
        matmul(2, 3, 2, &a, &b, &mut c);
        assert_eq!(c, [58.0, 64.0, 139.0, 154.0]);
    }
}
