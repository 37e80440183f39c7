//! `--out` complete or absent on every path, and stdout closed or full (issue 28):
//! a reused folder holds only the new run's files (besides files estim did not
//! write), a locked folder is refused, stale staging folders are removed, parents
//! created for a failed run are removed, signals clean up, every command checks
//! `--out` before computing, and no command panics on a closed or full stdout.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};

use estim::datasets::{DVL_HEADER, GT_HEADER};

fn bin() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_estim"));
    c.env_remove("ESTIM_DATA_DIR").stdin(Stdio::null());
    c
}

fn estim(args: &[&str]) -> Output {
    bin().args(args).output().expect("run estim")
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn names(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.filter_map(|e| e.ok().map(|e| e.file_name().to_string_lossy().into_owned()))
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// A 30 s simulated mission: every command that runs it ends in about a second.
fn short_config(dir: &Path) -> PathBuf {
    let p = dir.join("short.toml");
    std::fs::write(&p, "[mission]\nduration_s = 30.0\n").unwrap();
    p
}

#[track_caller]
fn ok(out: &Output) {
    assert_eq!(
        out.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// A second run on an --out folder replaces the first's files: the smoothing folder
/// of a `--smooth` run does not stay beside a run without it, a stale staging folder
/// (a process killed with SIGKILL) is removed, files estim did not write are kept.
#[test]
fn a_reused_out_holds_only_the_new_run() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_config(dir.path());
    let out = dir.path().join("out");
    let c = s(&config);
    ok(&estim(&[
        "reproduce",
        "--config",
        c,
        "--smooth",
        "--out",
        s(&out),
    ]));
    assert!(out.join("smoothing/smoothing.json").is_file());
    assert!(out.join("simulated_timeseries.csv").is_file());
    std::fs::write(out.join("notes.txt"), "mine").unwrap();
    let stale = out.join(".estim-partial-999999999");
    std::fs::create_dir(&stale).unwrap();
    std::fs::write(stale.join("report.json"), "{}").unwrap();
    // Without --smooth, with other plots (one filter's files are the same names).
    ok(&estim(&["reproduce", "--config", c, "--out", s(&out)]));
    let after = names(&out);
    assert!(!after.contains(&"smoothing".to_string()), "{after:?}");
    assert!(
        !after.iter().any(|n| n.starts_with(".estim-partial")),
        "{after:?}"
    );
    assert!(after.contains(&"notes.txt".to_string()), "{after:?}");
    assert!(after.contains(&"report.json".to_string()), "{after:?}");
    // `smooth --out` on the folder: only the smoothing files (and notes.txt) remain.
    ok(&estim(&["smooth", "--config", c, "--out", s(&out)]));
    let after = names(&out);
    assert!(!after.contains(&"report.json".to_string()), "{after:?}");
    assert!(after.contains(&"smoothing.json".to_string()), "{after:?}");
    assert!(after.contains(&"notes.txt".to_string()), "{after:?}");
}

/// Two runs on one --out cannot mix: while a lock is held on the folder, a run is
/// refused before computing and writes nothing.
#[test]
fn a_locked_out_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_config(dir.path());
    let out = dir.path().join("out");
    std::fs::create_dir(&out).unwrap();
    let holder = std::fs::File::open(&out).unwrap();
    holder.try_lock().expect("the test takes the lock first");
    for args in [
        &["reproduce", "--config", s(&config), "--out", s(&out)][..],
        &["smooth", "--config", s(&config), "--out", s(&out)][..],
    ] {
        let run = estim(args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{stderr}");
        assert!(stderr.contains("another estim run"), "{stderr}");
        assert!(names(&out).is_empty(), "{:?}", names(&out));
    }
    drop(holder);
    ok(&estim(&[
        "reproduce",
        "--config",
        s(&config),
        "--out",
        s(&out),
    ]));
}

/// A run that fails after creating --out and its missing parents removes them all.
#[test]
fn parents_created_for_a_failed_run_are_removed() {
    let dir = tempfile::tempdir().unwrap();
    let gt = dir.path().join("gt.csv");
    std::fs::write(&gt, format!("{}\n0,1,2,3\n", GT_HEADER.join(","))).unwrap();
    let dvl = dir.path().join("dvl.csv");
    std::fs::write(
        &dvl,
        format!("{}\n0,1,2,3\n1,1,2,3\n", DVL_HEADER.join(",")),
    )
    .unwrap();
    let out = dir.path().join("a/b/c/out");
    let run = estim(&[
        "reproduce",
        "--gt",
        s(&gt),
        "--dvl",
        s(&dvl),
        "--out",
        s(&out),
    ]);
    assert_eq!(run.status.code(), Some(2));
    assert!(!dir.path().join("a").exists(), "parents left behind");
}

/// Every command with --out checks it before computing: with an --out that cannot
/// be created, the error is about --out, not about the data read later.
#[test]
fn every_command_checks_out_before_computing() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("a-file");
    std::fs::write(&file, "").unwrap();
    let bad_out = file.join("out");
    let empty_data = tempfile::tempdir().unwrap();
    let npy = bad_out.join("x.npy");
    for args in [
        &["smooth", "--data", "/nonexistent", "--out", s(&bad_out)][..],
        &["reproduce", "--data", "/nonexistent", "--out", s(&bad_out)][..],
        &[
            "dataset",
            "beamsnet",
            "--data",
            s(empty_data.path()),
            "--out",
            s(&npy),
        ][..],
    ] {
        let run = estim(args);
        let stderr = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains(s(&bad_out)) && stderr.contains("cannot create"),
            "{args:?}: {stderr}"
        );
    }
}

fn spawn_until_staging(args: &[&str], out: &Path) -> Child {
    let mut child = bin()
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    // Wait (no time limit asserted) until the staging folder exists.
    loop {
        if names(out).iter().any(|n| n.starts_with(".estim-partial")) {
            return child;
        }
        if let Ok(Some(status)) = child.try_wait() {
            panic!("{args:?} ended ({status}) before its staging folder was seen");
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

/// SIGINT and SIGTERM remove the staging folder and the --out folder the run created
/// (exit 128 + signal); after SIGKILL the next run removes the stale staging folder.
#[test]
fn signals_leave_no_staging_folder() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_config(dir.path());
    for (signal, code) in [("-INT", 130), ("-TERM", 143)] {
        let out = dir.path().join(format!("out{signal}"));
        // The default 400 s mission with smoothing runs for seconds.
        let mut child = spawn_until_staging(&["reproduce", "--smooth", "--out", s(&out)], &out);
        let killed = Command::new("kill")
            .args([signal, &child.id().to_string()])
            .status()
            .unwrap();
        assert!(killed.success());
        let status = child.wait().unwrap();
        assert_eq!(status.code(), Some(code), "{signal}: {status:?}");
        assert!(!out.exists(), "{signal}: {:?}", names(&out));
    }
    let out = dir.path().join("out-kill");
    let mut child = spawn_until_staging(&["reproduce", "--smooth", "--out", s(&out)], &out);
    child.kill().unwrap();
    child.wait().unwrap();
    assert!(names(&out).iter().any(|n| n.starts_with(".estim-partial")));
    ok(&estim(&[
        "reproduce",
        "--config",
        s(&config),
        "--out",
        s(&out),
    ]));
    let after = names(&out);
    assert!(
        !after.iter().any(|n| n.starts_with(".estim-partial")),
        "{after:?}"
    );
}

fn beam_file(dir: &Path) -> PathBuf {
    let beams = dir.join("beams.csv");
    std::fs::write(&beams, "beam1,beam2,beam3,beam4\n0.1,0.2,0.3,0.4\n").unwrap();
    beams
}

/// Every command ends quietly with 141 on a closed stdout and with an error naming
/// stdout on a full one (/dev/full); never "failed printing to stdout".
#[test]
fn stdout_closed_or_full_never_panics() {
    let dir = tempfile::tempdir().unwrap();
    let config = short_config(dir.path());
    let c = s(&config);
    let beams = beam_file(dir.path());
    let commands: Vec<Vec<&str>> = vec![
        vec!["reproduce", "--print-config"],
        vec!["reproduce", "--config", c],
        vec!["reproduce", "--config", c, "--json", "--smooth"],
        vec!["reproduce", "--config", c, "--smooth"],
        vec!["smooth", "--config", c],
        vec!["smooth", "--config", c, "--json"],
        vec!["montecarlo", "--runs", "1", "--config", c],
        vec!["dvl", "solve", "--beam-angle", "20", s(&beams)],
        vec!["beamsnet", "eval", "--json"],
    ];
    for args in &commands {
        // The reader is gone before the command starts (closing it after the spawn
        // raced a fast command that wrote into the pipe's buffer first).
        let (reader, writer) = std::io::pipe().unwrap();
        drop(reader);
        let out = bin()
            .args(args)
            .stdout(writer)
            .stderr(Stdio::piped())
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(141), "{args:?}: {stderr}");
        assert!(!stderr.contains("panicked"), "{args:?}: {stderr}");
        let full = Path::new("/dev/full");
        if full.exists() {
            let out = bin()
                .args(args)
                .stdout(std::fs::OpenOptions::new().write(true).open(full).unwrap())
                .output()
                .unwrap();
            let stderr = String::from_utf8_lossy(&out.stderr);
            assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
            assert!(
                stderr.contains("cannot write to stdout") && !stderr.contains("panicked"),
                "{args:?}: {stderr}"
            );
        }
    }
}
