//! `estim navigate --stream`: sensor records as JSON lines in arrival order (stdin, a
//! file still being written with `--follow`, Water Linked DVL reports over TCP with
//! `--dvl-tcp`) through the streaming navigator
//! (`estim::navigator::StreamNavigator`); each solution line, in `solution.csv`'s
//! columns, is written to stdout and flushed as soon as it is final.
//!
//! Records (times in one epoch, seconds): `{"sensor": "imu", "time": t, "acc": [..],
//! "gyro": [..]}` (m/s^2, rad/s, the IMU's own axes and clock: the vehicle file's
//! `[imu]` axes, clock scale and time offset apply as in a batch run), `{"sensor":
//! "dvl", "time": t, "velocity": [vx, vy, vz] or null}`, `{"sensor": "beams", "time":
//! t, "beams": [b1, b2, b3, b4]}` (null = missing beam), `{"sensor": "depth", "time":
//! t, "depth": d}`, `{"sensor": "fix", "time": t, "lat_deg": .., "lon_deg": ..,
//! "sigma_m": ..}`; and Water Linked velocity reports (`"type": "velocity"`,
//! [`crate::waterlinked`]). Times are made relative to the first IMU record's whole
//! second, as a batch run makes them relative to its IMU file's.

use std::io::{BufRead, BufReader, Read, Write};
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use estim::core::nalgebra::Vector3;
use estim::ins::ImuSample;
use estim::navigator::{
    Admission, DepthSample, DvlInput, DvlRecord, FinalSolution, ImuFrame, MeasurementTiming,
    NavSolution, NavigatorConfig, NavigatorError, PositionFix, Refusal, SolutionKind, StreamConfig,
    StreamError, StreamNavigator,
};
use serde_json::{json, Map, Value};

use crate::navigate::{solution_row, vehicle_config, CSV_HEADER};
use crate::output::StagedDir;
use crate::schema;
use crate::waterlinked;

/// The longest line read \[bytes\]: a record is well under 1 KiB, a Water Linked
/// report about 2 KiB.
pub const MAX_LINE_BYTES: usize = 64 * 1024;

/// Records buffered before the first IMU record (which sets the epoch).
const MAX_BEFORE_IMU: usize = 100_000;

/// RDI's bad-velocity marker (-32768 mm/s), a row without lock as in a CSV.
const RDI_BAD_VELOCITY: f64 = -32.768;

/// Refusals printed on stderr one by one before only counting them.
const REFUSALS_PRINTED: usize = 10;

/// What `estim navigate --stream` was asked.
#[derive(Debug, Clone)]
pub struct Options {
    /// Vehicle TOML.
    pub vehicle: Option<PathBuf>,
    /// The history's length \[s\].
    pub history_s: f64,
    /// A file still being written, read instead of stdin.
    pub follow: Option<PathBuf>,
    /// With `follow`: seconds without new data that end the stream.
    pub idle_timeout_s: f64,
    /// A Water Linked DVL's TCP address.
    pub dvl_tcp: Option<String>,
    /// Measurements at their own times instead of the nearest IMU sample.
    pub exact_times: bool,
    /// Solutions at this rate too \[Hz\].
    pub rate: Option<f64>,
    /// Output folder.
    pub out: Option<PathBuf>,
    /// Summary as JSON.
    pub json: bool,
}

/// What was wrong with one line (the line's source and number are added by
/// [`LineError`]).
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum RecordError {
    /// Not JSON.
    #[error("not a JSON record: {0}")]
    Json(#[source] serde_json::Error),
    /// JSON, but not an object.
    #[error("a record is a JSON object")]
    NotAnObject,
    /// A key the record needs is missing.
    #[error("key `{key}` is missing")]
    MissingKey {
        /// The key.
        key: &'static str,
    },
    /// A key the sensor does not have.
    #[error("key `{key}` is not one of a `{sensor}` record's")]
    UnknownKey {
        /// The key.
        key: String,
        /// The record's sensor.
        sensor: &'static str,
    },
    /// A value that is not a finite number (or an array of them).
    #[error("key `{key}`: not a finite number (or array of the documented length)")]
    NotANumber {
        /// The key.
        key: &'static str,
    },
    /// A value that is not true or false.
    #[error("key `{key}`: not true or false")]
    NotABool {
        /// The key.
        key: &'static str,
    },
    /// An unknown `sensor`.
    #[error("sensor `{0}` is not imu, dvl, beams, depth or fix")]
    UnknownSensor(String),
    /// A line longer than [`MAX_LINE_BYTES`].
    #[error("longer than {MAX_LINE_BYTES} bytes")]
    TooLong,
    /// The stream ended inside a line.
    #[error("the stream ended inside this line (no newline): truncated")]
    Truncated,
    /// What the navigator refused (an IMU going back in time, a non-finite value).
    #[error(transparent)]
    Stream(StreamError),
}

/// A bad line: where it is and what was wrong.
#[derive(Debug, thiserror::Error)]
#[error("{source_name}:{line}: {error}")]
pub struct LineError {
    /// `stdin`, the followed file or the TCP address.
    pub source_name: String,
    /// The line's number (from 1).
    pub line: usize,
    /// What was wrong (in the message: not also a source, so printed once).
    pub error: RecordError,
}

/// One record read.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Record {
    Imu {
        time: f64,
        acc: [f64; 3],
        gyro: [f64; 3],
    },
    Dvl {
        time: f64,
        input: DvlInput,
    },
    /// A Water Linked velocity report (time of validity in Unix µs).
    WaterLinked {
        time_us: i64,
        input: DvlInput,
    },
    Depth {
        time: f64,
        depth: f64,
    },
    Fix {
        time: f64,
        lat_deg: f64,
        lon_deg: f64,
        sigma_m: f64,
    },
    /// A record of no use to the navigator (another Water Linked report type).
    Ignored,
}

/// Parse one line.
fn parse(bytes: &[u8]) -> Result<Record, RecordError> {
    let value: Value = serde_json::from_slice(bytes).map_err(RecordError::Json)?;
    let Value::Object(object) = value else {
        return Err(RecordError::NotAnObject);
    };
    if !object.contains_key("sensor") && object.contains_key("type") {
        return Ok(match waterlinked::report(&object)? {
            waterlinked::Report::Velocity {
                time_of_validity_us,
                velocity,
            } => Record::WaterLinked {
                time_us: time_of_validity_us,
                input: velocity.map_or(DvlInput::NoLock, dvl_velocity),
            },
            waterlinked::Report::Other => Record::Ignored,
        });
    }
    let sensor = match object.get("sensor") {
        None => return Err(RecordError::MissingKey { key: "sensor" }),
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err(RecordError::NotANumber { key: "sensor" }),
    };
    let (name, keys): (&'static str, &[&str]) = match sensor {
        "imu" => ("imu", &["sensor", "time", "acc", "gyro"]),
        "dvl" => ("dvl", &["sensor", "time", "velocity"]),
        "beams" => ("beams", &["sensor", "time", "beams"]),
        "depth" => ("depth", &["sensor", "time", "depth"]),
        "fix" => ("fix", &["sensor", "time", "lat_deg", "lon_deg", "sigma_m"]),
        other => return Err(RecordError::UnknownSensor(other.chars().take(40).collect())),
    };
    if let Some(key) = object.keys().find(|k| !keys.contains(&k.as_str())) {
        return Err(RecordError::UnknownKey {
            key: key.chars().take(40).collect(),
            sensor: name,
        });
    }
    let time = number(&object, "time")?;
    Ok(match name {
        "imu" => Record::Imu {
            time,
            acc: triple(&object, "acc")?,
            gyro: triple(&object, "gyro")?,
        },
        "dvl" => match object.get("velocity") {
            None => return Err(RecordError::MissingKey { key: "velocity" }),
            Some(Value::Null) => Record::Dvl {
                time,
                input: DvlInput::NoLock,
            },
            Some(_) => Record::Dvl {
                time,
                input: dvl_velocity(triple(&object, "velocity")?),
            },
        },
        "beams" => Record::Dvl {
            time,
            input: DvlInput::Beams(beams(&object)?),
        },
        "depth" => Record::Depth {
            time,
            depth: number(&object, "depth")?,
        },
        _ => Record::Fix {
            time,
            lat_deg: number(&object, "lat_deg")?,
            lon_deg: number(&object, "lon_deg")?,
            sigma_m: number(&object, "sigma_m")?,
        },
    })
}

/// A DVL velocity, or no lock for RDI's bad-value marker.
fn dvl_velocity(v: [f64; 3]) -> DvlInput {
    if v.contains(&RDI_BAD_VELOCITY) {
        DvlInput::NoLock
    } else {
        DvlInput::Velocity(Vector3::from(v))
    }
}

fn number(object: &Map<String, Value>, key: &'static str) -> Result<f64, RecordError> {
    match object.get(key) {
        None => Err(RecordError::MissingKey { key }),
        Some(v) => v
            .as_f64()
            .filter(|x| x.is_finite())
            .ok_or(RecordError::NotANumber { key }),
    }
}

fn triple(object: &Map<String, Value>, key: &'static str) -> Result<[f64; 3], RecordError> {
    let Some(value) = object.get(key) else {
        return Err(RecordError::MissingKey { key });
    };
    let values: Option<Vec<f64>> = value.as_array().filter(|a| a.len() == 3).and_then(|a| {
        a.iter()
            .map(|x| x.as_f64().filter(|x| x.is_finite()))
            .collect()
    });
    match values.as_deref() {
        Some(&[x, y, z]) => Ok([x, y, z]),
        _ => Err(RecordError::NotANumber { key }),
    }
}

/// Four beams; null, or RDI's marker, is a missing beam.
fn beams(object: &Map<String, Value>) -> Result<[Option<f64>; 4], RecordError> {
    let key = "beams";
    let Some(value) = object.get(key) else {
        return Err(RecordError::MissingKey { key });
    };
    let array = value
        .as_array()
        .filter(|a| a.len() == 4)
        .ok_or(RecordError::NotANumber { key })?;
    let mut out = [None; 4];
    for (slot, v) in out.iter_mut().zip(array) {
        *slot = match v {
            Value::Null => None,
            v => {
                let x = v
                    .as_f64()
                    .filter(|x| x.is_finite())
                    .ok_or(RecordError::NotANumber { key })?;
                (x != RDI_BAD_VELOCITY).then_some(x)
            }
        };
    }
    Ok(out)
}

/// What a reader thread sends.
enum Message {
    Line {
        source: usize,
        number: usize,
        bytes: Vec<u8>,
    },
    Failed {
        source: usize,
        number: usize,
        error: RecordError,
    },
    Io {
        source: usize,
        error: std::io::Error,
    },
    Ended {
        source: usize,
    },
}

/// How one line read ended.
enum LineRead {
    Line,
    End,
}

/// Read one line (without its newline, and a CR before it) into `buf`, at most
/// [`MAX_LINE_BYTES`]. With `follow`, wait at the end of the data for more, up to
/// `idle` without any.
fn read_line(
    reader: &mut impl BufRead,
    buf: &mut Vec<u8>,
    follow: Option<Duration>,
) -> Result<LineRead, Result<RecordError, std::io::Error>> {
    buf.clear();
    let mut idle_since = Instant::now();
    loop {
        let available = match reader.fill_buf() {
            Ok(a) => a,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(Err(e)),
        };
        if available.is_empty() {
            match follow {
                Some(idle) if idle_since.elapsed() < idle => {
                    std::thread::sleep(Duration::from_millis(20));
                    continue;
                }
                _ if buf.is_empty() => return Ok(LineRead::End),
                _ => return Err(Ok(RecordError::Truncated)),
            }
        }
        idle_since = Instant::now();
        let (take, done) = match available.iter().position(|&b| b == b'\n') {
            Some(i) => (i, true),
            None => (available.len(), false),
        };
        if buf.len() + take > MAX_LINE_BYTES {
            return Err(Ok(RecordError::TooLong));
        }
        buf.extend_from_slice(&available[..take]);
        reader.consume(take + usize::from(done));
        if done {
            if buf.last() == Some(&b'\r') {
                buf.pop();
            }
            return Ok(LineRead::Line);
        }
    }
}

/// Read lines from `reader` on a thread of its own, sending them to `tx`.
fn spawn_reader(
    source: usize,
    reader: Box<dyn Read + Send>,
    follow: Option<Duration>,
    tx: mpsc::SyncSender<Message>,
) {
    std::thread::spawn(move || {
        let mut reader = BufReader::with_capacity(64 * 1024, reader);
        let mut number = 0;
        let mut buf = Vec::new();
        loop {
            number += 1;
            let message = match read_line(&mut reader, &mut buf, follow) {
                Ok(LineRead::Line) => Message::Line {
                    source,
                    number,
                    bytes: std::mem::take(&mut buf),
                },
                Ok(LineRead::End) => Message::Ended { source },
                Err(Ok(error)) => Message::Failed {
                    source,
                    number,
                    error,
                },
                Err(Err(error)) => Message::Io { source, error },
            };
            let last = !matches!(message, Message::Line { .. });
            if tx.send(message).is_err() || last {
                return;
            }
        }
    });
}

/// The solution lines' destination: stdout (flushed per batch) or `--out`.
struct Output {
    stdout: Option<std::io::BufWriter<std::io::Stdout>>,
    file: Option<(std::io::BufWriter<std::fs::File>, PathBuf)>,
    line: String,
    track: Vec<[f64; 2]>,
    last: Option<NavSolution>,
}

impl Output {
    fn write(&mut self, epoch: f64, solutions: &[FinalSolution]) -> anyhow::Result<()> {
        if solutions.is_empty() {
            return Ok(());
        }
        for s in solutions {
            solution_row(&mut self.line, epoch, s.kind, &s.solution);
            if let Some(out) = &mut self.stdout {
                out.write_all(self.line.as_bytes())?;
            }
            if let Some((file, path)) = &mut self.file {
                file.write_all(self.line.as_bytes())
                    .with_context(|| format!("{}: cannot write", path.display()))?;
            }
            if s.kind == SolutionKind::Dvl && self.file.is_some() {
                self.track
                    .push([s.solution.longitude_deg, s.solution.latitude_deg]);
            }
            self.last = Some(s.solution);
        }
        if let Some(out) = &mut self.stdout {
            out.flush()?;
        }
        Ok(())
    }
}

/// The stream's state between the records.
struct Run {
    config: NavigatorConfig,
    frame: ImuFrame,
    stream: StreamConfig,
    nav: Option<StreamNavigator>,
    epoch: f64,
    first_imu: Option<f64>,
    before_imu: Vec<(usize, Record)>,
    water_linked: [usize; 2],
    ignored: usize,
    refusals_printed: usize,
    refusals: Vec<Value>,
}

impl Run {
    /// Feed one record (`at`: its source's name and line, for messages).
    fn feed(&mut self, record: Record, at: (&str, usize)) -> anyhow::Result<()> {
        let fail = |error: RecordError| LineError {
            source_name: at.0.to_string(),
            line: at.1,
            error,
        };
        if self.nav.is_none() {
            let Record::Imu { time, .. } = record else {
                if self.before_imu.len() >= MAX_BEFORE_IMU {
                    anyhow::bail!(
                        "{}:{}: {MAX_BEFORE_IMU} records before the first IMU record",
                        at.0,
                        at.1
                    );
                }
                self.before_imu.push((at.1, record));
                return Ok(());
            };
            self.start(time)?;
            let pending = std::mem::take(&mut self.before_imu);
            self.feed(record, at)?;
            for (line, r) in pending {
                self.feed(r, (at.0, line))?;
            }
            return Ok(());
        }
        let epoch = self.epoch;
        let Some(nav) = self.nav.as_mut() else {
            return Ok(());
        };
        let admission = match record {
            Record::Imu { time, acc, gyro } => {
                let t = time - epoch;
                let t0 = *self.first_imu.get_or_insert(t);
                let r = self.frame.rotation;
                let sample = ImuSample::new(
                    self.frame.time(t0, t),
                    r * Vector3::from(acc),
                    r * Vector3::from(gyro),
                );
                nav.push_imu(sample)
            }
            Record::Dvl { time, input } => nav.push_dvl(DvlRecord {
                time: time - epoch,
                input,
            }),
            Record::WaterLinked { time_us, input } => {
                self.water_linked[usize::from(input == DvlInput::NoLock)] += 1;
                let epoch_us = (epoch as i64).saturating_mul(1_000_000);
                nav.push_dvl(DvlRecord {
                    time: time_us.saturating_sub(epoch_us) as f64 * 1e-6,
                    input,
                })
            }
            Record::Depth { time, depth } => nav.push_depth(DepthSample {
                time: time - epoch,
                depth_m: depth,
            }),
            Record::Fix {
                time,
                lat_deg,
                lon_deg,
                sigma_m,
            } => nav.push_fix(PositionFix {
                time: time - epoch,
                latitude_deg: lat_deg,
                longitude_deg: lon_deg,
                sigma_m,
            }),
            Record::Ignored => {
                self.ignored += 1;
                return Ok(());
            }
        };
        match admission {
            Ok(Admission::Refused(refusal)) => self.refused(refusal, at),
            Ok(_) => {}
            Err(StreamError::Navigator(e)) => return Err(stopped(e, epoch, at)),
            Err(e @ (StreamError::ImuTimeOrder { .. } | StreamError::NonFinite { .. })) => {
                return Err(fail(RecordError::Stream(e)).into())
            }
            Err(e) => return Err(anyhow::anyhow!("{}:{}: {e}", at.0, at.1)),
        }
        Ok(())
    }

    /// The navigator, at the first IMU record's time `t` (its whole second is the
    /// epoch).
    fn start(&mut self, t: f64) -> anyhow::Result<()> {
        self.epoch = t.floor();
        let mut config = self.config.clone();
        config.initial.time_s = config.initial.time_s.map(|s| s - self.epoch);
        let settings = config
            .check()
            .map_err(|e| anyhow::anyhow!("vehicle: {e}"))?;
        self.nav = Some(StreamNavigator::new(settings, self.stream));
        Ok(())
    }

    fn refused(&mut self, refusal: Refusal, at: (&str, usize)) {
        if self.refusals_printed < REFUSALS_PRINTED {
            self.refusals_printed += 1;
            let text = match refusal {
                Refusal::TooOld {
                    sensor,
                    time,
                    boundary,
                } => format!(
                    "{sensor} record at t = {} s is older than the history (final up to {} s); \
                     refused",
                    self.epoch + time,
                    self.epoch + boundary
                ),
                Refusal::OutsideImuSpan { sensor, time } => format!(
                    "{sensor} record at t = {} s is outside the IMU's span; skipped",
                    self.epoch + time
                ),
                Refusal::HistoryFull { sensor, time } => format!(
                    "{sensor} record at t = {} s: the history is full; refused",
                    self.epoch + time
                ),
            };
            eprintln!("warning: {}:{}: {text}", at.0, at.1);
            self.refusals
                .push(json!({ "source": at.0, "line": at.1, "refusal": refusal }));
        }
    }
}

/// A navigator failure (numerical, a divergence) stops the run with exit status 3.
fn stopped(e: NavigatorError, epoch: f64, at: (&str, usize)) -> anyhow::Error {
    match e {
        NavigatorError::Filter { .. } | NavigatorError::Diverged { .. } => schema::RunStopped {
            message: format!(
                "navigate --stream stopped at {}:{} (epoch {epoch} s): {e}",
                at.0, at.1
            ),
        }
        .into(),
        other => anyhow::anyhow!("{}:{}: {other}", at.0, at.1),
    }
}

/// Run it.
pub fn run(options: Options) -> anyhow::Result<()> {
    if let Some(rate) = options.rate {
        anyhow::ensure!(
            rate.is_finite() && rate > 0.0,
            "--rate {rate}: not a positive rate"
        );
    }
    anyhow::ensure!(
        options.idle_timeout_s.is_finite() && options.idle_timeout_s > 0.0,
        "--idle-timeout {}: not a positive number of seconds",
        options.idle_timeout_s
    );
    let stream = StreamConfig::builder()
        .history_s(options.history_s)
        .output_rate_hz(options.rate)
        .timing(if options.exact_times {
            MeasurementTiming::Exact
        } else {
            MeasurementTiming::NearestImuSample
        })
        .build()
        .map_err(|e| anyhow::anyhow!("--history / --rate: {e}"))?;
    let config = match &options.vehicle {
        Some(p) => vehicle_config(p)?,
        None => NavigatorConfig::default(),
    };
    let in_vehicle = |e: NavigatorError| match &options.vehicle {
        Some(p) => anyhow::anyhow!("{}: {e}", p.display()),
        None => anyhow::anyhow!("{e}"),
    };
    let frame = config.imu_frame().map_err(in_vehicle)?;
    config.check().map_err(in_vehicle)?;
    let staged = match &options.out {
        Some(dir) => {
            let mut staged = StagedDir::new(dir)?;
            staged.keep_inputs(
                options
                    .vehicle
                    .iter()
                    .chain(&options.follow)
                    .map(PathBuf::as_path),
            );
            Some(staged)
        }
        None => None,
    };

    // The sources: stdin or the followed file (the stream's end), and the DVL's TCP.
    // At most 256 lines in flight (16 MiB of the longest lines).
    let (tx, rx) = mpsc::sync_channel::<Message>(256);
    let mut names = Vec::new();
    match &options.follow {
        Some(path) => {
            let file = std::fs::File::open(path)
                .with_context(|| format!("{}: cannot open", path.display()))?;
            names.push(path.display().to_string());
            let idle = Duration::from_secs_f64(options.idle_timeout_s);
            spawn_reader(0, Box::new(file), Some(idle), tx.clone());
        }
        None => {
            names.push("stdin".to_string());
            spawn_reader(0, Box::new(std::io::stdin()), None, tx.clone());
        }
    }
    if let Some(address) = &options.dvl_tcp {
        let socket = std::net::TcpStream::connect(address)
            .with_context(|| format!("--dvl-tcp {address}: cannot connect"))?;
        names.push(address.clone());
        spawn_reader(1, Box::new(socket), None, tx.clone());
    }
    drop(tx);

    let mut output = Output {
        stdout: None,
        file: None,
        line: String::new(),
        track: Vec::new(),
        last: None,
    };
    match &staged {
        Some(dir) => {
            let path = dir.path("solution.csv");
            let target = dir.target().join("solution.csv");
            let mut file = std::io::BufWriter::new(
                std::fs::File::create(&path)
                    .with_context(|| format!("{}: cannot create", target.display()))?,
            );
            file.write_all(CSV_HEADER.as_bytes())
                .with_context(|| format!("{}: cannot write", target.display()))?;
            output.file = Some((file, target));
        }
        None => {
            let mut out = std::io::BufWriter::new(std::io::stdout());
            out.write_all(CSV_HEADER.as_bytes())?;
            out.flush()?;
            output.stdout = Some(out);
        }
    }
    let mut run = Run {
        config,
        frame,
        stream,
        nav: None,
        epoch: 0.0,
        first_imu: None,
        before_imu: Vec::new(),
        water_linked: [0; 2],
        ignored: 0,
        refusals_printed: 0,
        refusals: Vec::new(),
    };
    let mut lines = [0usize; 2];
    let started = Instant::now();
    for message in rx.iter() {
        match message {
            Message::Line {
                source,
                number,
                bytes,
            } => {
                lines[source] += 1;
                if bytes.iter().all(u8::is_ascii_whitespace) {
                    continue;
                }
                let name = &names[source];
                let record = parse(&bytes).map_err(|error| LineError {
                    source_name: name.clone(),
                    line: number,
                    error,
                })?;
                run.feed(record, (name, number))?;
                if let Some(nav) = &mut run.nav {
                    output.write(run.epoch, &nav.take_final())?;
                }
            }
            Message::Failed {
                source,
                number,
                error,
            } => {
                return Err(LineError {
                    source_name: names[source].clone(),
                    line: number,
                    error,
                }
                .into())
            }
            Message::Io { source, error } => {
                return Err(
                    anyhow::Error::new(error).context(format!("{}: cannot read", names[source]))
                )
            }
            // The stream ends with stdin or the followed file; a DVL connection that
            // closes is one source less.
            Message::Ended { source: 0 } => break,
            Message::Ended { .. } => {}
        }
    }
    let Some(mut nav) = run.nav.take() else {
        anyhow::bail!("{}: no IMU record in the stream", names[0]);
    };
    if let Err(e) = nav.finish() {
        return Err(match e {
            StreamError::Navigator(e) => stopped(e, run.epoch, (&names[0], lines[0])),
            e => anyhow::anyhow!("{}: {e}", names[0]),
        });
    }
    output.write(run.epoch, &nav.take_final())?;
    let elapsed = started.elapsed().as_secs_f64();
    let summary = summary(&run, &nav, &output, &options, &lines, elapsed);
    if let Some(dir) = staged {
        if let Some((mut file, path)) = output.file.take() {
            file.flush()
                .with_context(|| format!("{}: cannot write", path.display()))?;
        }
        let write = |name: &str, text: &[u8]| {
            std::fs::write(dir.path(name), text)
                .with_context(|| format!("{}: cannot write", dir.target().join(name).display()))
        };
        let track = json!({
            "type": "FeatureCollection",
            "features": [{
                "type": "Feature",
                "properties": { "name": "estim navigate --stream track (DVL epochs)" },
                "geometry": { "type": "LineString", "coordinates": output.track },
            }],
        });
        write("track.geojson", serde_json::to_string(&track)?.as_bytes())?;
        write(
            "summary.json",
            serde_json::to_string_pretty(&summary)?.as_bytes(),
        )?;
        dir.commit()?;
        let text = if options.json {
            format!("{}\n", serde_json::to_string_pretty(&summary)?)
        } else {
            summary_text(&summary)
        };
        return crate::output::emit(&text);
    }
    if options.json {
        eprintln!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        eprint!("{}", summary_text(&summary));
    }
    Ok(())
}

/// The summary document (`summary.json`, `--json`).
fn summary(
    run: &Run,
    nav: &StreamNavigator,
    output: &Output,
    options: &Options,
    lines: &[usize; 2],
    elapsed_s: f64,
) -> Value {
    let counts = nav.counts();
    let updates = nav.update_counts().map(|[d, p, f]| {
        let c = |c: estim::navigator::UpdateCounts| json!({ "accepted": c.accepted, "gated": c.gated, "recovered": c.recovered });
        json!({ "dvl": c(d), "depth": c(p), "fixes": c(f) })
    });
    let epoch = run.epoch;
    let last = output.last.map(|f| {
        json!({
            "time_s": epoch + f.time,
            "latitude_deg": f.latitude_deg,
            "longitude_deg": f.longitude_deg,
            "depth_m": f.depth_m,
            "position_sigma_m": f.position_sigma_m,
            "heading_deg": f.heading_deg,
            "heading_sigma_deg": f.attitude_sigma_deg[2],
        })
    });
    schema::document(
        "navigate",
        json!({
            "mode": "stream",
            "follow": schema::path_json(options.follow.as_deref()),
            "dvl_tcp": options.dvl_tcp,
            "vehicle": schema::path_json(options.vehicle.as_deref()),
            "history_s": options.history_s,
            "exact_times": options.exact_times,
            "rate_hz": options.rate,
            "configuration": run.config,
        }),
        0,
        json!({
            "epoch_s": epoch,
            "lines": { "main": lines[0], "dvl_tcp": lines[1] },
            "imu_period_s": nav.imu_period(),
            "initial": nav.alignment(),
            "updates": updates,
            "stream": counts,
            "water_linked_velocity_reports": { "valid": run.water_linked[0], "no_lock": run.water_linked[1] },
            "ignored_records": run.ignored,
            "refusals_first": run.refusals,
            "dvl_noise_scale": nav.dvl_noise_scale(),
            "dvl_states": nav.dvl_states(),
            "solutions": counts.solutions,
            "final": last,
            "wall_time_s": elapsed_s,
        }),
    )
}

fn summary_text(summary: &Value) -> String {
    let s = &summary["stream"];
    format!(
        "streamed: {} IMU samples, {} measurements, {} solutions; refused as too old {}, \
         outside the IMU span {}, no lock {}; rewinds {} ({} events replayed); history \
         at most {} events, {} checkpoints\n",
        s["imu_samples"],
        s["measurements"],
        s["solutions"],
        s["refused_too_old"],
        s["outside_imu_span"],
        s["dvl_no_lock"],
        s["rewinds"],
        s["replayed_events"],
        s["max_history_events"],
        s["max_checkpoints"],
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_parse_and_bad_ones_name_what_is_wrong() {
        let imu = br#"{"sensor": "imu", "time": 1.5, "acc": [0, 0, -9.8], "gyro": [0, 0, 0.1]}"#;
        assert_eq!(
            parse(imu).unwrap(),
            Record::Imu {
                time: 1.5,
                acc: [0.0, 0.0, -9.8],
                gyro: [0.0, 0.0, 0.1]
            }
        );
        let dvl = br#"{"sensor": "dvl", "time": 2, "velocity": null}"#;
        assert!(matches!(
            parse(dvl).unwrap(),
            Record::Dvl {
                input: DvlInput::NoLock,
                ..
            }
        ));
        let beams = br#"{"sensor": "beams", "time": 2, "beams": [0.1, null, 0.2, -32.768]}"#;
        assert!(matches!(
            parse(beams).unwrap(),
            Record::Dvl {
                input: DvlInput::Beams([Some(_), None, Some(_), None]),
                ..
            }
        ));
        let cases: [(&[u8], &str); 8] = [
            (b"{\"sensor\": \"imu\"", "not a JSON record"),
            (b"[1, 2]", "JSON object"),
            (br#"{"sensor": "gps", "time": 1}"#, "sensor `gps`"),
            (
                br#"{"sensor": "imu", "time": 1, "acc": [0, 0], "gyro": [0, 0, 0]}"#,
                "`acc`",
            ),
            (
                br#"{"sensor": "depth", "time": 1, "depth": 1e999}"#,
                "not a JSON record",
            ),
            (
                br#"{"sensor": "fix", "time": 1, "lat_deg": 1, "lon_deg": 2}"#,
                "`sigma_m` is missing",
            ),
            (
                br#"{"sensor": "depth", "time": 1, "depth": 3, "extra": 1}"#,
                "`extra`",
            ),
            (
                br#"{"sensor": "dvl", "time": "soon", "velocity": null}"#,
                "`time`",
            ),
        ];
        for (line, expected) in cases {
            let e = parse(line).unwrap_err().to_string();
            assert!(e.contains(expected), "{e} lacks {expected}");
        }
    }

    #[test]
    fn lines_are_capped_and_a_missing_newline_is_truncation() {
        let long = vec![b'x'; MAX_LINE_BYTES + 10];
        let mut reader = std::io::Cursor::new(long);
        let mut buf = Vec::new();
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Err(Ok(RecordError::TooLong))
        ));
        let mut reader = std::io::Cursor::new(b"a\r\nb".to_vec());
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Ok(LineRead::Line)
        ));
        assert_eq!(buf, b"a");
        assert!(matches!(
            read_line(&mut reader, &mut buf, None),
            Err(Ok(RecordError::Truncated))
        ));
    }
}
