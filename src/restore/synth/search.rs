//! The nearest-neighbour search of synthesis: kd-trees over one orientation's source vectors,
//! exact or on a PCA reduction of them.

use super::*;

/// Nearest-neighbour search over one orientation's source vectors.
pub(super) trait Search: Send + Sync {
    fn nearest(&self, v: &[f32], k: usize, out: &mut Vec<u32>);
    /// The source in the leaf the query descends to, without backtracking: a match no
    /// nearer than the exact search's, found in a small fraction of its time.
    fn descend(&self, v: &[f32]) -> u32;
}

pub(super) struct Kd<const K: usize>(ImmutableKdTree<f32, K>);

impl<const K: usize> Search for Kd<K> {
    fn descend(&self, v: &[f32]) -> u32 {
        let mut q = [0f32; K];
        q[..v.len()].copy_from_slice(v);
        self.0
            .query(&q)
            .nearest_one::<SquaredEuclidean<f32>>()
            .approx()
            .execute()
            .item
    }

    fn nearest(&self, v: &[f32], k: usize, out: &mut Vec<u32>) {
        let mut q = [0f32; K];
        q[..v.len()].copy_from_slice(v);
        out.clear();
        if k <= 1 {
            let r = self
                .0
                .query(&q)
                .nearest_one::<SquaredEuclidean<f32>>()
                .execute();
            out.push(r.item);
        } else {
            let r = self
                .0
                .query(&q)
                .nearest_n::<SquaredEuclidean<f32>>(NonZero::new(k).expect("k > 1"))
                .execute();
            out.extend(r.iter().map(|it| it.item));
        }
    }
}

pub(super) fn kd<const K: usize>(points: &[f32], dim: usize) -> Box<dyn Search> {
    let pts: Vec<[f32; K]> = points
        .chunks(dim)
        .map(|c| {
            let mut a = [0f32; K];
            a[..dim].copy_from_slice(c);
            a
        })
        .collect();
    Box::new(Kd::<K>(
        ImmutableKdTree::new_from_slice(&pts).expect("a non-empty point set"),
    ))
}

/// A kd-tree over `points` (rows of `dim`), its width padded with zeros to the next supported
/// constant (kiddo's dimension is a type parameter; zero padding changes no distance). The
/// fast search's reduced vectors (1 to 8 numbers) get a tree of exactly their width: kiddo
/// splits on the dimensions in turn, and a split on a zero-padded dimension separates nothing,
/// so every query must descend both sides of it (on the corset scene, restoration took 2.6-2.75
/// s with 8-wide trees and 2.3 s with exact widths, `docs/benchmarks.md`).
pub(super) fn build_tree(points: &[f32], dim: usize) -> Box<dyn Search> {
    match dim {
        0..=1 => kd::<1>(points, dim),
        2 => kd::<2>(points, dim),
        3 => kd::<3>(points, dim),
        4 => kd::<4>(points, dim),
        5 => kd::<5>(points, dim),
        6 => kd::<6>(points, dim),
        7 => kd::<7>(points, dim),
        8 => kd::<8>(points, dim),
        9..=16 => kd::<16>(points, dim),
        17..=24 => kd::<24>(points, dim),
        25..=32 => kd::<32>(points, dim),
        33..=48 => kd::<48>(points, dim),
        49..=64 => kd::<64>(points, dim),
        65..=72 => kd::<72>(points, dim),
        73..=96 => kd::<96>(points, dim),
        _ => kd::<128>(points, dim),
    }
}

/// Most principal components the fast search keeps (fewer when 95% of the variance takes
/// fewer). A kd-tree slows quickly with its dimension: on 4096x4096 with 5% unseen, level 1
/// (nine components at a cap of 12 or 16) took 4.9-6.8 s, at eight 2.4 s, for 0.03 dB of mean
/// PSNR on the 54 OpenCV comparison cases (`docs/decisions.md`).
pub(super) const PCA_MAX_ROWS: usize = 8;

/// Source vectors the fast search's PCA is fitted on (every n-th, in scan order). The
/// covariance's accumulation is the cost (dimensions squared per vector): with 4096 it was
/// 1.0 of the corset's 2.3 CPU seconds building trees, with 1024 0.28, and the 54 OpenCV
/// comparison cases kept their figures (mean low-frequency PSNR 20.112 and 20.118 dB,
/// `docs/decisions.md`).
pub(super) const PCA_SAMPLE: usize = 1024;

/// Longest neighbourhood vector a tree accepts.
pub(crate) const MAX_DIMS: usize = 128;

/// PCA projection: the mean and `rows` basis vectors of `dim` numbers (stored transposed).
pub(super) struct Pca {
    pub(super) mean: Vec<f32>,
    /// The basis transposed: for each dimension, its weight in each of the `rows` rows, padded
    /// with zeros to [`PCA_MAX_ROWS`] (see [`Pca::project`]).
    pub(super) basis_t: Vec<f32>,
    pub(super) rows: usize,
}

impl Pca {
    /// Fits the components that hold `keep` of the variance of `vectors` (rows of `dim`),
    /// at most [`PCA_MAX_ROWS`] of them, on every n-th vector ([`PCA_SAMPLE`]).
    pub(super) fn fit(vectors: &[f32], dim: usize, keep: f64) -> Pca {
        let n = vectors.len() / dim;
        let step = (n / PCA_SAMPLE).max(1);
        let sample: Vec<&[f32]> = vectors.chunks(dim).step_by(step).collect();
        let m = sample.len() as f64;
        let mut mean = vec![0f64; dim];
        for s in &sample {
            for (a, &b) in mean.iter_mut().zip(s.iter()) {
                *a += b as f64;
            }
        }
        for a in &mut mean {
            *a /= m;
        }
        // The upper triangle, row-major in a flat buffer: contiguous rows the compiler
        // vectorises. Each entry still sums the samples in order, so the output is the same
        // bytes as the indexed loop it replaces; on the corset scene fit's share of the
        // run's `perf` samples fell from 7.3% to 5.3% (the eigen-solve is the rest).
        let mut upper = vec![0f64; dim * dim];
        let mut c = vec![0f64; dim];
        for s in &sample {
            for k in 0..dim {
                c[k] = s[k] as f64 - mean[k];
            }
            for a in 0..dim {
                let ca = c[a];
                let row = &mut upper[a * dim + a..(a + 1) * dim];
                for (r, &cb) in row.iter_mut().zip(&c[a..]) {
                    *r += ca * cb;
                }
            }
        }
        let cov =
            nalgebra::DMatrix::<f64>::from_fn(dim, dim, |a, b| upper[a.min(b) * dim + a.max(b)]);
        let eig = nalgebra::SymmetricEigen::new(cov);
        let mut order: Vec<usize> = (0..dim).collect();
        order.sort_by(|&a, &b| {
            eig.eigenvalues[b]
                .total_cmp(&eig.eigenvalues[a])
                .then(a.cmp(&b))
        });
        let total: f64 = eig.eigenvalues.iter().map(|v| v.max(0.0)).sum();
        let mut rows = 0;
        let mut acc = 0.0;
        for &k in &order {
            if rows >= PCA_MAX_ROWS || (total > 0.0 && acc >= keep * total) {
                break;
            }
            acc += eig.eigenvalues[k].max(0.0);
            rows += 1;
        }
        let rows = rows.max(1);
        let mut basis = Vec::with_capacity(rows * dim);
        for &k in &order[..rows] {
            let col = eig.eigenvectors.column(k);
            // Fix the sign so that the projection does not depend on the solver's choice.
            let s = if col
                .iter()
                .fold(0.0, |a: f64, &v| if v.abs() > a.abs() { v } else { a })
                < 0.0
            {
                -1.0
            } else {
                1.0
            };
            basis.extend(col.iter().map(|&v| (s * v) as f32));
        }
        let mut basis_t = vec![0f32; dim * PCA_MAX_ROWS];
        for (r, b) in basis.chunks_exact(dim).enumerate() {
            for (k, &w) in b.iter().enumerate() {
                basis_t[k * PCA_MAX_ROWS + r] = w;
            }
        }
        Pca {
            mean: mean.iter().map(|&v| v as f32).collect(),
            basis_t,
            rows,
        }
    }

    /// Projects `v` onto the basis. The rows' sums run over the dimensions in order, each
    /// from -0.0 as `Iterator::sum` does, so the result is the same bytes as one dot product
    /// per row; the dimensions are the outer loop so that the rows' sums advance together
    /// (one vector instruction per dimension instead of a chain of dependent adds per row).
    pub(super) fn project(&self, v: &[f32], out: &mut Vec<f32>) {
        out.clear();
        let mut acc = [-0.0f32; PCA_MAX_ROWS];
        for ((x, m), b) in v
            .iter()
            .zip(&self.mean)
            .zip(self.basis_t.chunks_exact(PCA_MAX_ROWS))
        {
            let c = x - m;
            for (a, w) in acc.iter_mut().zip(b) {
                *a += c * w;
            }
        }
        out.extend_from_slice(&acc[..self.rows]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::SplitMix64;

    #[test]
    fn projection_is_the_same_bits_as_one_dot_product_per_row() {
        let mut rng = SplitMix64::new(3);
        let mut r = || (rng.next_u64() % 2001) as f32 / 1000.0 - 1.0;
        let (dim, n) = (66, 3000);
        let vectors: Vec<f32> = (0..dim * n).map(|_| r()).collect();
        let pca = Pca::fit(&vectors, dim, 0.95);
        assert!(pca.rows >= 1 && pca.rows <= PCA_MAX_ROWS);
        let mut out = Vec::new();
        for v in vectors.chunks(dim).take(50) {
            pca.project(v, &mut out);
            assert_eq!(out.len(), pca.rows);
            for (row, &got) in out.iter().enumerate() {
                let want: f32 = v
                    .iter()
                    .zip(&pca.mean)
                    .enumerate()
                    .map(|(k, (x, m))| (x - m) * pca.basis_t[k * PCA_MAX_ROWS + row])
                    .sum();
                assert_eq!(got.to_bits(), want.to_bits(), "row {row}");
            }
        }
    }
}
