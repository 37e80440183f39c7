//! The 15-state INS error model: continuous F and G, discrete Phi and Q, injection and
//! reset, as an estim-core [`ProcessModel`] + [`ErrorStateModel`].

use estim_core::{ErrorStateModel, ProcessModel};
use nalgebra::{Matrix3, SMatrix, SVector, UnitQuaternion, Vector3};

use crate::earth::{
    inverse_root_of_prime_vertical_factor, latitude_sin_cos, normal_gravity_gradient_at,
    radii_of_curvature, EARTH_RATE, ECCENTRICITY_SQUARED, SEMI_MAJOR_AXIS,
};
use crate::imu_spec::ImuSpec;
use crate::kernel::{MultiplyAdd, Separate};
use crate::mechanization::{ImuSample, Mechanization};
use crate::state::{InsState, ACC_BIAS, ATT, ERROR_STATES, GYRO_BIAS, POS, VEL};

mod builds;
mod covariance;
mod transition;

use covariance::{has_model_structure, mirror_upper, propagate_upper};
use transition::{
    block_product, put_symmetric_block, ScaledBlocks, FULL, NO_EAST, PSI_V, PSI_V_T, SKEW,
};

type M3 = Matrix3<f64>;
/// 15 x 15 matrix of the error state.
pub type ErrorMatrix = SMatrix<f64, ERROR_STATES, ERROR_STATES>;
/// 15 x 12 noise-input matrix.
pub type NoiseInput = SMatrix<f64, ERROR_STATES, 12>;

#[inline]
fn skew(v: &Vector3<f64>) -> M3 {
    M3::new(0.0, -v.z, v.y, v.z, 0.0, -v.x, -v.y, v.x, 0.0)
}

/// The nonzero 3x3 blocks of the continuous system matrix F, by name (rows and columns
/// POS, VEL, ATT, ACC_BIAS, GYRO_BIAS). F_pv = I, F_va = F_ψg = -C_b^n and the bias
/// blocks are multiples of the identity, so they are kept as the rotation and two rates.
struct SystemBlocks {
    pp: M3,
    vp: M3,
    vv: M3,
    vpsi: M3,
    psip: M3,
    psiv: M3,
    psipsi: M3,
    c_bn: M3,
    acc_decay: f64,
    gyro_decay: f64,
}

impl SystemBlocks {
    fn dense(&self) -> ErrorMatrix {
        let mut out = ErrorMatrix::zeros();
        let id = M3::identity();
        for (i, j, b) in [
            (0, 0, self.pp),
            (0, 1, id),
            (1, 0, self.vp),
            (1, 1, self.vv),
            (1, 2, self.vpsi),
            (1, 3, -self.c_bn),
            (2, 0, self.psip),
            (2, 1, self.psiv),
            (2, 2, self.psipsi),
            (2, 4, -self.c_bn),
            (3, 3, id * self.acc_decay),
            (4, 4, id * self.gyro_decay),
        ] {
            out.fixed_view_mut::<3, 3>(3 * i, 3 * j).copy_from(&b);
        }
        out
    }
}

/// The 15-state INS error model over a strapdown [`Mechanization`] and an [`ImuSpec`].
///
/// # Formulation
///
/// Error state δx = \[δp (NED m), δv^n, ψ (NED rad), δb_a, δb_g\] with the pinned
/// convention `true = nominal + error` (see [`InsState`](crate::InsState)). The
/// continuous error dynamics δẋ = F δx + G w, w = \[w_a, w_g, w_ba, w_bg\], are those of
/// Groves (2013) sec. 14.2.3-14.2.4 (local-navigation-frame error equations 14.63-14.71,
/// with the gravity-gradient and transport-rate terms kept) and Farrell (2008) sec. 11.4,
/// rewritten for (i) position error in metres N, E, D instead of δL, δλ, δh and (ii)
/// errors defined as true minus nominal. Every sign is checked against finite
/// differences of [`navigation_rates`](crate::navigation_rates) in the tests:
///
/// ```text
/// δṗ  = F_pp δp + δv
/// δv̇  = F_vp δp + F_vv δv - [f^n×] ψ - C_b^n δb_a - C_b^n w_a
/// ψ̇   = F_ψp δp + F_ψv δv - [ω_in^n×] ψ - C_b^n δb_g - C_b^n w_g
/// δḃ_a = -δb_a / τ_a + w_ba,    δḃ_g = -δb_g / τ_g + w_bg
/// ```
///
/// with F_vp = [v×](2 W_ie + W_en) + ∂g/∂p, F_vv = \[v×\] ∂ω_en/∂v - \[(2ω_ie + ω_en)×\],
/// F_ψp = -(W_ie + W_en), F_ψv = -∂ω_en/∂v, W = ∂ω/∂δp (Groves eqs. 14.64-14.69).
/// Noise PSD Σ = diag(VRW² I, ARW² I, 2σ_a²/τ_a I, 2σ_g²/τ_g I) ([`ImuSpec`]).
///
/// # Discretisation
///
/// - Phi = I + F dt + (F dt)²/2 (Groves eq. 14.72 truncated after the second-order
///   term; Farrell 2008 eq. 4.115), evaluated column by column from the nonzero entries
///   of F's 3x3 blocks (F has 12 nonzero blocks out of 25).
/// - Q_d = ∫_0^dt (I + F s) G Σ G' (I + F s)' ds
///   = Q_1 dt + (F Q_1 + Q_1 F') dt²/2 + F Q_1 F' dt³/3, Q_1 = G Σ G'
///   (the second-order expansion of the Van Loan integral, Groves eq. 14.82-14.83 /
///   Farrell eq. 4.124; the dt³ term keeps it positive semidefinite). Because each
///   triad's noise is isotropic, Q_1 = diag(0, VRW² I, ARW² I, ...) does not depend on
///   the attitude. [`InsErrorModel::van_loan`] gives the exact Van Loan result for
///   comparison (used by the tests).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsErrorModel {
    spec: ImuSpec,
    mechanization: Mechanization,
}

impl InsErrorModel {
    /// The error model of an IMU with the given error specification.
    #[must_use]
    pub fn new(spec: ImuSpec) -> Self {
        Self {
            spec,
            mechanization: Mechanization::new(),
        }
    }

    /// The IMU error specification.
    #[must_use]
    pub fn spec(&self) -> &ImuSpec {
        &self.spec
    }

    /// The mechanization used by [`ProcessModel::propagate`].
    #[must_use]
    pub fn mechanization(&self) -> &Mechanization {
        &self.mechanization
    }

    /// The 3x3 blocks of the continuous system matrix F at `state` with the raw sample `imu`.
    /// Inlined into each kernel build, whose sin/cos of the latitude is the inline one of
    /// [`latitude_sin_cos`] (no library call).
    #[inline(always)]
    fn system_blocks<M: MultiplyAdd>(&self, state: &InsState, imu: &ImuSample) -> SystemBlocks {
        let lat = state.latitude;
        let h = state.height;
        let v = state.velocity_ned;
        let (s, c) = latitude_sin_cos::<M>(lat);
        // Reciprocals once, then products: the Earth terms below need 1/cos L, 1/d,
        // 1/(R_N+h) and 1/(R_E+h) many times, and each division is a slow instruction.
        let inverse_cos = 1.0 / c;
        let t = s * inverse_cos;
        // Radii, their latitude derivatives and gravity from one sin/cos (Groves eqs.
        // 2.105, 2.106, 2.134, 2.139; same formulas as crate::earth).
        let e2 = ECCENTRICITY_SQUARED;
        let inverse_root = inverse_root_of_prime_vertical_factor::<M>(s * s);
        let inverse_d = inverse_root * inverse_root;
        let re0 = SEMI_MAJOR_AXIS * inverse_root;
        let rn0 = re0 * (1.0 - e2) * inverse_d;
        let e2sc_d = e2 * s * c * inverse_d;
        let dre = re0 * e2sc_d;
        let drn = 3.0 * rn0 * e2sc_d;
        let (rn, re) = (rn0 + h, re0 + h);
        // 1/(R_N+h) and 1/(R_E+h) from one division.
        let inverse_product = 1.0 / (rn * re);
        let (inverse_rn, inverse_re) = (re * inverse_product, rn * inverse_product);
        let (inverse_rn2, inverse_re2) = (inverse_rn * inverse_rn, inverse_re * inverse_re);
        let lat_rate = v.x * inverse_rn;
        let c_bn = state.attitude.to_rotation_matrix().into_inner();
        let specific_force_ned = c_bn * (imu.specific_force - state.acc_bias);
        let w_ie = Vector3::new(EARTH_RATE * c, 0.0, -EARTH_RATE * s);
        let w_en = Vector3::new(v.y * inverse_re, -v.x * inverse_rn, -v.y * t * inverse_re);
        let zero = Vector3::zeros();
        // ∂ω/∂δp = [∂ω/∂L / (R_N + h), 0, -∂ω/∂h] since δL = δp_N/(R_N+h), δh = -δp_D.
        let position_jacobian =
            |dl: Vector3<f64>, dh: Vector3<f64>| M3::from_columns(&[dl * inverse_rn, zero, -dh]);
        let w_ie_p = position_jacobian(Vector3::new(-EARTH_RATE * s, 0.0, -EARTH_RATE * c), zero);
        let w_en_p = position_jacobian(
            Vector3::new(
                -v.y * dre * inverse_re2,
                v.x * drn * inverse_rn2,
                -v.y * (inverse_cos * inverse_cos * inverse_re - t * dre * inverse_re2),
            ),
            Vector3::new(-v.y * inverse_re2, v.x * inverse_rn2, v.y * t * inverse_re2),
        );
        let w_en_v = M3::new(
            0.0,
            inverse_re,
            0.0,
            -inverse_rn,
            0.0,
            0.0,
            0.0,
            -t * inverse_re,
            0.0,
        );
        let (dg_dl, dg_dh) = normal_gravity_gradient_at(s, c, inverse_root, h);
        let mut gravity_p = M3::zeros();
        gravity_p[(2, 0)] = dg_dl * inverse_rn;
        gravity_p[(2, 2)] = -dg_dh;

        // Position rows (derived from L̇ = v_N/(R_N+h), λ̇ = v_E/((R_E+h) cos L), ḣ = -v_D).
        let pp = M3::new(
            -v.z * inverse_rn,
            0.0,
            v.x * inverse_rn,
            (v.y * t - v.y * dre * inverse_re) * inverse_rn,
            (dre * lat_rate - v.z) * inverse_re - t * lat_rate,
            v.y * inverse_re,
            0.0,
            0.0,
            0.0,
        );
        let v_skew = skew(&v);
        let vp = block_product::<SKEW, NO_EAST>(&v_skew, &(2.0 * w_ie_p + w_en_p)) + gravity_p;
        let vv = block_product::<SKEW, PSI_V>(&v_skew, &w_en_v) - skew(&(2.0 * w_ie + w_en));
        let vpsi = -skew(&specific_force_ned);
        let psip = -(w_ie_p + w_en_p);
        let psiv = -w_en_v;
        let psipsi = -skew(&(w_ie + w_en));
        SystemBlocks {
            pp,
            vp,
            vv,
            vpsi,
            psip,
            psiv,
            psipsi,
            c_bn,
            acc_decay: -self.spec.accelerometer().bias_decay_rate(),
            gyro_decay: -self.spec.gyroscope().bias_decay_rate(),
        }
    }

    /// Continuous system matrix F (15 x 15) at `state` with the raw IMU sample `imu`.
    #[must_use]
    pub fn system_matrix(&self, state: &InsState, imu: &ImuSample) -> ErrorMatrix {
        self.system_blocks::<Separate>(state, imu).dense()
    }

    /// Noise-input matrix G (15 x 12) for w = \[w_a, w_g, w_ba, w_bg\]: -C_b^n into the
    /// velocity and misalignment rows, I into the bias rows.
    #[must_use]
    pub fn noise_input(&self, state: &InsState) -> NoiseInput {
        let c_bn = state.attitude.to_rotation_matrix().into_inner();
        let mut g = NoiseInput::zeros();
        g.fixed_view_mut::<3, 3>(VEL, 0).copy_from(&(-c_bn));
        g.fixed_view_mut::<3, 3>(ATT, 3).copy_from(&(-c_bn));
        g.fixed_view_mut::<3, 3>(ACC_BIAS, 6)
            .copy_from(&M3::identity());
        g.fixed_view_mut::<3, 3>(GYRO_BIAS, 9)
            .copy_from(&M3::identity());
        g
    }

    /// Diagonal of the continuous noise PSD Σ (12), see [`ImuSpec::continuous_noise_psd`].
    /// A white-noise component averaged over one IMU sample of length dt has per-sample
    /// variance Σ_ii / dt.
    #[must_use]
    pub fn noise_psd(&self) -> SVector<f64, 12> {
        self.spec.continuous_noise_psd()
    }

    /// Phi and Q_d over `dt` in one pass (the formulas of [`InsErrorModel`]).
    #[must_use]
    pub fn transition_and_noise(
        &self,
        state: &InsState,
        imu: &ImuSample,
        dt: f64,
    ) -> (ErrorMatrix, ErrorMatrix) {
        builds::transition_and_noise(self, state, imu, dt)
    }

    /// Phi alone, from the build of [`InsErrorModel::transition_and_noise`] (same bits).
    fn transition_matrix(&self, state: &InsState, imu: &ImuSample, dt: f64) -> ErrorMatrix {
        builds::transition(self, state, imu, dt)
    }

    /// One covariance step in place: P <- Phi P Phi' + Q_d with Phi and Q_d of
    /// [`InsErrorModel::transition_and_noise`] over `dt` at `state` (before the
    /// mechanization step) with `imu`, propagated as [`ProcessModel::propagate_covariance`]
    /// does (same operations in the same order, so the same result to the last bit on a
    /// given CPU). For a loop that needs only P: nothing 15 x 15 is returned or copied (Phi
    /// stays on the stack, Q_d's blocks go straight into P's upper triangle), and the whole
    /// step runs the AVX-512 or AVX2 build with fused multiply-adds when the CPU has them
    /// (chosen through estim-core's dispatch; the trait path's propagation picks the
    /// same build). A CPU without FMA runs the portable build, whose
    /// products and sums are rounded separately: its P differs from an FMA CPU's by
    /// rounding only (both are within 1e-12 of the dense reference over a 400 s mission,
    /// `tests/error_model.rs`).
    pub fn predict_covariance(
        &self,
        state: &InsState,
        imu: &ImuSample,
        dt: f64,
        covariance: &mut ErrorMatrix,
    ) {
        builds::predict_covariance(self, state, imu, dt, covariance);
    }

    /// Q_d = dt \[Q_1 + (A Q_1 + Q_1 A')/2 + A Q_1 A'/3\], A = F dt, Q_1 = G Σ G' =
    /// diag(0, q_v I, q_ψ I, q_a I, q_g I), from the nonzero blocks of A's velocity,
    /// misalignment and bias columns:
    ///
    /// ```text
    /// column v (w = q_v dt): rows p (α I), v (A_vv), ψ (A_ψv)
    /// column ψ (w = q_ψ dt): rows v (A_vψ), ψ (A_ψψ)
    /// column a (w = q_a dt): rows v (A_va), a (k_a I)
    /// column g (w = q_g dt): rows ψ (A_ψg), g (k_g I)
    /// ```
    ///
    /// each column c adding w I at (c, c), A_rc w/2 at (r, c) and A_rc A_sc' w/3 at
    /// (r, s), plus the mirror images. A_ψψ = -\[ω_in×\] dt is skew, so its half term
    /// vanishes. Written block by block (8 3x3 products, upper triangle, mirrored).
    /// `out` must be zero outside the blocks listed (it is written, not added to).
    #[inline(always)]
    fn write_noise(
        &self,
        a: &ScaledBlocks,
        dt: f64,
        out: &mut [[f64; ERROR_STATES]; ERROR_STATES],
    ) {
        self.noise_blocks(a, dt, |r, c, b| put_symmetric_block(out, r, c, b));
    }

    /// The nonzero blocks (row block, column block, block) of Q_d's upper block
    /// triangle, handed to `sink` one by one (no array of blocks to copy); each diagonal
    /// block is exactly symmetric (sums of X X' products, whose (i, j) and (j, i)
    /// entries are the same sums in the same order).
    #[inline(always)]
    fn noise_blocks(&self, a: &ScaledBlocks, dt: f64, mut sink: impl FnMut(usize, usize, &M3)) {
        let psd = self.spec.continuous_noise_psd();
        let (wv, wpsi, wa, wg) = (psd[0] * dt, psd[3] * dt, psd[6] * dt, psd[9] * dt);
        let third = 1.0 / 3.0;
        let id = M3::identity();
        let alpha = a.alpha;
        // Blocks of the upper triangle (row block <= column block).
        let pp = id * (alpha * alpha * wv * third);
        let pv = id * (0.5 * alpha * wv) + a.vv.transpose() * (alpha * wv * third);
        let ppsi = a.psiv.transpose() * (alpha * wv * third);
        // Products with the zero patterns of the blocks (see `block_product`).
        let psiv_t = a.psiv.transpose();
        let vv = id * wv
            + (a.vv + a.vv.transpose()) * (0.5 * wv)
            + (block_product::<FULL, FULL>(&a.vv, &a.vv.transpose()) * wv
                + block_product::<SKEW, SKEW>(&a.vpsi, &a.vpsi.transpose()) * wpsi
                + block_product::<FULL, FULL>(&a.va, &a.va.transpose()) * wa)
                * third;
        let vpsi = psiv_t * (0.5 * wv)
            + a.vpsi * (0.5 * wpsi)
            + (block_product::<FULL, PSI_V_T>(&a.vv, &psiv_t) * wv
                + block_product::<SKEW, SKEW>(&a.vpsi, &a.psipsi.transpose()) * wpsi)
                * third;
        let va = a.va * (wa * (0.5 + a.ka * third));
        let psipsi = id * wpsi
            + (block_product::<PSI_V, PSI_V_T>(&a.psiv, &psiv_t) * wv
                + block_product::<SKEW, SKEW>(&a.psipsi, &a.psipsi.transpose()) * wpsi
                + block_product::<FULL, FULL>(&a.psig, &a.psig.transpose()) * wg)
                * third;
        let psig = a.psig * (wg * (0.5 + a.kg * third));
        let aa = id * (wa * (1.0 + a.ka + a.ka * a.ka * third));
        let gg = id * (wg * (1.0 + a.kg + a.kg * a.kg * third));
        sink(0, 0, &pp);
        sink(0, 1, &pv);
        sink(0, 2, &ppsi);
        sink(1, 1, &vv);
        sink(1, 2, &vpsi);
        sink(1, 3, &va);
        sink(2, 2, &psipsi);
        sink(2, 4, &psig);
        sink(3, 3, &aa);
        sink(4, 4, &gg);
    }

    /// Exact discretisation by Van Loan's method (Van Loan 1978, "Computing integrals
    /// involving the matrix exponential"; Groves eq. 14.80 context): exponentiates the
    /// 30 x 30 matrix [\[-F, G Σ G'\], \[0, F'\]] dt. Returns (Phi = e^{F dt}, Q_d). For tests
    /// and low-rate use: about 100 times slower than [`InsErrorModel::transition_and_noise`].
    #[must_use]
    pub fn van_loan(
        &self,
        state: &InsState,
        imu: &ImuSample,
        dt: f64,
    ) -> (ErrorMatrix, ErrorMatrix) {
        let f = self.system_matrix(state, imu);
        let g = self.noise_input(state);
        let q1 = g * SMatrix::<f64, 12, 12>::from_diagonal(&self.noise_psd()) * g.transpose();
        let mut m = SMatrix::<f64, 30, 30>::zeros();
        m.fixed_view_mut::<15, 15>(0, 0).copy_from(&(-f * dt));
        m.fixed_view_mut::<15, 15>(0, 15).copy_from(&(q1 * dt));
        m.fixed_view_mut::<15, 15>(15, 15)
            .copy_from(&(f.transpose() * dt));
        let e = expm(&m);
        let phi = e.fixed_view::<15, 15>(15, 15).transpose();
        let q = phi * e.fixed_view::<15, 15>(0, 15);
        (phi, q)
    }
}

/// Phi and Q_d over `dt` (the math of [`InsErrorModel::transition_and_noise`]), for
/// the builds of [`builds`].
#[inline(always)]
fn transition_and_noise_body<M: MultiplyAdd>(
    model: &InsErrorModel,
    state: &InsState,
    imu: &ImuSample,
    dt: f64,
) -> (ErrorMatrix, ErrorMatrix) {
    let a = ScaledBlocks::new(&model.system_blocks::<M>(state, imu), dt);
    // Both written in place into the returned pair: no 15 x 15 temporaries to copy.
    let mut out = (ErrorMatrix::zeros(), ErrorMatrix::zeros());
    a.write_transition::<M>(&mut out.0.data.0);
    model.write_noise(&a, dt, &mut out.1.data.0);
    out
}

/// Phi alone (the math of `transition_matrix`), for the builds of [`builds`].
#[inline(always)]
fn transition_body<M: MultiplyAdd>(
    model: &InsErrorModel,
    state: &InsState,
    imu: &ImuSample,
    dt: f64,
) -> ErrorMatrix {
    ScaledBlocks::new(&model.system_blocks::<M>(state, imu), dt).transition::<M>()
}

/// One covariance step in place (the math of [`InsErrorModel::predict_covariance`]),
/// for the builds of [`builds`].
#[inline(always)]
fn predict_covariance_body<M: MultiplyAdd>(
    model: &InsErrorModel,
    state: &InsState,
    imu: &ImuSample,
    dt: f64,
    covariance: &mut ErrorMatrix,
) {
    let a = ScaledBlocks::new(&model.system_blocks::<M>(state, imu), dt);
    let mut phi = [[0.0f64; ERROR_STATES]; ERROR_STATES];
    a.write_transition::<M>(&mut phi);
    let p = &mut covariance.data.0;
    propagate_upper::<M>(p, &phi);
    // Q_d's blocks added to the upper triangle only. Q_d is exactly symmetric, so this
    // equals the trait path's mean of its two triangles ((q + q) / 2 = q exactly).
    model.noise_blocks(&a, dt, |r, c, b| {
        for j in 0..3 {
            let rows = if r == c { j + 1 } else { 3 };
            for i in 0..rows {
                p[3 * c + j][3 * r + i] += b[(i, j)];
            }
        }
    });
    mirror_upper(p);
}

/// Matrix exponential by scaling and squaring with a degree-16 Taylor polynomial
/// (Moler & Van Loan 2003, "Nineteen dubious ways", method 3); ample for the
/// well-scaled 30 x 30 Van Loan matrices of the tests.
fn expm<const N: usize>(m: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    let norm = m.abs().row_sum().max();
    let mut squarings = 0;
    let mut scale = 1.0;
    while norm * scale > 0.25 {
        scale *= 0.5;
        squarings += 1;
    }
    let a = m * scale;
    let mut term = SMatrix::<f64, N, N>::identity();
    let mut sum = term;
    for k in 1..=16 {
        term = term * a / f64::from(k);
        sum += term;
    }
    for _ in 0..squarings {
        sum = sum * sum;
    }
    sum
}

impl ProcessModel<f64, ERROR_STATES> for InsErrorModel {
    type State = InsState;
    type Input = ImuSample;

    fn propagate(
        &self,
        state: &InsState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<InsState> {
        Ok(self.mechanization.step(state, input, dt)?)
    }

    fn transition(
        &self,
        state: &InsState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<ErrorMatrix> {
        check_dt(dt)?;
        Ok(self.transition_matrix(state, input, dt))
    }

    fn process_noise(
        &self,
        state: &InsState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<ErrorMatrix> {
        check_dt(dt)?;
        Ok(InsErrorModel::transition_and_noise(self, state, input, dt).1)
    }

    /// Both from one evaluation of the system blocks (the default would build them
    /// twice, once in `transition` and once in `process_noise`).
    fn transition_and_noise(
        &self,
        state: &InsState,
        input: &ImuSample,
        dt: f64,
    ) -> estim_core::Result<(ErrorMatrix, ErrorMatrix)> {
        check_dt(dt)?;
        Ok(InsErrorModel::transition_and_noise(self, state, input, dt))
    }

    /// P' = Phi P Phi' + Q from the block structure of Phi (see
    /// `propagate_structured`); falls back to the dense product when Phi lacks that
    /// structure. Equal to the default up to rounding (tested to 1e-12 over a 400 s
    /// mission).
    fn propagate_covariance(
        &self,
        covariance: &ErrorMatrix,
        transition: &ErrorMatrix,
        process_noise: &ErrorMatrix,
    ) -> ErrorMatrix {
        if !has_model_structure(transition) {
            return transition * covariance * transition.transpose() + process_noise;
        }
        let mut out = *covariance;
        let (p, phi, q) = (&mut out.data.0, &transition.data.0, &process_noise.data.0);
        // The builds of `predict_covariance`, so that both give the same bits.
        builds::propagate_covariance(p, phi, q);
        out
    }

    /// Phi_later Phi_earlier from the structure of `later` (see `compose_structured`);
    /// the dense product when it lacks that structure. Equal to the default's values
    /// (tested over a 400 s mission).
    fn compose_transitions(&self, later: &ErrorMatrix, earlier: &ErrorMatrix) -> ErrorMatrix {
        if !has_model_structure(later) {
            return later * earlier;
        }
        builds::compose_transitions(&later.data.0, &earlier.data.0)
    }
}

fn check_dt(dt: f64) -> estim_core::Result<()> {
    if dt.is_finite() && dt > 0.0 {
        Ok(())
    } else {
        Err(estim_core::Error::InvalidParameter {
            name: "dt",
            reason: format!("must be finite and > 0, got {dt}"),
        })
    }
}

impl ErrorStateModel<f64, ERROR_STATES> for InsErrorModel {
    /// true = nominal + error: position through the radii at the nominal latitude and
    /// height, attitude C_true = exp(\[ψ×\]) C_nominal (= (I + \[ψ×\]) C to first order).
    fn inject(
        &self,
        nominal: &InsState,
        error: &SVector<f64, ERROR_STATES>,
    ) -> estim_core::Result<InsState> {
        if !error.iter().all(|x| x.is_finite()) {
            return Err(estim_core::Error::NonFinite {
                what: "INS error state",
            });
        }
        Ok(inject(nominal, error))
    }

    /// Only the misalignment block differs from I: re-centring ψ on the corrected attitude
    /// gives ψ' = J_l(ψ̂)(ψ - ψ̂) ≈ (I + \[ψ̂×\]/2)(ψ - ψ̂) (Solà 2017, "Quaternion kinematics for
    /// the error-state Kalman filter", eq. 287 for global-frame errors). The position
    /// radii change by O(δp/R) < 1e-6 and are left as identity.
    fn reset_jacobian(
        &self,
        _nominal: &InsState,
        error: &SVector<f64, ERROR_STATES>,
    ) -> ErrorMatrix {
        let mut j = ErrorMatrix::identity();
        let psi = Vector3::new(error[ATT], error[ATT + 1], error[ATT + 2]);
        let mut block = j.fixed_view_mut::<3, 3>(ATT, ATT);
        block += skew(&psi) * 0.5;
        j
    }
}

/// true = nominal + error (the convention of [`InsState`]).
#[must_use]
pub fn inject(nominal: &InsState, error: &SVector<f64, ERROR_STATES>) -> InsState {
    let (rn, re) = radii_of_curvature(nominal.latitude);
    let mut out = *nominal;
    out.latitude += error[POS] / (rn + nominal.height);
    out.longitude += error[POS + 1] / ((re + nominal.height) * nominal.latitude.cos());
    out.height -= error[POS + 2];
    out.velocity_ned += error.fixed_rows::<3>(VEL);
    out.attitude = UnitQuaternion::from_scaled_axis(error.fixed_rows::<3>(ATT).into_owned())
        * nominal.attitude;
    out.acc_bias += error.fixed_rows::<3>(ACC_BIAS);
    out.gyro_bias += error.fixed_rows::<3>(GYRO_BIAS);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Mission, MissionConfig};
    use estim_core::dispatch::{cpu, with_features, Features};

    /// The builds to compare, as the dispatch features that select them: the portable
    /// one, and those this CPU has (AVX2 + FMA, AVX-512 + FMA).
    fn builds() -> Vec<(&'static str, Features)> {
        let cpu = cpu();
        let mut out = vec![("portable", Features::PORTABLE)];
        if cpu.avx2 && cpu.fma {
            let avx2 = Features {
                avx2: true,
                avx512f: false,
                fma: true,
            };
            out.push(("avx2+fma", avx2));
            if cpu.avx512f {
                out.push((
                    "avx512+fma",
                    Features {
                        avx512f: true,
                        ..avx2
                    },
                ));
            }
        }
        out
    }

    /// Phi P Phi' + Q by explicit loops, products and sums rounded separately (an
    /// independent reference: no structure, no kernel code).
    fn dense_reference(p: &ErrorMatrix, phi: &ErrorMatrix, q: &ErrorMatrix) -> ErrorMatrix {
        let phi_p = ErrorMatrix::from_fn(|i, j| (0..15).map(|k| phi[(i, k)] * p[(k, j)]).sum());
        ErrorMatrix::from_fn(|i, j| {
            (0..15).map(|k| phi_p[(i, k)] * phi[(j, k)]).sum::<f64>() + q[(i, j)]
        })
    }

    /// Largest |a - b| / sqrt(b_ii b_jj).
    fn scaled_error(a: &ErrorMatrix, b: &ErrorMatrix) -> f64 {
        let mut worst = 0.0f64;
        for i in 0..15 {
            for j in 0..15 {
                let scale = (b[(i, i)] * b[(j, j)]).sqrt();
                worst = worst.max((a[(i, j)] - b[(i, j)]).abs() / scale);
            }
        }
        worst
    }

    /// Phi from each build (the portable one, and the FMA ones when this CPU has them)
    /// against I + A + A²/2 formed from `system_matrix` with dense nalgebra products (no
    /// zero patterns, no column kernel): every entry within 16 ε of the sum of its terms'
    /// magnitudes (an exact zero where every term is zero), at every 97th state of the
    /// default mission. Each build runs through the dispatch's in-process override, so
    /// this is where a machine with FMA checks the portable Phi (and the other way round).
    #[test]
    fn every_transition_build_equals_the_dense_formula() {
        let mission = Mission::generate(&MissionConfig::default(), 7).unwrap();
        let model = InsErrorModel::new(ImuSpec::akit_observed());
        let dt = mission.imu_dt;
        let identity = ErrorMatrix::identity();
        for (name, build) in builds() {
            let mut worst = 0.0f64;
            for (state, imu) in mission.truth.iter().zip(&mission.imu).step_by(97) {
                let a = model.system_matrix(state, imu) * dt;
                let reference = identity + a + a * a * 0.5;
                let magnitude = a.abs();
                let bound =
                    (identity + magnitude + magnitude * magnitude * 0.5) * (16.0 * f64::EPSILON);
                let phi = with_features(build, || model.transition_matrix(state, imu, dt));
                for i in 0..15 {
                    for j in 0..15 {
                        let error = (phi[(i, j)] - reference[(i, j)]).abs();
                        assert!(
                            error <= bound[(i, j)],
                            "{name} ({i}, {j}): {error:e} > {:e}",
                            bound[(i, j)]
                        );
                        if bound[(i, j)] > 0.0 {
                            worst = worst.max(error / bound[(i, j)]);
                        }
                    }
                }
            }
            println!("{name}: worst error {worst:.3} of the bound");
        }
    }

    /// The portable kernel (products and sums rounded separately) and, when this CPU has
    /// them, the fused-multiply-add builds: each as a chain over the first 60 s of the
    /// default mission, every step within 1e-12 of the dense reference on the same
    /// prior, the chains within 1e-12 of a dense chain, and exactly symmetric. Each build
    /// runs through the dispatch's in-process override, so this is where the others are
    /// checked on a machine that has FMA (and the FMA ones where it has not: they are
    /// skipped there). The kernels differ from one another by the
    /// rounding of a fused multiply-add (one rounding fewer per term).
    #[test]
    fn every_covariance_kernel_equals_the_dense_reference() {
        let mission = Mission::generate(&MissionConfig::default(), 7).unwrap();
        let model = InsErrorModel::new(ImuSpec::akit_observed());
        let dt = mission.imu_dt;
        let p0 = ErrorMatrix::from_diagonal(&SVector::<f64, 15>::from_fn(|i, _| {
            [1.0, 1e-2, 1e-6, 1e-6, 1e-10][i / 3]
        }));
        let mut finals: Vec<ErrorMatrix> = Vec::new();
        for (name, build) in builds() {
            let (mut s, mut p, mut dense) = (mission.truth[0], p0, p0);
            let (mut worst_step, mut worst_chain) = (0.0f64, 0.0f64);
            for imu in mission.imu.iter().take(6000) {
                let (phi, q) = model.transition_and_noise(&s, imu, dt);
                let mut next = p;
                with_features(build, || {
                    builds::propagate_covariance(&mut next.data.0, &phi.data.0, &q.data.0);
                });
                assert_eq!(next, next.transpose(), "{name}");
                worst_step = worst_step.max(scaled_error(&next, &dense_reference(&p, &phi, &q)));
                p = next;
                dense = dense_reference(&dense, &phi, &q);
                worst_chain = worst_chain.max(scaled_error(&p, &dense));
                s = model.mechanization.step(&s, imu, dt).unwrap();
            }
            // How far this build's chain ends from the portable one's (rounding only).
            let from_portable = finals.first().map_or(0.0, |first| scaled_error(&p, first));
            println!(
                "{name}: worst per step {worst_step:e}, between the chains {worst_chain:e}, \
                 final P from the portable kernel's {from_portable:e}"
            );
            assert!(worst_step < 1e-12, "{name}: {worst_step:e}");
            assert!(worst_chain < 1e-12, "{name}: {worst_chain:e}");
            finals.push(p);
        }
    }
}
