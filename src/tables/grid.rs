//! The threshold grid of the lambda sweep, and where a method's own
//! lambda falls on it.

use crate::matching::deep::decision::KindLambdas;

/// The threshold grid of the lambda sweep (binary entropy in bits): 0 to 1
/// by 0.05, the methods' own lambdas (of every uncertainty type), and "no
/// threshold" (infinite) last.
pub fn lambda_grid<'a>(lambdas: impl IntoIterator<Item = &'a KindLambdas>) -> Vec<f64> {
    let mut g: Vec<f64> = (0..=20).map(|k| f64::from(k) / 20.0).collect();
    g.extend(
        lambdas
            .into_iter()
            .flat_map(|l| l.values())
            .filter(|l| l.is_finite()),
    );
    g.sort_by(f64::total_cmp);
    g.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    g.push(f64::INFINITY);
    g
}

/// The index of `lambda` in `grid` (the same value, else the nearest).
pub(super) fn grid_index(grid: &[f64], lambda: f64) -> usize {
    if let Some(k) = grid.iter().position(|&g| g == lambda) {
        return k;
    }
    (0..grid.len())
        .filter(|&k| grid[k].is_finite())
        .min_by(|&a, &b| {
            (grid[a] - lambda)
                .abs()
                .total_cmp(&(grid[b] - lambda).abs())
        })
        .unwrap_or(0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_lambda_grid_has_every_twentieth_each_lambda_once_and_no_threshold() {
        let g = lambda_grid(&[KindLambdas::all(0.7)]);
        assert_eq!(g.len(), 22);
        assert_eq!((g[0], g[20], g[21]), (0.0, 1.0, f64::INFINITY));
        assert!(g.windows(2).all(|w| w[0] < w[1]));
        assert_eq!(grid_index(&g, f64::INFINITY), 21);
        assert_eq!(grid_index(&g, 0.96), 19);
        let g = lambda_grid(&[
            KindLambdas::from_values([0.72, 0.72, 0.33]),
            KindLambdas::from_values([f64::NAN, f64::INFINITY, 0.72]),
        ]);
        assert_eq!(g.len(), 24);
        assert!(g.contains(&0.72) && g.contains(&0.33));
        assert_eq!(
            grid_index(&g, 0.72),
            g.iter().position(|&x| x == 0.72).unwrap()
        );
    }
}
