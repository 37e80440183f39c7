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

use std::io::Write;
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::Context;
use estim::core::nalgebra::Vector3;
use estim::navigator::{
    Admission, DepthSample, DvlInput, DvlRecord, FinalSolution, ImuFrame, MeasurementTiming,
    NavSolution, NavigatorConfig, NavigatorError, PositionFix, Refusal, SolutionKind, StreamConfig,
    StreamError, StreamNavigator,
};
use serde_json::{json, Value};

use crate::navigate::{solution_row, vehicle_config, CSV_HEADER};
use crate::output::StagedDir;
use crate::schema;

mod input;

pub use input::RecordError;
use input::{parse, spawn_reader, LineError, Message, Record};

/// Records buffered before the first IMU record (which sets the epoch).
const MAX_BEFORE_IMU: usize = 100_000;

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
    /// The lag of the smoothed rows \[s\], if any.
    pub lag_s: Option<f64>,
    /// Solutions at this rate too \[Hz\].
    pub rate: Option<f64>,
    /// Output folder.
    pub out: Option<PathBuf>,
    /// Summary as JSON.
    pub json: bool,
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
    /// Solution lines to `solution.csv` in `dir`, else to stdout; the header first.
    fn new(dir: Option<&StagedDir>) -> anyhow::Result<Self> {
        let mut output = Self {
            stdout: None,
            file: None,
            line: String::new(),
            track: Vec::new(),
            last: None,
        };
        match dir {
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
        Ok(output)
    }

    /// Flush `solution.csv` and write `track.geojson` and `summary.json` into `dir`.
    fn finish(&mut self, dir: &StagedDir, summary: &Value) -> anyhow::Result<()> {
        if let Some((mut file, path)) = self.file.take() {
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
                "geometry": { "type": "LineString", "coordinates": self.track },
            }],
        });
        write("track.geojson", serde_json::to_string(&track)?.as_bytes())?;
        write(
            "summary.json",
            serde_json::to_string_pretty(summary)?.as_bytes(),
        )
    }

    fn write(&mut self, epoch: f64, solutions: &[FinalSolution]) -> anyhow::Result<()> {
        if solutions.is_empty() {
            return Ok(());
        }
        for s in solutions {
            let kind = if s.smoothed { "lag" } else { s.kind.as_str() };
            solution_row(&mut self.line, epoch, kind, &s.solution);
            if let Some(out) = &mut self.stdout {
                out.write_all(self.line.as_bytes())?;
            }
            if let Some((file, path)) = &mut self.file {
                file.write_all(self.line.as_bytes())
                    .with_context(|| format!("{}: cannot write", path.display()))?;
            }
            if s.kind == SolutionKind::Dvl && !s.smoothed && self.file.is_some() {
                self.track
                    .push([s.solution.longitude_deg, s.solution.latitude_deg]);
            }
            if !s.smoothed {
                self.last = Some(s.solution);
            }
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
                let frame = &self.frame;
                let t0 = *self.first_imu.get_or_insert_with(|| frame.origin(epoch, t));
                let sample = self
                    .frame
                    .sample(t0, t, Vector3::from(acc), Vector3::from(gyro));
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
    let (config, frame, stream) = settings(&options)?;
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
    let (rx, names) = sources(&options)?;
    let mut output = Output::new(staged.as_ref())?;
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
    let started = Instant::now();
    let lines = pump(&rx, &names, &mut run, &mut output)?;
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
    match staged {
        Some(dir) => {
            output.finish(&dir, &summary)?;
            dir.commit()?;
            let text = if options.json {
                format!("{}\n", serde_json::to_string_pretty(&summary)?)
            } else {
                summary_text(&summary)
            };
            crate::output::emit(&text)
        }
        None => {
            if options.json {
                eprintln!("{}", serde_json::to_string_pretty(&summary)?);
            } else {
                eprint!("{}", summary_text(&summary));
            }
            Ok(())
        }
    }
}

/// The vehicle configuration, its IMU frame and the stream's settings, checked.
fn settings(options: &Options) -> anyhow::Result<(NavigatorConfig, ImuFrame, StreamConfig)> {
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
        .lag_s(options.lag_s)
        .timing(if options.exact_times {
            MeasurementTiming::Exact
        } else {
            MeasurementTiming::NearestImuSample
        })
        .build()
        .map_err(|e| anyhow::anyhow!("--history / --rate / --lag: {e}"))?;
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
    anyhow::ensure!(
        options.lag_s.is_none() || config.dvl_states.is_none(),
        "{}: --lag runs the 15-state filter (as estim smooth); remove the [dvl_states] table",
        options
            .vehicle
            .as_deref()
            .map_or_else(|| "vehicle".to_string(), |p| p.display().to_string())
    );
    Ok((config, frame, stream))
}

/// The readers: stdin or the followed file (source 0, the stream's end), and the
/// DVL's TCP connection (source 1); the channel they send on and their names.
fn sources(options: &Options) -> anyhow::Result<(mpsc::Receiver<Message>, Vec<String>)> {
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
        spawn_reader(1, Box::new(socket), None, tx);
    }
    Ok((rx, names))
}

/// Feed every line the readers send until the main source ends, writing the final
/// solutions as they come; the lines read per source.
fn pump(
    rx: &mpsc::Receiver<Message>,
    names: &[String],
    run: &mut Run,
    output: &mut Output,
) -> anyhow::Result<[usize; 2]> {
    let mut lines = [0usize; 2];
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
    Ok(lines)
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
            "lag_s": options.lag_s,
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
            "lag_failure": nav.lag_failure(),
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
