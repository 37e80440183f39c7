//! [`NavigatorConfig::check`]: every key's value checked once, naming the key, into
//! [`NavigatorSettings`]; and the IMU's frame and clock ([`ImuFrame`]) it derives.

use super::*;

fn finite(name: &str, values: &[f64]) -> Result<()> {
    if values.iter().all(|v| v.is_finite()) {
        Ok(())
    } else {
        Err(NavigatorError::invalid(name, "not finite"))
    }
}

/// The largest lever-arm component accepted \[m\]: a lever arm joins two points of one
/// rigid vehicle, so anything longer is a unit slip (millimetres) or a position.
const MAX_LEVER_ARM_M: f64 = 1000.0;

fn lever_arm(name: &str, values: &[f64; 3]) -> Result<()> {
    finite(name, values)?;
    match values.iter().position(|v| v.abs() > MAX_LEVER_ARM_M) {
        Some(i) => Err(NavigatorError::invalid(
            name,
            format!(
                "[{i}] = {:e} is outside [-{MAX_LEVER_ARM_M:e}, {MAX_LEVER_ARM_M:e}] m: a lever \
                 arm joins two points of one vehicle (body frame, metres)",
                values[i]
            ),
        )),
        None => Ok(()),
    }
}

fn positive(name: &str, value: f64) -> Result<()> {
    if value.is_finite() && value > 0.0 {
        Ok(())
    } else {
        Err(NavigatorError::invalid(
            name,
            format!("{value:?} is not a positive finite number"),
        ))
    }
}

/// How the IMU's samples map onto the body frame and the navigator's clock
/// (`[imu]` keys `axes`, `mounting_rpy_deg`, `clock_scale`, `time_offset_s`,
/// `gyroscope_scale`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuFrame {
    /// Rotation from the IMU's axes to the body frame (a signed permutation times the
    /// mounting rotation).
    pub rotation: Matrix3<f64>,
    /// Clock scale s.
    pub clock_scale: f64,
    /// The IMU stamp about which the scale acts \[s\] (`imu.clock_origin_s`); `None`:
    /// the log's first stamp.
    pub clock_origin_s: Option<f64>,
    /// Time offset tau \[s\].
    pub time_offset_s: f64,
    /// Gyroscope scale factor per body axis: body rates are divided by it.
    pub gyroscope_scale: Vector3<f64>,
}

impl ImuFrame {
    /// True when the samples pass unchanged.
    pub fn is_identity(&self) -> bool {
        self.rotation == Matrix3::identity()
            && self.clock_scale == 1.0
            && self.time_offset_s == 0.0
            && self.gyroscope_scale == Vector3::repeat(1.0)
    }

    /// The navigator time of a stamp `t` for a clock scale about the stamp `t0`
    /// ([`ImuFrame::origin`]): `t0 + s (t - t0) - tau`.
    pub fn time(&self, t0: f64, t: f64) -> f64 {
        t0 + self.clock_scale * (t - t0) - self.time_offset_s
    }

    /// The stamp the clock scale acts about, for stamps taken relative to `epoch`
    /// (the log's epoch on its own clock) and a log whose first relative stamp is
    /// `first`: `clock_origin_s - epoch` when it is given, else `first`.
    pub fn origin(&self, epoch: f64, first: f64) -> f64 {
        self.clock_origin_s.map_or(first, |o| o - epoch)
    }

    /// Rotate every sample into the body frame, correct the gyroscope's scale and put
    /// its stamp on the navigator's clock; the stamps are relative to `epoch`, the
    /// log's epoch on its own clock.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] (`imu.clock_origin_s`) when the clock's
    /// mapping makes a stamp non-finite or puts two stamps that were in order out of
    /// order (an origin too far from the stamps for their digits); the samples are
    /// then left as they were.
    pub fn apply(&self, samples: &mut [estim_ins::ImuSample], epoch: f64) -> Result<()> {
        if self.is_identity() {
            return Ok(());
        }
        let t0 = self.origin(epoch, samples.first().map_or(0.0, |s| s.time));
        let mut previous: Option<(f64, f64)> = None;
        for s in samples.iter() {
            let mapped = self.time(t0, s.time);
            let broken = !mapped.is_finite()
                || previous.is_some_and(|(raw, at)| s.time > raw && mapped <= at);
            if broken {
                return Err(NavigatorError::invalid(
                    "imu.clock_origin_s",
                    format!(
                        "with clock_scale {} about stamp {:e} the IMU stamp {} s maps to {:e} s, \
                         not after the stamp before it or not finite: the origin is too far \
                         from the log's stamps",
                        self.clock_scale,
                        t0 + epoch,
                        s.time + epoch,
                        mapped + epoch
                    ),
                ));
            }
            previous = Some((s.time, mapped));
        }
        for s in samples {
            *s = self.sample(t0, s.time, s.specific_force, s.angular_rate);
        }
        Ok(())
    }

    /// One sample as the IMU logged it (stamp `t`, `t0` the stamp the clock scale acts
    /// about, IMU axes), in the body frame on the navigator's clock with the gyroscope's
    /// scale corrected.
    pub fn sample(
        &self,
        t0: f64,
        t: f64,
        specific_force: Vector3<f64>,
        angular_rate: Vector3<f64>,
    ) -> estim_ins::ImuSample {
        estim_ins::ImuSample::new(
            self.time(t0, t),
            self.rotation * specific_force,
            (self.rotation * angular_rate).component_div(&self.gyroscope_scale),
        )
    }
}

/// The body axis of one signed IMU axis name (`x`, `-y`, `+z`, ...).
fn signed_axis(key: usize, name: &str) -> Result<Vector3<f64>> {
    let trimmed = name.trim();
    let (sign, axis) = match trimmed.strip_prefix('-') {
        Some(rest) => (-1.0, rest),
        None => (1.0, trimmed.strip_prefix('+').unwrap_or(trimmed)),
    };
    let index = match axis.to_ascii_lowercase().as_str() {
        "x" => 0,
        "y" => 1,
        "z" => 2,
        _ => {
            return Err(NavigatorError::invalid(
                format!("imu.axes[{key}]"),
                format!("`{name}` is not a signed axis (x, -x, y, -y, z, -z)"),
            ))
        }
    };
    let mut v = Vector3::zeros();
    v[index] = sign;
    Ok(v)
}

impl NavigatorConfig {
    /// The IMU's axes and clock as configured.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`] naming the key: an axis name that is not a signed
    /// axis, an axis used twice, a non-finite angle or offset, a clock scale that is
    /// not within 10 % of 1.
    pub fn imu_frame(&self) -> Result<ImuFrame> {
        let imu = &self.imu;
        let mut rows = [Vector3::zeros(); 3];
        for (i, name) in imu.axes.iter().enumerate() {
            rows[i] = signed_axis(i, name)?;
        }
        let permutation = Matrix3::from_rows(&[
            rows[0].transpose(),
            rows[1].transpose(),
            rows[2].transpose(),
        ]);
        if (permutation.determinant().abs() - 1.0).abs() > 1e-12 {
            return Err(NavigatorError::conflict(
                "imu.axes",
                format!(
                    "{:?} names an axis twice (each of x, y, z once, with a sign)",
                    imu.axes
                ),
            ));
        }
        finite("imu.mounting_rpy_deg", &imu.mounting_rpy_deg)?;
        finite("imu.time_offset_s", &[imu.time_offset_s])?;
        finite("imu.clock_origin_s", &[imu.clock_origin_s.unwrap_or(0.0)])?;
        finite("imu.accelerometer_bias", &imu.accelerometer_bias)?;
        finite("imu.gyroscope_bias", &imu.gyroscope_bias)?;
        for (axis, scale) in ["x", "y", "z"].iter().zip(imu.gyroscope_scale) {
            if !(scale.is_finite() && (scale - 1.0).abs() <= 0.1) {
                return Err(NavigatorError::invalid(
                    "imu.gyroscope_scale",
                    format!("{scale:?} on body {axis} is not within 10 % of 1"),
                ));
            }
        }
        if !(imu.clock_scale.is_finite() && (imu.clock_scale - 1.0).abs() <= 0.1) {
            return Err(NavigatorError::invalid(
                "imu.clock_scale",
                format!("{:?} is not within 10 % of 1", imu.clock_scale),
            ));
        }
        let [r, p, y] = imu.mounting_rpy_deg.map(f64::to_radians);
        let mounting = nalgebra::Rotation3::from_euler_angles(r, p, y).into_inner();
        Ok(ImuFrame {
            rotation: mounting * permutation,
            clock_scale: imu.clock_scale,
            clock_origin_s: imu.clock_origin_s,
            time_offset_s: imu.time_offset_s,
            gyroscope_scale: Vector3::from(imu.gyroscope_scale),
        })
    }

    /// Validate every value once and assemble the models.
    ///
    /// # Errors
    /// [`NavigatorError::InvalidValue`], [`NavigatorError::UnknownName`],
    /// [`NavigatorError::Conflict`] or [`NavigatorError::ColumnMap`] naming the key;
    /// the member crates' errors for
    /// invalid model parameters.
    pub fn check(&self) -> Result<NavigatorSettings> {
        self.columns.check().map_err(NavigatorError::ColumnMap)?;
        let mut sensor = imu_preset(&self.imu.preset)?;
        if self.imu.accelerometer.is_some() || self.imu.gyroscope.is_some() {
            sensor = ImuSpec::builder()
                .accelerometer(
                    self.imu
                        .accelerometer
                        .map_or(*sensor.accelerometer(), |c| c.over(sensor.accelerometer())),
                )
                .gyroscope(
                    self.imu
                        .gyroscope
                        .map_or(*sensor.gyroscope(), |c| c.over(sensor.gyroscope())),
                )
                .build()?;
        }
        if let Some(rate) = self.imu.rate_hz {
            positive("imu.rate_hz", rate)?;
        }
        let filter_spec = filter_imu_spec(&sensor)?;
        let d = &self.dvl;
        lever_arm("dvl.lever_arm_m", &d.lever_arm_m)?;
        finite("dvl.time_offset_s", &[d.time_offset_s])?;
        positive("dvl.scale_factor", d.scale_factor)?;
        positive("dvl.noise_std_mps", d.noise_std_mps)?;
        let dvl = dvl_model(
            d,
            Matrix3::from_diagonal_element(d.noise_std_mps * d.noise_std_mps),
        )?;
        if !(d.beam_angle_deg > 0.0 && d.beam_angle_deg < 90.0) {
            return Err(NavigatorError::invalid(
                "dvl.beam_angle_deg",
                format!("{:?} is not in (0, 90)", d.beam_angle_deg),
            ));
        }
        finite("dvl.beam1_azimuth_deg", &[d.beam1_azimuth_deg])?;
        let dvl_noise_scale = match d.adaptive_noise_window {
            // A DVL innovation beyond the health check's NIS limit (none of a filter
            // that follows its measurements) counts on that limit: one wild row does
            // not decide the noise level of the next hundreds.
            Some(window) if (1..=100_000).contains(&window) => Some(NoiseScaleConfig {
                window,
                max_nis: Some(self.health.nis_limit * 3.0),
                ..NoiseScaleConfig::default()
            }),
            Some(window) => {
                return Err(NavigatorError::invalid(
                    "dvl.adaptive_noise_window",
                    format!("{window} is not in 1-100000"),
                ))
            }
            None => None,
        };
        let geometry = BeamGeometry::janus(d.beam_angle_deg)
            .azimuth_offset(d.beam1_azimuth_deg)
            .build()?;
        lever_arm("depth.lever_arm_m", &self.depth.lever_arm_m)?;
        finite("depth.time_offset_s", &[self.depth.time_offset_s])?;
        positive("depth.noise_std_m", self.depth.noise_std_m)?;
        lever_arm("fixes.lever_arm_m", &self.fixes.lever_arm_m)?;
        finite("fixes.time_offset_s", &[self.fixes.time_offset_s])?;
        let g = &self.gate;
        if !(g.probability == 0.0 || (g.probability > 0.0 && g.probability < 1.0)) {
            return Err(NavigatorError::invalid(
                "gate.probability",
                format!("{:?} is not 0 (off) or in (0, 1)", g.probability),
            ));
        }
        let i = &self.initial;
        match (i.latitude_deg, i.longitude_deg) {
            (Some(lat), Some(lon)) => {
                if !(lat.abs() < 85.0 && lon.is_finite()) {
                    return Err(NavigatorError::invalid(
                        "initial.latitude_deg / longitude_deg",
                        format!("{lat:?} deg / {lon:?} deg out of range (|lat| < 85)"),
                    ));
                }
            }
            (None, None) => {}
            _ => {
                return Err(NavigatorError::conflict(
                    "initial.latitude_deg / longitude_deg",
                    "give both, or neither",
                ))
            }
        }
        finite("initial.depth_m", &[i.depth_m.unwrap_or(0.0)])?;
        finite("initial.time_s", &[i.time_s.unwrap_or(0.0)])?;
        finite("initial.velocity_ned_mps", &i.velocity_ned_mps)?;
        finite("initial.attitude_deg", &i.attitude_deg.unwrap_or([0.0; 3]))?;
        finite("initial.heading_deg", &[i.heading_deg])?;
        positive("initial.alignment_s", i.alignment_s)?;
        positive("initial.position_std_m", i.position_std_m)?;
        positive("initial.velocity_std_mps", i.velocity_std_mps)?;
        positive("initial.level_std_deg", i.level_std_deg)?;
        positive("initial.heading_std_deg", i.heading_std_deg)?;
        if let Some(s) = i.acc_bias_std_mps2 {
            positive("initial.acc_bias_std_mps2", s)?;
        }
        if let Some(s) = i.gyro_bias_std_radps {
            positive("initial.gyro_bias_std_radps", s)?;
        }
        if let Some(states) = &self.dvl_states {
            states.check()?;
        }
        self.health.check()?;
        self.imu_frame()?;
        let t = &self.truth;
        lever_arm("truth.lever_arm_m", &t.lever_arm_m)?;
        if !(t.clock_scale.is_finite() && (t.clock_scale - 1.0).abs() <= 0.1) {
            return Err(NavigatorError::invalid(
                "truth.clock_scale",
                format!("{:?} is not within 10 % of 1", t.clock_scale),
            ));
        }
        finite("truth.clock_origin_s", &[t.clock_origin_s.unwrap_or(0.0)])?;
        finite("truth.time_offset_s", &[t.time_offset_s.unwrap_or(0.0)])?;
        Ok(NavigatorSettings {
            config: self.clone(),
            sensor_spec: sensor,
            filter_spec,
            filter_config: filter_config(g.probability, g.recovery_after)?,
            dvl,
            geometry,
            dvl_noise_scale,
        })
    }
}
