//! IMU error specifications: white noise, bias instability (first-order Gauss-Markov),
//! turn-on bias and scale factor, with presets for three classes of unit.
//!
//! Units are SI: white-noise densities in (m/s^2)/√Hz = m/s/√s (velocity random walk,
//! VRW) and (rad/s)/√Hz = rad/√s (angle random walk, ARW). Datasheet conversions:
//! 1 °/√h = π/180/60 rad/√s ≈ 2.909e-4 rad/√s; 1 m/s/√h = 1/60 m/s/√s;
//! 1 µg/√Hz = 9.80665e-6 m/s^2/√Hz; 1 °/h = 4.848e-6 rad/s; 1 mg = 9.80665e-3 m/s^2.

use crate::error::{Error, Result};

const G0: f64 = 9.806_65;
const DEG: f64 = std::f64::consts::PI / 180.0;
/// 1 °/h in rad/s.
const DEG_PER_HOUR: f64 = DEG / 3600.0;
/// 1 °/√h in rad/√s.
const DEG_PER_ROOT_HOUR: f64 = DEG / 60.0;

/// Error parameters of one sensor triad (same values on the three axes).
///
/// With the `serde` feature an infinite `bias_time_constant` (a random-constant bias)
/// is written as `null`, which JSON can hold, and read back as infinity.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
pub struct SensorSpec {
    /// White-noise density (VRW for accelerometers \[m/s/√s\], ARW for gyroscopes \[rad/√s\]).
    pub white_noise_density: f64,
    /// Steady-state standard deviation σ of the first-order Gauss-Markov bias drift
    /// (bias instability) \[m/s^2 or rad/s\].
    pub bias_instability: f64,
    /// Correlation time τ of the Gauss-Markov bias drift \[s\]; `f64::INFINITY` makes the
    /// drift a random constant (driving noise 0).
    #[cfg_attr(feature = "serde", serde(with = "infinite_as_null"))]
    pub bias_time_constant: f64,
    /// Standard deviation of the constant turn-on bias \[m/s^2 or rad/s\].
    pub turn_on_bias: f64,
    /// Standard deviation of the scale-factor error (dimensionless, 1e-6 = 1 ppm).
    pub scale_factor: f64,
}

impl SensorSpec {
    /// Power spectral density of the Gauss-Markov driving noise, 2 σ^2 / τ
    /// (Groves 2013, eq. 14.86 context; Farrell 2008, sec. 4.9.3): the steady-state
    /// variance of ḃ = -b/τ + w is σ^2 when PSD(w) = 2 σ^2 / τ.
    #[must_use]
    pub fn bias_driving_psd(&self) -> f64 {
        if self.bias_time_constant.is_infinite() {
            0.0
        } else {
            2.0 * self.bias_instability * self.bias_instability / self.bias_time_constant
        }
    }

    /// Decay rate 1/τ of the Gauss-Markov bias \[1/s\] (0 for a random constant).
    #[must_use]
    pub fn bias_decay_rate(&self) -> f64 {
        1.0 / self.bias_time_constant
    }

    fn check(&self, sensor: &'static str) -> Result<()> {
        let fields = [
            ("white_noise_density", self.white_noise_density),
            ("bias_instability", self.bias_instability),
            ("turn_on_bias", self.turn_on_bias),
            ("scale_factor", self.scale_factor),
        ];
        for (field, value) in fields {
            if !(value.is_finite() && value >= 0.0) {
                return Err(Error::InvalidParameter {
                    name: sensor,
                    reason: format!("{field} must be finite and >= 0, got {value:?}"),
                });
            }
        }
        let tau = self.bias_time_constant;
        if tau.is_nan() || tau <= 0.0 {
            return Err(Error::InvalidParameter {
                name: sensor,
                reason: format!("bias_time_constant must be > 0 (or infinite), got {tau:?}"),
            });
        }
        Ok(())
    }
}

/// A checked IMU error specification (build it with [`ImuSpec::builder`] or a preset).
///
/// With the `serde` feature: `{ "accelerometer": SensorSpec, "gyroscope": SensorSpec }`,
/// validated by [`ImuSpecBuilder::build`] on deserialization.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(try_from = "ImuSpecBuilder")
)]
pub struct ImuSpec {
    accelerometer: SensorSpec,
    gyroscope: SensorSpec,
}

/// Builder of [`ImuSpec`]; [`ImuSpecBuilder::build`] validates.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(deny_unknown_fields)
)]
pub struct ImuSpecBuilder {
    accelerometer: SensorSpec,
    gyroscope: SensorSpec,
}

const ZERO_SENSOR: SensorSpec = SensorSpec {
    white_noise_density: 0.0,
    bias_instability: 0.0,
    bias_time_constant: f64::INFINITY,
    turn_on_bias: 0.0,
    scale_factor: 0.0,
};

impl TryFrom<ImuSpecBuilder> for ImuSpec {
    type Error = Error;

    /// [`ImuSpecBuilder::build`].
    fn try_from(builder: ImuSpecBuilder) -> Result<Self> {
        builder.build()
    }
}

/// serde for a time constant that may be infinite: JSON has no infinity (serde_json
/// writes it as `null`), so infinity is written as `null` and `null` read as infinity.
#[cfg(feature = "serde")]
mod infinite_as_null {
    use serde::{Deserialize, Deserializer, Serializer};

    pub(super) fn serialize<S: Serializer>(value: &f64, serializer: S) -> Result<S::Ok, S::Error> {
        if value.is_infinite() && *value > 0.0 {
            serializer.serialize_none()
        } else {
            serializer.serialize_some(value)
        }
    }

    pub(super) fn deserialize<'de, D: Deserializer<'de>>(deserializer: D) -> Result<f64, D::Error> {
        Ok(Option::<f64>::deserialize(deserializer)?.unwrap_or(f64::INFINITY))
    }
}

impl ImuSpecBuilder {
    /// Set the accelerometer triad's errors (SI units, see [`SensorSpec`]).
    #[must_use]
    pub fn accelerometer(mut self, spec: SensorSpec) -> Self {
        self.accelerometer = spec;
        self
    }

    /// Set the gyroscope triad's errors (SI units, see [`SensorSpec`]).
    #[must_use]
    pub fn gyroscope(mut self, spec: SensorSpec) -> Self {
        self.gyroscope = spec;
        self
    }

    /// Validate: every value finite and >= 0, time constants > 0 (infinite allowed).
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the sensor and the field.
    pub fn build(self) -> Result<ImuSpec> {
        self.accelerometer.check("accelerometer")?;
        self.gyroscope.check("gyroscope")?;
        Ok(ImuSpec {
            accelerometer: self.accelerometer,
            gyroscope: self.gyroscope,
        })
    }
}

impl ImuSpec {
    /// A builder starting from an error-free IMU.
    #[must_use]
    pub fn builder() -> ImuSpecBuilder {
        ImuSpecBuilder {
            accelerometer: ZERO_SENSOR,
            gyroscope: ZERO_SENSOR,
        }
    }

    /// An error-free IMU (for round-trip tests).
    #[must_use]
    pub fn perfect() -> Self {
        Self {
            accelerometer: ZERO_SENSOR,
            gyroscope: ZERO_SENSOR,
        }
    }

    /// The accelerometer triad's errors.
    #[must_use]
    pub fn accelerometer(&self) -> &SensorSpec {
        &self.accelerometer
    }

    /// The gyroscope triad's errors.
    #[must_use]
    pub fn gyroscope(&self) -> &SensorSpec {
        &self.gyroscope
    }

    /// Navigation-grade FOG unit, iXblue Phins class.
    ///
    /// Gyro bias instability 0.01 °/h and accelerometer bias 50 µg: the Phins datasheet
    /// class figures (iXblue, "PHINS Subsea", bias < 0.01 °/h, and the navigation-grade
    /// row of El-Sheimy & Youssef, "Inertial sensors technologies for navigation
    /// applications", Satellite Navigation 1:2, 2020, table 1: gyro drift < 0.01 °/h,
    /// ARW < 0.002-0.02 °/√h, accelerometer bias < 100 µg). ARW 0.002 °/√h, VRW 20 µg/√Hz,
    /// Gauss-Markov τ = 1 h, scale factors 10 ppm (gyro) and 50 ppm (accelerometer).
    /// The VRW, τ and the scale factors are values chosen for the class, not figures of
    /// a cited datasheet.
    #[must_use]
    pub fn navigation_grade_fog() -> Self {
        Self {
            accelerometer: SensorSpec {
                white_noise_density: 20e-6 * G0,
                bias_instability: 50e-6 * G0,
                bias_time_constant: 3600.0,
                turn_on_bias: 50e-6 * G0,
                scale_factor: 50e-6,
            },
            gyroscope: SensorSpec {
                white_noise_density: 0.002 * DEG_PER_ROOT_HOUR,
                bias_instability: 0.01 * DEG_PER_HOUR,
                bias_time_constant: 3600.0,
                turn_on_bias: 0.01 * DEG_PER_HOUR,
                scale_factor: 10e-6,
            },
        }
    }

    /// Tactical-grade MEMS unit (Safran Sensonor STIM300 class).
    ///
    /// STIM300 datasheet (TS1524 rev. 31): gyro bias instability 0.3 °/h, ARW
    /// 0.15 °/√h; accelerometer (10 g) bias instability 0.05 mg, VRW 0.07 m/s/√h.
    /// Turn-on biases 1 °/h and 1 mg (El-Sheimy & Youssef 2020, table 1, tactical:
    /// 1-10 °/h, 1-5 mg), τ = 600 s, scale factors 500 ppm (τ and the scale factors are
    /// values chosen for the class, not datasheet figures).
    #[must_use]
    pub fn tactical_mems() -> Self {
        Self {
            accelerometer: SensorSpec {
                white_noise_density: 0.07 / 60.0,
                bias_instability: 0.05e-3 * G0,
                bias_time_constant: 600.0,
                turn_on_bias: 1e-3 * G0,
                scale_factor: 500e-6,
            },
            gyroscope: SensorSpec {
                white_noise_density: 0.15 * DEG_PER_ROOT_HOUR,
                bias_instability: 0.3 * DEG_PER_HOUR,
                bias_time_constant: 600.0,
                turn_on_bias: 1.0 * DEG_PER_HOUR,
                scale_factor: 500e-6,
            },
        }
    }

    /// Consumer MEMS unit (Xsens MTi-1 class).
    ///
    /// MTi-1 datasheet: gyro noise density 0.007 °/s/√Hz, bias instability 10 °/h;
    /// accelerometer noise density 120 µg/√Hz, bias instability 0.03 mg. Turn-on
    /// biases 0.2 °/s and 5 mg (typical consumer run-to-run figures, El-Sheimy & Youssef
    /// 2020 table 1: "commercial grade" 0.1 °/s, 100-1000 µg), τ = 100 s, scale factors
    /// 0.5 % (accelerometer) and 1 % (gyro) (τ and the scale factors are values chosen
    /// for the class, not datasheet figures).
    #[must_use]
    pub fn consumer_mems() -> Self {
        Self {
            accelerometer: SensorSpec {
                white_noise_density: 120e-6 * G0,
                bias_instability: 0.03e-3 * G0,
                bias_time_constant: 100.0,
                turn_on_bias: 5e-3 * G0,
                scale_factor: 5e-3,
            },
            gyroscope: SensorSpec {
                white_noise_density: 0.007 * DEG,
                bias_instability: 10.0 * DEG_PER_HOUR,
                bias_time_constant: 100.0,
                turn_on_bias: 0.2 * DEG,
                scale_factor: 1e-2,
            },
        }
    }

    /// The white noise seen in the A-KIT 100 Hz IMU excerpt (shared/data/README.md):
    /// about 0.03 m/s^2 and 5e-4 rad/s per sample at 100 Hz, i.e. densities
    /// 0.003 m/s/√s and 5e-5 rad/√s; biases as [`ImuSpec::tactical_mems`].
    #[must_use]
    pub fn akit_observed() -> Self {
        let mut spec = Self::tactical_mems();
        spec.accelerometer.white_noise_density = 0.03 / 100f64.sqrt();
        spec.gyroscope.white_noise_density = 5e-4 / 100f64.sqrt();
        spec
    }

    /// Diagonal of the continuous noise PSD Σ (12) ordered as the columns of the noise
    /// input G: [accelerometer white (3), gyro white (3), accelerometer bias driving (3),
    /// gyro bias driving (3)]; units (m/s^2)^2/Hz, (rad/s)^2/Hz, (m/s^3)^2/Hz, (rad/s^2)^2/Hz.
    #[must_use]
    pub fn continuous_noise_psd(&self) -> nalgebra::SVector<f64, 12> {
        let a = self.accelerometer.white_noise_density.powi(2);
        let g = self.gyroscope.white_noise_density.powi(2);
        let ba = self.accelerometer.bias_driving_psd();
        let bg = self.gyroscope.bias_driving_psd();
        nalgebra::SVector::<f64, 12>::from_fn(|i, _| [a, g, ba, bg][i / 3])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_ordered_by_grade() {
        let presets = [
            ImuSpec::navigation_grade_fog(),
            ImuSpec::tactical_mems(),
            ImuSpec::consumer_mems(),
        ];
        for p in presets {
            ImuSpec::builder()
                .accelerometer(*p.accelerometer())
                .gyroscope(*p.gyroscope())
                .build()
                .unwrap();
        }
        for w in presets.windows(2) {
            assert!(w[0].gyroscope().bias_instability < w[1].gyroscope().bias_instability);
            assert!(w[0].gyroscope().white_noise_density < w[1].gyroscope().white_noise_density);
        }
        // 0.01 °/h = 4.848e-8 rad/s.
        let fog = ImuSpec::navigation_grade_fog();
        assert!((fog.gyroscope().bias_instability - 4.848_136_8e-8).abs() < 1e-14);
    }

    #[test]
    fn builder_rejects_bad_values_and_names_them() {
        let bad = SensorSpec {
            white_noise_density: -1.0,
            ..ZERO_SENSOR
        };
        let e = ImuSpec::builder().gyroscope(bad).build().unwrap_err();
        assert!(e.to_string().contains("gyroscope") && e.to_string().contains("white_noise"));
        let bad_tau = SensorSpec {
            bias_time_constant: 0.0,
            ..ZERO_SENSOR
        };
        assert!(ImuSpec::builder().accelerometer(bad_tau).build().is_err());
        let nan = SensorSpec {
            scale_factor: f64::NAN,
            ..ZERO_SENSOR
        };
        assert!(ImuSpec::builder().accelerometer(nan).build().is_err());
    }

    #[test]
    fn gauss_markov_psd_has_the_factor_two() {
        let s = SensorSpec {
            bias_instability: 0.5,
            bias_time_constant: 10.0,
            ..ZERO_SENSOR
        };
        assert!((s.bias_driving_psd() - 0.05).abs() < 1e-15);
    }
}
