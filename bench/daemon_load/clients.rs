//! The load the daemon is put under: SSE clients that follow `/api/events` (and one that
//! stalls on a raw socket with a small receive buffer), and the open-loop `GET /api/status`
//! clients.

use super::*;

// ------------------------------------------------- the stalled client's raw HTTP/1.1 socket

/// One HTTP/1.1 connection with a receive buffer set small, for the client that stalls (the
/// typed client cannot size its sockets' buffers).
pub(crate) struct Conn {
    pub(crate) io: BufReader<TcpStream>,
}

impl Conn {
    /// Sends `GET /api/events` on a socket whose receive buffer is `rcvbuf` bytes (a client
    /// that cannot keep up fills it quickly).
    async fn events(addr: SocketAddr, token: &str, rcvbuf: u32) -> Result<Conn> {
        let socket = tokio::net::TcpSocket::new_v4()?;
        socket.set_recv_buffer_size(rcvbuf)?;
        let mut stream = socket.connect(addr).await?;
        stream.set_nodelay(true)?;
        let req = format!(
            "GET /api/events HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\r\n"
        );
        stream.write_all(req.as_bytes()).await?;
        Ok(Conn {
            io: BufReader::with_capacity(64 << 10, stream),
        })
    }

    /// Reads the response head; the body must be a chunked 200.
    async fn read_head(&mut self) -> Result<()> {
        let mut line = String::new();
        if self.io.read_line(&mut line).await? == 0 {
            return Err("connection closed".into());
        }
        let status = line.split_whitespace().nth(1).unwrap_or("").to_string();
        let mut chunked = false;
        loop {
            line.clear();
            if self.io.read_line(&mut line).await? == 0 {
                return Err("connection closed in the head".into());
            }
            let l = line.trim_end().to_ascii_lowercase();
            if l.is_empty() {
                break;
            }
            chunked |= l.starts_with("transfer-encoding:") && l.ends_with("chunked");
        }
        if status != "200" || !chunked {
            return Err(format!("/api/events: {status}").into());
        }
        Ok(())
    }

    /// The next chunk of a chunked body (`None` at its end).
    async fn read_chunk(&mut self) -> Result<Option<Vec<u8>>> {
        let mut line = String::new();
        if self.io.read_line(&mut line).await? == 0 {
            return Err("connection closed in a chunked body".into());
        }
        let size = line.trim().split(';').next().unwrap_or("");
        let n = usize::from_str_radix(size, 16).map_err(|e| format!("chunk size {size:?}: {e}"))?;
        let mut buf = vec![0; n];
        self.io.read_exact(&mut buf).await?;
        line.clear();
        self.io.read_line(&mut line).await?;
        Ok((n > 0).then_some(buf))
    }

    /// The body's events (parsed by the typed client's SSE reader).
    fn into_events(self) -> EventStream {
        let chunks = futures_util::stream::unfold(Some(self), |conn| async move {
            let mut c = conn?;
            match c.read_chunk().await {
                Ok(Some(chunk)) => Some((Ok(chunk), Some(c))),
                Ok(None) => None,
                Err(e) => Some((Err(e.to_string()), None)),
            }
        });
        EventStream::from_bytes("stalled".into(), chunks)
    }
}

// ---------------------------------------------------------------------------- SSE clients

/// What one SSE client has seen so far (read while it runs).
#[derive(Debug, Default)]
pub(crate) struct Counters {
    pub(crate) events: AtomicUsize,
    pub(crate) resyncs: AtomicUsize,
    pub(crate) run_events: AtomicUsize,
}

/// A snapshot of [`Counters`].
#[derive(Debug, Default, Clone, Copy)]
pub(crate) struct Seen {
    pub(crate) events: usize,
    pub(crate) resyncs: usize,
    pub(crate) run_events: usize,
}

impl Counters {
    pub(crate) fn seen(&self) -> Seen {
        Seen {
            events: self.events.load(Ordering::SeqCst),
            resyncs: self.resyncs.load(Ordering::SeqCst),
            run_events: self.run_events.load(Ordering::SeqCst),
        }
    }
}

/// How an SSE client ended.
#[derive(Debug, Default, Clone)]
pub(crate) struct Ending {
    /// The stream was still open when the benchmark stopped it.
    pub(crate) connected_at_end: bool,
    pub(crate) error: Option<String>,
}

/// Counts a stream's events (by name, not decoded) until it ends or fails. The first
/// `resync` is the stream's initial state: it bumps `ready` and is not counted as a resync.
pub(crate) async fn follow_stream(
    events: &mut EventStream,
    stats: &Counters,
    ready: Option<&AtomicUsize>,
) -> Result<()> {
    let mut first = true;
    loop {
        let ev = match events.next_raw().await {
            Some(ev) => ev?,
            None => return Err("the daemon ended the stream".into()),
        };
        stats.events.fetch_add(1, Ordering::SeqCst);
        if ev.name == "resync" {
            if first {
                if let Some(r) = ready {
                    r.fetch_add(1, Ordering::SeqCst);
                }
            } else {
                stats.resyncs.fetch_add(1, Ordering::SeqCst);
            }
        } else if ev.name == "run" {
            stats.run_events.fetch_add(1, Ordering::SeqCst);
        }
        first = false;
    }
}

/// Follows `/api/events` until `stop`, counting events by name.
pub(crate) async fn sse_client(
    client: Client,
    ready: Arc<AtomicUsize>,
    stats: Arc<Counters>,
    mut stop: watch::Receiver<bool>,
) -> Ending {
    let mut end = Ending::default();
    let r = async {
        let mut events = client.events(None).await?;
        tokio::select! {
            r = follow_stream(&mut events, &stats, Some(&ready)) => r,
            _ = stop.wait_for(|s| *s) => Ok(()),
        }
    }
    .await;
    match r {
        Ok(()) => end.connected_at_end = true,
        Err(e) => end.error = Some(e.to_string()),
    }
    end
}

/// An SSE client with a 4 KiB receive buffer that subscribes and reads nothing until `stop`;
/// then it reads what it is sent for 3 s (to see whether the daemon resynchronised it).
pub(crate) async fn stalled_client(
    addr: SocketAddr,
    token: String,
    stats: Arc<Counters>,
    mut stop: watch::Receiver<bool>,
) -> Ending {
    let mut end = Ending::default();
    let r = async {
        let mut c = Conn::events(addr, &token, 4096).await?;
        let _ = stop.wait_for(|s| *s).await;
        c.read_head().await?;
        let mut events = c.into_events();
        let drain = follow_stream(&mut events, &stats, None);
        match tokio::time::timeout(Duration::from_secs(3), drain).await {
            Ok(r) => r,
            Err(_) => Ok(()),
        }
    }
    .await;
    match r {
        Ok(()) => end.connected_at_end = true,
        Err(e) => end.error = Some(e.to_string()),
    }
    end
}

// ------------------------------------------------------------------------- status load

/// What one status connection measured.
#[derive(Debug, Default)]
pub(crate) struct StatusStats {
    /// Latency of each request from its scheduled send time, seconds.
    pub(crate) latencies_s: Vec<f64>,
    pub(crate) errors: usize,
    pub(crate) non_200: usize,
}

/// Sends `GET /api/status` every `interval` (open loop, starting at `start`) until `stop`,
/// on one keep-alive connection (a client of its own: its pool holds that one connection).
pub(crate) async fn status_client(
    client: Client,
    start: tokio::time::Instant,
    interval: Duration,
    stop: watch::Receiver<bool>,
) -> StatusStats {
    let mut stats = StatusStats::default();
    let mut k: u32 = 0;
    while !*stop.borrow() {
        let at = start + interval * k;
        k += 1;
        tokio::time::sleep_until(at).await;
        if *stop.borrow() {
            break;
        }
        match client.raw(Method::GET, "/api/status", Body::Empty).await {
            Ok(reply) => {
                stats
                    .latencies_s
                    .push(tokio::time::Instant::now().duration_since(at).as_secs_f64());
                if reply.status != 200 {
                    stats.non_200 += 1;
                }
            }
            Err(_) => stats.errors += 1,
        }
    }
    stats
}
