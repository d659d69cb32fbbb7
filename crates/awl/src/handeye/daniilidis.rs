//! Daniilidis (1999), "Hand-eye calibration using dual quaternions".
//!
//! Each motion as a unit dual quaternion `q + e q'` (`q'= t q / 2`), signs chosen so the scalar
//! parts are non-negative (equal for `A` and `B` by screw congruence). `a X = X b` gives six linear
//! equations in the 8 unknowns `(x, x')`:
//! `[a - b, [a + b]x, 0, 0; a' - b', [a' + b']x, a - b, [a + b]x] (x0, x_v, x'0, x'_v) = 0`
//! (vector parts). The solution is the combination `l1 v7 + l2 v8` of the two right singular vectors
//! of the stacked system with the smallest singular values that satisfies `|x| = 1` and `x . x' = 0`.

use nalgebra::{DMatrix, Isometry3, Quaternion, SVector, Translation3, UnitQuaternion};

use crate::error::{Error, Result};
use crate::handeye::motion::{Motion, skew};

/// `(q, q')` of an isometry, with `q.w >= 0`.
fn dual_quaternion(iso: &Isometry3<f64>) -> (Quaternion<f64>, Quaternion<f64>) {
    let mut q = *iso.rotation.quaternion();
    if q.w < 0.0 {
        q = -q;
    }
    let qd = Quaternion::from_imag(iso.translation.vector) * q * 0.5;
    (q, qd)
}

fn split(v: &SVector<f64, 8>) -> (SVector<f64, 4>, SVector<f64, 4>) {
    (v.fixed_rows::<4>(0).into_owned(), v.fixed_rows::<4>(4).into_owned())
}

/// `ee_from_camera` by Daniilidis over `motions`.
///
/// # Errors
/// [`Error::Invalid`] when the null space is not two-dimensional enough to pick a solution.
pub(crate) fn solve(motions: &[Motion]) -> Result<Isometry3<f64>> {
    let n = motions.len();
    let mut t = DMatrix::<f64>::zeros(6 * n, 8);
    for (k, m) in motions.iter().enumerate() {
        let (a, ad) = dual_quaternion(&m.a);
        let (b, bd) = dual_quaternion(&m.b);
        let (av, bv, adv, bdv) = (a.imag(), b.imag(), ad.imag(), bd.imag());
        let r = 6 * k;
        t.view_mut((r, 0), (3, 1)).copy_from(&(av - bv));
        t.view_mut((r, 1), (3, 3)).copy_from(&skew(&(av + bv)));
        t.view_mut((r + 3, 0), (3, 1)).copy_from(&(adv - bdv));
        t.view_mut((r + 3, 1), (3, 3)).copy_from(&skew(&(adv + bdv)));
        t.view_mut((r + 3, 4), (3, 1)).copy_from(&(av - bv));
        t.view_mut((r + 3, 5), (3, 3)).copy_from(&skew(&(av + bv)));
    }
    let svd = t.svd(false, true);
    let v_t = svd.v_t.ok_or_else(|| Error::invalid("poses", "Daniilidis SVD failed"))?;
    let mut order: Vec<usize> = (0..8).collect();
    order.sort_by(|&i, &j| svd.singular_values[i].total_cmp(&svd.singular_values[j]));
    let row = |i: usize| SVector::<f64, 8>::from_iterator(v_t.row(i).iter().copied());
    let (u1, v1) = split(&row(order[0]));
    let (u2, v2) = split(&row(order[1]));
    // s = l1 / l2 solves a s^2 + b s + c = 0 (x . x' = 0); pick the root with the larger |x|^2
    let (a, b, c) = (u1.dot(&v1), u1.dot(&v2) + u2.dot(&v1), u2.dot(&v2));
    let norm2 = |s: f64| s * s * u1.dot(&u1) + 2.0 * s * u1.dot(&u2) + u2.dot(&u2);
    let roots: Vec<f64> = if a.abs() > 1e-12 * (b.abs() + c.abs()).max(1e-300) {
        let disc = b * b - 4.0 * a * c;
        if disc < 0.0 {
            return Err(Error::invalid("poses", "degenerate motion: no real dual-quaternion solution (Daniilidis)"));
        }
        let sq = disc.sqrt();
        vec![(-b + sq) / (2.0 * a), (-b - sq) / (2.0 * a)]
    } else if b.abs() > 1e-300 {
        vec![-c / b]
    } else {
        return Err(Error::invalid("poses", "degenerate motion: the dual-quaternion null space is ambiguous"));
    };
    let s = roots.into_iter().max_by(|x, y| norm2(*x).total_cmp(&norm2(*y))).unwrap_or(0.0);
    let l2 = 1.0 / norm2(s).max(1e-300).sqrt();
    let l1 = s * l2;
    let x = u1 * l1 + u2 * l2;
    let xd = v1 * l1 + v2 * l2;
    let q = Quaternion::new(x[0], x[1], x[2], x[3]);
    let qd = Quaternion::new(xd[0], xd[1], xd[2], xd[3]);
    let rotation = UnitQuaternion::from_quaternion(q);
    let translation = (qd * q.conjugate() * 2.0).imag();
    if !translation.iter().all(|v| v.is_finite()) {
        return Err(Error::invalid("poses", "degenerate motion: Daniilidis gave a non-finite solution"));
    }
    Ok(Isometry3::from_parts(Translation3::from(translation), rotation))
}
