//! Strict fixed-length arrays for the vehicle file: `[f64; 3]` keys refuse an array of
//! any other length (serde's own array impl would read the first three numbers of a
//! longer one and ignore the rest).

use serde::de::Error as _;
use serde::{Deserialize, Deserializer};

/// Exactly three numbers.
pub(crate) fn three<'de, D: Deserializer<'de>>(d: D) -> Result<[f64; 3], D::Error> {
    let v = Vec::<f64>::deserialize(d)?;
    <[f64; 3]>::try_from(v.as_slice())
        .map_err(|_| D::Error::invalid_length(v.len(), &"an array of 3 numbers"))
}

/// Exactly three numbers, or the key left out.
pub(crate) fn three_opt<'de, D: Deserializer<'de>>(d: D) -> Result<Option<[f64; 3]>, D::Error> {
    three(d).map(Some)
}

// The vehicle file's TOML reader is the CLI's; toml is a dev-dependency here.
#[cfg(test)]
mod tests {
    use crate::navigator::NavigatorConfig;

    fn parse(text: &str) -> Result<NavigatorConfig, toml::de::Error> {
        toml::from_str(text)
    }

    #[test]
    fn a_three_number_key_refuses_other_lengths() {
        assert!(parse("[dvl]\nlever_arm_m = [-1.87, -0.03, 0.2]\n").is_ok());
        for bad in ["[-1.87, -0.03, 0.2, 99.0]", "[1.0, 2.0]", "[]"] {
            let e = parse(&format!("[dvl]\nlever_arm_m = {bad}\n")).unwrap_err();
            assert!(e.to_string().contains("3 numbers"), "{bad}: {e}");
        }
        assert!(parse("[initial]\nattitude_deg = [1.0, 2.0, 3.0, 4.0]\n").is_err());
        assert!(parse("[imu]\ngyroscope_bias = [1e-5, 0.0]\n").is_err());
        assert!(parse("[imu]\ngyroscope_scale = [1.0, 1.0]\n").is_err());
        assert!(parse("[truth]\nlever_arm_m = [1.0, 2.0, 3.0, 4.0]\n").is_err());
    }

    #[test]
    fn imu_axes_map_and_refusals() {
        let config = parse("[imu]\naxes = [\"y\", \"-x\", \"-z\"]\n").unwrap();
        let frame = config.imu_frame().unwrap();
        let v = frame.rotation * nalgebra::Vector3::new(1.0, 2.0, 3.0);
        assert_eq!(v, nalgebra::Vector3::new(2.0, -1.0, -3.0));
        for bad in ["[\"x\", \"x\", \"z\"]", "[\"x\", \"up\", \"z\"]"] {
            let config = parse(&format!("[imu]\naxes = {bad}\n")).unwrap();
            assert!(config.check().is_err(), "{bad}");
        }
        let config = parse("[imu]\nclock_scale = 1.5\n").unwrap();
        assert!(config.check().is_err());
        // Each noise key alone replaces the preset's.
        let config = parse("[imu.gyroscope]\nturn_on_bias = 3.5e-5\n").unwrap();
        let settings = config.check().unwrap();
        let preset = estim_ins::ImuSpec::akit_observed();
        let g = settings.sensor_spec().gyroscope();
        assert_eq!(g.turn_on_bias, 3.5e-5);
        assert_eq!(
            g.white_noise_density,
            preset.gyroscope().white_noise_density
        );
    }

    #[test]
    fn the_frame_applies_axes_and_clock() {
        let config = parse(
            "[imu]\naxes = [\"x\", \"-y\", \"z\"]\nclock_scale = 1.0025\ntime_offset_s = 0.5\n",
        )
        .unwrap();
        let frame = config.imu_frame().unwrap();
        let v = nalgebra::Vector3::new(0.1, 0.2, -9.8);
        let mut samples = vec![
            estim_ins::ImuSample::new(10.0, v, v * 0.01),
            estim_ins::ImuSample::new(20.0, v, v * 0.01),
        ];
        frame.apply(&mut samples, 0.0).unwrap();
        assert_eq!(samples[0].time, 10.0 - 0.5);
        assert!((samples[1].time - (10.0 + 1.0025 * 10.0 - 0.5)).abs() < 1e-12);
        assert_eq!(
            samples[1].specific_force,
            nalgebra::Vector3::new(0.1, -0.2, -9.8)
        );
        // No gyroscope scale: the rates are only re-signed.
        assert_eq!(
            samples[1].angular_rate,
            nalgebra::Vector3::new(0.001, -0.002, -0.098)
        );
    }

    #[test]
    fn a_clock_origin_keeps_the_timing_of_a_cut_log() {
        // A clock stamped t relates to the navigator's as 1.0025 t - 0.5 from stamp 0.
        // The same sample, stamped 200 s, read from the whole log (epoch 0) and from a
        // copy cut to start at 150 s (epoch 150), must land at the same navigator time.
        let v = nalgebra::Vector3::new(0.1, 0.2, -9.8);
        let whole_and_cut = |vehicle: &str| {
            let frame = parse(vehicle).unwrap().imu_frame().unwrap();
            let mut whole = vec![
                estim_ins::ImuSample::new(0.0, v, v),
                estim_ins::ImuSample::new(200.0, v, v),
            ];
            let mut cut = vec![
                estim_ins::ImuSample::new(0.0, v, v),
                estim_ins::ImuSample::new(50.0, v, v),
            ];
            frame.apply(&mut whole, 0.0).unwrap();
            frame.apply(&mut cut, 150.0).unwrap();
            (whole[1].time, 150.0 + cut[1].time)
        };
        let (whole, cut) = whole_and_cut(
            "[imu]\nclock_scale = 1.0025\nclock_origin_s = 0.0\ntime_offset_s = 0.5\n",
        );
        assert!((whole - (1.0025 * 200.0 - 0.5)).abs() < 1e-12, "{whole}");
        assert!((cut - whole).abs() < 1e-12, "{cut} vs {whole}");
        // Without an origin the scale acts about each log's first stamp: the cut copy
        // is then early by (s - 1) 150 s.
        let (whole, cut) = whole_and_cut("[imu]\nclock_scale = 1.0025\ntime_offset_s = 0.5\n");
        assert!(
            (whole - cut - 0.0025 * 150.0).abs() < 1e-9,
            "{cut} vs {whole}"
        );
        // An origin so far from the stamps that their digits are lost is refused,
        // naming the key, and leaves the samples as they were.
        let frame = parse("[imu]\nclock_scale = 1.0025\nclock_origin_s = 1e300\n")
            .unwrap()
            .imu_frame()
            .unwrap();
        let mut samples = vec![
            estim_ins::ImuSample::new(0.0, v, v),
            estim_ins::ImuSample::new(0.01, v, v),
        ];
        let error = frame.apply(&mut samples, 0.0).unwrap_err().to_string();
        assert!(error.contains("imu.clock_origin_s"), "{error}");
        assert_eq!(samples[1].time, 0.01);
        assert!(parse("[imu]\nclock_origin_s = nan\n")
            .unwrap()
            .check()
            .is_err());
    }

    #[test]
    fn the_gyroscope_scale_divides_body_rates() {
        // y reversed, then the body rates divided per body axis (the scale is given in
        // body axes, as `estim imu calibrate` prints it).
        let config = parse(
            "[imu]\naxes = [\"x\", \"-y\", \"z\"]\ngyroscope_scale = [1.0025, 0.998, 1.01]\n",
        )
        .unwrap();
        let frame = config.imu_frame().unwrap();
        let s = frame.sample(
            0.0,
            1.0,
            nalgebra::Vector3::new(0.1, 0.2, -9.8),
            nalgebra::Vector3::new(0.01, 0.02, 0.3),
        );
        assert_eq!(s.specific_force, nalgebra::Vector3::new(0.1, -0.2, -9.8));
        let want = [0.01 / 1.0025, -0.02 / 0.998, 0.3 / 1.01];
        for (got, want) in s.angular_rate.iter().zip(want) {
            assert!((got - want).abs() <= 1e-16, "{got} vs {want}");
        }
        for bad in ["[1.2, 1.0, 1.0]", "[1.0, 0.0, 1.0]", "[1.0, 1.0, nan]"] {
            let config = parse(&format!("[imu]\ngyroscope_scale = {bad}\n")).unwrap();
            let e = config.check().unwrap_err().to_string();
            assert!(e.contains("imu.gyroscope_scale"), "{bad}: {e}");
        }
    }
}
