//! `stagehand serve` and `--realtime-priority`: by default the daemon's runtime threads run at
//! `SCHED_FIFO` 10 and the threads they start at normal scheduling (Linux, with the privilege
//! CI has as root); a priority given is used; `off` keeps every thread normal.

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

/// Each thread of `pid` as (name, scheduling policy, real-time priority), from
/// `/proc/PID/task/*/stat`.
fn thread_policies(pid: u32) -> Vec<(String, u32, u32)> {
    let mut out = Vec::new();
    for task in std::fs::read_dir(format!("/proc/{pid}/task")).expect("tasks") {
        let Ok(stat) = std::fs::read_to_string(task.expect("task").path().join("stat")) else {
            continue; // the thread ended
        };
        let (Some(open), Some(close)) = (stat.find('('), stat.rfind(')')) else {
            continue;
        };
        // Fields after the name: state is field 3, the real-time priority field 40, the policy
        // field 41.
        let fields: Vec<&str> = stat[close + 2..].split_whitespace().collect();
        let field = |n: usize| -> u32 { fields[n - 3].parse().expect("numeric field") };
        out.push((stat[open + 1..close].to_string(), field(41), field(40)));
    }
    out
}

/// Starts `stagehand serve` with `args` on a fresh data directory, waits for its banner and
/// returns the banner and its threads' scheduling; the daemon is stopped.
fn serve_threads(args: &[&str]) -> (String, Vec<(String, u32, u32)>) {
    let data = tempfile::tempdir().expect("temp dir");
    let mut daemon = Command::new(BIN)
        .arg("serve")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .arg("--data")
        .arg(data.path())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("daemon starts");
    // It prints its scheduling after its dashboard's address once it listens: its runtime is
    // up by then.
    let mut banner = String::new();
    let mut lines = BufReader::new(daemon.stderr.take().expect("stderr")).lines();
    for line in lines.by_ref() {
        let line = line.expect("stderr line");
        banner.push_str(&line);
        banner.push('\n');
        if line.contains("scheduling:") {
            break;
        }
    }
    let threads = thread_policies(daemon.id());
    let _ = daemon.kill();
    let _ = daemon.wait();
    assert!(
        banner.contains("dashboard:") && banner.contains("scheduling:"),
        "the daemon did not start:\n{banner}"
    );
    (banner, threads)
}

const SCHED_OTHER: u32 = 0;
const SCHED_FIFO: u32 = 1;

/// Asserts that the runtime's threads run at `SCHED_FIFO` `priority` and every other thread
/// at normal scheduling.
fn assert_runtime_at(priority: u32, banner: &str, threads: &[(String, u32, u32)]) {
    assert!(
        banner.contains(&format!(
            "scheduling: real-time for the rig's threads (SCHED_FIFO {priority})"
        )),
        "{banner}"
    );
    let (runtime, others): (Vec<_>, Vec<_>) = threads
        .iter()
        .partition(|(name, _, _)| name.starts_with("tokio-r"));
    assert!(!runtime.is_empty(), "no runtime threads in {threads:?}");
    assert!(
        runtime
            .iter()
            .all(|(_, p, rt)| *p == SCHED_FIFO && *rt == priority),
        "runtime threads not all SCHED_FIFO {priority}: {threads:?}"
    );
    assert_all_normal(&others, threads);
}

/// Asserts that each of `some` (of `threads`) runs at normal scheduling.
fn assert_all_normal(some: &[&(String, u32, u32)], threads: &[(String, u32, u32)]) {
    assert!(
        some.iter().all(|(_, p, rt)| *p == SCHED_OTHER && *rt == 0),
        "threads not all normal: {threads:?}"
    );
}

#[test]
fn the_daemon_runs_its_runtime_real_time_by_default_and_its_other_threads_normal() {
    let _turn = crate::grbl_peer::alongside();
    if !cfg!(target_os = "linux") || !may_raise() {
        eprintln!("skipped: this process may not raise threads to real-time priority");
        return;
    }
    let (banner, threads) = serve_threads(&[]);
    assert_runtime_at(10, &banner, &threads);
    let (banner, threads) = serve_threads(&["--realtime-priority", "12"]);
    assert_runtime_at(12, &banner, &threads);
}

#[test]
fn realtime_priority_off_keeps_every_thread_normal() {
    let _turn = crate::grbl_peer::alongside();
    if !cfg!(target_os = "linux") {
        eprintln!("skipped: scheduling is read from Linux's /proc");
        return;
    }
    let (banner, threads) = serve_threads(&["--realtime-priority", "off"]);
    assert!(
        banner.contains("scheduling: normal (--realtime-priority off)"),
        "{banner}"
    );
    assert_all_normal(&threads.iter().collect::<Vec<_>>(), &threads);
}
