//! Levenberg-Marquardt over the keyframe poses with a sparse Cholesky solve of the normal
//! equations (nalgebra-sparse's `CscCholesky`; the pattern is block-banded by the odometry chain
//! with a few off-band blocks per loop, so the natural order fills in little).

use super::factors::{cauchy_cost, cauchy_weight, Factor};
use crate::se3;
use nalgebra::{DVector, Isometry3, Matrix6, Vector6};
use nalgebra_sparse::factorization::CscCholesky;
use nalgebra_sparse::{CooMatrix, CscMatrix};

/// Solver settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SolveOptions {
    /// Most LM iterations (accepted or rejected steps).
    pub max_iterations: usize,
    /// Stop when the relative cost decrease of an accepted step is below this.
    pub min_relative_decrease: f64,
    /// Cauchy kernel scale on the squared Mahalanobis error of robust (loop) factors.
    pub loop_cauchy_c: f64,
}

/// What one optimisation did.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct SolveReport {
    /// Robust cost before.
    pub initial_cost: f64,
    /// Robust cost after.
    pub final_cost: f64,
    /// Iterations run.
    pub iterations: usize,
    /// True when a step stopped decreasing the cost by a meaningful amount.
    pub converged: bool,
}

fn cost(poses: &[Isometry3<f64>], factors: &[Factor], c: f64) -> f64 {
    factors
        .iter()
        .map(|f| {
            let s = f.chi2(poses);
            if f.is_robust() {
                cauchy_cost(s, c)
            } else {
                s
            }
        })
        .sum()
}

/// One 6x6 block of the normal matrix at (block row, block column).
type Block = (usize, usize, Matrix6<f64>);

/// Normal equations `H dx = -b` at `poses`, IRLS weights on robust factors.
fn normal_equations(
    poses: &[Isometry3<f64>],
    factors: &[Factor],
    c: f64,
) -> (Vec<Block>, DVector<f64>) {
    let mut blocks = Vec::with_capacity(factors.len() * 4 + poses.len());
    let mut b = DVector::zeros(poses.len() * 6);
    for f in factors {
        let l = f.linearise(poses);
        let w = if f.is_robust() {
            cauchy_weight(f.chi2(poses), c)
        } else {
            1.0
        };
        let info = l.info * w;
        for (a, ja) in &l.blocks {
            let jt_info = ja.transpose() * info;
            let ba: Vector6<f64> = jt_info * l.error;
            let mut seg = b.fixed_rows_mut::<6>(a * 6);
            seg += ba;
            for (bb, jb) in &l.blocks {
                blocks.push((*a, *bb, jt_info * jb));
            }
        }
    }
    (blocks, b)
}

/// Optimises `poses` in place against `factors`. Keyframes no factor constrains stay put (the
/// damping keeps the system definite).
///
/// The loop kernel is annealed (graduated non-convexity): a loop verified after a long drift
/// has a huge error at the drifted poses, and the final Cauchy scale would weight it out before
/// it could pull. So the scale starts at the largest loop error and shrinks fourfold per stage
/// down to `loop_cauchy_c`; a loop consistent with the rest ends with a small error and full
/// weight, an inconsistent one is left large and weighted down.
pub fn optimise(
    poses: &mut [Isometry3<f64>],
    factors: &[Factor],
    opt: &SolveOptions,
) -> SolveReport {
    let c_final = opt.loop_cauchy_c.max(1e-6);
    let initial_cost = cost(poses, factors, c_final);
    let largest = factors
        .iter()
        .filter(|f| f.is_robust())
        .map(|f| f.chi2(poses).sqrt())
        .fold(0.0f64, f64::max);
    let mut c = largest.max(c_final);
    let mut iterations = 0;
    let mut converged;
    loop {
        let stage = SolveOptions {
            loop_cauchy_c: c,
            max_iterations: opt.max_iterations.saturating_sub(iterations).max(1),
            ..*opt
        };
        let r = optimise_fixed_kernel(poses, factors, &stage);
        iterations += r.iterations;
        converged = r.converged;
        if c <= c_final || iterations >= opt.max_iterations {
            break;
        }
        c = (c / 4.0).max(c_final);
    }
    SolveReport {
        initial_cost,
        final_cost: cost(poses, factors, c_final),
        iterations,
        converged,
    }
}

/// Levenberg-Marquardt with one kernel scale.
fn optimise_fixed_kernel(
    poses: &mut [Isometry3<f64>],
    factors: &[Factor],
    opt: &SolveOptions,
) -> SolveReport {
    let c = opt.loop_cauchy_c;
    let mut current = cost(poses, factors, c);
    let mut report = SolveReport {
        initial_cost: current,
        final_cost: current,
        iterations: 0,
        converged: false,
    };
    if poses.is_empty() || factors.is_empty() {
        report.converged = true;
        return report;
    }
    let n = poses.len() * 6;
    let mut lambda = 1e-4;
    for it in 0..opt.max_iterations.max(1) {
        report.iterations = it + 1;
        let (blocks, b) = normal_equations(poses, factors, c);
        // Diagonal of H for Marquardt's scaling.
        let mut diag = vec![0.0; n];
        for (a, bb, m) in &blocks {
            if a == bb {
                for k in 0..6 {
                    diag[a * 6 + k] += m[(k, k)];
                }
            }
        }
        let mut coo = CooMatrix::new(n, n);
        for (a, bb, m) in &blocks {
            coo.push_matrix(a * 6, bb * 6, m);
        }
        for (k, d) in diag.iter().enumerate() {
            coo.push(k, k, lambda * d.max(1e-6) + 1e-9);
        }
        let h = CscMatrix::from(&coo);
        let Ok(chol) = CscCholesky::factor(&h) else {
            lambda *= 10.0;
            continue;
        };
        let dx = chol.solve(&(-&b));
        let candidate: Vec<Isometry3<f64>> = poses
            .iter()
            .enumerate()
            .map(|(i, t)| {
                let d = Vector6::from_fn(|k, _| dx[(i * 6 + k, 0)]);
                t * se3::exp(&d)
            })
            .collect();
        let new_cost = cost(&candidate, factors, c);
        if new_cost.is_finite() && new_cost < current {
            let rel = (current - new_cost) / current.max(1e-300);
            poses.copy_from_slice(&candidate);
            current = new_cost;
            lambda = (lambda / 3.0).max(1e-9);
            if rel < opt.min_relative_decrease {
                report.converged = true;
                break;
            }
        } else {
            lambda *= 4.0;
            if lambda > 1e8 {
                // No step decreases the cost: at the minimum to numerical precision.
                report.converged = true;
                break;
            }
        }
    }
    report.final_cost = current;
    report
}
