//! `stagehand run --remote URL`: runs a script on a running daemon instead of opening the rig
//! here (the daemon owns the devices). Uploads the script, starts the run, follows the live
//! events (SSE) with the same progress bar as a local run, answers prompts from the terminal
//! (or automatically with `-y`) and aborts on Ctrl-C. Exit codes as for a local run: 0 done,
//! 1 failed or aborted, 2 bad input (the daemon said 4xx, or it cannot be reached).

use std::io::{BufRead, BufReader, Read};
use std::path::PathBuf;
use std::sync::mpsc;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::Deserialize;
use serde_json::{Value, json};

use crate::units::hms;

/// How long the event stream may stay quiet before the client checks the run is still active
/// (its `run_finished` event may have been lost by a client that fell behind).
const QUIET_CHECK: Duration = Duration::from_secs(5);

/// The environment variable holding the API token when `--token` is not given.
pub const TOKEN_ENV: &str = "STAGEHAND_TOKEN";

/// What `run --remote` needs.
#[derive(Debug, Clone)]
pub struct RemoteRun {
    /// The daemon's base URL, e.g. `http://127.0.0.1:8080`.
    pub url: String,
    /// `--token`; `$STAGEHAND_TOKEN` otherwise.
    pub token: Option<String>,
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
    /// Bad arguments (no token, unreadable script, malformed `--set`, unusable URL).
    #[error("{0}")]
    Input(String),
    /// Nothing listens at the URL (or the network is in the way).
    #[error(
        "cannot reach the daemon at {url}: {reason}; is `stagehand serve` running there? (check the URL and port)"
    )]
    Unreachable { url: String, reason: String },
    /// The daemon refused the request (4xx): what it said and what to do.
    #[error("{}", rejected(*.status, .error, .hint.as_deref()))]
    Rejected {
        status: u16,
        error: String,
        hint: Option<String>,
    },
    /// The script or its plan has errors (the daemon's dry run says where).
    #[error(
        "{0}\n  nothing was started; fix the script and run again (`stagehand plan` shows the same locally)"
    )]
    Invalid(String),
    /// The daemon failed (5xx) or answered something this client does not understand.
    #[error("the daemon at {url}: {message}")]
    Server { url: String, message: String },
    /// The event stream broke during the run and could not be reopened.
    #[error(
        "lost the event stream of {url} during run {run_id}: {reason}; the run continues on the daemon (see its dashboard)"
    )]
    Lost {
        url: String,
        run_id: String,
        reason: String,
    },
}

fn rejected(status: u16, error: &str, hint: Option<&str>) -> String {
    match hint {
        Some(h) => format!("the daemon refused ({status}): {error}\n  hint: {h}"),
        None => format!("the daemon refused ({status}): {error}"),
    }
}

impl RemoteError {
    /// 2 when nothing started (bad input, refused, unreachable), 1 otherwise.
    pub fn exit_code(&self) -> i32 {
        match self {
            RemoteError::Input(_) | RemoteError::Unreachable { .. } => 2,
            RemoteError::Rejected { .. } | RemoteError::Invalid(_) => 2,
            RemoteError::Server { .. } | RemoteError::Lost { .. } => 1,
        }
    }
}

/// Runs `args` on the daemon and returns the process exit code (errors are printed).
pub fn run(args: RemoteRun) -> i32 {
    match run_remote(args) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e}");
            e.exit_code()
        }
    }
}

/// The daemon's base URL: `http://` added when missing, no trailing slash.
pub fn normalise_url(url: &str) -> Result<String, RemoteError> {
    let url = url.trim().trim_end_matches('/');
    if url.is_empty() {
        return Err(RemoteError::Input("--remote needs the daemon's URL".into()));
    }
    if url.starts_with("https://") {
        return Err(RemoteError::Input(format!(
            "{url}: this client speaks plain HTTP (the daemon serves loopback or the lab LAN); use http:// or an SSH tunnel"
        )));
    }
    if url.starts_with("http://") {
        Ok(url.to_string())
    } else if url.contains("://") {
        Err(RemoteError::Input(format!(
            "{url}: only http:// URLs are supported"
        )))
    } else {
        Ok(format!("http://{url}"))
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

/// A small blocking client of the daemon's API.
struct Client {
    agent: ureq::Agent,
    base: String,
    auth: String,
}

/// A response: status and body text.
struct Reply {
    status: u16,
    body: String,
}

impl Reply {
    fn json<T: serde::de::DeserializeOwned>(&self, url: &str) -> Result<T, RemoteError> {
        serde_json::from_str(&self.body).map_err(|e| RemoteError::Server {
            url: url.to_string(),
            message: format!("unexpected answer ({e}): {}", excerpt(&self.body)),
        })
    }
}

/// The JSON error body of the API.
#[derive(Debug, Default, Deserialize)]
struct ErrorJson {
    #[serde(default)]
    error: String,
    #[serde(default)]
    hint: Option<String>,
}

fn excerpt(text: &str) -> String {
    let t: String = text.chars().take(300).collect();
    if t.len() < text.len() {
        format!("{t}…")
    } else {
        t
    }
}

impl Client {
    fn new(base: String, token: &str) -> Client {
        let agent = ureq::Agent::config_builder()
            .http_status_as_error(false)
            .timeout_connect(Some(Duration::from_secs(5)))
            .timeout_global(Some(Duration::from_secs(120)))
            .build()
            .new_agent();
        Client {
            agent,
            base,
            auth: format!("Bearer {token}"),
        }
    }

    fn url(&self, path: &str) -> String {
        format!("{}{path}", self.base)
    }

    fn transport_error(&self, e: ureq::Error) -> RemoteError {
        RemoteError::Unreachable {
            url: self.base.clone(),
            reason: e.to_string(),
        }
    }

    fn finish(
        &self,
        r: Result<ureq::http::Response<ureq::Body>, ureq::Error>,
    ) -> Result<Reply, RemoteError> {
        let mut resp = r.map_err(|e| self.transport_error(e))?;
        let status = resp.status().as_u16();
        let body = resp
            .body_mut()
            .read_to_string()
            .map_err(|e| self.transport_error(e))?;
        Ok(Reply { status, body })
    }

    fn get(&self, path: &str) -> Result<Reply, RemoteError> {
        let r = self
            .agent
            .get(self.url(path))
            .header("Authorization", &self.auth)
            .call();
        self.finish(r)
    }

    fn post(&self, path: &str, body: &Value) -> Result<Reply, RemoteError> {
        let r = self
            .agent
            .post(self.url(path))
            .header("Authorization", &self.auth)
            .send_json(body);
        self.finish(r)
    }

    fn put_text(&self, path: &str, text: &str) -> Result<Reply, RemoteError> {
        let r = self
            .agent
            .put(self.url(path))
            .header("Authorization", &self.auth)
            .content_type("text/plain; charset=utf-8")
            .send(text);
        self.finish(r)
    }

    /// `Ok` for 2xx; a 4xx is [`RemoteError::Rejected`], anything else a server error.
    fn check(&self, reply: Reply) -> Result<Reply, RemoteError> {
        match reply.status {
            200..=299 => Ok(reply),
            400..=499 => {
                let e: ErrorJson =
                    serde_json::from_str(&reply.body).unwrap_or_else(|_| ErrorJson {
                        error: excerpt(&reply.body),
                        hint: None,
                    });
                Err(RemoteError::Rejected {
                    status: reply.status,
                    error: e.error,
                    hint: e.hint,
                })
            }
            s => Err(RemoteError::Server {
                url: self.base.clone(),
                message: format!("{s}: {}", excerpt(&reply.body)),
            }),
        }
    }

    /// Opens the SSE stream (no overall timeout: it lasts as long as the run).
    fn events(&self) -> Result<Box<dyn Read + Send>, RemoteError> {
        let resp = self
            .agent
            .get(self.url("/api/events"))
            .header("Authorization", &self.auth)
            .header("Accept", "text/event-stream")
            .config()
            .timeout_global(None)
            .build()
            .call()
            .map_err(|e| self.transport_error(e))?;
        let reply_status = resp.status().as_u16();
        if reply_status != 200 {
            let mut resp = resp;
            let body = resp.body_mut().read_to_string().unwrap_or_default();
            return Err(self
                .check(Reply {
                    status: reply_status,
                    body,
                })
                .err()
                .unwrap_or_else(|| RemoteError::Server {
                    url: self.base.clone(),
                    message: format!("/api/events answered {reply_status}"),
                }));
        }
        Ok(Box::new(resp.into_body().into_reader()))
    }
}

/// One Server-Sent Event.
#[derive(Debug, Clone, PartialEq)]
pub struct SseEvent {
    /// The `event:` name (`message` when absent).
    pub name: String,
    /// The `data:` lines joined with newlines.
    pub data: String,
}

/// Incremental SSE parser: feed it lines (without their line ending), get events at blank
/// lines. Comments (`:` keep-alives), `id:` and `retry:` are skipped.
#[derive(Debug, Default)]
pub struct SseParser {
    name: Option<String>,
    data: Vec<String>,
}

impl SseParser {
    /// Takes one line; returns the event it completes, if any.
    pub fn push_line(&mut self, line: &str) -> Option<SseEvent> {
        let line = line.strip_suffix('\r').unwrap_or(line);
        if line.is_empty() {
            let name = self.name.take();
            if self.data.is_empty() {
                return None;
            }
            let data = std::mem::take(&mut self.data).join("\n");
            return Some(SseEvent {
                name: name.unwrap_or_else(|| "message".into()),
                data,
            });
        }
        if line.starts_with(':') {
            return None;
        }
        let (field, value) = match line.split_once(':') {
            Some((f, v)) => (f, v.strip_prefix(' ').unwrap_or(v)),
            None => (line, ""),
        };
        match field {
            "event" => self.name = Some(value.to_string()),
            "data" => self.data.push(value.to_string()),
            _ => {}
        }
        None
    }
}

/// What the main loop waits for.
enum Input {
    Event(SseEvent),
    /// The stream broke and reconnecting failed.
    Lost(String),
    Line(String),
    StdinClosed,
    Interrupt,
}

/// Follows `/api/events` on a thread, reconnecting a few times if the stream breaks (each new
/// stream starts with a `resync` carrying the whole state, so nothing is lost for good).
fn follow_events(client: Client, tx: mpsc::Sender<Input>) {
    std::thread::spawn(move || {
        let mut failures = 0;
        loop {
            let reason = match client.events() {
                Ok(stream) => {
                    let mut parser = SseParser::default();
                    let mut reader = BufReader::new(stream);
                    let mut line = String::new();
                    loop {
                        line.clear();
                        match reader.read_line(&mut line) {
                            Ok(0) => break "the daemon closed the stream".to_string(),
                            Ok(_) => {
                                failures = 0;
                                let l = line.strip_suffix('\n').unwrap_or(&line);
                                if let Some(ev) = parser.push_line(l)
                                    && tx.send(Input::Event(ev)).is_err()
                                {
                                    return;
                                }
                            }
                            Err(e) => break e.to_string(),
                        }
                    }
                }
                Err(e) => e.to_string(),
            };
            failures += 1;
            if failures > 5 {
                let _ = tx.send(Input::Lost(reason));
                return;
            }
            tracing::debug!("event stream: {reason}; reconnecting");
            std::thread::sleep(Duration::from_secs(1));
        }
    });
}

/// Reads the operator's lines on a thread (started at the first prompt).
fn read_stdin(tx: mpsc::Sender<Input>) {
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        let mut line = String::new();
        loop {
            line.clear();
            match stdin.lock().read_line(&mut line) {
                Ok(0) | Err(_) => {
                    let _ = tx.send(Input::StdinClosed);
                    return;
                }
                Ok(_) => {
                    if tx.send(Input::Line(line.trim().to_string())).is_err() {
                        return;
                    }
                }
            }
        }
    });
}

/// Sends [`Input::Interrupt`] at every Ctrl-C.
fn catch_interrupts(tx: mpsc::Sender<Input>) {
    std::thread::spawn(move || {
        let Ok(rt) = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
        else {
            return;
        };
        rt.block_on(async move {
            while tokio::signal::ctrl_c().await.is_ok() {
                if tx.send(Input::Interrupt).is_err() {
                    return;
                }
            }
        });
    });
}

/// The dry run the daemon answers to an upload or a validation.
#[derive(Debug, Default, Deserialize)]
struct DryRun {
    #[serde(default)]
    ok: bool,
    #[serde(default)]
    steps: usize,
    #[serde(default)]
    estimate: Value,
    #[serde(default)]
    violations: Vec<ViolationJson>,
    #[serde(default)]
    error: Option<String>,
    #[serde(default)]
    report: String,
}

#[derive(Debug, Default, Deserialize)]
struct ViolationJson {
    #[serde(default)]
    severity: String,
    #[serde(default)]
    line: Value,
    #[serde(default)]
    col: Value,
    #[serde(default)]
    step: Value,
    #[serde(default)]
    message: String,
}

fn show(v: &Value) -> String {
    match v {
        Value::Null => "?".into(),
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

impl DryRun {
    fn print_violations(&self, script: &str, severity: &str) {
        for v in self.violations.iter().filter(|v| v.severity == severity) {
            eprintln!(
                "{script}:{}:{}: {severity}: {} (step {})",
                show(&v.line),
                show(&v.col),
                v.message,
                show(&v.step)
            );
        }
    }

    /// Prints what is wrong and returns the refusal, or prints the warnings and a summary.
    fn check(&self, script: &str) -> Result<(), RemoteError> {
        if let Some(e) = &self.error {
            return Err(RemoteError::Invalid(e.clone()));
        }
        if !self.ok {
            if self.report.is_empty() {
                self.print_violations(script, "error");
            } else {
                eprintln!("{}", self.report.trim_end());
            }
            return Err(RemoteError::Invalid(format!(
                "the plan of {script} has errors (listed above)"
            )));
        }
        self.print_violations(script, "warning");
        let est = &self.estimate;
        let rig_s = est.get("rig_time_s").and_then(Value::as_f64);
        let frames = est.get("frames").and_then(Value::as_u64);
        let bytes = est.get("bytes").and_then(Value::as_u64);
        eprintln!(
            "{script}: {} steps, estimated rig time {}, {} frames, {}",
            self.steps,
            rig_s.map(hms).unwrap_or_else(|| "?".into()),
            frames.map(|f| f.to_string()).unwrap_or_else(|| "?".into()),
            bytes
                .map(crate::units::human_bytes)
                .unwrap_or_else(|| "? bytes".into())
        );
        Ok(())
    }
}

/// Reads a dry-run answer: a 2xx DryRun, or a 4xx that may itself be a DryRun (errors) or an
/// error body.
fn dry_run_of(client: &Client, reply: Reply, script: &str) -> Result<(), RemoteError> {
    if (400..500).contains(&reply.status)
        && let Ok(dr) = serde_json::from_str::<DryRun>(&reply.body)
        && (!dr.report.is_empty() || !dr.violations.is_empty())
    {
        return dr
            .check(script)
            .and_then(|()| client.check(reply).map(|_| ()));
    }
    let reply = client.check(reply)?;
    let dr: DryRun = reply.json(&client.base)?;
    dr.check(script)
}

/// Puts the script in the daemon's library and returns the name it has there and whether
/// its dry run was checked already. The same text already there (e.g. a built-in sequence)
/// is used as is; a built-in of the same name with other text makes the upload go under
/// `NAME-<hash>` instead.
fn upload(
    client: &Client,
    path: &std::path::Path,
    name: String,
    text: &str,
) -> Result<(String, bool), RemoteError> {
    let existing = client.get(&format!("/api/scripts/{name}"))?;
    if matches!(existing.status, 401 | 403) {
        return client.check(existing).map(|_| (name, false));
    }
    if existing.status == 200 && existing.body == text {
        eprintln!("`{name}` on {} is this script already", client.base);
        return Ok((name, false));
    }
    eprintln!(
        "uploading {} to {} as `{name}`",
        path.display(),
        client.base
    );
    let reply = client.put_text(&format!("/api/scripts/{name}"), text)?;
    if reply.status != 409 {
        dry_run_of(client, reply, &name)?;
        return Ok((name, true));
    }
    let digest = crate::storage::checksum::sha256_hex(text.as_bytes());
    let other = format!("{name}-{}", &digest[..8.min(digest.len())]);
    eprintln!("`{name}` is taken by a different script on the daemon; uploading as `{other}`");
    let reply = client.put_text(&format!("/api/scripts/{other}"), text)?;
    dry_run_of(client, reply, &other)?;
    Ok((other, true))
}

/// The `--set` overrides as the JSON object the API takes.
fn set_object(set: &[String]) -> Result<serde_json::Map<String, Value>, RemoteError> {
    set.iter()
        .map(|s| {
            crate::script::parse_set(s)
                .map(|(k, v)| (k, Value::String(v)))
                .map_err(|e| RemoteError::Input(e.to_string()))
        })
        .collect()
}

/// The whole remote run; returns the exit code.
fn run_remote(args: RemoteRun) -> Result<i32, RemoteError> {
    let base = normalise_url(&args.url)?;
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
    let client = Client::new(base.clone(), token.trim());

    let (name, validated) = upload(&client, &args.script, name, &text)?;
    if !validated || !set.is_empty() {
        let reply = client.post(
            &format!("/api/scripts/{name}/validate"),
            &json!({ "set": set }),
        )?;
        dry_run_of(&client, reply, &name)?;
    }

    // Subscribe before starting so no event of the run is missed: the stream's first event
    // is a `resync`.
    let (tx, rx) = mpsc::channel::<Input>();
    follow_events(Client::new(base.clone(), token.trim()), tx.clone());
    match rx.recv_timeout(Duration::from_secs(10)) {
        Ok(Input::Event(_)) => {}
        Ok(Input::Lost(reason)) => {
            return Err(RemoteError::Unreachable {
                url: base,
                reason: format!("/api/events: {reason}"),
            });
        }
        _ => {
            return Err(RemoteError::Server {
                url: base,
                message: "/api/events sent nothing for 10 s".into(),
            });
        }
    }
    catch_interrupts(tx.clone());
    let mut start = json!({ "script": name, "set": set });
    if let Some(seed) = args.seed {
        start["seed"] = json!(seed);
    }
    let reply = client.post("/api/runs", &start)?;
    let reply = client.check(reply)?;
    let started: Value = reply.json(&base)?;
    let run_id = started
        .get("run_id")
        .and_then(Value::as_str)
        .ok_or_else(|| RemoteError::Server {
            url: base.clone(),
            message: format!(
                "POST /api/runs answered no run_id: {}",
                excerpt(&reply.body)
            ),
        })?
        .to_string();
    eprintln!("run {run_id} started on {base}");

    let mut follow = Follower::new(&client, run_id.clone(), args.yes, tx);
    let status = follow.run(&rx)?;
    follow.bar.finish_and_clear();
    report(&client, &run_id, &status);
    Ok(if status == "done" { 0 } else { 1 })
}

/// The progress bar and prompt state of the followed run.
struct Follower<'a> {
    client: &'a Client,
    run_id: String,
    yes: bool,
    tx: mpsc::Sender<Input>,
    bar: ProgressBar,
    frames: u64,
    /// The step of the prompt waiting for the operator's line.
    prompt: Option<u64>,
    stdin_started: bool,
    interrupted: bool,
}

impl<'a> Follower<'a> {
    fn new(client: &'a Client, run_id: String, yes: bool, tx: mpsc::Sender<Input>) -> Self {
        let bar = ProgressBar::with_draw_target(Some(0), ProgressDrawTarget::stderr_with_hz(5));
        let style = ProgressStyle::with_template("{bar:30.cyan/blue} {pos}/{len} steps  {msg}")
            .unwrap_or_else(|_| ProgressStyle::default_bar());
        bar.set_style(style);
        Follower {
            client,
            run_id,
            yes,
            tx,
            bar,
            frames: 0,
            prompt: None,
            stdin_started: false,
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

    fn ours(&self, data: &Value) -> bool {
        data.get("run_id").and_then(Value::as_str) == Some(self.run_id.as_str())
    }

    /// Follows the run until it ends; returns its final status.
    fn run(&mut self, rx: &mpsc::Receiver<Input>) -> Result<String, RemoteError> {
        loop {
            let input = match rx.recv_timeout(QUIET_CHECK) {
                Ok(input) => input,
                // Quiet for a while: make sure the run's end was not among lost events.
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    if let Some(status) = self.ended_unseen()? {
                        return Ok(status);
                    }
                    continue;
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => {
                    return Err(self.lost("the event thread stopped".into()));
                }
            };
            match input {
                Input::Event(ev) => {
                    if let Some(status) = self.on_event(&ev)? {
                        return Ok(status);
                    }
                }
                Input::Lost(reason) => return Err(self.lost(reason)),
                Input::Line(line) => self.on_line(&line)?,
                Input::StdinClosed => {
                    if self.prompt.is_some() {
                        self.answer("abort")?;
                    }
                }
                Input::Interrupt => self.on_interrupt()?,
            }
        }
    }

    fn lost(&self, reason: String) -> RemoteError {
        RemoteError::Lost {
            url: self.client.base.clone(),
            run_id: self.run_id.clone(),
            reason,
        }
    }

    fn on_interrupt(&mut self) -> Result<(), RemoteError> {
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
        let reply = self
            .client
            .post(&format!("/api/runs/{}/abort", self.run_id), &json!({}))?;
        if !(200..300).contains(&reply.status) {
            self.say(format!(
                "the daemon did not take the abort ({}): {}",
                reply.status,
                excerpt(&reply.body)
            ));
        }
        Ok(())
    }

    /// Handles one event; `Some(status)` when the run has ended.
    fn on_event(&mut self, ev: &SseEvent) -> Result<Option<String>, RemoteError> {
        let Ok(hub) = serde_json::from_str::<Value>(&ev.data) else {
            return Ok(None);
        };
        match ev.name.as_str() {
            "resync" => return self.on_resync(&hub),
            "estop" => self.say(format!(
                "E-STOP: {}",
                hub.get("data").map(show).unwrap_or_default()
            )),
            "warning" => {
                let data = hub.get("data").cloned().unwrap_or(Value::Null);
                let msg = data.get("message").map(show).unwrap_or_else(|| show(&data));
                self.say(format!("warning: {msg}"));
            }
            "prompt" => {
                let data = hub.get("data").cloned().unwrap_or(Value::Null);
                if self.ours(&data) {
                    self.on_prompt(&data)?;
                }
            }
            "run" => {
                let data = hub.get("data").cloned().unwrap_or(Value::Null);
                if self.ours(&data) {
                    return Ok(self.on_run_event(&data));
                }
            }
            _ => {}
        }
        Ok(None)
    }

    fn on_run_event(&mut self, data: &Value) -> Option<String> {
        let u = |k: &str| data.get(k).and_then(Value::as_u64).unwrap_or(0);
        let f = |k: &str| data.get(k).and_then(Value::as_f64).unwrap_or(0.0);
        let s = |k: &str| data.get(k).map(show).unwrap_or_default();
        match data.get("event").and_then(Value::as_str).unwrap_or("") {
            "run_started" => {
                self.bar.set_length(u("total_steps"));
                self.bar
                    .set_position(u("total_steps").saturating_sub(u("steps_to_do")));
            }
            "step_finished" => {
                self.frames += u("frames");
                self.bar.set_length(u("total_steps"));
                self.bar.set_position(u("step") + 1);
                self.bar.set_message(format!(
                    "{} raw frames  rig time {}  ETA {}",
                    self.frames,
                    hms(f("rig_time_s")),
                    hms(f("eta_s"))
                ));
            }
            "warning" => self.say(format!("warning: {}", s("message"))),
            "device_fault" => self.say(format!(
                "paused at step {} (fault {}): {}; reconnecting and re-homing",
                s("step"),
                s("attempt"),
                s("message")
            )),
            "recovered" => self.say(format!(
                "{} recovered; running step {} again",
                s("device"),
                s("step")
            )),
            "paused" => self.say(format!("paused before step {}", s("before_step"))),
            "resumed" => self.say("resumed"),
            "run_finished" => {
                if let Some(m) = data.get("message").and_then(Value::as_str) {
                    self.say(m.to_string());
                }
                return Some(s("status"));
            }
            _ => {}
        }
        None
    }

    /// A `resync` (the stream's first event, or after falling behind): the whole status.
    fn on_resync(&mut self, status: &Value) -> Result<Option<String>, RemoteError> {
        let run = status.get("run").cloned().unwrap_or(Value::Null);
        if !self.ours(&run) {
            // Our run is no longer active: it ended while this client was behind.
            return self.final_status().map(Some);
        }
        let u = |k: &str| run.get(k).and_then(Value::as_u64).unwrap_or(0);
        self.bar.set_length(u("total_steps"));
        self.bar.set_position(u("steps_done"));
        self.frames = u("frames_written");
        if let Some(p) = run.get("prompt").filter(|p| !p.is_null())
            && self.prompt.is_none()
        {
            let mut p = p.clone();
            if let Some(o) = p.as_object_mut() {
                o.insert("run_id".into(), Value::String(self.run_id.clone()));
            }
            self.on_prompt(&p)?;
        }
        Ok(None)
    }

    /// `Some(final status)` if the run is no longer active (its end was not seen).
    fn ended_unseen(&self) -> Result<Option<String>, RemoteError> {
        let reply = self.client.get("/api/status")?;
        let status: Value = self.client.check(reply)?.json(&self.client.base)?;
        let run = status.get("run").cloned().unwrap_or(Value::Null);
        if self.ours(&run) {
            Ok(None)
        } else {
            self.final_status().map(Some)
        }
    }

    /// The status of the run from `GET /api/runs/{id}` (after it ended unseen).
    fn final_status(&self) -> Result<String, RemoteError> {
        let reply = self.client.get(&format!("/api/runs/{}", self.run_id))?;
        let reply = self.client.check(reply)?;
        let v: Value = reply.json(&self.client.base)?;
        Ok(v.get("status")
            .map(show)
            .unwrap_or_else(|| "unknown".into()))
    }

    fn on_prompt(&mut self, data: &Value) -> Result<(), RemoteError> {
        let step = data.get("step").and_then(Value::as_u64).unwrap_or(0);
        if let Some(answered) = data.get("answered") {
            if self.prompt == Some(step) {
                self.prompt = None;
                self.bar
                    .set_draw_target(ProgressDrawTarget::stderr_with_hz(5));
                eprintln!("   answered elsewhere: {}", show(answered));
            }
            return Ok(());
        }
        let message = data.get("message").map(show).unwrap_or_default();
        if self.yes {
            self.say(format!(
                "operator, step {step}: {message} (confirmed by -y)"
            ));
            self.prompt = Some(step);
            return self.answer("continue");
        }
        // Hide the bar while the operator reads and types.
        self.bar.set_draw_target(ProgressDrawTarget::hidden());
        eprintln!("\n── operator, step {step}: {message}");
        eprintln!("   press Enter when done, or type `abort` and Enter to stop the run safely");
        self.prompt = Some(step);
        if !self.stdin_started {
            self.stdin_started = true;
            read_stdin(self.tx.clone());
        }
        Ok(())
    }

    fn on_line(&mut self, line: &str) -> Result<(), RemoteError> {
        if self.prompt.is_none() {
            return Ok(());
        }
        let answer = if line.eq_ignore_ascii_case("abort") {
            "abort"
        } else {
            "continue"
        };
        self.answer(answer)
    }

    fn answer(&mut self, answer: &str) -> Result<(), RemoteError> {
        self.prompt = None;
        self.bar
            .set_draw_target(ProgressDrawTarget::stderr_with_hz(5));
        let reply = self.client.post(
            &format!("/api/runs/{}/prompt", self.run_id),
            &json!({ "answer": answer }),
        )?;
        if !(200..300).contains(&reply.status) {
            // Most likely answered from the dashboard first.
            let e: ErrorJson = serde_json::from_str(&reply.body).unwrap_or_default();
            self.say(format!(
                "the daemon did not take the answer ({}): {}",
                reply.status, e.error
            ));
        }
        Ok(())
    }
}

/// Prints the run's summary from `GET /api/runs/{id}`, like a local run's report.
fn report(client: &Client, run_id: &str, status: &str) {
    println!("run {status}: {run_id} on {}", client.base);
    let Ok(reply) = client.get(&format!("/api/runs/{run_id}")) else {
        return;
    };
    let Ok(reply) = client.check(reply) else {
        return;
    };
    let Ok(v) = serde_json::from_str::<Value>(&reply.body) else {
        return;
    };
    let get = |k: &str| v.get(k).map(show).unwrap_or_else(|| "?".into());
    println!(
        "  steps {}/{}, frames {}",
        get("steps_done"),
        get("steps_total"),
        get("frames")
    );
    println!(
        "  frames: GET {}/api/runs/{run_id}/frames (or the dashboard)",
        client.base
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sse_lines_make_events() {
        let mut p = SseParser::default();
        let mut out = Vec::new();
        for l in [
            ": keep-alive",
            "event: run",
            "id: 3",
            "data: {\"a\":",
            "data: 1}",
            "",
            "",
            "data:plain\r",
            "\r",
        ] {
            out.extend(p.push_line(l));
        }
        assert_eq!(
            out,
            vec![
                SseEvent {
                    name: "run".into(),
                    data: "{\"a\":\n1}".into()
                },
                SseEvent {
                    name: "message".into(),
                    data: "plain".into()
                }
            ]
        );
    }

    #[test]
    fn urls_and_names_are_normalised() -> Result<(), RemoteError> {
        assert_eq!(normalise_url("127.0.0.1:8080/")?, "http://127.0.0.1:8080");
        assert_eq!(normalise_url("http://lab:1")?, "http://lab:1");
        assert!(normalise_url("https://lab").is_err());
        assert!(normalise_url("ftp://lab").is_err());
        assert!(normalise_url(" ").is_err());
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
    fn refusals_say_what_to_do() {
        let e = RemoteError::Rejected {
            status: 409,
            error: "a run is active".into(),
            hint: Some("abort it first".into()),
        };
        assert_eq!(e.exit_code(), 2);
        let text = e.to_string();
        assert!(
            text.contains("409") && text.contains("abort it first"),
            "{text}"
        );
        let e = RemoteError::Unreachable {
            url: "http://127.0.0.1:1".into(),
            reason: "connection refused".into(),
        };
        assert!(e.to_string().contains("http://127.0.0.1:1"));
    }
}
