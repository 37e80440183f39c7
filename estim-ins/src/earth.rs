//! The WGS-84 Earth model: radii of curvature, normal gravity, Earth rate, transport rate.
//!
//! Sources: NIMA TR8350.2 (WGS-84 definition, 3rd ed., 2000) for the constants;
//! P. D. Groves, *Principles of GNSS, Inertial, and Multisensor Integrated Navigation
//! Systems*, 2nd ed., Artech House, 2013 (below "Groves"), sec. 2.4 for the formulas.
//! Every function accepts negative heights (below the ellipsoid, e.g. an AUV at -20 m).

use nalgebra::Vector3;

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
