//! The floor filters of `core_update`'s predict + update benchmark (the module docs
//! there): the plain arithmetic of each form, no checks beyond the variant's own.

// Index loops: every index addresses several matrices at once, as in the math.
#![allow(clippy::needless_range_loop)]

/// Column-major N x N.
pub type Square<const N: usize> = [[f64; N]; N];

/// A B (A: R x K as K columns, B: K x C as C columns), in column (axpy) order.
#[inline(always)]
fn product<const R: usize, const K: usize, const C: usize>(
    a: &[[f64; R]; K],
    b: &[[f64; K]; C],
) -> [[f64; R]; C] {
    let mut out = [[0.0; R]; C];
    for j in 0..C {
        for k in 0..K {
            let s = b[j][k];
            for i in 0..R {
                out[j][i] += a[k][i] * s;
            }
        }
    }
    out
}

/// A X' (X: C x K as K columns).
#[inline(always)]
fn product_transposed<const R: usize, const K: usize, const C: usize>(
    a: &[[f64; R]; K],
    x: &[[f64; C]; K],
) -> [[f64; R]; C] {
    let mut out = [[0.0; R]; C];
    for j in 0..C {
        for k in 0..K {
            let s = x[k][j];
            for i in 0..R {
                out[j][i] += a[k][i] * s;
            }
        }
    }
    out
}

/// A linear filter with two measurements (closed-form S^-1).
pub struct Filter<const N: usize> {
    pub f: Square<N>,
    pub q: Square<N>,
    /// H as N columns of 2.
    pub h: [[f64; 2]; N],
    /// R and its Cholesky factor and LDL' (R is fixed: factored once).
    pub r: Square<2>,
    pub r_factor: Square<2>,
    pub r_unit: Square<2>,
    pub r_pivots: [f64; 2],
    pub x: [f64; N],
    pub p: Square<N>,
    /// The joint check's margin, computed once (estim's runner reuses its
    /// certificates of Q_acc's and R's blocks while Q_acc is unchanged).
    pub joint_margin: f64,
}

/// What the checked floor hands back: what estim's update report carries for
/// an uncorrelated update (the cross-covariance, noise mean and gate are zero or
/// absent there and cost a store).
#[derive(Clone, Copy)]
pub struct Report<const N: usize> {
    pub innovation: [f64; 2],
    pub innovation_covariance: Square<2>,
    pub nis: f64,
    pub joint_margin: f64,
    pub gain: [[f64; N]; 2],
    pub correction: [f64; N],
}

impl<const N: usize> Report<N> {
    pub fn zeros() -> Self {
        Self {
            innovation: [0.0; 2],
            innovation_covariance: [[0.0; 2]; 2],
            nis: 0.0,
            joint_margin: 0.0,
            gain: [[0.0; N]; 2],
            correction: [0.0; N],
        }
    }
}

/// Whether every value is finite (branch-free, as estim's check).
#[inline(always)]
fn finite(values: &[f64]) -> bool {
    values.iter().fold(true, |ok, v| ok & v.is_finite())
}

impl<const N: usize> Filter<N> {
    /// One predict + update; `LDL` selects P = L D L' instead of chol(P).
    /// `CHECKED` adds what estim's runner must check and report, each in its
    /// cheapest form: the predicted state and covariance, the measurement, the
    /// predicted measurement and the posterior finite; S positive definite and
    /// not ill-conditioned (estim's reciprocal-condition floor, 1000 eps); each
    /// pivot of P's factor finite and above 16 (N + 2) eps P_jj (one test per
    /// column; the semidefinite case, which these runs never reach, is refused
    /// instead of handled); the joint margin (Q_acc = Q: one predict per update,
    /// so the margin is reused); a report.
    /// Err names the check.
    #[inline(always)]
    fn step_body<const LDL: bool, const CHECKED: bool>(
        &mut self,
        y: &[f64; 2],
        report: &mut Report<N>,
    ) -> Result<f64, &'static str> {
        let (mut x, p) = self.predicted();
        if CHECKED {
            if !finite(&x) {
                return Err("predicted state");
            }
            if !finite(p.as_flattened()) {
                return Err("predicted covariance");
            }
            // Committed, as a separate predict call would.
            self.p = p;
            self.x = x;
            if !finite(y) {
                return Err("measurement");
            }
        }
        let pht = product_transposed(&p, &self.h);
        let mut s = self.r;
        for j in 0..2 {
            for k in 0..N {
                for i in 0..2 {
                    s[j][i] += self.h[k][i] * pht[j][k];
                }
            }
        }
        let (a, b, d) = (s[0][0], s[0][1], s[1][1]);
        let det = a * d - b * b;
        let r = 1.0 / det;
        if CHECKED {
            let floor = 1000.0 * f64::EPSILON;
            let k = (1.0 - floor) / (1.0 + floor);
            let ad = a * d;
            if !(a > 0.0 && det >= 4.0 / f64::MAX && det.is_finite() && r.is_finite()) {
                return Err("innovation covariance not positive definite");
            }
            let conditioned = b * b < k * k * ad;
            if !conditioned {
                return Err("innovation covariance ill-conditioned");
            }
        }
        let inverse = [[d * r, -b * r], [-b * r, a * r]];
        let k = product(&pht, &inverse);
        let mut predicted = [0.0; 2];
        for (i, v) in predicted.iter_mut().enumerate() {
            for kk in 0..N {
                *v += self.h[kk][i] * x[kk];
            }
        }
        if CHECKED && !finite(&predicted) {
            return Err("predicted measurement");
        }
        let nu = [y[0] - predicted[0], y[1] - predicted[1]];
        let mut nis = 0.0;
        for i in 0..2 {
            for j in 0..2 {
                nis += nu[i] * inverse[j][i] * nu[j];
            }
        }
        let prior_x = x;
        for kk in 0..2 {
            for i in 0..N {
                x[i] += k[kk][i] * nu[kk];
            }
        }
        let (l, pivots) = factor::<N, LDL, CHECKED>(&p)?;
        let out = self.posterior_covariance::<LDL>(&l, &pivots, &k);
        if CHECKED {
            if !finite(&x) {
                return Err("posterior state");
            }
            if !finite(out.as_flattened()) {
                return Err("posterior covariance");
            }
            *report = Report {
                innovation: nu,
                innovation_covariance: s,
                nis,
                joint_margin: self.joint_margin,
                gain: k,
                correction: std::array::from_fn(|i| x[i] - prior_x[i]),
            };
        }
        self.p = out;
        self.x = x;
        Ok(nis)
    }

    /// x = F x, P = F P F' + Q (symmetric).
    #[inline(always)]
    fn predicted(&self) -> ([f64; N], [[f64; N]; N]) {
        let fp = product(&self.f, &self.p);
        let mut p = product_transposed(&fp, &self.f);
        for j in 0..N {
            for i in 0..=j {
                let v = p[j][i] + self.q[j][i];
                p[j][i] = v;
                p[i][j] = v;
            }
        }
        let mut x = [0.0; N];
        for k in 0..N {
            for i in 0..N {
                x[i] += self.f[k][i] * self.x[k];
            }
        }
        (x, p)
    }

    /// P+ = B1 D B1' + B2 D_R B2' with B1 = (I - K H) L, B2 = K L_R (`pivots` = D,
    /// all ones for chol(P)).
    #[inline(always)]
    fn posterior_covariance<const LDL: bool>(
        &self,
        l: &[[f64; N]; N],
        pivots: &[f64; N],
        k: &[[f64; N]; 2],
    ) -> [[f64; N]; N] {
        let hl = product(&self.h, l);
        let khl = product(k, &hl);
        let mut b1 = *l;
        for j in 0..N {
            for i in 0..N {
                b1[j][i] -= khl[j][i];
            }
        }
        let (r_factor, r_pivots) = if LDL {
            (&self.r_unit, self.r_pivots)
        } else {
            (&self.r_factor, [1.0; 2])
        };
        let b2 = product(k, r_factor);
        let mut out = [[0.0; N]; N];
        for j in 0..N {
            for kk in 0..N {
                let w = b1[kk][j] * pivots[kk];
                for i in 0..N {
                    out[j][i] += b1[kk][i] * w;
                }
            }
            for kk in 0..2 {
                let w = b2[kk][j] * r_pivots[kk];
                for i in 0..N {
                    out[j][i] += b2[kk][i] * w;
                }
            }
        }
        out
    }

    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    fn step_avx2<const LDL: bool, const CHECKED: bool>(
        &mut self,
        y: &[f64; 2],
        report: &mut Report<N>,
    ) -> Result<f64, &'static str> {
        self.step_body::<LDL, CHECKED>(y, report)
    }

    /// `step_body`, compiled for AVX2 where estim's dispatch allows it (as estim's
    /// runners are; `ESTIM_FORCE_PORTABLE=1` turns it off for both).
    fn dispatch<const LDL: bool, const CHECKED: bool>(
        &mut self,
        y: &[f64; 2],
        report: &mut Report<N>,
    ) -> Result<f64, &'static str> {
        #[cfg(target_arch = "x86_64")]
        {
            if estim_core::dispatch::features().avx2 {
                // SAFETY: a safe `#[target_feature]` function requires only that the
                // CPU has AVX2, which the dispatch reports on the line above.
                return unsafe { self.step_avx2::<LDL, CHECKED>(y, report) };
            }
        }
        self.step_body::<LDL, CHECKED>(y, report)
    }

    /// One step with no check; the NIS.
    pub fn step<const LDL: bool>(&mut self, y: &[f64; 2]) -> f64 {
        let mut unused = Report::zeros();
        // Without checks the body has no error path.
        self.dispatch::<LDL, false>(y, &mut unused)
            .unwrap_or(f64::NAN)
    }

    /// One step with the runner's checks, writing the report.
    pub fn checked_step<const LDL: bool>(
        &mut self,
        y: &[f64; 2],
        report: &mut Report<N>,
    ) -> Result<f64, &'static str> {
        self.dispatch::<LDL, true>(y, report)
    }
}

/// The factor of P: L (and D for LDL', `LDL`); with `CHECKED`, each pivot finite and
/// above 16 (N + 2) eps P_jj.
#[inline(always)]
fn factor<const N: usize, const LDL: bool, const CHECKED: bool>(
    p: &[[f64; N]; N],
) -> Result<([[f64; N]; N], [f64; N]), &'static str> {
    let mut l = [[0.0; N]; N];
    let mut pivots = [1.0; N];
    let tolerance = 16.0 * (N + 2) as f64 * f64::EPSILON;
    for j in 0..N {
        let mut pivot = p[j][j];
        for kk in 0..j {
            pivot -= l[kk][j] * l[kk][j] * if LDL { pivots[kk] } else { 1.0 };
        }
        if CHECKED
            && !(pivot.is_finite()
                & (pivot > tolerance * p[j][j].abs())
                & (1.0 / pivot).is_finite())
        {
            return Err("covariance factor: a pivot not clearly positive");
        }
        let inverse = if LDL {
            pivots[j] = pivot;
            l[j][j] = 1.0;
            1.0 / pivot
        } else {
            let root = pivot.sqrt();
            l[j][j] = root;
            root * (1.0 / pivot)
        };
        for i in (j + 1)..N {
            let mut v = p[j][i];
            for kk in 0..j {
                v -= l[kk][i] * l[kk][j] * if LDL { pivots[kk] } else { 1.0 };
            }
            l[j][i] = v * inverse;
        }
    }
    Ok((l, pivots))
}
