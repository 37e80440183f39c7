//! Seeded DVL beam error models: scale factor, per-beam bias, white noise, dropouts,
//! and the BeamsNet beam protocol.

use nalgebra::{Vector3, Vector4};
use rand::{Rng, RngExt};
use rand_distr::StandardNormal;

use crate::error::{finite, Error, Result};
use crate::geometry::BeamGeometry;

/// Beam-level DVL errors:
///
/// ```text
/// beam_i = (1 + scale_factor_error) (A v)_i + bias_i + noise_std * n_i,   n_i ~ N(0, 1)
/// ```
///
/// and each beam is independently lost with probability `dropout_probability`.
/// Randomness comes only from the generator passed in, so a seeded generator
/// reproduces a run; the draws per call are: 4 normals (beam order), then, only when
/// `dropout_probability > 0`, 4 uniforms.
///
/// ```
/// use estim_dvl::{BeamGeometry, DvlErrorModel};
/// use estim_dvl::nalgebra::Vector3;
/// use rand::SeedableRng;
///
/// let model = DvlErrorModel::builder()
///     .scale_factor_error(0.002)
///     .noise_std(0.01)
///     .dropout_probability(0.05)
///     .build()?;
/// let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
/// let beams = model.corrupt(&BeamGeometry::beamsnet(), &Vector3::new(2.0, 0.0, 0.1), &mut rng);
/// let solution = BeamGeometry::beamsnet().solve(&beams);
/// # Ok::<(), estim_dvl::Error>(())
/// ```
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DvlErrorModel {
    scale_factor_error: f64,
    beam_bias: Vector4<f64>,
    noise_std: f64,
    dropout_probability: f64,
}

/// Builder of a [`DvlErrorModel`] (every error zero by default).
#[must_use]
#[derive(Debug, Clone, Copy, Default)]
pub struct DvlErrorModelBuilder {
    scale_factor_error: f64,
    beam_bias: [f64; 4],
    noise_std: f64,
    dropout_probability: f64,
}

impl DvlErrorModelBuilder {
    /// Scale-factor error k: beams scaled by (1 + k). Must be in (-1, 1).
    pub fn scale_factor_error(mut self, k: f64) -> Self {
        self.scale_factor_error = k;
        self
    }

    /// Bias of each beam \[m/s\].
    pub fn beam_bias(mut self, bias: [f64; 4]) -> Self {
        self.beam_bias = bias;
        self
    }

    /// Standard deviation of the white noise on each beam \[m/s\], >= 0.
    pub fn noise_std(mut self, std: f64) -> Self {
        self.noise_std = std;
        self
    }

    /// Probability that a beam is lost, in [0, 1].
    pub fn dropout_probability(mut self, p: f64) -> Self {
        self.dropout_probability = p;
        self
    }

    /// Validate.
    pub fn build(self) -> Result<DvlErrorModel> {
        let k = finite("scale_factor_error", self.scale_factor_error)?;
        if k.abs() >= 1.0 {
            return Err(Error::InvalidParameter {
                name: "scale_factor_error",
                reason: format!("{k} is outside (-1, 1)"),
            });
        }
        for b in self.beam_bias {
            finite("beam_bias", b)?;
        }
        let s = finite("noise_std", self.noise_std)?;
        if s < 0.0 {
            return Err(Error::InvalidParameter {
                name: "noise_std",
                reason: format!("{s} is negative"),
            });
        }
        let p = finite("dropout_probability", self.dropout_probability)?;
        if !(0.0..=1.0).contains(&p) {
            return Err(Error::InvalidParameter {
                name: "dropout_probability",
                reason: format!("{p} is outside [0, 1]"),
            });
        }
        Ok(DvlErrorModel {
            scale_factor_error: k,
            beam_bias: Vector4::from(self.beam_bias),
            noise_std: s,
            dropout_probability: p,
        })
    }
}

impl DvlErrorModel {
    /// A builder with every error zero.
    pub fn builder() -> DvlErrorModelBuilder {
        DvlErrorModelBuilder::default()
    }

    /// Scale-factor error k.
    pub fn scale_factor_error(&self) -> f64 {
        self.scale_factor_error
    }

    /// Per-beam bias \[m/s\].
    pub fn beam_bias(&self) -> &Vector4<f64> {
        &self.beam_bias
    }

    /// White-noise standard deviation per beam \[m/s\].
    pub fn noise_std(&self) -> f64 {
        self.noise_std
    }

    /// Probability that a beam is lost.
    pub fn dropout_probability(&self) -> f64 {
        self.dropout_probability
    }

    /// Beams with every error but dropouts: (1 + k) A v + bias + sigma n.
    pub fn beams<R: Rng + ?Sized>(
        &self,
        geometry: &BeamGeometry,
        velocity: &Vector3<f64>,
        rng: &mut R,
    ) -> Vector4<f64> {
        let noise = Vector4::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal));
        geometry.beams(velocity) * (1.0 + self.scale_factor_error)
            + noise * self.noise_std
            + self.beam_bias
    }

    /// Beams with every error, a lost beam as `None` (feed to [`BeamGeometry::solve`]).
    pub fn corrupt<R: Rng + ?Sized>(
        &self,
        geometry: &BeamGeometry,
        velocity: &Vector3<f64>,
        rng: &mut R,
    ) -> [Option<f64>; 4] {
        let beams = self.beams(geometry, velocity, rng);
        if self.dropout_probability > 0.0 {
            std::array::from_fn(|i| {
                let lost = rng.random::<f64>() < self.dropout_probability;
                (!lost).then_some(beams[i])
            })
        } else {
            std::array::from_fn(|i| Some(beams[i]))
        }
    }
}

/// Which BeamsNet test scripts the bias comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BeamsNetScripts {
    /// BeamsNetV1 scripts: bias 0.001 m/s on every beam.
    V1,
    /// BeamsNetV2 scripts: bias 0.0001 m/s on every beam.
    V2,
}

/// The beam protocol of the BeamsNet test scripts (ansfl/BeamsNet; data README), as
/// written there:
///
/// ```text
/// beams = A v (1 + 0.007) + 0.042**2 * randn(4) + bias
/// ```
///
/// with the BeamsNet geometry (Janus, 20 deg, azimuths 45 + k 90 deg). Note that the
/// noise term multiplies by `0.042**2`: the per-beam noise standard deviation is
/// [`BeamsNetProtocol::NOISE_STD`] = 0.001764 m/s, not 0.042.
#[derive(Debug, Clone, PartialEq)]
pub struct BeamsNetProtocol {
    geometry: BeamGeometry,
    scripts: BeamsNetScripts,
    model: DvlErrorModel,
}

impl BeamsNetProtocol {
    /// Scale-factor error of the scripts (`1 + 0.007`).
    pub const SCALE_FACTOR_ERROR: f64 = 0.007;
    /// Per-beam white-noise standard deviation, `0.042**2` in the scripts.
    pub const NOISE_STD: f64 = 0.042 * 0.042;
    /// Bias of the V1 scripts.
    pub const BIAS_V1: f64 = 0.001;
    /// Bias of the V2 scripts.
    pub const BIAS_V2: f64 = 0.0001;

    /// The protocol of the given scripts, on the BeamsNet geometry.
    pub fn new(scripts: BeamsNetScripts) -> Self {
        let bias = match scripts {
            BeamsNetScripts::V1 => Self::BIAS_V1,
            BeamsNetScripts::V2 => Self::BIAS_V2,
        };
        Self {
            geometry: BeamGeometry::beamsnet(),
            scripts,
            model: DvlErrorModel {
                scale_factor_error: Self::SCALE_FACTOR_ERROR,
                beam_bias: Vector4::repeat(bias),
                noise_std: Self::NOISE_STD,
                dropout_probability: 0.0,
            },
        }
    }

    /// The V1 scripts' protocol (bias 0.001).
    pub fn v1() -> Self {
        Self::new(BeamsNetScripts::V1)
    }

    /// The V2 scripts' protocol (bias 0.0001).
    pub fn v2() -> Self {
        Self::new(BeamsNetScripts::V2)
    }

    /// Which scripts.
    pub fn scripts(&self) -> BeamsNetScripts {
        self.scripts
    }

    /// The geometry (BeamsNet, 20 deg).
    pub fn geometry(&self) -> &BeamGeometry {
        &self.geometry
    }

    /// The protocol as a [`DvlErrorModel`].
    pub fn error_model(&self) -> &DvlErrorModel {
        &self.model
    }

    /// Simulated beams for a DVL velocity `v` (4 standard normal draws).
    pub fn beams<R: Rng + ?Sized>(&self, velocity: &Vector3<f64>, rng: &mut R) -> Vector4<f64> {
        self.model.beams(&self.geometry, velocity, rng)
    }

    /// The least-squares velocity of simulated beams, v_LS = (A'A)^-1 A' beams.
    pub fn least_squares<R: Rng + ?Sized>(
        &self,
        velocity: &Vector3<f64>,
        rng: &mut R,
    ) -> Vector3<f64> {
        self.geometry.least_squares(&self.beams(velocity, rng))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn builder_rejects_bad_values() {
        assert!(DvlErrorModel::builder().noise_std(-1.0).build().is_err());
        assert!(DvlErrorModel::builder()
            .dropout_probability(1.5)
            .build()
            .is_err());
        assert!(DvlErrorModel::builder()
            .scale_factor_error(f64::NAN)
            .build()
            .is_err());
        assert!(DvlErrorModel::builder()
            .beam_bias([0.0, f64::INFINITY, 0.0, 0.0])
            .build()
            .is_err());
    }

    #[test]
    fn protocol_matches_the_script_formula_draw_for_draw() {
        // Same seed, formula transcribed from the scripts independently.
        let p = BeamsNetProtocol::v1();
        let v = Vector3::new(1.8, -0.4, 0.2);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let beams = p.beams(&v, &mut rng);
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let t = 20f64.to_radians();
        for i in 0..4 {
            let psi = (45.0 + 90.0 * i as f64).to_radians();
            let b = Vector3::new(psi.cos() * t.sin(), psi.sin() * t.sin(), t.cos());
            let n: f64 = rng.sample(StandardNormal);
            let expected = b.dot(&v) * (1.0 + 0.007) + 0.042f64.powi(2) * n + 0.001;
            assert!((beams[i] - expected).abs() < 1e-14);
        }
        assert!((BeamsNetProtocol::NOISE_STD - 0.001764).abs() < 1e-15);
        assert_eq!(BeamsNetProtocol::v2().error_model().beam_bias()[3], 0.0001);
    }

    #[test]
    fn dropout_rate_and_noise_level_are_as_configured() {
        let g = BeamGeometry::rdi_workhorse_navigator();
        let m = DvlErrorModel::builder()
            .noise_std(0.02)
            .dropout_probability(0.1)
            .build()
            .unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let v = Vector3::new(1.0, 0.5, -0.1);
        let truth = g.beams(&v);
        let (mut lost, mut count, mut sq) = (0usize, 0usize, 0.0);
        let n = 20_000;
        for _ in 0..n {
            for (i, b) in m.corrupt(&g, &v, &mut rng).iter().enumerate() {
                match b {
                    None => lost += 1,
                    Some(x) => {
                        count += 1;
                        sq += (x - truth[i]).powi(2);
                    }
                }
            }
        }
        let rate = lost as f64 / (4 * n) as f64;
        // binomial standard error sqrt(0.1 * 0.9 / 80000) ~ 0.0011: 5 sigma
        assert!((rate - 0.1).abs() < 0.0055, "dropout rate {rate}");
        let std = (sq / count as f64).sqrt();
        // relative standard error of a std estimate ~ 1/sqrt(2 * 72000) ~ 0.0026: 5 sigma
        assert!((std / 0.02 - 1.0).abs() < 0.013, "noise std {std}");
    }
}
