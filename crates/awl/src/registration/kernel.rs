//! Robust kernels (M-estimators) as iteratively-reweighted-least-squares weights.

use serde::{Deserialize, Serialize};

/// A robust kernel; its scale `k` (metres of point-to-plane residual) is set per ICP level.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "kebab-case")]
pub enum Kernel {
    /// Plain least squares: every correspondence weighs 1.
    L2,
    /// Huber: 1 inside `k`, `k/|r|` outside.
    Huber,
    /// Cauchy: `1 / (1 + (r/k)^2)`.
    Cauchy,
    /// Geman-McClure: `(k^2 / (k^2 + r^2))^2`.
    GemanMcClure,
    /// Tukey's biweight: `(1 - (r/k)^2)^2` inside `k`, 0 outside.
    Tukey,
}

impl Kernel {
    /// IRLS weight of a residual `r` (metres) at scale `k` (metres, > 0).
    pub fn weight(self, r: f64, k: f64) -> f64 {
        let u2 = (r / k) * (r / k);
        match self {
            Kernel::L2 => 1.0,
            Kernel::Huber => {
                if r.abs() <= k {
                    1.0
                } else {
                    k / r.abs()
                }
            }
            Kernel::Cauchy => 1.0 / (1.0 + u2),
            Kernel::GemanMcClure => {
                let s = 1.0 / (1.0 + u2);
                s * s
            }
            Kernel::Tukey => {
                if u2 >= 1.0 {
                    0.0
                } else {
                    (1.0 - u2) * (1.0 - u2)
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_at_known_residuals() {
        let k = 0.01;
        for kernel in [Kernel::L2, Kernel::Huber, Kernel::Cauchy, Kernel::GemanMcClure, Kernel::Tukey] {
            assert!((kernel.weight(0.0, k) - 1.0).abs() < 1e-15, "{kernel:?} at 0");
        }
        assert!((Kernel::Huber.weight(0.02, k) - 0.5).abs() < 1e-12);
        assert!((Kernel::Cauchy.weight(0.01, k) - 0.5).abs() < 1e-12);
        assert!((Kernel::GemanMcClure.weight(0.01, k) - 0.25).abs() < 1e-12);
        assert!((Kernel::Tukey.weight(0.005, k) - 0.5625).abs() < 1e-12);
        assert_eq!(Kernel::Tukey.weight(0.011, k), 0.0);
    }
}
