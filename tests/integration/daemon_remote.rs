//! The daemon owns the rig: a second opener of its real ports (the CLI's `run`, a second
//! daemon) is told where the daemon is and to use `run --remote`, and `run --remote` refuses
//! bad input with the daemon's message and runs a script on the daemon. The CLI runs as a
//! process of its own, so these tests talk to the daemon over its socket.

use crate::common;

use std::path::{Path, PathBuf};

use stagehand::daemon::{DaemonError, RunningDaemon};

type TestResult = Result<(), Box<dyn std::error::Error + Send + Sync>>;

const BIN: &str = env!("CARGO_BIN_EXE_stagehand");

/// A small simulated light stage (cameras 64×48) as a rig file.
fn small_rig(dir: &Path) -> PathBuf {
    common::small_rig_file(dir, "lightstage", 64, 48)
}

async fn start(dir: &Path, rig: &Path) -> Result<RunningDaemon, DaemonError> {
    common::start_daemon(&dir.join("data"), Some(rig)).await
}

/// The rig with its lamp board behind a (fake) real serial port: opening it takes the port's
/// lock, without touching the port until a lamp switches.
fn rig_with_a_real_port(
    dir: &Path,
) -> Result<(PathBuf, String), Box<dyn std::error::Error + Send + Sync>> {
    let port = dir.join("ttyFAKE-lamps").display().to_string();
    let text = std::fs::read_to_string(small_rig(dir))?;
    let from = "[[switch_bank]]\nid = \"lamps\"\nbackend = \"sim\"\n";
    if !text.contains(from) {
        return Err("the built-in light stage's lamp bank is not where this test expects".into());
    }
    let text = text.replacen(
        from,
        &format!(
            "[[switch_bank]]\nid = \"lamps\"\nbackend = \"relay-serial\"\nport = \"{port}\"\n"
        ),
        1,
    );
    let path = dir.join("real-port-rig.toml");
    std::fs::write(&path, text)?;
    Ok((path, port))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_second_opener_of_the_daemons_ports_is_told_to_use_remote() -> TestResult {
    // Alone: the daemon's URL in the port locks is the process's, and a daemon of another
    // test beside this one would record its own.
    let _turn = crate::grbl_peer::exclusive();
    let tmp = tempfile::tempdir()?;
    let (rig, port) = rig_with_a_real_port(tmp.path())?;
    let d = start(tmp.path(), &rig).await?;
    let url = format!("http://{}", d.addr);
    // The daemon records its URL once it listens (idempotent if `start` did already).
    stagehand::rig::port_lock::record_listen_addr(d.addr);

    // The CLI's `run` on the same rig is refused, naming the port and the daemon.
    let out_dir = tmp.path().join("runs");
    let script = common::root().join("sequences/quickstart.rhai");
    let (rig2, out2) = (rig.clone(), out_dir.clone());
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new(BIN)
            .arg("run")
            .arg("--rig")
            .arg(&rig2)
            .arg("--out")
            .arg(&out2)
            .arg("-y")
            .arg(&script)
            .output()
    })
    .await??;
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(stderr.contains(&port), "{stderr}");
    assert!(
        stderr.contains(&format!(
            "the daemon at {url} owns this rig; use `stagehand run --remote {url} script.rhai`"
        )),
        "{stderr}"
    );
    assert!(
        stderr.contains(&format!("pid {}", std::process::id())),
        "{stderr}"
    );
    let made = std::fs::read_dir(&out_dir).map(|d| d.count()).unwrap_or(0);
    assert_eq!(
        made,
        0,
        "a refused run left a run directory in {}",
        out_dir.display()
    );

    // A second daemon on the same rig is refused too.
    let second = tmp.path().join("second");
    std::fs::create_dir_all(&second)?;
    match start(&second, &rig).await {
        Ok(other) => {
            other.shutdown().await;
            d.shutdown().await;
            return Err("a second daemon opened the first one's ports".into());
        }
        Err(e) => {
            let text = e.to_string();
            assert!(
                text.contains(&port) && text.contains("owns this rig"),
                "{text}"
            );
        }
    }
    d.shutdown().await;
    // The fake port's lock file is this test's own: leave the shared lock directory clean.
    let lock = stagehand::rig::port_lock::lock_file_for(
        &stagehand::rig::port_lock::lock_dir(),
        &stagehand::rig::port_lock::canonical_port(&port),
    );
    let _ = std::fs::remove_file(lock);
    Ok(())
}

/// Runs `stagehand ARGS` (blocking, in a worker thread) with `STAGEHAND_TOKEN` removed.
async fn cli(
    args: Vec<String>,
) -> Result<std::process::Output, Box<dyn std::error::Error + Send + Sync>> {
    Ok(tokio::task::spawn_blocking(move || {
        std::process::Command::new(BIN)
            .args(&args)
            .env_remove("STAGEHAND_TOKEN")
            .stdin(std::process::Stdio::null())
            .output()
    })
    .await??)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn run_remote_refuses_bad_input_and_runs_a_script_on_the_daemon() -> TestResult {
    let _turn = crate::grbl_peer::alongside();
    let tmp = tempfile::tempdir()?;
    let rig = small_rig(tmp.path());
    let d = start(tmp.path(), &rig).await?;
    let url = format!("http://{}", d.addr);
    let token = d.state.tokens.operator.clone();
    let write = |name: &str, text: &str| -> std::io::Result<String> {
        let p = tmp.path().join(name);
        std::fs::write(&p, text)?;
        Ok(p.display().to_string())
    };
    let tiny = write(
        "tiny.rhai",
        "prompt(\"Check the sample\");\nonly_lamp(lamps()[0]);\nmove_to(\"turntable\", 3.0);\ncapture(0.01);\nlamps_off();\n",
    )?;
    let broken = write("broken.rhai", "let x = ;\n")?;
    let outside = write("outside.rhai", "move_to(\"turntable\", 99999.0);\n")?;
    let s = |v: &[&str]| v.iter().map(|s| s.to_string()).collect::<Vec<_>>();
    let text = |o: &std::process::Output| {
        format!(
            "{}{}",
            String::from_utf8_lossy(&o.stdout),
            String::from_utf8_lossy(&o.stderr)
        )
    };

    // No token, a wrong token, nothing listening, a script with errors, a plan with errors,
    // an unknown parameter: exit 2 with the daemon's message, nothing started.
    let cases: Vec<(Vec<String>, &str)> = vec![
        (s(&["run", "--remote", &url, &tiny]), "STAGEHAND_TOKEN"),
        (
            s(&["run", "--remote", &url, "--token", &"0".repeat(64), &tiny]),
            "401",
        ),
        (
            s(&[
                "run",
                "--remote",
                "http://127.0.0.1:9",
                "--token",
                &token,
                &tiny,
            ]),
            "cannot reach the daemon at http://127.0.0.1:9",
        ),
        (
            s(&["run", "--remote", &url, "--token", &token, &broken]),
            "1:9",
        ),
        (
            s(&["run", "--remote", &url, "--token", &token, &outside]),
            "soft limits",
        ),
        (
            s(&[
                "run", "--remote", &url, "--token", &token, "--set", "nope=1", &tiny,
            ]),
            "nope",
        ),
        (
            s(&[
                "run", "--remote", &url, "--token", &token, "--rig", "x.toml", &tiny,
            ]),
            "cannot be used with",
        ),
    ];
    for (args, needle) in cases {
        let o = cli(args.clone()).await?;
        let t = text(&o);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {t}");
        assert!(t.contains(needle), "{args:?}: expected `{needle}` in {t}");
        assert!(!t.contains("panicked"), "{t}");
    }
    assert!(d.state.runs.snapshot().is_none(), "bad input started a run");

    // The real thing: uploaded, run on the daemon, prompt confirmed by -y, exit 0.
    let o = cli(s(&[
        "run", "--remote", &url, "--token", &token, "-y", &tiny,
    ]))
    .await?;
    let t = text(&o);
    assert_eq!(o.status.code(), Some(0), "{t}");
    assert!(t.contains("run done:"), "{t}");
    assert!(t.contains("Check the sample"), "{t}");
    assert!(t.contains("steps 5/5"), "{t}");
    d.shutdown().await;
    Ok(())
}
