//! Spikes in an IMU log: one to [`MAX_SPIKE_SAMPLES`] consecutive samples of a channel
//! that leave both of their neighbours by far more than the channel's sample-to-sample
//! change, while the neighbours agree with each other (a corrupted record, a bit
//! error), not a step of the motion. Integrated, one such sample of 50 m/s^2 on a
//! 100 Hz log is a 0.5 m/s velocity step the filter's covariance knows nothing of.
//!
//! A run of samples k..k+j-1 (j <= [`MAX_SPIKE_SAMPLES`]) of channel c is a spike when
//! every sample of it departs from both neighbours x_{k-1} and x_{k+j} in the same
//! direction by more than the threshold T_c, and the neighbours differ by at most half
//! of the smallest of those departures. T_c is the larger of [`SPIKE_SCALES`] times the
//! channel's typical change (the root mean square of its sample-to-sample differences
//! at or below their 99th percentile, so that a few spikes do not raise it) and an
//! absolute floor, [`SPIKE_FLOOR_SPECIFIC_FORCE`] or [`SPIKE_FLOOR_ANGULAR_RATE`] (a
//! channel quantized to a few steps, or noise-free, has little or no typical change).
//! None of the 11 A-KIT training logs (100 Hz, recorded IMU) has a spike
//! (`estim-cli/tests/navigate_recorded.rs::every_training_trajectory_navigates_on_its_recorded_imu`
//! checks that their runs warn about nothing).

use estim_ins::ImuSample;

/// Threshold of a spike in typical sample-to-sample changes of its channel.
pub const SPIKE_SCALES: f64 = 30.0;

/// Smallest departure of a specific-force spike \[m/s^2\].
pub const SPIKE_FLOOR_SPECIFIC_FORCE: f64 = 1.0;

/// Smallest departure of an angular-rate spike \[rad/s\].
pub const SPIKE_FLOOR_ANGULAR_RATE: f64 = 0.05;

/// Longest run of consecutive samples taken as one spike.
pub const MAX_SPIKE_SAMPLES: usize = 3;

/// The six channels' names, in [`ImuSpike::channel`] order (body axes).
pub const CHANNELS: [&str; 6] = ["acc x", "acc y", "acc z", "gyro x", "gyro y", "gyro z"];

/// One spike of one channel.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSpike {
    /// Index of its first sample in the log (0-based: data row `index + 1` of a file of
    /// rates, `index + 2` of a file of increments, whose first row only starts the
    /// clock).
    pub index: usize,
    /// Its number of samples (1 to [`MAX_SPIKE_SAMPLES`]).
    pub samples: usize,
    /// The channel, an index into [`CHANNELS`] (0-2 specific force, 3-5 angular rate).
    pub channel: usize,
    /// Its largest departure from the mean of its two neighbours (signed; m/s^2 or
    /// rad/s).
    pub departure: f64,
    /// The threshold it exceeded (same unit).
    pub threshold: f64,
}

fn channel(sample: &ImuSample, c: usize) -> f64 {
    if c < 3 {
        sample.specific_force[c]
    } else {
        sample.angular_rate[c - 3]
    }
}

/// The threshold T_c of a channel's values (see the module docs); `None` when it has
/// fewer than 3 finite values.
fn threshold(values: &[f64], floor: f64) -> Option<f64> {
    let mut changes: Vec<f64> = values
        .windows(2)
        .map(|w| (w[1] - w[0]).abs())
        .filter(|d| d.is_finite())
        .collect();
    if changes.len() < 2 {
        return None;
    }
    let k = (changes.len() - 1) * 99 / 100;
    let (_, &mut p99, _) = changes.select_nth_unstable_by(k, f64::total_cmp);
    let kept: Vec<f64> = changes.iter().copied().filter(|&d| d <= p99).collect();
    let typical = (kept.iter().map(|d| d * d).sum::<f64>() / kept.len() as f64).sqrt();
    Some((SPIKE_SCALES * typical).max(floor))
}

/// The spikes of an IMU log (see the module docs), by channel and then by index. A
/// log's first and last samples, which have one neighbour, are never spikes.
pub fn imu_spikes(imu: &[ImuSample]) -> Vec<ImuSpike> {
    let mut spikes = Vec::new();
    for c in 0..CHANNELS.len() {
        let x: Vec<f64> = imu.iter().map(|s| channel(s, c)).collect();
        let floor = if c < 3 {
            SPIKE_FLOOR_SPECIFIC_FORCE
        } else {
            SPIKE_FLOOR_ANGULAR_RATE
        };
        let Some(t) = threshold(&x, floor) else {
            continue;
        };
        let mut k = 1;
        while k + 1 < x.len() {
            match spike_at(&x, k, t) {
                Some((samples, departure)) => {
                    spikes.push(ImuSpike {
                        index: k,
                        samples,
                        channel: c,
                        departure,
                        threshold: t,
                    });
                    k += samples;
                }
                None => k += 1,
            }
        }
    }
    spikes
}

/// The shortest run from `k` that is a spike at threshold `t`: its length and its
/// largest signed departure from the neighbours' mean.
fn spike_at(x: &[f64], k: usize, t: f64) -> Option<(usize, f64)> {
    let left = x[k - 1];
    // Every run from k starts by leaving the left neighbour by more than t.
    if (x[k] - left).abs() <= t {
        return None;
    }
    for j in 1..=MAX_SPIKE_SAMPLES {
        let &right = x.get(k + j)?;
        let run = &x[k..k + j];
        let sign = (run[0] - left).signum();
        let mut smallest = f64::INFINITY;
        let mut ok = sign != 0.0;
        for &v in run {
            let (a, b) = ((v - left) * sign, (v - right) * sign);
            ok &= a > t && b > t;
            smallest = smallest.min(a).min(b);
        }
        if ok && (right - left).abs() <= 0.5 * smallest {
            let mean = 0.5 * (left + right);
            let departure = run
                .iter()
                .map(|v| v - mean)
                .max_by(|a, b| a.abs().total_cmp(&b.abs()))
                .unwrap_or(0.0);
            return Some((j, departure));
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// A turning, accelerating vehicle at 100 Hz with white noise of 0.03 m/s^2 and
    /// 5e-4 rad/s per sample (the A-KIT IMU's), seeded.
    fn log(seed: u64, seconds: usize) -> Vec<ImuSample> {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (acc, gyro) = (
            Normal::new(0.0, 0.03).expect("std"),
            Normal::new(0.0, 5e-4).expect("std"),
        );
        (0..seconds * 100)
            .map(|k| {
                let t = k as f64 * 0.01;
                let f = Vector3::new(0.3 * (0.2 * t).sin(), 0.1 * (0.05 * t).cos(), -9.81)
                    + Vector3::from_fn(|_, _| acc.sample(&mut rng));
                let w = Vector3::new(0.0, 0.0, 0.05 * (0.1 * t).sin())
                    + Vector3::from_fn(|_, _| gyro.sample(&mut rng));
                ImuSample::new(t, f, w)
            })
            .collect()
    }

    /// A vehicle at rest, level, noise-free: 5 s at 100 Hz.
    fn still() -> Vec<ImuSample> {
        (0..500)
            .map(|k| {
                ImuSample::new(
                    k as f64 * 0.01,
                    Vector3::new(0.0, 0.0, -9.81),
                    Vector3::zeros(),
                )
            })
            .collect()
    }

    #[test]
    fn a_clean_log_has_no_spike() {
        for seed in 1..=4 {
            assert!(imu_spikes(&log(seed, 120)).is_empty(), "seed {seed}");
        }
        // Noise-free and constant: no change, the floors hold.
        let still = still();
        assert!(imu_spikes(&still).is_empty());
    }

    #[test]
    fn spikes_are_found_on_their_samples_and_channels() {
        for seed in 1..=4 {
            let mut imu = log(seed, 60);
            imu[1000].specific_force.x += 50.0;
            imu[2500].angular_rate.z -= 0.4;
            // Two consecutive samples, one spike.
            imu[4000].specific_force.z += 5.0;
            imu[4001].specific_force.z += 6.0;
            let found = imu_spikes(&imu);
            let brief: Vec<(usize, usize, usize)> = found
                .iter()
                .map(|s| (s.index, s.samples, s.channel))
                .collect();
            assert_eq!(
                brief,
                vec![(1000, 1, 0), (4000, 2, 2), (2500, 1, 5)],
                "seed {seed}"
            );
            // The departure is the added value, give or take the noise.
            assert!((found[0].departure - 50.0).abs() < 0.2, "{:?}", found[0]);
            assert!((found[1].departure - 6.0).abs() < 0.2, "{:?}", found[1]);
            assert!((found[2].departure + 0.4).abs() < 0.003, "{:?}", found[2]);
            // 30 typical changes: a difference of two samples of noise 0.03 has a
            // std of 0.03 sqrt 2, and the RMS of a normal variable's magnitude below
            // its 99th percentile (2.5758 std) is sqrt(1 - 2 (2.5758) phi(2.5758) /
            // 0.99) = 0.9616 of its std (phi the standard normal density); the motion
            // adds little. Over 6,000 correlated differences the RMS varies by about
            // 1 % from seed to seed: 4 % is 4 of those. The gyroscope's, 30 x 6.8e-4,
            // is below its floor.
            let expected = 30.0 * 0.03 * 2f64.sqrt() * 0.9616;
            assert!(
                (found[0].threshold / expected - 1.0).abs() < 0.04,
                "{:?}",
                found[0]
            );
            assert_eq!(found[2].threshold, SPIKE_FLOOR_ANGULAR_RATE);
        }
        // On a noise-free constant channel the floor decides.
        let mut still = still();
        still[250].specific_force.x = 1.5;
        still[300].specific_force.y = 0.5;
        let found = imu_spikes(&still);
        assert_eq!(found.len(), 1, "{found:?}");
        assert_eq!((found[0].index, found[0].channel), (250, 0));
    }

    #[test]
    fn a_step_or_a_long_excursion_is_motion_not_a_spike() {
        let mut imu = log(7, 60);
        // A step of 5 m/s^2 that stays, and an excursion of 4 samples.
        for s in &mut imu[3000..] {
            s.specific_force.x += 5.0;
        }
        for s in &mut imu[1000..1000 + MAX_SPIKE_SAMPLES + 1] {
            s.angular_rate.z += 0.5;
        }
        assert!(imu_spikes(&imu).is_empty());
        // A spike at either end has one neighbour.
        let mut imu = log(8, 10);
        let last = imu.len() - 1;
        imu[0].specific_force.x += 50.0;
        imu[last].specific_force.x += 50.0;
        assert!(imu_spikes(&imu).is_empty());
    }

    #[test]
    fn a_few_spikes_do_not_raise_the_threshold() {
        // The threshold by hand: 30 times the RMS of the sorted changes up to their
        // 99th percentile.
        let by_hand = |imu: &[ImuSample]| {
            let mut d: Vec<f64> = imu
                .windows(2)
                .map(|w| (w[1].specific_force.x - w[0].specific_force.x).abs())
                .collect();
            d.sort_by(f64::total_cmp);
            let kept = &d[..=(d.len() - 1) * 99 / 100];
            30.0 * (kept.iter().map(|v| v * v).sum::<f64>() / kept.len() as f64).sqrt()
        };
        let clean = log(3, 60);
        let mut spiked = clean.clone();
        for k in [500, 1500, 2500, 3500, 4500] {
            spiked[k].specific_force.x += 100.0;
        }
        let found = imu_spikes(&spiked);
        assert_eq!(found.len(), 5, "{found:?}");
        let t = found[0].threshold;
        assert!((t - by_hand(&spiked)).abs() < 1e-12 * t, "{t}");
        // 10 of 5999 changes are the spikes' (0.17 %), above the percentile: they
        // only move the cut by 10 of the clean log's 60 largest changes, and the
        // threshold stays the clean log's within 2 % (counted in, they would make the
        // RMS about 100 times larger).
        assert!(
            (t / by_hand(&clean) - 1.0).abs() < 0.02,
            "{t} {}",
            by_hand(&clean)
        );
        assert!(t > SPIKE_FLOOR_SPECIFIC_FORCE);
    }
}
