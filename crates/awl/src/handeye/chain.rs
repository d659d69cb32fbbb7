//! The hand-eye refined from registered views of the kinematic chain `T_model_camera = T_model_world *
//! T_world_base * T_base_ee * T_ee_camera`, where the camera poses come from registration (a scan's
//! views onto each other, a shot's views onto the model), not from a calibration target.
//!
//! Views taken from one base stop share its `T_world_base`, and its error: their camera motion
//! (registration, sub-millimetre) and their flange motion (kinematics) make one `A X = X B` per
//! pair. [`refine_chain`] solves for every unknown at once by Gauss-Newton (Levenberg-Marquardt):
//! - `X = ee_from_camera`, with the recorded one as a prior ([`ChainPrior`], 1-sigma per axis);
//! - `G = model_from_world` (free; fixed when the stops' base poses are free: then it is redundant);
//! - per stop the error of its recorded base pose `D_s` (`world_from_base_true = world_from_base *
//!   D_s`): free, known (a shot: world = the robot base), or with a prior per axis ([`StopPrior`]; a
//!   mobile base's SLAM errs mostly in x, y and yaw, little in z, roll and pitch).
//!
//! Each view's residual is the arm's error in the flange frame,
//! `Δ_i = base_from_ee_i^-1 * (G * world_from_base * D_s)^-1 * model_from_camera_i * X^-1`
//! (rotation vector, radians; translation, metres), weighted by [`ChainNoise`]. Perturbations are
//! right-multiplied (`X * (exp ω, v)`: ω and v in the camera frame), and so are the covariances'
//! coordinates: rotation first (rad), then translation (m).
//!
//! What the data alone determine about `X` is its information with the prior left out and the other
//! unknowns marginalised ([`ChainEstimate::data_sigma`]): a direction the motions leave unobserved
//! (every within-stop rotation about parallel axes) keeps the prior's value and sigma.

use nalgebra::{DMatrix, DVector, Isometry3, Matrix3, Matrix6, Point3, SymmetricEigen, Vector3, Vector6};

use crate::error::{Error, Result};
use crate::transform::isometry_from_translation_rotvec;

/// One registered view of the chain.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainView {
    /// The base stop the view was taken from (views of one stop share `world_from_base`'s error).
    pub stop: usize,
    /// The recorded `T_world_base` (SLAM; identity in a shot, where world = the robot base).
    pub world_from_base: Isometry3<f64>,
    /// The recorded `T_base_ee` (forward kinematics).
    pub base_from_ee: Isometry3<f64>,
    /// The registered `T_model_camera`.
    pub model_from_camera: Isometry3<f64>,
}

/// What is known of a stop's recorded base pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StopPrior {
    /// Nothing: each stop's base pose is free (then `model_from_world` is fixed, as it is redundant).
    Free,
    /// Exactly: the recorded base pose is the true one (a shot, whose world is the robot base).
    Known,
    /// 1-sigma of its error per axis of the base frame: roll, pitch, yaw (rad), x, y, z (m).
    Sigma([f64; 6]),
}

/// Measurement noise of a view, 1-sigma per axis.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ChainNoise {
    /// The arm's pose error at the flange (kinematics), metres.
    pub arm_m: f64,
    /// The arm's pose error at the flange, radians.
    pub arm_rad: f64,
    /// The registered camera pose's error, metres.
    pub camera_m: f64,
    /// The registered camera pose's error, radians.
    pub camera_rad: f64,
}

impl Default for ChainNoise {
    /// 0.7 mm / 0.07 deg at the flange (awl's simulated arm: 0.6 mm / 0.06 deg; the other
    /// simulator's about 1 mm / 0.1 deg in all), 0.3 mm / 0.02 deg for a registered camera pose.
    fn default() -> Self {
        let deg = std::f64::consts::PI / 180.0;
        Self { arm_m: 0.0007, arm_rad: 0.07 * deg, camera_m: 0.0003, camera_rad: 0.02 * deg }
    }
}

/// The recorded hand-eye and how far it may be off, 1-sigma per axis of the camera frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainPrior {
    /// The recorded `T_ee_camera`.
    pub ee_from_camera: Isometry3<f64>,
    /// Covariance of its error `(ω, v)` (rad², m²), camera frame.
    pub covariance: Matrix6<f64>,
}

impl ChainPrior {
    /// A prior with independent errors: `sigma_rad` about each axis, `sigma_m` along each.
    pub fn isotropic(ee_from_camera: Isometry3<f64>, sigma_m: f64, sigma_rad: f64) -> Self {
        let d = Vector6::new(sigma_rad, sigma_rad, sigma_rad, sigma_m, sigma_m, sigma_m);
        Self { ee_from_camera, covariance: Matrix6::from_diagonal(&d.component_mul(&d)) }
    }
}

/// What [`refine_chain`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct ChainEstimate {
    /// The refined `T_ee_camera`.
    pub ee_from_camera: Isometry3<f64>,
    /// Covariance of its error `(ω, v)` (rad², m²), camera frame, scaled by
    /// [`ChainEstimate::residual_scale`]² when that exceeds 1.
    pub covariance: Matrix6<f64>,
    /// The refined `T_model_world`.
    pub model_from_world: Isometry3<f64>,
    /// Joint covariance of the errors of `X` and `G` (`X`'s `(ω, v)` first, then `G`'s, right
    /// perturbations), scaled like `covariance`.
    pub joint_covariance: DMatrix<f64>,
    /// 1-sigma of `X`'s error per axis `(ω, v)` from the data alone (the prior left out, the other
    /// unknowns marginalised); infinite where the data do not constrain it.
    pub data_sigma: [f64; 6],
    /// The eigen-directions of the data's information about `X`'s rotation: the least observed
    /// axis (camera frame) and its 1-sigma (rad).
    pub weakest_rotation: (Vector3<f64>, f64),
    /// ... and of its translation: the least observed direction (camera frame), 1-sigma (m).
    pub weakest_translation: (Vector3<f64>, f64),
    /// `sqrt(chi² / degrees of freedom)` of the weighted view residuals at the solution (1 when
    /// the noise model fits).
    pub residual_scale: f64,
    /// Each view's weighted squared residual at the solution (its share of chi²), in input order.
    pub view_chi2: Vec<f64>,
    /// RMS of the views' flange-frame residuals: translation (m), rotation (rad).
    pub rms_m: f64,
    /// ... rotation, radians.
    pub rms_rad: f64,
    /// Gauss-Newton iterations run (over every reweighting pass).
    pub iterations: usize,
    /// The weight the prior's information carried at the solution: 1, or less where `prior_dof`
    /// discounted a prior the data contradict.
    pub prior_weight: f64,
}

/// `(ω, v)` of a right perturbation as an isometry (rotation `exp ω`, translation `v`).
fn perturbation(d: &[f64]) -> Isometry3<f64> {
    isometry_from_translation_rotvec(Vector3::new(d[3], d[4], d[5]), Vector3::new(d[0], d[1], d[2]))
}

/// The decoupled log of an isometry: rotation vector, then translation.
pub(crate) fn log(iso: &Isometry3<f64>) -> Vector6<f64> {
    let w = iso.rotation.scaled_axis();
    let t = iso.translation.vector;
    Vector6::new(w.x, w.y, w.z, t.x, t.y, t.z)
}

/// The unknowns' layout: `X` (6), `G` (6, when estimated), then each estimated stop (6).
struct Layout {
    g: Option<usize>,
    stops: Vec<Option<usize>>,
    len: usize,
}

fn layout(stop_count: usize, prior: &StopPrior) -> Layout {
    let estimate_g = !matches!(prior, StopPrior::Free);
    let mut next = if estimate_g { 12 } else { 6 };
    let stops = (0..stop_count)
        .map(|_| {
            (!matches!(prior, StopPrior::Known)).then(|| {
                next += 6;
                next - 6
            })
        })
        .collect();
    Layout { g: estimate_g.then_some(6), stops, len: next }
}

struct Problem<'a> {
    views: &'a [ChainView],
    /// Dense stop index of each view.
    stop_of: Vec<usize>,
    x0: Isometry3<f64>,
    g0: Isometry3<f64>,
    layout: Layout,
    /// Square root of the prior's information on `X` (upper-triangular factor).
    prior_sqrt: Matrix6<f64>,
    stop_sqrt: Option<Vector6<f64>>,
    view_weight: Vector6<f64>,
    /// Per view with unobserved directions: the square root of its residual's information with
    /// them left out (`None`: `view_weight`).
    view_sqrt: Vec<Option<Matrix6<f64>>>,
}

impl Problem<'_> {
    fn x(&self, p: &DVector<f64>) -> Isometry3<f64> {
        self.x0 * perturbation(&p.as_slice()[0..6])
    }

    fn g(&self, p: &DVector<f64>) -> Isometry3<f64> {
        match self.layout.g {
            Some(at) => self.g0 * perturbation(&p.as_slice()[at..at + 6]),
            None => self.g0,
        }
    }

    /// The flange-frame residual of view `i` (unweighted).
    fn view_residual(&self, p: &DVector<f64>, i: usize) -> Vector6<f64> {
        self.view_residual_at(p, i, &self.views[i].model_from_camera)
    }

    /// ... had it been registered at `model_from_camera`.
    fn view_residual_at(&self, p: &DVector<f64>, i: usize, model_from_camera: &Isometry3<f64>) -> Vector6<f64> {
        let v = &self.views[i];
        let d = match self.layout.stops[self.stop_of[i]] {
            Some(at) => perturbation(&p.as_slice()[at..at + 6]),
            None => Isometry3::identity(),
        };
        let model_from_base = self.g(p) * v.world_from_base * d;
        log(&(v.base_from_ee.inverse() * model_from_base.inverse() * model_from_camera * self.x(p).inverse()))
    }

    fn view_rows(&self) -> usize {
        6 * self.views.len()
    }

    /// Every weighted residual: the views', the prior on `X`, the stops' priors.
    fn residuals(&self, p: &DVector<f64>) -> DVector<f64> {
        let stop_rows = if self.stop_sqrt.is_some() { 6 * self.layout.stops.len() } else { 0 };
        let mut r = DVector::zeros(self.view_rows() + 6 + stop_rows);
        for i in 0..self.views.len() {
            let d = self.view_residual(p, i);
            let weighted = match &self.view_sqrt[i] {
                Some(sqrt) => sqrt * d,
                None => d.component_mul(&self.view_weight),
            };
            r.fixed_rows_mut::<6>(6 * i).copy_from(&weighted);
        }
        let px = Vector6::from_column_slice(&p.as_slice()[0..6]);
        r.fixed_rows_mut::<6>(self.view_rows()).copy_from(&(self.prior_sqrt * px));
        if let Some(w) = &self.stop_sqrt {
            for (k, at) in self.layout.stops.iter().enumerate() {
                if let Some(at) = at {
                    let d = Vector6::from_column_slice(&p.as_slice()[*at..at + 6]);
                    r.fixed_rows_mut::<6>(self.view_rows() + 6 + 6 * k).copy_from(&d.component_mul(w));
                }
            }
        }
        r
    }

    /// Central-difference Jacobian of [`Problem::residuals`].
    fn jacobian(&self, p: &DVector<f64>) -> DMatrix<f64> {
        const STEP: f64 = 1e-7;
        let rows = self.residuals(p).len();
        let mut j = DMatrix::zeros(rows, p.len());
        for c in 0..p.len() {
            let (mut hi, mut lo) = (p.clone(), p.clone());
            hi[c] += STEP;
            lo[c] -= STEP;
            j.set_column(c, &((self.residuals(&hi) - self.residuals(&lo)) / (2.0 * STEP)));
        }
        j
    }
}

/// Settings of [`refine_chain`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ChainParams {
    /// Each view's measurement noise.
    pub noise: ChainNoise,
    /// What is known of the stops' base poses.
    pub stops: StopPrior,
    /// Iteration cap. Default 30.
    pub max_iterations: usize,
    /// The prior's tail: `Some(ν)` is a Student-t of ν degrees of freedom with a Gaussian core. Where
    /// the refined `X` lies farther from the prior than its expected squared Mahalanobis distance
    /// (6), the prior's information is scaled by `(ν + 6) / (ν + d²)` (iteratively reweighted to a
    /// fixed point): a hand-eye the data show to be far off (a knocked camera) is not held near
    /// its recorded value. `None`: Gaussian.
    pub prior_dof: Option<f64>,
}

/// The prior's weight at squared Mahalanobis distance `d2` for a Student-t of `dof` degrees of
/// freedom over 6 axes, at most 1 (the Gaussian core).
fn prior_weight(dof: Option<f64>, d2: f64) -> f64 {
    dof.map_or(1.0, |nu| ((nu + 6.0) / (nu + d2.max(0.0))).min(1.0))
}

fn check_finite(what: &str, iso: &Isometry3<f64>) -> Result<()> {
    let q = iso.rotation.quaternion().coords;
    if iso.translation.vector.iter().chain(q.iter()).all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(Error::invalid(what, "non-finite pose (NaN or infinity)"))
    }
}

fn positive(name: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 { Ok(()) } else { Err(Error::invalid(name, format!("{v} is not a positive number"))) }
}

fn validate(views: &[ChainView], prior: &ChainPrior, params: &ChainParams) -> Result<()> {
    if views.is_empty() {
        return Err(Error::invalid("hand-eye views", "no view"));
    }
    check_finite("hand-eye prior T_ee_camera", &prior.ee_from_camera)?;
    for (i, v) in views.iter().enumerate() {
        check_finite(&format!("view {i} T_world_base"), &v.world_from_base)?;
        check_finite(&format!("view {i} T_base_ee"), &v.base_from_ee)?;
        check_finite(&format!("view {i} registered T_model_camera"), &v.model_from_camera)?;
    }
    let n = &params.noise;
    positive("hand-eye noise arm_m", n.arm_m)?;
    positive("hand-eye noise arm_rad", n.arm_rad)?;
    if !(n.camera_m.is_finite() && n.camera_m >= 0.0 && n.camera_rad.is_finite() && n.camera_rad >= 0.0) {
        return Err(Error::invalid("hand-eye noise camera_m / camera_rad", "must be finite numbers >= 0"));
    }
    if let StopPrior::Sigma(s) = &params.stops {
        for v in s {
            positive("hand-eye stop sigma", *v)?;
        }
    }
    if prior.covariance.iter().any(|v| !v.is_finite()) || prior.covariance.cholesky().is_none() {
        return Err(Error::invalid("hand-eye prior covariance", "must be finite and positive definite"));
    }
    Ok(())
}

/// 1-sigma and least-observed direction of a 3x3 information block (`inf` when singular).
fn weakest(information: &Matrix3<f64>) -> (Vector3<f64>, f64) {
    let e = SymmetricEigen::new(*information);
    let (k, l) =
        e.eigenvalues.iter().enumerate().fold((0, f64::INFINITY), |b, (k, &l)| if l < b.1 { (k, l) } else { b });
    let sigma = if l > 0.0 { 1.0 / l.sqrt() } else { f64::INFINITY };
    (e.eigenvectors.column(k).into_owned(), sigma)
}

/// Refines `prior` from registered `views` (see the module docs).
///
/// # Errors
/// [`Error::Invalid`] for no view, a non-finite pose, a noise or prior that is not positive, or a
/// system that cannot be solved.
pub fn refine_chain(views: &[ChainView], prior: &ChainPrior, params: &ChainParams) -> Result<ChainEstimate> {
    refine_chain_observed(views, &[], prior, params)
}

/// [`refine_chain`] where view `i`'s registration left the motions `unobserved[i]` unobserved
/// (twists `(ω, v)` of its `T_model_camera` in the model frame: `exp(ξ) T_model_camera`; a point
/// `p` moves at `v + ω × p`): its residual carries no information along them (their variance is
/// taken as infinite), so the hand-eye is refined from the observed directions only. A short
/// `unobserved` leaves the rest of the views as they are.
///
/// # Errors
/// As [`refine_chain`].
pub fn refine_chain_observed(
    views: &[ChainView],
    unobserved: &[Vec<Vector6<f64>>],
    prior: &ChainPrior,
    params: &ChainParams,
) -> Result<ChainEstimate> {
    validate(views, prior, params)?;
    let mut stop_ids: Vec<usize> = views.iter().map(|v| v.stop).collect();
    stop_ids.sort_unstable();
    stop_ids.dedup();
    let stop_of: Vec<usize> = views.iter().map(|v| stop_ids.binary_search(&v.stop).unwrap_or(0)).collect();
    let first = &views[0];
    let g0 = first.model_from_camera * (first.world_from_base * first.base_from_ee * prior.ee_from_camera).inverse();
    let information = prior.covariance.try_inverse().ok_or_else(|| Error::invalid("hand-eye prior", "singular"))?;
    let prior_sqrt = information.cholesky().map(|c| c.l().transpose()).unwrap_or_else(Matrix6::zeros);
    let n = &params.noise;
    let (sr, st) = ((n.arm_rad.powi(2) + n.camera_rad.powi(2)).sqrt(), (n.arm_m.powi(2) + n.camera_m.powi(2)).sqrt());
    let mut problem = Problem {
        views,
        stop_of,
        x0: prior.ee_from_camera,
        g0,
        layout: layout(stop_ids.len(), &params.stops),
        prior_sqrt,
        stop_sqrt: match params.stops {
            StopPrior::Sigma(s) => Some(Vector6::from_iterator(s.iter().map(|v| 1.0 / v))),
            _ => None,
        },
        view_weight: Vector6::new(1.0 / sr, 1.0 / sr, 1.0 / sr, 1.0 / st, 1.0 / st, 1.0 / st),
        view_sqrt: vec![None; views.len()],
    };
    let mut left_out = 0;
    for (i, twists) in unobserved.iter().enumerate().take(views.len()) {
        if let Some(sqrt) = observed_sqrt(&problem, i, twists) {
            problem.view_sqrt[i] = Some(sqrt);
            left_out += twists.len();
        }
    }
    // Gauss-Newton on the prior as weighted, reweighted until the weight settles (one pass for a
    // Gaussian prior)
    let mut p = DVector::zeros(problem.layout.len);
    let (mut weight, mut iterations) = (1.0_f64, 0);
    for _ in 0..10 {
        problem.prior_sqrt = prior_sqrt * weight.sqrt();
        iterations += least_squares(&problem, &mut p, params.max_iterations);
        let px = Vector6::from_column_slice(&p.as_slice()[0..6]);
        let next = prior_weight(params.prior_dof, px.dot(&(information * px)));
        let settled = (next - weight).abs() <= 1e-4 * weight;
        weight = next;
        if settled {
            break;
        }
    }
    problem.prior_sqrt = prior_sqrt * weight.sqrt();
    let j = problem.jacobian(&p);
    let h = j.transpose() * &j;
    let covariance_all =
        h.clone().try_inverse().ok_or_else(|| Error::invalid("hand-eye refinement", "singular system"))?;
    // the views' residuals at the solution
    let rows = problem.view_rows();
    let r = problem.residuals(&p);
    let chi2 = r.rows(0, rows).norm_squared();
    let dof = rows.saturating_sub(problem.layout.len - 6 + left_out).max(1);
    let residual_scale = (chi2 / dof as f64).sqrt();
    let scale = residual_scale.max(1.0).powi(2);
    let (mut sum_t, mut sum_r) = (0.0, 0.0);
    for i in 0..views.len() {
        let d = problem.view_residual(&p, i);
        sum_r += d.fixed_rows::<3>(0).norm_squared();
        sum_t += d.fixed_rows::<3>(3).norm_squared();
    }
    // the data's information on X: the prior's rows left out, the other unknowns marginalised
    let mut data = h;
    for a in 0..6 {
        for b in 0..6 {
            data[(a, b)] -= weight * information[(a, b)];
        }
    }
    let marginal = marginal_information(&data);
    let data_sigma =
        std::array::from_fn(|k| if marginal[(k, k)] > 0.0 { 1.0 / marginal[(k, k)].sqrt() } else { f64::INFINITY });
    let kept: Vec<usize> = (0..6).chain(problem.layout.g.map_or(0..0, |at| at..at + 6)).collect();
    let joint_covariance = DMatrix::from_fn(kept.len(), kept.len(), |a, b| covariance_all[(kept[a], kept[b])] * scale);
    Ok(ChainEstimate {
        ee_from_camera: problem.x(&p),
        covariance: Matrix6::from_fn(|a, b| covariance_all[(a, b)] * scale),
        model_from_world: problem.g(&p),
        joint_covariance,
        data_sigma,
        weakest_rotation: weakest(&marginal.fixed_view::<3, 3>(0, 0).into_owned()),
        weakest_translation: weakest(&marginal.fixed_view::<3, 3>(3, 3).into_owned()),
        residual_scale,
        view_chi2: (0..views.len()).map(|i| r.fixed_rows::<6>(6 * i).norm_squared()).collect(),
        rms_m: (sum_t / views.len() as f64).sqrt(),
        rms_rad: (sum_r / views.len() as f64).sqrt(),
        iterations,
        prior_weight: weight,
    })
}

/// Levenberg-Marquardt on `problem` from `p` (updated in place); the iterations run.
fn least_squares(problem: &Problem<'_>, p: &mut DVector<f64>, max_iterations: usize) -> usize {
    let mut cost = problem.residuals(p).norm_squared();
    let mut lambda = 1e-3;
    let mut iterations = 0;
    for _ in 0..max_iterations {
        iterations += 1;
        let j = problem.jacobian(p);
        let r = problem.residuals(p);
        let h = j.transpose() * &j;
        let g = j.transpose() * &r;
        let mut improved = false;
        for _ in 0..10 {
            let mut damped = h.clone();
            for k in 0..damped.nrows() {
                damped[(k, k)] += lambda * h[(k, k)].max(1e-12);
            }
            let Some(step) = damped.cholesky().map(|c| c.solve(&(-&g))) else {
                lambda *= 10.0;
                continue;
            };
            let candidate = &*p + &step;
            let c = problem.residuals(&candidate).norm_squared();
            if c < cost {
                let small = step.amax() < 1e-10;
                (*p, cost, lambda, improved) = (candidate, c, (lambda * 0.3).max(1e-9), true);
                if small {
                    improved = false;
                }
                break;
            }
            lambda *= 10.0;
        }
        if !improved {
            break;
        }
    }
    iterations
}

/// The square root of view `i`'s residual information with the directions the registered pose's
/// `twists` move it in left out: `W - W D (Dᵀ W D)⁻¹ Dᵀ W` (`W` the view's weight², `D` the
/// residual's response to each twist, by central differences at the prior); `None` for no twist.
fn observed_sqrt(problem: &Problem<'_>, i: usize, twists: &[Vector6<f64>]) -> Option<Matrix6<f64>> {
    const STEP: f64 = 1e-6;
    if twists.is_empty() {
        return None;
    }
    let p = DVector::zeros(problem.layout.len);
    let m = problem.views[i].model_from_camera;
    let columns: Vec<Vector6<f64>> = (twists.iter())
        .map(|t| {
            let moved = |h: f64| perturbation((t * h).as_slice()) * m;
            (problem.view_residual_at(&p, i, &moved(STEP)) - problem.view_residual_at(&p, i, &moved(-STEP)))
                / (2.0 * STEP)
        })
        .collect();
    let d = nalgebra::OMatrix::<f64, nalgebra::U6, nalgebra::Dyn>::from_columns(&columns);
    let w = Matrix6::from_diagonal(&problem.view_weight.component_mul(&problem.view_weight));
    let wd = w * &d;
    let inner = (d.transpose() * &wd).try_inverse()?;
    let information = w - &wd * inner * wd.transpose();
    let e = SymmetricEigen::new((information + information.transpose()) * 0.5);
    let root = Matrix6::from_diagonal(&e.eigenvalues.map(|l| l.max(0.0).sqrt()));
    Some(root * e.eigenvectors.transpose())
}

/// The Schur complement of the first 6 unknowns in an information matrix (the rest marginalised;
/// a tiny ridge keeps unobserved nuisances from making it singular).
fn marginal_information(h: &DMatrix<f64>) -> Matrix6<f64> {
    let n = h.nrows();
    let hxx = Matrix6::from_fn(|a, b| h[(a, b)]);
    if n == 6 {
        return hxx;
    }
    let hxn = h.view((0, 6), (6, n - 6)).into_owned();
    let mut hnn = h.view((6, 6), (n - 6, n - 6)).into_owned();
    let ridge = 1e-9 * (0..n - 6).map(|k| hnn[(k, k)]).fold(0.0, f64::max).max(1e-12);
    for k in 0..n - 6 {
        hnn[(k, k)] += ridge;
    }
    match hnn.cholesky() {
        Some(c) => {
            let solved = c.solve(&hxn.transpose());
            let s = hxx - &hxn * solved;
            Matrix6::from_fn(|a, b| s[(a, b)])
        }
        None => Matrix6::zeros(),
    }
}

/// The covariance of a point `p_model` carried into the world frame by `world_from_model =
/// model_from_world^-1` (`G`'s right perturbation, covariance `g_covariance`): m², world frame.
pub fn point_covariance(
    model_from_world: &Isometry3<f64>,
    g_covariance: &Matrix6<f64>,
    p_model: &Point3<f64>,
) -> Matrix3<f64> {
    // world_from_model_true = D^-1 * world_from_model, D = (exp ω, v): p_world ≈ q - ω x q - v
    let q = model_from_world.inverse() * p_model;
    let mut j = nalgebra::Matrix3x6::zeros();
    j.fixed_view_mut::<3, 3>(0, 0).copy_from(&crate::transform::skew(&q.coords));
    j.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-Matrix3::identity()));
    j * g_covariance * j.transpose()
}

#[cfg(test)]
mod tests {
    use nalgebra::{Translation3, UnitQuaternion};
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    use super::*;
    use crate::random::{normal_perturbation, uniform, unit_vector};

    const ARM_M: f64 = 0.0006;
    const ARM_RAD: f64 = 0.06 * std::f64::consts::PI / 180.0;

    struct Case {
        views: Vec<ChainView>,
        truth: Isometry3<f64>,
        prior: ChainPrior,
    }

    /// `stops` stops of 2 views each, the flange turned `turn_deg` between them about a random
    /// axis (or about world z for every stop when `parallel`), the camera ~1 m from the scene.
    fn case(seed: u64, stops: usize, turn_deg: f64, parallel: bool, noise: f64) -> Case {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = Isometry3::from_parts(
            Translation3::new(0.032, -0.018, 0.048),
            UnitQuaternion::from_scaled_axis(Vector3::new(0.01, -0.015, 1.57)),
        );
        let recorded = truth * normal_perturbation(&mut rng, 0.0017, 0.003);
        let model_from_world = normal_perturbation(&mut rng, 0.5, 0.5);
        let mut views = Vec::new();
        for s in 0..stops {
            let a = uniform(&mut rng, 0.0, std::f64::consts::TAU);
            let world_from_base = Isometry3::from_parts(
                Translation3::new(1.3 * a.cos(), 1.3 * a.sin(), 0.45),
                UnitQuaternion::from_axis_angle(&Vector3::z_axis(), a + std::f64::consts::PI),
            );
            let slam = normal_perturbation(&mut rng, 0.01 * noise, 0.01 * noise);
            for k in 0..2 {
                let axis = if parallel { Vector3::z() } else { unit_vector(&mut rng) };
                let turn = UnitQuaternion::from_scaled_axis(axis * (k as f64 * turn_deg.to_radians()));
                let base_from_ee = Isometry3::from_parts(
                    Translation3::new(0.5, 0.1 * k as f64, 0.4),
                    UnitQuaternion::from_scaled_axis(Vector3::new(0.0, 1.6, 0.0)) * turn,
                );
                let arm = normal_perturbation(&mut rng, ARM_M * noise, ARM_RAD * noise);
                views.push(ChainView {
                    stop: 10 * s + 3,
                    world_from_base: world_from_base * slam,
                    base_from_ee: base_from_ee * arm,
                    model_from_camera: model_from_world * world_from_base * base_from_ee * truth,
                });
            }
        }
        Case { views, truth, prior: ChainPrior::isotropic(recorded, 0.0017, 0.003) }
    }

    fn params(stops: StopPrior) -> ChainParams {
        ChainParams {
            noise: ChainNoise { arm_m: ARM_M, arm_rad: ARM_RAD, camera_m: 0.0, camera_rad: 0.0 },
            stops,
            max_iterations: 30,
            prior_dof: None,
        }
    }

    #[test]
    fn exact_chains_give_the_true_hand_eye() {
        let mut c = case(1, 6, 35.0, false, 0.0);
        // a prior of 1 m / 1 rad: the exact data alone decide
        c.prior = ChainPrior::isotropic(c.prior.ee_from_camera, 1.0, 1.0);
        let e = refine_chain(&c.views, &c.prior, &params(StopPrior::Free)).expect("refine");
        let (dt, dr) = crate::transform::pose_difference(&e.ee_from_camera, &c.truth);
        assert!(dt < 1e-6 && dr < 1e-7, "{dt} {dr}");
        assert!(e.residual_scale < 0.05, "{}", e.residual_scale);
    }

    #[test]
    fn the_covariance_covers_the_error_of_noisy_chains() {
        // 200 seeded scans of 6 stops; the 6-dof Mahalanobis distance of X's error falls within
        // chi2_6(95 %) = 12.59 for about 95 % of them
        let mut inside = 0;
        let mut gain = Vec::new();
        for seed in 0..200 {
            let c = case(seed, 6, 35.0, false, 1.0);
            let e = refine_chain(&c.views, &c.prior, &params(StopPrior::Free)).expect("refine");
            let err = log(&(e.ee_from_camera.inverse() * c.truth));
            let m = err.transpose() * e.covariance.try_inverse().expect("invertible") * err;
            inside += usize::from(m[(0, 0)] < 12.59);
            let before = crate::transform::pose_difference(&c.prior.ee_from_camera, &c.truth).1;
            let after = crate::transform::pose_difference(&e.ee_from_camera, &c.truth).1;
            gain.push(before / after.max(1e-12));
        }
        gain.sort_by(f64::total_cmp);
        // measured 190 / 200 inside, median rotation gain 2.4x
        assert!((180..=199).contains(&inside), "{inside} of 200 inside the 95 % ellipsoid");
        assert!(gain[100] > 1.8, "median rotation gain {}", gain[100]);
    }

    #[test]
    fn a_prior_the_data_contradict_is_weighed_less_with_a_t_tail() {
        // 100 seeded scans of 6 stops whose recorded hand-eye is 5 mm / 1 deg off (3 and 5.8 sigma
        // of the 1.7 mm / 0.17 deg prior): a Gaussian prior holds the estimate near it, the t tail
        // (6 degrees of freedom) lets the data decide; where the prior is right (its own draws),
        // the tail changes little and the covariance still covers the error
        let t_tail = |stops| ChainParams { prior_dof: Some(6.0), ..params(stops) };
        let (mut gaussian, mut tailed, mut weights) = (Vec::new(), Vec::new(), Vec::new());
        let mut inside = 0;
        for seed in 0..100 {
            let mut c = case(seed, 6, 35.0, false, 1.0);
            let e = refine_chain(&c.views, &c.prior, &t_tail(StopPrior::Free)).expect("refine");
            let err = log(&(e.ee_from_camera.inverse() * c.truth));
            inside += usize::from(err.dot(&(e.covariance.try_inverse().expect("invertible") * err)) < 12.59);
            let mut rng = ChaCha8Rng::seed_from_u64(1000 + seed);
            let off = isometry_from_translation_rotvec(
                unit_vector(&mut rng) * 0.005,
                unit_vector(&mut rng) * 1f64.to_radians(),
            );
            c.prior.ee_from_camera = c.truth * off;
            let g = refine_chain(&c.views, &c.prior, &params(StopPrior::Free)).expect("gaussian");
            let t = refine_chain(&c.views, &c.prior, &t_tail(StopPrior::Free)).expect("t");
            gaussian.push(crate::transform::pose_difference(&g.ee_from_camera, &c.truth));
            tailed.push(crate::transform::pose_difference(&t.ee_from_camera, &c.truth));
            weights.push(t.prior_weight);
        }
        let median = |v: &mut Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v[v.len() / 2]
        };
        let (gt, gr) =
            (median(&mut gaussian.iter().map(|e| e.0).collect()), median(&mut gaussian.iter().map(|e| e.1).collect()));
        let (tt, tr) =
            (median(&mut tailed.iter().map(|e| e.0).collect()), median(&mut tailed.iter().map(|e| e.1).collect()));
        let w = median(&mut weights);
        println!(
            "median error: Gaussian {:.2} mm {:.3} deg, t {:.2} mm {:.3} deg; median prior weight {w:.2}; {inside} of 100 inside",
            gt * 1e3,
            gr.to_degrees(),
            tt * 1e3,
            tr.to_degrees()
        );
        // measured: Gaussian 1.16 mm / 0.176 deg, t 1.15 mm / 0.116 deg (the translation here is
        // limited by the arm's noise, not by the prior); median weight 0.27; 96 of 100 inside
        assert!(tt < 1.05 * gt && tr < 0.75 * gr, "t {tt} m {tr} rad vs Gaussian {gt} m {gr} rad");
        assert!(w < 0.5, "median prior weight {w}");
        assert!((88..=100).contains(&inside), "{inside} of 100 inside the 95 % ellipsoid");
    }

    #[test]
    fn parallel_rotation_axes_leave_the_translation_along_them_to_the_prior() {
        let c = case(3, 6, 35.0, true, 1.0);
        let e = refine_chain(&c.views, &c.prior, &params(StopPrior::Free)).expect("refine");
        // every flange motion turns about the flange's z: the hand-eye's translation along that
        // axis (camera frame) is unobserved by the data (Shiu & Ahmad 1989), and stays at the prior
        let (axis, sigma) = e.weakest_translation;
        let common = (c.truth.rotation.inverse() * Vector3::z()).normalize();
        assert!(axis.dot(&common).abs() > 0.99, "weakest direction {axis:?} vs {common:?}");
        assert!(sigma > 1.0, "data sigma along it {sigma} m");
        let shift = (e.ee_from_camera.translation.vector - c.prior.ee_from_camera.translation.vector)
            .dot(&(c.truth.rotation * common));
        assert!(shift.abs() < 1e-4, "moved {shift} m along the unobserved direction");
        let spread = case(3, 6, 35.0, false, 1.0);
        let e = refine_chain(&spread.views, &spread.prior, &params(StopPrior::Free)).expect("refine");
        assert!(e.weakest_translation.1 < 0.01 && e.weakest_rotation.1 < 0.01, "{:?}", e.data_sigma);
    }

    #[test]
    fn a_shot_locates_its_base_with_the_views_known_base() {
        // one stop, world = base known: G is estimated, the stop's pose is fixed
        let mut c = case(4, 1, 30.0, false, 0.0);
        c.prior.ee_from_camera = c.truth;
        for v in &mut c.views {
            v.world_from_base = Isometry3::identity();
        }
        let truth_g = c.views[0].model_from_camera * (c.views[0].base_from_ee * c.truth).inverse();
        for v in &mut c.views {
            v.model_from_camera = truth_g * v.base_from_ee * c.truth;
        }
        let e = refine_chain(&c.views, &c.prior, &params(StopPrior::Known)).expect("refine");
        assert_eq!(e.joint_covariance.nrows(), 12);
        let (dt, _) = crate::transform::pose_difference(&e.model_from_world, &truth_g);
        assert!(dt < 1e-9, "{dt}");
        let cov = point_covariance(
            &e.model_from_world,
            &Matrix6::from_fn(|a, b| e.joint_covariance[(a + 6, b + 6)]),
            &Point3::origin(),
        );
        assert!(cov.trace().is_finite() && cov.trace() > 0.0);
    }

    #[test]
    fn bad_input_is_refused_by_name() {
        let c = case(5, 2, 30.0, false, 1.0);
        assert!(refine_chain(&[], &c.prior, &params(StopPrior::Free)).is_err());
        let mut bad = c.views.clone();
        bad[1].base_from_ee.translation.x = f64::NAN;
        let e = refine_chain(&bad, &c.prior, &params(StopPrior::Free)).expect_err("nan");
        assert!(e.to_string().contains("view 1 T_base_ee"), "{e}");
        let mut p = params(StopPrior::Free);
        p.noise.arm_m = 0.0;
        assert!(refine_chain(&c.views, &c.prior, &p).expect_err("zero").to_string().contains("arm_m"));
    }
}
