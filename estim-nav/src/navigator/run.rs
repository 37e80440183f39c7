//! The one loop that feeds an IMU stream and time-ordered measurement epochs into a
//! [`Navigator`], with a per-epoch hook ([`EpochHook`], the observer pattern of
//! estim-core's runners): the loop owns the timing, the hook applies each epoch's
//! measurements and records what it needs.
//!
//! Timing (the navigator's rules, [`Navigator`]): for an epoch at time t, every IMU
//! sample stamped at or before t is fed (a sample stamped exactly t goes first), then
//! the held sample is integrated up to t (unless the hook says the epoch only reads
//! the estimate, [`EpochHook::propagates`]), then the hook sees the epoch. After the last
//! epoch the remaining samples are fed or not ([`Tail`]).

use estim_core::Observer;
use estim_ins::ImuSample;

use super::{NavigationModel, Navigator, NavigatorError};

/// What the loop does after the last epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Tail {
    /// Feed the IMU samples left (a survey's run to the end of its IMU).
    FeedRest,
    /// Stop at the last epoch (a study run sampled at its DVL epochs).
    StopAtLastEpoch,
}

/// The per-epoch hook of [`run_epochs`]: sees every IMU sample fed and every epoch,
/// applies the epoch's measurements, and can stop the run with its own typed error.
///
/// ```
/// use estim_nav::navigator::{run_epochs, EpochHook, Navigator, NavigatorConfig, NavigatorError, Tail};
/// use estim_core::Zero;
/// use estim_ins::{ErrorMatrix, ImuSample, InsState};
/// use estim_core::nalgebra::{UnitQuaternion, Vector3};
///
/// /// DVL velocities at their epochs; counts the accepted updates.
/// struct Dvl(usize);
/// impl EpochHook<estim_ins::InsErrorModel, estim_core::NoObserver, 15> for Dvl {
///     type Measurement = Vector3<f64>;
///     type Error = NavigatorError;
///     fn on_epoch(&mut self, nav: &mut Navigator, time: f64, v: Vector3<f64>)
///         -> Result<(), NavigatorError> {
///         self.0 += usize::from(nav.dvl_velocity(time, &v, &Zero)?.is_accepted());
///         Ok(())
///     }
/// }
///
/// let settings = NavigatorConfig::default().check()?;
/// let start = InsState::new(0.0, 0.57, 0.61, -20.0, Vector3::new(1.0, 0.0, 0.0),
///     UnitQuaternion::identity());
/// let mut nav = Navigator::new(&settings, start, ErrorMatrix::identity() * 1e-4, 0.01)?;
/// let g = estim_ins::earth::normal_gravity(0.57, -20.0);
/// let imu: Vec<ImuSample> = (0..200)
///     .map(|k| ImuSample::new(k as f64 * 0.01, Vector3::new(0.0, 0.0, -g), Vector3::zeros()))
///     .collect();
/// let epochs = [(1.0, Vector3::new(1.0, 0.0, 0.0)), (1.995, Vector3::new(1.0, 0.0, 0.0))];
/// let mut hook = Dvl(0);
/// let fed = run_epochs(&mut nav, &imu, epochs, &mut hook, Tail::FeedRest)?;
/// assert_eq!((fed, hook.0), (200, 2));
/// # Ok::<(), Box<dyn std::error::Error>>(())
/// ```
pub trait EpochHook<E: NavigationModel<N>, O, const N: usize> {
    /// What one epoch holds.
    type Measurement;
    /// The error that stops a run (the navigator's convert into it).
    type Error: From<NavigatorError>;

    /// Before the samples up to an epoch at `time` are fed (e.g. to check the epoch).
    ///
    /// # Errors
    /// Whatever stops the run.
    fn before_epoch(&mut self, _nav: &Navigator<E, O, N>, _time: f64) -> Result<(), Self::Error> {
        Ok(())
    }

    /// Whether the navigator is propagated to an epoch holding `measurement` before
    /// [`EpochHook::on_epoch`]: by default yes; no for an epoch that only reads the
    /// estimate (e.g. with [`Navigator::predicted`]), so that the filter's steps stay
    /// those of a run without it.
    fn propagates(&self, _measurement: &Self::Measurement) -> bool {
        true
    }

    /// After `sample` was fed.
    ///
    /// # Errors
    /// Whatever stops the run.
    fn on_sample(
        &mut self,
        _nav: &Navigator<E, O, N>,
        _sample: &ImuSample,
    ) -> Result<(), Self::Error> {
        Ok(())
    }

    /// An epoch: the navigator has been propagated to `time`; apply `measurement`.
    ///
    /// # Errors
    /// Whatever stops the run.
    fn on_epoch(
        &mut self,
        nav: &mut Navigator<E, O, N>,
        time: f64,
        measurement: Self::Measurement,
    ) -> Result<(), Self::Error>;

    /// The error for a failure of the navigator while feeding the IMU or propagating
    /// to an epoch (by default converted as is).
    fn stopped(&mut self, error: NavigatorError) -> Self::Error {
        error.into()
    }
}

/// Feed `imu` and the `epochs` (time, measurement), in time order, into `nav`, calling
/// `hook` (module docs); returns the number of IMU samples fed.
///
/// # Errors
/// The hook's, and the navigator's through [`EpochHook::stopped`].
pub fn run_epochs<E, O, H, const N: usize>(
    nav: &mut Navigator<E, O, N>,
    imu: &[ImuSample],
    epochs: impl IntoIterator<Item = (f64, H::Measurement)>,
    hook: &mut H,
    tail: Tail,
) -> Result<usize, H::Error>
where
    E: NavigationModel<N>,
    O: Observer<f64, E::State, N>,
    H: EpochHook<E, O, N>,
{
    let mut fed = 0;
    for (time, measurement) in epochs {
        hook.before_epoch(nav, time)?;
        fed = feed(nav, imu, fed, time, hook)?;
        if hook.propagates(&measurement) {
            if let Err(e) = nav.propagate_to(time) {
                return Err(hook.stopped(e));
            }
        }
        hook.on_epoch(nav, time, measurement)?;
    }
    if tail == Tail::FeedRest {
        fed = feed(nav, imu, fed, f64::INFINITY, hook)?;
    }
    Ok(fed)
}

/// Feed the samples from index `fed` stamped up to `limit`; the new count.
fn feed<E, O, H, const N: usize>(
    nav: &mut Navigator<E, O, N>,
    imu: &[ImuSample],
    mut fed: usize,
    limit: f64,
    hook: &mut H,
) -> Result<usize, H::Error>
where
    E: NavigationModel<N>,
    O: Observer<f64, E::State, N>,
    H: EpochHook<E, O, N>,
{
    while let Some(sample) = imu.get(fed).filter(|s| s.time <= limit) {
        if let Err(e) = nav.imu(sample) {
            return Err(hook.stopped(e));
        }
        fed += 1;
        hook.on_sample(nav, sample)?;
    }
    Ok(fed)
}
