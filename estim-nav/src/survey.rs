//! A survey's files read, checked and merged into [`SurveyInputs`] in one call: the
//! glue between the readers ([`crate::datasets`]) and the navigator.

use std::path::{Path, PathBuf};

use estim_dvl::{Pd0Report, Pd0Skip};
use nalgebra::Vector3;

use crate::datasets::{
    load_depth_with, load_fixes_with, read_pd0_input, DatasetError, DvlLog, ImuLog, MAX_INPUT_BYTES,
};
use crate::navigator::{
    pd0_records, rdi_beam_geometry, DvlRecord, NavigatorConfig, NavigatorError, NavigatorSettings,
    Pd0Conversion, SurveyInputs,
};

/// A survey's input files: an IMU log, one DVL source (velocity CSV, beams CSV or a
/// Teledyne RDI PD0 file, taken in that order when several are given), optional depth
/// and position fixes.
///
/// ```no_run
/// use estim_nav::navigator::{NavigatorConfig, SurveyInputs};
/// use estim_nav::SurveyFiles;
///
/// let files = SurveyFiles {
///     imu: "imu.csv".into(),
///     dvl: Some("dvl.csv".into()),
///     ..SurveyFiles::default()
/// };
/// let survey = SurveyInputs::load(&files, &NavigatorConfig::default())?;
/// println!("{} IMU samples from t = {} s", survey.inputs.imu.len(), survey.epoch);
/// # Ok::<(), estim_nav::SurveyError>(())
/// ```
#[derive(Debug, Clone, Default)]
pub struct SurveyFiles {
    /// IMU CSV (specific force and angular rate, or increments; any rate).
    pub imu: PathBuf,
    /// DVL velocity CSV (body frame).
    pub dvl: Option<PathBuf>,
    /// DVL beams CSV (beam1..beam4).
    pub beams: Option<PathBuf>,
    /// Teledyne RDI PD0 file.
    pub pd0: Option<PathBuf>,
    /// Depth CSV.
    pub depth: Option<PathBuf>,
    /// Position fixes CSV.
    pub fixes: Option<PathBuf>,
    /// The vehicle file the configuration was read from: it names configuration errors
    /// (it is not read here).
    pub vehicle: Option<PathBuf>,
}

/// What the PD0 reader and the conversion to DVL rows did.
#[derive(Debug, Clone)]
pub struct Pd0Load {
    /// The reader's counts and skipped spans.
    pub report: Pd0Report,
    /// Ensembles per coordinate system, bad values, the fixed leaders' beam layout.
    pub conversion: Pd0Conversion,
    /// The beam angle in effect \[deg\]: the fixed leaders', else the vehicle file's.
    pub beam_angle_deg: f64,
}

/// A survey read and checked: the navigator's inputs and settings.
#[derive(Debug, Clone)]
pub struct LoadedSurvey {
    /// The time-ordered inputs, times relative to [`LoadedSurvey::epoch`].
    pub inputs: SurveyInputs,
    /// The checked configuration (with a PD0 file's beam layout).
    pub settings: NavigatorSettings,
    /// The epoch \[s\] every time is relative to (the IMU file's).
    pub epoch: f64,
    /// The true accelerometer and gyroscope biases per IMU sample, when the IMU file
    /// carries them (a simulated IMU).
    pub true_biases: Option<Vec<(Vector3<f64>, Vector3<f64>)>>,
    /// What the PD0 reader did, for a PD0 file.
    pub pd0: Option<Pd0Load>,
}

/// Errors of [`SurveyInputs::load`]: each names the file, and the line where there is
/// one.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum SurveyError {
    /// A reader's error.
    #[error(transparent)]
    Dataset(#[from] DatasetError),
    /// The navigator's error.
    #[error(transparent)]
    Navigator(#[from] NavigatorError),
    /// An invalid configuration (named by [`SurveyFiles::vehicle`] when given).
    #[error("{}{error}", vehicle.as_ref().map_or(String::new(), |p| format!("{}: ", p.display())))]
    Configuration {
        /// The vehicle file.
        vehicle: Option<PathBuf>,
        /// What is wrong (in the message, not chained as a source).
        error: NavigatorError,
    },
    /// No DVL file among [`SurveyFiles::dvl`], [`SurveyFiles::beams`],
    /// [`SurveyFiles::pd0`].
    #[error("no DVL file: give a DVL velocity, beams or PD0 file")]
    NoDvl,
    /// A PD0 file without one good ensemble.
    #[error("{}: no good PD0 ensemble in {input_bytes} bytes ({skipped} spans skipped)", path.display())]
    Pd0Empty {
        /// The file.
        path: PathBuf,
        /// Its size \[bytes\].
        input_bytes: usize,
        /// Spans skipped.
        skipped: usize,
    },
    /// PD0 ensembles that cannot be turned into DVL rows.
    #[error("{}: {error}", path.display())]
    Pd0 {
        /// The file.
        path: PathBuf,
        /// Why (in the message, not chained as a source).
        error: NavigatorError,
    },
    /// No PD0 ensemble within the IMU's time span.
    #[error("{}: no ensemble time ({first:.2}..{last:.2} s, Unix) falls in the IMU's span ({imu_first:.2}..{imu_last:.2} s); PD0 times are the instrument's clock read as UTC", path.display())]
    Pd0OutsideImu {
        /// The file.
        path: PathBuf,
        /// First ensemble time \[s, Unix\].
        first: f64,
        /// Last ensemble time \[s, Unix\].
        last: f64,
        /// First IMU time \[s, Unix\].
        imu_first: f64,
        /// Last IMU time \[s, Unix\].
        imu_last: f64,
    },
    /// `initial.time_s` cannot be used on the navigator's clock.
    #[error("initial.time_s: {error}")]
    InitialTime {
        /// Why (in the message, not chained as a source).
        error: NavigatorError,
    },
    /// A truth file that cannot be put on the navigator's clock
    /// ([`Truth::load`](crate::truth::Truth::load)).
    #[error("{}: {reason}", path.display())]
    Truth {
        /// The truth file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A vehicle TOML that is not a vehicle configuration
    /// ([`read_vehicle`](crate::truth::read_vehicle)).
    #[error("{}{}: {message}", path.display(), line.map_or(String::new(), |l| format!(":{l}")))]
    Vehicle {
        /// The vehicle file.
        path: PathBuf,
        /// The line of the offending key or value, when known.
        line: Option<usize>,
        /// What is wrong (the TOML reader's message: the key, the expected type).
        message: String,
    },
    /// An aiding file none of whose records falls in the IMU's span
    /// ([`check_survey`](crate::check_survey)).
    #[error("{message}")]
    OutsideImuSpan {
        /// The aiding file.
        path: PathBuf,
        /// Both spans, the offset key and its value.
        message: String,
    },
    /// A DVL file with no bottom lock at all and nothing else aiding the INS
    /// ([`check_survey`](crate::check_survey)).
    #[error("{message}")]
    NoLock {
        /// The DVL file.
        path: PathBuf,
        /// What its rows hold.
        message: String,
    },
}

/// `Result` of [`SurveyInputs::load`].
pub type Result<T> = std::result::Result<T, SurveyError>;

impl SurveyInputs {
    /// Read and check every file of a survey with the vehicle configuration `config`:
    /// the IMU in the body frame (`[imu]` axes), the DVL rows, depth and fixes on the
    /// IMU file's epoch, and the settings with `initial.time_s` on that clock.
    /// [`SurveyFiles::read`] and [`LoadedSurvey::settle_initial`] are its two steps.
    ///
    /// # Errors
    /// [`SurveyError`], naming the file (and the line) or the configuration key.
    pub fn load(files: &SurveyFiles, config: &NavigatorConfig) -> Result<LoadedSurvey> {
        let mut survey = files.read(config, &mut |_, _| {})?;
        survey.settle_initial(config)?;
        Ok(survey)
    }
}

impl SurveyFiles {
    /// Read and check the files with `config`, the initial state's time left as
    /// configured (for a caller that sets the initial state from the data first, then
    /// calls [`LoadedSurvey::settle_initial`]). Each span a PD0 reader skipped is
    /// passed to `skipped` with the file, as it is found.
    ///
    /// # Errors
    /// As [`SurveyInputs::load`].
    pub fn read(
        &self,
        config: &NavigatorConfig,
        skipped: &mut dyn FnMut(&Path, &Pd0Skip),
    ) -> Result<LoadedSurvey> {
        let in_vehicle = |error: NavigatorError| SurveyError::Configuration {
            vehicle: self.vehicle.clone(),
            error,
        };
        let mut settings = config.check().map_err(in_vehicle)?;
        let map = &config.columns;
        let mut imu = ImuLog::load_with(&self.imu, None, map)?;
        config
            .imu_frame()
            .map_err(in_vehicle)?
            .apply(&mut imu.samples, imu.epoch_s)
            .map_err(in_vehicle)?;
        let epoch = imu.epoch_s;
        let mut pd0 = None;
        let dvl = match (&self.dvl, &self.beams, &self.pd0) {
            (Some(p), _, _) => DvlLog::load_velocity_with(p, Some(epoch), map)?.records,
            (None, Some(p), _) => DvlLog::load_beams_with(p, Some(epoch), map)?.records,
            (None, None, Some(p)) => {
                let (records, with_geometry, load) = load_pd0(p, epoch, settings, skipped)?;
                settings = with_geometry;
                let (first, last) = (
                    imu.samples.first().map_or(0.0, |s| s.time),
                    imu.samples.last().map_or(0.0, |s| s.time),
                );
                if !records.iter().any(|r| r.time >= first && r.time <= last) {
                    return Err(SurveyError::Pd0OutsideImu {
                        path: p.clone(),
                        first: epoch + records.first().map_or(0.0, |r| r.time),
                        last: epoch + records.last().map_or(0.0, |r| r.time),
                        imu_first: epoch + first,
                        imu_last: epoch + last,
                    });
                }
                pd0 = Some(load);
                records
            }
            (None, None, None) => return Err(SurveyError::NoDvl),
        };
        let depth = match &self.depth {
            Some(p) => load_depth_with(p, Some(epoch), map)?.0,
            None => Vec::new(),
        };
        let fixes = match &self.fixes {
            Some(p) => load_fixes_with(p, Some(epoch), map)?.0,
            None => Vec::new(),
        };
        Ok(LoadedSurvey {
            inputs: SurveyInputs {
                imu: imu.samples,
                dvl,
                depth,
                fixes,
                output_epochs: Vec::new(),
            },
            settings,
            epoch,
            true_biases: imu.true_biases,
            pd0,
        })
    }
}

impl LoadedSurvey {
    /// Check `config` again with its `initial.time_s` (given in the inputs' own time)
    /// on the navigator's clock, which runs from [`LoadedSurvey::epoch`]; the PD0 beam
    /// layout is kept. Nothing changes without an `initial.time_s`.
    ///
    /// # Errors
    /// [`SurveyError::InitialTime`] for a configuration that this time makes invalid.
    pub fn settle_initial(&mut self, config: &NavigatorConfig) -> Result<()> {
        if config.initial.time_s.is_some() {
            let mut relative = config.clone();
            relative.initial.time_s = config.initial.time_s.map(|t| t - self.epoch);
            let geometry = self.settings.beam_geometry().clone();
            self.settings = relative
                .check()
                .map_err(|error| SurveyError::InitialTime { error })?
                .with_beam_geometry(geometry);
        }
        Ok(())
    }
}

/// Read a PD0 file into DVL rows, with the beam layout its fixed leaders declare.
fn load_pd0(
    path: &Path,
    epoch: f64,
    settings: NavigatorSettings,
    skipped: &mut dyn FnMut(&Path, &Pd0Skip),
) -> Result<(Vec<DvlRecord>, NavigatorSettings, Pd0Load)> {
    // Streamed, with the limit of every input (`dvl pd0`'s): a sparse 2 GiB file is
    // refused before reading and /dev/zero at the limit, naming the file.
    let read = read_pd0_input(path, MAX_INPUT_BYTES)?;
    if read.ensembles.is_empty() {
        return Err(SurveyError::Pd0Empty {
            path: path.to_path_buf(),
            input_bytes: read.report.input_bytes,
            skipped: read.report.skipped.len(),
        });
    }
    for skip in &read.report.skipped {
        skipped(path, skip);
    }
    let (records, conversion) =
        pd0_records(&read.ensembles, epoch).map_err(|error| SurveyError::Pd0 {
            path: path.to_path_buf(),
            error,
        })?;
    let angle = conversion
        .beam_angle_deg
        .unwrap_or(settings.config().dvl.beam_angle_deg);
    let geometry = rdi_beam_geometry(angle, conversion.convex)?;
    let load = Pd0Load {
        report: read.report,
        conversion,
        beam_angle_deg: angle,
    };
    Ok((records, settings.with_beam_geometry(geometry), load))
}
