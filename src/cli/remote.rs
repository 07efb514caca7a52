//! `stagehand run --remote URL`: runs a script on a running daemon instead of opening the rig
//! here (the daemon owns the devices). Uploads the script, starts the run, follows the live
//! events with the same progress bar as a local run, answers prompts from the terminal (or
//! automatically with `-y`) and aborts on Ctrl-C. Exit codes as for a local run: 0 done,
//! 1 failed or aborted, 2 bad input (the daemon said 4xx, or it cannot be reached).
//!
//! The HTTP side is [`crate::client`]; this module is the terminal side, on one
//! current-thread runtime.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde_json::Value;
use tokio::signal::unix::{Signal, SignalKind};
use tokio::sync::mpsc;

use crate::client::{
    Client, ClientError, DaemonEvent, DryRun, EventKind, EventStream, PromptAnswer, PromptEvent,
    RunState, StartRun, StoredStatus,
};
use crate::executor::Event;
use crate::units::hms;

/// How long the event stream may stay quiet before the client checks the run is still active
/// (its `run_finished` event may have been lost by a client that fell behind).
const QUIET_CHECK: Duration = Duration::from_secs(5);
/// How long the event stream may take to send its first event.
const FIRST_EVENT: Duration = Duration::from_secs(10);
/// Reconnections of a broken event stream in a row before giving up.
const RECONNECTS: u32 = 5;

/// The environment variable holding the API token when `--token` is not given.
pub const TOKEN_ENV: &str = "STAGEHAND_TOKEN";

/// What `run --remote` needs.
#[derive(Debug, Clone)]
pub struct RemoteRun {
    /// The daemon's base URL, e.g. `http://127.0.0.1:8080`.
    pub url: String,
    /// `--token`; `$STAGEHAND_TOKEN` otherwise.
    pub token: Option<String>,
    /// The script file to run.
    pub script: PathBuf,
    /// `NAME=VALUE` overrides.
    pub set: Vec<String>,
    /// `--seed`: must match the daemon's when given (it seeds the noise when it opens the rig).
    pub seed: Option<u64>,
    /// Confirm every prompt automatically.
    pub yes: bool,
}

/// Why a remote run could not start or finish.
#[derive(Debug, thiserror::Error)]
pub enum RemoteError {
    /// Bad arguments (no token, unreadable script, malformed `--set`).
    #[error("{0}")]
    Input(String),
    /// A request to the daemon failed: unreachable, refused (4xx), failed (5xx) or answered
    /// something this client does not understand.
    #[error(transparent)]
    Client(#[from] ClientError),
    /// The script or its plan has errors (the daemon's dry run says where).
    #[error(
        "{0}\n  nothing was started; fix the script and run again (`stagehand plan` shows the same locally)"
    )]
    Invalid(String),
    /// The event stream broke during the run and could not be reopened.
    #[error(
        "lost the event stream of {url} during run {run_id}: {reason}; the run continues on the daemon (see its dashboard)"
    )]
    Lost {
        /// The daemon's base URL.
        url: String,
        /// The run followed.
        run_id: String,
        /// What broke last.
        reason: String,
    },
}

impl RemoteError {
    /// 2 when nothing started (bad input, refused, unreachable), 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            RemoteError::Input(_) | RemoteError::Invalid(_) => 2,
            RemoteError::Client(
                ClientError::BadUrl { .. }
                | ClientError::Unreachable { .. }
                | ClientError::Rejected { .. },
            ) => 2,
            RemoteError::Client(_) | RemoteError::Lost { .. } => 1,
        }
    }
}

/// Runs `args` on the daemon and returns the process exit code (errors are printed).
pub fn run(args: RemoteRun) -> i32 {
    let runtime = match tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
    {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("error: cannot start the async runtime: {e}");
            return 1;
        }
    };
    match runtime.block_on(run_remote(args)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
    }
}

/// The library name a script file is uploaded as: its stem, with characters the daemon does
/// not allow in names replaced by `_`.
pub fn script_name(path: &std::path::Path) -> Result<String, RemoteError> {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    let name: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .take(64)
        .collect();
    if name.is_empty() {
        return Err(RemoteError::Input(format!(
            "{}: cannot make a script name from this file name; rename it (letters, digits, `_`, `-`)",
            path.display()
        )));
    }
    Ok(name)
}

/// JSON as the operator reads it: strings without quotes, `?` for null.
fn show(v: &Value) -> String {
    match v {
        Value::Null => "?".into(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

/// Prints the dry run's violations of one severity, at their script positions.
fn print_violations(dr: &DryRun, severity: &str) {
    for v in dr.violations.iter().filter(|v| v.severity == severity) {
        eprintln!(
            "{}:{}:{}: {severity}: {} (step {})",
            dr.script, v.line, v.col, v.message, v.step
        );
    }
}

/// Prints what is wrong and returns the refusal, or prints the warnings and a summary.
fn check_dry_run(dr: &DryRun, script: &str) -> Result<(), RemoteError> {
    if let Some(e) = &dr.error {
        return Err(RemoteError::Invalid(e.clone()));
    }
    if !dr.ok {
        if dr.report.is_empty() {
            print_violations(dr, "error");
        } else {
            eprintln!("{}", dr.report.trim_end());
        }
        return Err(RemoteError::Invalid(format!(
            "the plan of {script} has errors (listed above)"
        )));
    }
    print_violations(dr, "warning");
    match &dr.estimate {
        Some(est) => eprintln!(
            "{script}: {} steps, estimated rig time {}, {} frames, {}",
            dr.steps,
            hms(est.rig_time_s),
            est.frames,
            crate::units::human_bytes(est.bytes)
        ),
        None => eprintln!("{script}: {} steps", dr.steps),
    }
    Ok(())
}

/// Puts the script in the daemon's library and returns the name it has there and whether
/// its dry run was checked already. The same text already there (e.g. a built-in sequence)
/// is used as is; a built-in of the same name with other text makes the upload go under
/// `NAME-<hash>` instead.
async fn upload(
    client: &Client,
    path: &std::path::Path,
    name: String,
    text: &str,
) -> Result<(String, bool), RemoteError> {
    match client.script(&name).await {
        Ok(Some(existing)) if existing == text => {
            eprintln!("`{name}` on {} is this script already", client.base());
            return Ok((name, false));
        }
        Ok(_) => {}
        // A bad token is said now; any other refusal is the upload's to say.
        Err(e @ ClientError::Rejected { .. }) if !matches!(e.status(), Some(401 | 403)) => {}
        Err(e) => return Err(e.into()),
    }
    eprintln!(
        "uploading {} to {} as `{name}`",
        path.display(),
        client.base()
    );
    match client.put_script(&name, text).await {
        Ok(dr) => {
            check_dry_run(&dr, &name)?;
            return Ok((name, true));
        }
        Err(e) if e.status() == Some(409) => {}
        Err(e) => return Err(e.into()),
    }
    let digest = crate::storage::checksum::sha256_hex(text.as_bytes());
    let other = format!("{name}-{}", &digest[..8.min(digest.len())]);
    eprintln!("`{name}` is taken by a different script on the daemon; uploading as `{other}`");
    let dr = client.put_script(&other, text).await?;
    check_dry_run(&dr, &other)?;
    Ok((other, true))
}

/// The `--set` overrides as the JSON object the API takes.
fn set_object(set: &[String]) -> Result<BTreeMap<String, Value>, RemoteError> {
    set.iter()
        .map(|s| {
            crate::script::parse_set(s)
                .map(|(k, v)| (k, Value::String(v)))
                .map_err(|e| RemoteError::Input(e.to_string()))
        })
        .collect()
}

/// The whole remote run; returns the exit code.
async fn run_remote(args: RemoteRun) -> Result<i32, RemoteError> {
    let token = args
        .token
        .clone()
        .or_else(|| std::env::var(TOKEN_ENV).ok())
        .filter(|t| !t.trim().is_empty())
        .ok_or_else(|| {
            RemoteError::Input(format!(
                "--remote needs the daemon's operator token: pass --token TOKEN or set {TOKEN_ENV} (it is in tokens.json in the daemon's data directory)"
            ))
        })?;
    let text = std::fs::read_to_string(&args.script)
        .map_err(|e| RemoteError::Input(format!("cannot read {}: {e}", args.script.display())))?;
    let name = script_name(&args.script)?;
    let set = set_object(&args.set)?;
    let client = Client::new(&args.url, Some(token.trim()))?;

    let (name, validated) = upload(&client, &args.script, name, &text).await?;
    if !validated || !set.is_empty() {
        let dr = client.validate(&name, &set).await?;
        check_dry_run(&dr, &name)?;
    }

    // Subscribe before starting so no event of the run is missed: the stream's first event
    // is a `resync`.
    let mut events = client.events(None).await?;
    match tokio::time::timeout(FIRST_EVENT, events.next_raw()).await {
        Ok(Some(Ok(_))) => {}
        Ok(Some(Err(e))) => return Err(e.into()),
        Ok(None) | Err(_) => {
            return Err(RemoteError::Input(format!(
                "GET /api/events of {} sent nothing for {} s; is it a stagehand daemon?",
                client.base(),
                FIRST_EVENT.as_secs()
            )));
        }
    }
    let interrupts = tokio::signal::unix::signal(SignalKind::interrupt())
        .map_err(|e| RemoteError::Input(format!("cannot catch Ctrl-C: {e}")))?;
    let start = StartRun {
        script: name,
        set: Some(set),
        seed: args.seed,
    };
    let started = client.start_run(&start).await?;
    let run_id = started.run_id;
    eprintln!("run {run_id} started on {}", client.base());

    let mut follow = Follower::new(client, run_id, args.yes, events, interrupts);
    let status = follow.run().await?;
    follow.bar.finish_and_clear();
    report(&follow.client, &follow.run_id, status).await;
    Ok(if status == StoredStatus::Done { 0 } else { 1 })
}

/// What the follower waits for.
enum Input {
    /// The next event, an error, or the end of the stream.
    Event(Option<Result<DaemonEvent, ClientError>>),
    /// The operator's next line (`None`: stdin closed).
    Line(Option<String>),
    Interrupt,
    /// Nothing happened for [`QUIET_CHECK`].
    Quiet,
}

/// The progress bar and prompt state of the followed run.
struct Follower {
    client: Client,
    run_id: String,
    yes: bool,
    events: EventStream,
    interrupts: Signal,
    /// The operator's lines, read from the first prompt on.
    stdin: Option<mpsc::UnboundedReceiver<String>>,
    bar: ProgressBar,
    frames: u64,
    /// The step of the prompt waiting for the operator's line.
    prompt: Option<usize>,
    interrupted: bool,
}

/// The next line of `stdin`, never while it is not read.
async fn next_line(stdin: &mut Option<mpsc::UnboundedReceiver<String>>) -> Option<String> {
    match stdin {
        Some(lines) => lines.recv().await,
        None => std::future::pending().await,
    }
}

/// The operator's lines, read on a thread of their own (a blocking read of the terminal
/// cannot be cancelled; the thread ends with the process). The channel closes at the end of
/// stdin.
fn read_stdin() -> mpsc::UnboundedReceiver<String> {
    let (tx, rx) = mpsc::unbounded_channel();
    std::thread::spawn(move || {
        for line in std::io::stdin().lines() {
            let Ok(line) = line else { return };
            if tx.send(line).is_err() {
                return;
            }
        }
    });
    rx
}

impl Follower {
    fn new(
        client: Client,
        run_id: String,
        yes: bool,
        events: EventStream,
        interrupts: Signal,
    ) -> Self {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr_with_hz(5));
        let style = ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} steps  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        Follower {
            client,
            run_id,
            yes,
            events,
            interrupts,
            stdin: None,
            bar,
            frames: 0,
            prompt: None,
            interrupted: false,
        }
    }

    /// Prints a line above the bar (on stderr directly when the bar is hidden, e.g. not a
    /// terminal, where indicatif would drop it).
    fn say(&self, line: impl Into<String>) {
        let line = line.into();
        if self.bar.is_hidden() {
            eprintln!("{line}");
        } else {
            self.bar.println(line);
        }
    }

    fn ours(&self, run_id: &str) -> bool {
        run_id == self.run_id
    }

    /// Follows the run until it ends; returns its final status.
    async fn run(&mut self) -> Result<StoredStatus, RemoteError> {
        let mut failures = 0;
        loop {
            let input = tokio::select! {
                ev = self.events.next() => Input::Event(ev),
                line = next_line(&mut self.stdin) => Input::Line(line),
                _ = self.interrupts.recv() => Input::Interrupt,
                () = tokio::time::sleep(QUIET_CHECK) => Input::Quiet,
            };
            match input {
                Input::Event(Some(Ok(ev))) => {
                    failures = 0;
                    if let Some(status) = self.on_event(ev).await? {
                        return Ok(status);
                    }
                }
                // One event this client cannot read: say so, follow the rest.
                Input::Event(Some(Err(e @ ClientError::Decode { .. }))) => {
                    self.say(format!("warning: {e}"));
                }
                Input::Event(broken) => {
                    let reason = match broken {
                        Some(Err(e)) => e.to_string(),
                        _ => "the daemon closed the stream".to_string(),
                    };
                    failures += 1;
                    self.reconnect(reason, &mut failures).await?;
                }
                Input::Line(Some(line)) => self.on_line(&line).await?,
                Input::Line(None) => {
                    self.stdin = None;
                    if self.prompt.is_some() {
                        self.answer(PromptAnswer::Abort).await?;
                    }
                }
                Input::Interrupt => self.on_interrupt().await?,
                // Quiet for a while: make sure the run's end was not among lost events.
                Input::Quiet => {
                    if let Some(status) = self.ended_unseen().await? {
                        return Ok(status);
                    }
                }
            }
        }
    }

    /// Reopens the event stream after it broke, from the last event seen (a new stream
    /// replays what was missed or starts with a `resync`, so nothing is lost for good).
    async fn reconnect(
        &mut self,
        mut reason: String,
        failures: &mut u32,
    ) -> Result<(), RemoteError> {
        loop {
            if *failures > RECONNECTS {
                return Err(RemoteError::Lost {
                    url: self.client.base().to_string(),
                    run_id: self.run_id.clone(),
                    reason,
                });
            }
            tracing::debug!("event stream: {reason}; reconnecting");
            tokio::time::sleep(Duration::from_secs(1)).await;
            match self.client.events(self.events.last_event_id()).await {
                Ok(events) => {
                    self.events = events;
                    return Ok(());
                }
                Err(e) => {
                    reason = e.to_string();
                    *failures += 1;
                }
            }
        }
    }

    async fn on_interrupt(&mut self) -> Result<(), RemoteError> {
        if self.interrupted {
            self.bar.abandon();
            eprintln!(
                "second interrupt: leaving; the daemon finishes aborting run {}",
                self.run_id
            );
            std::process::exit(1);
        }
        self.interrupted = true;
        self.say("interrupt: aborting the run on the daemon (lamps and laser off, axes stopped)…");
        match self.client.abort(&self.run_id).await {
            Ok(_) => Ok(()),
            Err(e @ (ClientError::Rejected { .. } | ClientError::Server { .. })) => {
                self.say(format!("the daemon did not take the abort: {e}"));
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    }

    /// Handles one event; `Some(status)` when the run has ended.
    async fn on_event(&mut self, ev: DaemonEvent) -> Result<Option<StoredStatus>, RemoteError> {
        match ev {
            DaemonEvent::Resync(status) => return self.on_resync(status.run).await,
            DaemonEvent::Warning(w) => self.say(format!("warning: {}", w.message)),
            DaemonEvent::Prompt(p) => {
                if self.ours(&p.run_id) {
                    self.on_prompt(p).await?;
                }
            }
            DaemonEvent::Run(r) => {
                if self.ours(&r.run_id) {
                    return Ok(self.on_run_event(r.event));
                }
            }
            DaemonEvent::Other(hub) => {
                if hub.kind == EventKind::Estop {
                    self.say(format!("E-STOP: {}", show(&hub.data)));
                }
            }
        }
        Ok(None)
    }

    fn on_run_event(&mut self, event: Event) -> Option<StoredStatus> {
        match event {
            Event::RunStarted {
                total_steps,
                steps_to_do,
                ..
            } => {
                self.bar.set_length(total_steps as u64);
                self.bar
                    .set_position(total_steps.saturating_sub(steps_to_do) as u64);
            }
            Event::StepFinished {
                step,
                frames,
                rig_time_s,
                total_steps,
                eta_s,
                ..
            } => {
                self.frames += frames as u64;
                self.bar.set_length(total_steps as u64);
                self.bar.set_position(step as u64 + 1);
                self.bar.set_message(format!(
                    "{} raw frames  rig time {}  ETA {}",
                    self.frames,
                    hms(rig_time_s),
                    hms(eta_s)
                ));
            }
            Event::Warning { message } => self.say(format!("warning: {message}")),
            Event::DeviceFault {
                step,
                message,
                attempt,
                ..
            } => self.say(format!(
                "paused at step {step} (fault {attempt}): {message}; reconnecting and re-homing"
            )),
            Event::Recovered { step, device } => {
                self.say(format!("{device} recovered; running step {step} again"))
            }
            Event::Paused { before_step } => self.say(format!("paused before step {before_step}")),
            Event::Resumed { .. } => self.say("resumed"),
            Event::RunFinished {
                status, message, ..
            } => {
                if let Some(m) = message {
                    self.say(m);
                }
                return Some(status.into());
            }
            Event::StepStarted { .. } | Event::StepDurable { .. } | Event::Prompt { .. } => {}
        }
        None
    }

    /// A `resync` (the stream's first event, or after falling behind): the whole status.
    async fn on_resync(
        &mut self,
        run: Option<RunState>,
    ) -> Result<Option<StoredStatus>, RemoteError> {
        let Some(run) = run.filter(|r| self.ours(&r.run_id)) else {
            // Our run is no longer active: it ended while this client was behind.
            return self.final_status().await.map(Some);
        };
        self.bar.set_length(run.total_steps as u64);
        self.bar.set_position(run.steps_done as u64);
        self.frames = run.frames_written as u64;
        if let Some(p) = run.prompt
            && self.prompt.is_none()
        {
            self.on_prompt(PromptEvent {
                run_id: self.run_id.clone(),
                step: p.step,
                message: Some(p.message),
                answered: None,
            })
            .await?;
        }
        Ok(None)
    }

    /// `Some(final status)` if the run is no longer active (its end was not seen).
    async fn ended_unseen(&self) -> Result<Option<StoredStatus>, RemoteError> {
        let active = self.client.active_run().await?;
        if active.is_some_and(|r| self.ours(&r.run_id)) {
            Ok(None)
        } else {
            self.final_status().await.map(Some)
        }
    }

    /// The status of the run from `GET /api/runs/{id}` (after it ended unseen).
    async fn final_status(&self) -> Result<StoredStatus, RemoteError> {
        Ok(self.client.run(&self.run_id).await?.run.status)
    }

    async fn on_prompt(&mut self, p: PromptEvent) -> Result<(), RemoteError> {
        let step = p.step;
        if let Some(answered) = p.answered {
            if self.prompt == Some(step) {
                self.prompt = None;
                self.bar
                    .set_draw_target(ProgressDrawTarget::stderr_with_hz(5));
                let answered = match answered {
                    PromptAnswer::Continue => "continue",
                    PromptAnswer::Abort => "abort",
                };
                eprintln!("   answered elsewhere: {answered}");
            }
            return Ok(());
        }
        let message = p.message.unwrap_or_default();
        if self.yes {
            self.say(format!(
                "operator, step {step}: {message} (confirmed by -y)"
            ));
            self.prompt = Some(step);
            return self.answer(PromptAnswer::Continue).await;
        }
        // Hide the bar while the operator reads and types.
        self.bar.set_draw_target(ProgressDrawTarget::hidden());
        eprintln!("\n── operator, step {step}: {message}");
        eprintln!("   press Enter when done, or type `abort` and Enter to stop the run safely");
        self.prompt = Some(step);
        if self.stdin.is_none() {
            self.stdin = Some(read_stdin());
        }
        Ok(())
    }

    async fn on_line(&mut self, line: &str) -> Result<(), RemoteError> {
        if self.prompt.is_none() {
            return Ok(());
        }
        let answer = if line.trim().eq_ignore_ascii_case("abort") {
            PromptAnswer::Abort
        } else {
            PromptAnswer::Continue
        };
        self.answer(answer).await
    }

    async fn answer(&mut self, answer: PromptAnswer) -> Result<(), RemoteError> {
        self.prompt = None;
        self.bar
            .set_draw_target(ProgressDrawTarget::stderr_with_hz(5));
        match self.client.answer_prompt(&self.run_id, answer).await {
            Ok(_) => Ok(()),
            // Most likely answered from the dashboard first.
            Err(e @ (ClientError::Rejected { .. } | ClientError::Server { .. })) => {
                self.say(format!("the daemon did not take the answer: {e}"));
                Ok(())
            }
            Err(e) => Err(e.into()),
        }
    }
}

/// Prints the run's summary from `GET /api/runs/{id}`, like a local run's report.
async fn report(client: &Client, run_id: &str, status: StoredStatus) {
    println!("run {status}: {run_id} on {}", client.base());
    match client.run(run_id).await {
        Ok(r) => println!(
            "  steps {}/{}, frames {}",
            r.run.steps_done, r.run.steps_total, r.run.frames
        ),
        Err(e) => eprintln!("  (no summary: {e})"),
    }
    println!(
        "  frames: GET {}/api/runs/{run_id}/frames (or the dashboard)",
        client.base()
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_are_made_from_file_names() -> Result<(), RemoteError> {
        assert_eq!(
            script_name(std::path::Path::new("a/my scan.v2.rhai"))?,
            "my_scan_v2"
        );
        assert_eq!(
            script_name(std::path::Path::new("quickstart.rhai"))?,
            "quickstart"
        );
        assert!(script_name(std::path::Path::new("/")).is_err());
        Ok(())
    }

    #[test]
    fn refusals_and_bad_urls_exit_2_other_failures_1() {
        let refused = RemoteError::Client(ClientError::Rejected {
            endpoint: "POST /api/runs".into(),
            status: 409,
            body: crate::client::ErrorBody {
                error: "a run is active".into(),
                hint: None,
                violations: Vec::new(),
            },
        });
        assert_eq!(refused.exit_code(), 2);
        let Err(bad_url) = Client::new("https://lab", None) else {
            panic!("an https URL was taken");
        };
        assert_eq!(RemoteError::from(bad_url).exit_code(), 2);
        let failed = RemoteError::Client(ClientError::Server {
            endpoint: "GET /api/status".into(),
            status: 500,
            body: String::new(),
        });
        assert_eq!(failed.exit_code(), 1);
    }
}
