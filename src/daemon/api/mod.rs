//! The HTTP API under `/api/`, documented from the handlers themselves (utoipa) so
//! `/openapi.json` always matches the routes.

mod devices;
mod frames;
mod queue;
mod runs;
mod scripts;
mod status;
mod verify;

/// The run types [`crate::client`] decodes.
pub use runs::{PromptAnswer, PromptReply, RunSummary};

use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::{Modify, OpenApi};
use utoipa_axum::router::OpenApiRouter;

use super::state::AppState;

#[derive(OpenApi)]
#[openapi(
    info(
        title = "stagehand",
        description = "Control of an appearance-capture light stage: devices, capture scripts, runs, frames and live events. Every `/api/` route needs `Authorization: Bearer <token>` (tokens.json in the daemon's data directory); methods other than GET need the operator token."
    ),
    components(schemas(frames::KindParam, frames::FormatParam)),
    modifiers(&BearerAuth),
    security(("bearer" = []))
)]
struct ApiDoc;

struct BearerAuth;

impl Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(HttpBuilder::new().scheme(HttpAuthScheme::Bearer).build()),
        );
    }
}

/// Documents the errors every route can answer whatever its handler does: 401 (no or a wrong
/// token, from the auth middleware), 403 (a read-only token on a change), and for JSON bodies
/// 400/413/415/422 (malformed, too large, wrong content type, wrong shape).
struct CommonErrors;

impl Modify for CommonErrors {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::{ContentBuilder, Ref, ResponseBuilder};
        let error = |description: &str| {
            ResponseBuilder::new()
                .description(description)
                .content(
                    "application/json",
                    ContentBuilder::new()
                        .schema(Some(Ref::from_schema_name("ErrorBody")))
                        .build(),
                )
                .build()
        };
        for (path, item) in openapi.paths.paths.iter_mut() {
            if !path.starts_with("/api/") || path == "/api/health" {
                continue;
            }
            let operations = [
                (&mut item.get, false),
                (&mut item.head, false),
                (&mut item.post, true),
                (&mut item.put, true),
                (&mut item.patch, true),
                (&mut item.delete, true),
            ];
            for (operation, mutating) in operations {
                let Some(op) = operation.as_mut() else {
                    continue;
                };
                let mut add = |code: &str, description: &str| {
                    op.responses
                        .responses
                        .entry(code.to_string())
                        .or_insert_with(|| error(description).into());
                };
                add("401", "no bearer token, or not a valid one");
                if mutating {
                    add("403", "the token is read-only");
                }
                if op.request_body.is_some() {
                    add("400", "the body is not valid JSON or text");
                    add("413", "the body is larger than the limit");
                    add("415", "wrong Content-Type");
                    add("422", "the body has the wrong shape or values");
                }
            }
        }
    }
}

/// Completes the document once every route is in it (derive-time modifiers run before the
/// routes are merged): the errors every route can answer.
pub fn document_common_errors(openapi: &mut utoipa::openapi::OpenApi) {
    CommonErrors.modify(openapi);
}

/// The API routes that need no token (`GET /api/health`), with their OpenAPI description.
pub fn public_routes() -> OpenApiRouter<AppState> {
    status::public_routes()
}

/// Every API route with its OpenAPI description (paths relative to the server root).
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(status::routes())
        .merge(devices::routes())
        .merge(scripts::routes())
        .merge(runs::routes())
        .merge(frames::routes())
        .merge(queue::routes())
        .merge(verify::routes())
}
