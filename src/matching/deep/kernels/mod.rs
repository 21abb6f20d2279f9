//! The arithmetic the plain inference paths share: dense f32 matrix
//! products on one thread through the `gemm` crate (the kernel burn's
//! CPU backend uses; the matcher bench's peak is the same call), the lane
//! kernels ([`lanes`]) and Sinkhorn without tensors ([`sinkhorn`]).

pub(crate) mod lanes;
pub(crate) mod sinkhorn;
pub(crate) mod spline;

/// `c = a b` for row-major `a` `[m, k]`, `b` `[k, n]` and `c` `[m, n]`
/// (`c` overwritten, one thread).
///
/// The kernel fills its registers with 16 rows of `c` at a time, so a
/// product with few rows and many columns (a few graphs' nodes against a
/// layer's cell weights) runs as its transpose `c^T = b^T a^T`, which the
/// strides express without a copy.
///
/// # Panics
/// When a buffer is shorter than its shape.
pub fn matmul(m: usize, k: usize, n: usize, a: &[f32], b: &[f32], c: &mut [f32]) {
    assert!(
        a.len() >= m * k && b.len() >= k * n && c.len() >= m * n,
        "matmul: buffers shorter than [{m}, {k}] x [{k}, {n}]"
    );
    let (n_, k_) = (n as isize, k as isize);
    // (rows, cols, dst col/row strides, lhs, its col/row strides, rhs, its
    // col/row strides) of the product gemm computes.
    let (rows, cols, dst, lhs, rhs) = if m >= n {
        (m, n, (1, n_), (a, 1, k_), (b, 1, n_))
    } else {
        (n, m, (n_, 1), (b, n_, 1), (a, k_, 1))
    };
    // SAFETY: the assert above bounds every index gemm reads or writes:
    // `c` is [m, n] (or its transpose [n, m] with the strides swapped),
    // `a` [m, k] and `b` [k, n], row-major; `c` does not overlap `a` or
    // `b` (a unique and two shared borrows).
    unsafe {
        gemm::gemm(
            rows,
            cols,
            k,
            c.as_mut_ptr(),
            dst.0,
            dst.1,
            false,
            lhs.0.as_ptr(),
            lhs.1,
            lhs.2,
            rhs.0.as_ptr(),
            rhs.1,
            rhs.2,
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
        // Fewer rows than columns (the transposed call): [1, 3] x [3, 2].
        let mut c = [f32::NAN; 2];
        matmul(1, 3, 2, &a[..3], &b, &mut c);
        assert_eq!(c, [58.0, 64.0]);
        // And more: [3, 2] x [2, 1].
        let mut c = [f32::NAN; 3];
        matmul(3, 2, 1, &a, &[1.0, -1.0], &mut c);
        assert_eq!(c, [-1.0, -1.0, -1.0]);
    }
}
