//! `stagehand serve --realtime-priority`: the daemon's runtime threads run at `SCHED_FIFO`
//! and the threads they start at normal scheduling (Linux, with the privilege CI has as root).

use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

/// Whether this process may raise threads to real-time priority (`CAP_SYS_NICE`, bit 23 of the
/// effective capabilities).
fn may_raise() -> bool {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("CapEff:"))
                .and_then(|hex| u64::from_str_radix(hex.trim(), 16).ok())
        })
        .is_some_and(|caps| caps & (1 << 23) != 0)
}

/// Each thread of `pid` as (name, scheduling policy), from `/proc/PID/task/*/stat`.
fn thread_policies(pid: u32) -> Vec<(String, u32)> {
    let mut out = Vec::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task")).expect("tasks") {
        let Ok(stat) = std::fs::read_to_string(task.expect("task").path().join("stat")) else {
            continue; // the thread ended
        };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        // Fields after the name: state is field 3, the policy field 41.
        let policy = stat[close + 2..]
            .split_whitespace()
            .nth(38)
            .and_then(|p| p.parse().ok())
            .expect("policy field");
        out.push((stat[open + 1..close].to_string(), policy));
    }
    out
}

#[test]
fn the_daemon_runs_its_runtime_real_time_and_its_other_threads_normal() {
    let _turn = crate::grbl_peer::alongside();
    if !cfg!(target_os = "linux") || !may_raise() {
        eprintln!("skipped: this process may not raise threads to real-time priority");
        return;
    }
    let data = tempfile::tempdir().expect("temp dir");
    let mut daemon = Command::new(BIN)
        .args([
            "serve",
            "--realtime-priority",
            "10",
            "--listen",
            "127.0.0.1:0",
        ])
        .arg("--data")
        .arg(data.path())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("daemon starts");
    // It prints its dashboard's address once it listens: its runtime is up by then.
    let mut banner = String::new();
    let mut lines = BufReader::new(daemon.stderr.take().expect("stderr")).lines();
    for line in lines.by_ref() {
        let line = line.expect("stderr line");
        banner.push_str(&line);
        banner.push('\n');
        if line.contains("dashboard:") {
            break;
        }
    }
    let threads = thread_policies(daemon.id());
    let _ = daemon.kill();
    let _ = daemon.wait();
    assert!(
        banner.contains("dashboard:"),
        "the daemon did not start:\n{banner}"
    );
    assert!(!banner.contains("keep normal scheduling"), "{banner}");
    let (runtime, others): (Vec<_>, Vec<_>) = threads
        .iter()
        .partition(|(name, _)| name.starts_with("tokio-r"));
    const SCHED_OTHER: u32 = 0;
    const SCHED_FIFO: u32 = 1;
    assert!(!runtime.is_empty(), "no runtime threads in {threads:?}");
    assert!(
        runtime.iter().all(|(_, p)| *p == SCHED_FIFO),
        "runtime threads not all SCHED_FIFO: {threads:?}"
    );
    assert!(
        others.iter().all(|(_, p)| *p == SCHED_OTHER),
        "other threads not all normal: {threads:?}"
    );
}
