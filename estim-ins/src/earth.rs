//! The WGS-84 Earth model: radii of curvature, normal gravity, Earth rate, transport rate.
//!
//! Sources: NIMA TR8350.2 (WGS-84 definition, 3rd ed., 2000) for the constants;
//! P. D. Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
//! Systems*, 2nd ed., Artech House, 2013 (below "Groves"), sec. 2.4 for the formulas.
//! Every function accepts negative heights (below the ellipsoid, e.g. an AUV at -20 m).

use nalgebra::Vector3;

use crate::kernel::MultiplyAdd;

/// WGS-84 semi-major axis a \[m\].
pub const SEMI_MAJOR_AXIS: f64 = 6_378_137.0;
/// WGS-84 flattening f.
pub const FLATTENING: f64 = 1.0 / 298.257_223_563;
/// WGS-84 semi-minor axis b = a (1 - f) \[m\].
pub const SEMI_MINOR_AXIS: f64 = SEMI_MAJOR_AXIS * (1.0 - FLATTENING);
/// First eccentricity squared e^2 = f (2 - f).
pub const ECCENTRICITY_SQUARED: f64 = FLATTENING * (2.0 - FLATTENING);
/// WGS-84 Earth rotation rate ω_ie \[rad/s\].
pub const EARTH_RATE: f64 = 7.292_115e-5;
/// WGS-84 gravitational constant GM \[m^3/s^2\].
pub const GRAVITATIONAL_CONSTANT: f64 = 3.986_004_418e14;
/// WGS-84 normal gravity at the equator \[m/s^2\] (TR8350.2 table 3.4).
pub const GRAVITY_EQUATOR: f64 = 9.780_325_335_9;
/// WGS-84 normal gravity at the poles \[m/s^2\] (TR8350.2 table 3.4).
pub const GRAVITY_POLE: f64 = 9.832_184_937_8;

/// Somigliana's constant k = b g_p / (a g_e) - 1, as published (TR8350.2 eq. 4-2).
pub(crate) const SOMIGLIANA_K: f64 = 0.001_931_852_652_41;
/// m = ω² a² b / GM (Groves eq. 2.139).
const GRAVITY_M: f64 =
    EARTH_RATE * EARTH_RATE * SEMI_MAJOR_AXIS * SEMI_MAJOR_AXIS * SEMI_MINOR_AXIS
        / GRAVITATIONAL_CONSTANT;

/// sin L and cos L of a latitude, inline (the hot loops evaluate them every step; the
/// library call costs a call, a range reduction for any argument and its own branches).
/// For |L| <= π/4 Taylor polynomials in L² to L¹⁷ (sine) and L¹⁸ (cosine), whose
/// truncation is below 1e-19 there; for π/4 < |L| <= 1.5 the same polynomials at
/// r = π/2 - |L| (cos L = sin r, sin |L| = cos r), with π/2 split in two parts so that the
/// subtraction is exact to 1e-21 (Cody and Waite 1980; the leading part has 33 bits, so
/// |L| - part is exact). Every result is within about one unit in the last place of the
/// exact value (`tests::inline_sin_cos_matches_the_library`); anything else (|L| > 1.5,
/// where cos L < 0.071 needs a finer reduction, or not finite) takes the library's
/// sin_cos.
#[inline(always)]
pub(crate) fn latitude_sin_cos<M: MultiplyAdd>(latitude: f64) -> (f64, f64) {
    // π/2 = PIO2_HI + PIO2_LO to 1e-27 (fdlibm's pio2_1 = 1.57079632673412561417 with 33
    // significant bits, and pio2_1t = 6.07710050650619224932e-11), by their bits.
    const PIO2_HI: f64 = f64::from_bits(0x3FF9_21FB_5440_0000);
    const PIO2_LO: f64 = f64::from_bits(0x3DD0_B461_1A62_6331);
    let a = latitude.abs();
    if a <= core::f64::consts::FRAC_PI_4 {
        taylor_sin_cos::<M>(latitude)
    } else if a <= 1.5 {
        let (s, c) = taylor_sin_cos::<M>((PIO2_HI - a) + PIO2_LO);
        (c.copysign(latitude), s)
    } else {
        latitude.sin_cos()
    }
}

/// (sin r, cos r) for |r| <= π/4 by their Taylor series to r¹⁷ and r¹⁸ (next terms below
/// 1e-19 and 4e-21), the polynomials in r² evaluated in Estrin's pairs (shorter dependency
/// chains than Horner's rule; the terms past the leading ones are below 0.09 of the sum,
/// so the evaluation order moves the result by a fraction of a rounding). The cosine
/// recovers the rounding error of 1 - r²/2 (w + ((1 - w) - r²/2), as fdlibm's __kernel_cos
/// does), which would otherwise be as large as the rest of the error.
#[inline(always)]
fn taylor_sin_cos<M: MultiplyAdd>(r: f64) -> (f64, f64) {
    // 1/n! with alternating signs: sine's r^3, r^5, ..., r^17 and cosine's r^4, ..., r^18
    // coefficients.
    const S: [f64; 8] = [
        -1.0 / 6.0,
        1.0 / 120.0,
        -1.0 / 5_040.0,
        1.0 / 362_880.0,
        -1.0 / 39_916_800.0,
        1.0 / 6_227_020_800.0,
        -1.0 / 1_307_674_368_000.0,
        1.0 / 355_687_428_096_000.0,
    ];
    const C: [f64; 8] = [
        1.0 / 24.0,
        -1.0 / 720.0,
        1.0 / 40_320.0,
        -1.0 / 3_628_800.0,
        1.0 / 479_001_600.0,
        -1.0 / 87_178_291_200.0,
        1.0 / 20_922_789_888_000.0,
        -1.0 / 6_402_373_705_728_000.0,
    ];
    let r2 = r * r;
    let r4 = r2 * r2;
    let r8 = r4 * r4;
    let mad = M::multiply_add;
    // sin is odd, so its sign is r's (copied so that sin(-0) = -0, as the library gives).
    let sin = mad(r * r2, estrin::<M>(&S, r2, r4, r8), r).copysign(r);
    let half = 0.5 * r2;
    let w = 1.0 - half;
    let cos = w + mad(r4, estrin::<M>(&C, r2, r4, r8), (1.0 - w) - half);
    (sin, cos)
}

/// k_0 + k_1 x + ... + k_7 x^7 at x = r2 in Estrin's pairs, given r2², r2⁴ (a function, not
/// a closure: closures do not inherit an FMA build's target features).
#[inline(always)]
fn estrin<M: MultiplyAdd>(k: &[f64; 8], r2: f64, r4: f64, r8: f64) -> f64 {
    let mad = M::multiply_add;
    let low = mad(mad(k[3], r2, k[2]), r4, mad(k[1], r2, k[0]));
    let high = mad(mad(k[7], r2, k[6]), r4, mad(k[5], r2, k[4]));
    mad(high, r8, low)
}

/// 1 / sqrt(1 - e² sin² L) from sin² L by its binomial series in x = e² sin² L <= e² =
/// 0.0067: sum of binom(2n, n)/4^n x^n to x⁷ (the coefficients are exact in binary; the
/// remainder is below 0.2 x⁸ < 1e-18, under a tenth of a rounding of the result), in
/// Estrin's pairs. It replaces a square root and a division (about 35 cycles of latency
/// on the mechanization's dependency chain, three times a step) by eleven multiplications
/// and additions, for every latitude (|sin L| <= 1 always).
#[inline(always)]
pub(crate) fn inverse_root_of_prime_vertical_factor<M: MultiplyAdd>(sin_squared: f64) -> f64 {
    let x = ECCENTRICITY_SQUARED * sin_squared;
    let x2 = x * x;
    let x4 = x2 * x2;
    let mad = M::multiply_add;
    let low = mad(mad(0.312_5, x, 0.375), x2, mad(0.5, x, 1.0));
    let high = mad(
        mad(429.0 / 2_048.0, x, 231.0 / 1_024.0),
        x2,
        mad(63.0 / 256.0, x, 35.0 / 128.0),
    );
    mad(high, x4, low)
}

/// Meridian (north-south) and transverse (east-west) radii of curvature (R_N, R_E) \[m\]
/// at geodetic latitude `latitude` \[rad\] (Groves eqs. 2.105, 2.106).
#[inline]
pub fn radii_of_curvature(latitude: f64) -> (f64, f64) {
    let s = latitude.sin();
    let d = 1.0 - ECCENTRICITY_SQUARED * s * s;
    let sqrt_d = d.sqrt();
    let transverse = SEMI_MAJOR_AXIS / sqrt_d;
    let meridian = SEMI_MAJOR_AXIS * (1.0 - ECCENTRICITY_SQUARED) / (d * sqrt_d);
    (meridian, transverse)
}

/// Derivatives of (R_N, R_E) with respect to latitude \[m/rad\] (differentiating
/// Groves eqs. 2.105, 2.106).
#[inline]
pub fn radii_of_curvature_derivative(latitude: f64) -> (f64, f64) {
    let (s, c) = latitude.sin_cos();
    let d = 1.0 - ECCENTRICITY_SQUARED * s * s;
    let e2sc = ECCENTRICITY_SQUARED * s * c;
    let transverse = SEMI_MAJOR_AXIS * e2sc / (d * d.sqrt());
    let meridian = 3.0 * SEMI_MAJOR_AXIS * (1.0 - ECCENTRICITY_SQUARED) * e2sc / (d * d * d.sqrt());
    (meridian, transverse)
}

/// Normal gravity on the ellipsoid, Somigliana's formula (Groves eq. 2.134) \[m/s^2\].
#[inline]
fn surface_gravity(sin_lat: f64) -> f64 {
    let s2 = sin_lat * sin_lat;
    GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s2) / (1.0 - ECCENTRICITY_SQUARED * s2).sqrt()
}

/// Height factor of Groves eq. 2.139: g(L, h) = g_0(L) \[1 - 2/a (1 + f + m) h + 3 h^2 / a^2\].
#[inline]
pub(crate) fn height_factor(height: f64) -> f64 {
    // 3 / a² as one constant: a division by a² would stay a divide instruction in the
    // hot loops (the term is below 1e-10 of the factor, so its rounding is immaterial).
    1.0 - 2.0 / SEMI_MAJOR_AXIS * (1.0 + FLATTENING + GRAVITY_M) * height
        + height * height * (3.0 / (SEMI_MAJOR_AXIS * SEMI_MAJOR_AXIS))
}

/// Magnitude of normal gravity (gravitation plus centrifugal) at latitude \[rad\] and
/// height \[m\] above the ellipsoid: Somigliana's formula with the second-order height
/// correction (Groves eqs. 2.134 and 2.139). Valid for negative heights.
#[inline]
pub fn normal_gravity(latitude: f64, height: f64) -> f64 {
    surface_gravity(latitude.sin()) * height_factor(height)
}

/// Partial derivatives (∂g/∂latitude \[m/s^2/rad\], ∂g/∂height \[1/s^2\]) of [`normal_gravity`].
pub fn normal_gravity_gradient(latitude: f64, height: f64) -> (f64, f64) {
    let (s, c) = latitude.sin_cos();
    let inverse_root = 1.0 / (1.0 - ECCENTRICITY_SQUARED * s * s).sqrt();
    normal_gravity_gradient_at(s, c, inverse_root, height)
}

/// [`normal_gravity_gradient`] from sin L, cos L and 1 / sqrt(1 - e² sin² L) already at
/// hand (the error model evaluates them once per step for all its Earth terms), with no
/// division of its own.
#[inline]
pub(crate) fn normal_gravity_gradient_at(
    s: f64,
    c: f64,
    inverse_root: f64,
    height: f64,
) -> (f64, f64) {
    let sc = s * c * inverse_root;
    let surface = GRAVITY_EQUATOR * (1.0 + SOMIGLIANA_K * s * s) * inverse_root;
    // d g_0 / dL = g_e [2 k s c / sqrt(d) + (1 + k s²) e² s c / d^(3/2)], d = 1 - e² s².
    let dg0 = GRAVITY_EQUATOR * (2.0 * SOMIGLIANA_K * sc)
        + surface * ECCENTRICITY_SQUARED * sc * inverse_root;
    let dh = -2.0 / SEMI_MAJOR_AXIS * (1.0 + FLATTENING + GRAVITY_M)
        + height * (6.0 / (SEMI_MAJOR_AXIS * SEMI_MAJOR_AXIS));
    (dg0 * height_factor(height), surface * dh)
}

/// Gravity vector in NED, \[0, 0, g(L, h)\]. The deflection of the normal-gravity vector
/// from the ellipsoid normal above the surface (at most ~8e-9 h sin 2L m/s^2 north,
/// Groves eq. 2.140) is neglected: below 2e-7 m/s^2 at |h| < 20 m.
#[inline]
pub fn gravity_ned(latitude: f64, height: f64) -> Vector3<f64> {
    Vector3::new(0.0, 0.0, normal_gravity(latitude, height))
}

/// Earth rotation rate in NED, ω_ie^n = Ω \[cos L, 0, -sin L\] (Groves eq. 5.41).
#[inline]
pub fn earth_rate_ned(latitude: f64) -> Vector3<f64> {
    let (s, c) = latitude.sin_cos();
    Vector3::new(EARTH_RATE * c, 0.0, -EARTH_RATE * s)
}

/// Transport rate ω_en^n = \[v_E/(R_E+h), -v_N/(R_N+h), -v_E tan L/(R_E+h)\]
/// (Groves eq. 5.44), rotation rate of NED with respect to the Earth.
#[inline]
pub fn transport_rate_ned(latitude: f64, height: f64, velocity_ned: &Vector3<f64>) -> Vector3<f64> {
    let (meridian, transverse) = radii_of_curvature(latitude);
    let re = transverse + height;
    Vector3::new(
        velocity_ned.y / re,
        -velocity_ned.x / (meridian + height),
        -velocity_ned.y * latitude.tan() / re,
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::kernel::{Fused, Separate};

    /// Distance between two doubles in units in the last place of `reference`.
    fn ulps(value: f64, reference: f64) -> f64 {
        let magnitude = reference.abs();
        let ulp = f64::from_bits(magnitude.to_bits() + 1) - magnitude;
        (value - reference).abs() / ulp
    }

    #[test]
    fn inline_sin_cos_matches_the_library() {
        // Reference: the platform library's sin_cos (independent code, within one unit in
        // the last place of the exact value). A dense grid over both branches and past the
        // cut-over to the library (|L| > 1.5), the branch boundaries and their
        // neighbours, tiny and signed-zero arguments.
        let quarter = core::f64::consts::FRAC_PI_4;
        let mut points: Vec<f64> = (0..=200_000)
            .map(|k| -1.6 + 3.2 * f64::from(k) / 200_000.0)
            .collect();
        for edge in [quarter, 1.5, 1e-300, 1e-8, 0.0] {
            for x in [
                edge,
                f64::from_bits(edge.to_bits() + 1),
                f64::from_bits(edge.to_bits().saturating_sub(1)),
            ] {
                points.extend([x, -x]);
            }
        }
        points.extend([-0.0, 3.0, -100.0, 1e10]);
        let (mut worst_sin, mut worst_cos) = (0.0f64, 0.0f64);
        for &x in &points {
            // Both builds: products and sums rounded separately, and fused (`f64::mul_add`
            // is exact-then-rounded on any CPU, a library call where FMA is missing).
            for (s, c) in [
                latitude_sin_cos::<Separate>(x),
                latitude_sin_cos::<Fused>(x),
            ] {
                let (s_ref, c_ref) = x.sin_cos();
                if s_ref == 0.0 {
                    assert_eq!(s, s_ref, "sin {x}");
                    assert_eq!(
                        s.is_sign_negative(),
                        s_ref.is_sign_negative(),
                        "sign of sin {x}"
                    );
                } else {
                    worst_sin = worst_sin.max(ulps(s, s_ref));
                }
                worst_cos = worst_cos.max(ulps(c, c_ref));
            }
        }
        println!("inline sin_cos against the library: worst {worst_sin} ulp (sin), {worst_cos} ulp (cos)");
        // One unit each for this function and the library, at most.
        assert!(
            worst_sin <= 2.0 && worst_cos <= 2.0,
            "{worst_sin} {worst_cos}"
        );
        // The two-part π/2 against the published decimal values.
        assert_eq!(
            f64::from_bits(0x3FF9_21FB_5440_0000),
            1.570_796_326_734_125_6
        );
        assert_eq!(
            f64::from_bits(0x3DD0_B461_1A62_6331),
            6.077_100_506_506_192e-11
        );
        assert_eq!(
            f64::from_bits(0x3FF9_21FB_5440_0000) + f64::from_bits(0x3DD0_B461_1A62_6331),
            core::f64::consts::FRAC_PI_2
        );
        for x in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
            let (s, c) = latitude_sin_cos::<Separate>(x);
            assert!(s.is_nan() && c.is_nan(), "{x}");
        }
    }

    #[test]
    fn prime_vertical_series_matches_the_square_root() {
        // Reference: 1 / sqrt(1 - e² s²) by the square root and a division.
        let mut worst = 0.0f64;
        for k in 0..=100_000 {
            let s = -1.0 + 2.0 * f64::from(k) / 100_000.0;
            let reference = 1.0 / (1.0 - ECCENTRICITY_SQUARED * s * s).sqrt();
            worst = worst.max(ulps(
                inverse_root_of_prime_vertical_factor::<Separate>(s * s),
                reference,
            ));
            worst = worst.max(ulps(
                inverse_root_of_prime_vertical_factor::<Fused>(s * s),
                reference,
            ));
        }
        println!("prime-vertical series against 1/sqrt: worst {worst} ulp");
        // Each side rounds about twice (the square root and the division; the series'
        // last additions).
        assert!(worst <= 2.0, "{worst}");
    }

    #[test]
    fn gravity_matches_published_values() {
        // TR8350.2 table 3.4 values on the ellipsoid.
        assert!((normal_gravity(0.0, 0.0) - 9.780_325_335_9).abs() < 1e-10);
        assert!((normal_gravity(std::f64::consts::FRAC_PI_2, 0.0) - 9.832_184_937_8).abs() < 1e-9);
        // k = b g_p / (a g_e) - 1 from the defining constants (rounded: 1e-11).
        let k = SEMI_MINOR_AXIS * GRAVITY_POLE / (SEMI_MAJOR_AXIS * GRAVITY_EQUATOR) - 1.0;
        assert!((SOMIGLIANA_K - k).abs() < 1e-11);
        // Free-air gradient ≈ -3.086e-6 /s^2; at -20 m gravity is larger than at 0.
        let g0 = normal_gravity(0.6, 0.0);
        let below = normal_gravity(0.6, -20.0);
        assert!(below > g0);
        assert!(((below - g0) / 20.0 - 3.086e-6).abs() < 0.01e-6);
    }

    #[test]
    fn radii_match_closed_forms() {
        // Equator: R_N = a (1 - e^2), R_E = a; pole: both a^2 / b.
        let (rn, re) = radii_of_curvature(0.0);
        assert!((rn - SEMI_MAJOR_AXIS * (1.0 - ECCENTRICITY_SQUARED)).abs() < 1e-6);
        assert!((re - SEMI_MAJOR_AXIS).abs() < 1e-6);
        let (rn, re) = radii_of_curvature(std::f64::consts::FRAC_PI_2);
        let polar = SEMI_MAJOR_AXIS * SEMI_MAJOR_AXIS / SEMI_MINOR_AXIS;
        assert!((rn - polar).abs() < 1e-6 && (re - polar).abs() < 1e-6);
    }

    #[test]
    fn derivatives_match_finite_differences() {
        for &lat in &[-1.2, -0.3, 0.0, 0.5733, 1.1] {
            let e = 1e-6;
            let (a, b) = radii_of_curvature(lat + e);
            let (c, d) = radii_of_curvature(lat - e);
            let (dn, de) = radii_of_curvature_derivative(lat);
            assert!(((a - c) / (2.0 * e) - dn).abs() < 1e-4 * (1.0 + dn.abs()));
            assert!(((b - d) / (2.0 * e) - de).abs() < 1e-4 * (1.0 + de.abs()));
            for &h in &[-20.0, 0.0, 500.0] {
                let (gl, gh) = normal_gravity_gradient(lat, h);
                let fl = (normal_gravity(lat + e, h) - normal_gravity(lat - e, h)) / (2.0 * e);
                let fh = (normal_gravity(lat, h + 1.0) - normal_gravity(lat, h - 1.0)) / 2.0;
                assert!((gl - fl).abs() < 1e-7, "{gl} {fl}");
                assert!((gh - fh).abs() < 1e-12, "{gh} {fh}");
            }
        }
    }
}
