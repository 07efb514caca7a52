//! Bearer tokens and roles. Two tokens are created on the daemon's first start and stored in
//! `<data>/tokens.json` with mode 0600: one for operators (may change the rig), one read-only.
//! Tokens are compared in constant time. `GET`/`HEAD` requests need any token; every other
//! method needs the operator token, except `POST /api/estop`, which any token may press.
//! Browsers' `EventSource` and `<img>` cannot send headers, so
//! `GET` requests may carry the token as `?access_token=` instead.

use std::io::Write;
use std::os::unix::fs::{OpenOptionsExt, PermissionsExt};
use std::path::{Path, PathBuf};

use axum::extract::{Request, State};
use axum::http::{Method, StatusCode, Uri, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde::{Deserialize, Serialize};
use subtle::ConstantTimeEq;

use super::error::ApiError;
use super::state::AppState;

/// What a token allows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize, utoipa::ToSchema)]
#[serde(rename_all = "snake_case")]
pub enum Role {
    /// May read state, events, runs and frames.
    ReadOnly,
    /// May also move axes, switch lamps and the laser, run scripts and e-stop.
    Operator,
}

/// The daemon's tokens, as stored in `tokens.json`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct Tokens {
    pub operator: String,
    pub read_only: String,
}

/// The e-stop route, which every valid token may use (resetting it needs the operator).
pub const ESTOP_PATH: &str = "/api/estop";

/// The file name of the tokens inside the data directory.
pub const TOKENS_FILE: &str = "tokens.json";

/// Why the API tokens could not be loaded or created; `path` is the tokens file.
#[derive(Debug, thiserror::Error)]
pub enum TokensError {
    /// The file's permissions cannot be read.
    #[error("{}: {source}", path.display())]
    Metadata {
        /// The tokens file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Other users may read the file.
    #[error(
        "{}: mode {mode:o} lets other users read the API tokens; run `chmod 600 {}`",
        path.display(),
        path.display()
    )]
    Readable {
        /// The tokens file.
        path: PathBuf,
        /// Its permission bits.
        mode: u32,
    },
    /// The file is not the tokens' JSON.
    #[error("{}: {source}; fix it or delete it to get new tokens", path.display())]
    Parse {
        /// The tokens file.
        path: PathBuf,
        /// Why.
        source: serde_json::Error,
    },
    /// A token is too short to be secret.
    #[error(
        "{}: tokens must be at least 16 characters; delete the file to get new ones",
        path.display()
    )]
    TooShort {
        /// The tokens file.
        path: PathBuf,
    },
    /// The operating system gave no random bytes.
    #[error("no randomness for the API tokens: {0}")]
    Random(getrandom::Error),
    /// The new tokens could not be serialised.
    #[error("{0}")]
    Serialise(serde_json::Error),
    /// The file cannot be created.
    #[error("cannot create {}: {source}", path.display())]
    Create {
        /// The tokens file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file cannot be written.
    #[error("cannot write {}: {source}", path.display())]
    Write {
        /// The tokens file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// The file cannot be read.
    #[error("cannot read {}: {source}", path.display())]
    Read {
        /// The tokens file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
}

impl Tokens {
    /// Loads `<data>/tokens.json`, creating it (mode 0600, fresh random tokens) on first start.
    /// A file others can read is refused: the tokens would be worthless.
    pub fn load_or_create(data_dir: &Path) -> Result<(Tokens, PathBuf, bool), TokensError> {
        let path = data_dir.join(TOKENS_FILE);
        match std::fs::read_to_string(&path) {
            Ok(text) => {
                let mode = std::fs::metadata(&path)
                    .map_err(|source| TokensError::Metadata {
                        path: path.clone(),
                        source,
                    })?
                    .permissions()
                    .mode();
                if mode & 0o077 != 0 {
                    return Err(TokensError::Readable {
                        path,
                        mode: mode & 0o777,
                    });
                }
                let tokens: Tokens =
                    serde_json::from_str(&text).map_err(|source| TokensError::Parse {
                        path: path.clone(),
                        source,
                    })?;
                if tokens.operator.len() < 16 || tokens.read_only.len() < 16 {
                    return Err(TokensError::TooShort { path });
                }
                Ok((tokens, path, false))
            }
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
                let tokens = Tokens {
                    operator: random_token()?,
                    read_only: random_token()?,
                };
                let text = serde_json::to_string_pretty(&tokens).map_err(TokensError::Serialise)?;
                let mut f = std::fs::OpenOptions::new()
                    .write(true)
                    .create_new(true)
                    .mode(0o600)
                    .open(&path)
                    .map_err(|source| TokensError::Create {
                        path: path.clone(),
                        source,
                    })?;
                f.write_all(text.as_bytes())
                    .and_then(|()| f.sync_all())
                    .map_err(|source| TokensError::Write {
                        path: path.clone(),
                        source,
                    })?;
                Ok((tokens, path, true))
            }
            Err(source) => Err(TokensError::Read { path, source }),
        }
    }

    /// The role `token` grants, comparing against both tokens in constant time.
    pub fn role_of(&self, token: &str) -> Option<Role> {
        let t = token.as_bytes();
        let op: bool = t.ct_eq(self.operator.as_bytes()).into();
        let ro: bool = t.ct_eq(self.read_only.as_bytes()).into();
        if op {
            Some(Role::Operator)
        } else if ro {
            Some(Role::ReadOnly)
        } else {
            None
        }
    }
}

/// 32 random bytes as 64 hex digits.
fn random_token() -> Result<String, TokensError> {
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes).map_err(TokensError::Random)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

/// The token a request carries: `Authorization: Bearer …`, or `?access_token=…` on `GET`.
fn token_of(req: &Request) -> Option<String> {
    if let Some(v) = req.headers().get(header::AUTHORIZATION) {
        let v = v.to_str().ok()?;
        let (scheme, token) = v.split_once(' ')?;
        return scheme
            .eq_ignore_ascii_case("bearer")
            .then(|| token.trim().to_string());
    }
    if req.method() == Method::GET {
        let query = req.uri().query()?;
        return query
            .split('&')
            .find_map(|kv| kv.strip_prefix("access_token=").map(|t| t.to_string()));
    }
    None
}

/// Middleware on `/api/`: 401 without a valid token, 403 when a read-only token tries to
/// change something. Puts the caller's [`Role`] in the request's extensions.
pub async fn require_token(State(app): State<AppState>, mut req: Request, next: Next) -> Response {
    let Some(token) = token_of(&req) else {
        return unauthorized("no bearer token");
    };
    let Some(role) = app.tokens.role_of(&token) else {
        return unauthorized("the bearer token is not valid");
    };
    let reads = matches!(*req.method(), Method::GET | Method::HEAD);
    // Anyone allowed to watch the rig may stop it: the e-stop only makes things safe.
    let estop = req.method() == Method::POST && req.uri().path() == ESTOP_PATH;
    if !reads && !estop && role != Role::Operator {
        return ApiError::new(
            StatusCode::FORBIDDEN,
            format!(
                "{} {} needs the operator token",
                req.method(),
                req.uri().path()
            ),
        )
        .hint("this token is read-only; the operator token is in the daemon's tokens.json")
        .into_response();
    }
    req.extensions_mut().insert(role);
    strip_access_token(&mut req);
    next.run(req).await
}

/// Drops `access_token` from the query string once checked, so handlers whose query
/// parameters refuse unknown fields (`<img src=…/thumbnail?size=256&access_token=…>`) never
/// see it.
fn strip_access_token(req: &mut Request) {
    let Some(query) = req.uri().query() else {
        return;
    };
    if !query.split('&').any(|kv| kv.starts_with("access_token=")) {
        return;
    }
    let rest: Vec<&str> = query
        .split('&')
        .filter(|kv| !kv.is_empty() && !kv.starts_with("access_token="))
        .collect();
    let path = req.uri().path();
    let path_and_query = if rest.is_empty() {
        path.to_string()
    } else {
        format!("{path}?{}", rest.join("&"))
    };
    let mut parts = req.uri().clone().into_parts();
    let Ok(pq) = path_and_query.parse() else {
        return;
    };
    parts.path_and_query = Some(pq);
    if let Ok(uri) = Uri::from_parts(parts) {
        *req.uri_mut() = uri;
    }
}

fn unauthorized(what: &str) -> Response {
    let mut r = ApiError::new(StatusCode::UNAUTHORIZED, what)
        .hint("send `Authorization: Bearer <token>`; the tokens are in tokens.json in the daemon's data directory")
        .into_response();
    r.headers_mut().insert(
        header::WWW_AUTHENTICATE,
        header::HeaderValue::from_static("Bearer"),
    );
    r
}
