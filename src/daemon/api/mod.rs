//! The HTTP API under `/api/`, documented from the handlers themselves (utoipa) so
//! `/openapi.json` always matches the routes.

mod devices;
mod frames;
mod runs;
mod scripts;
mod status;

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

/// Every API route with its OpenAPI description (paths relative to the server root).
pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::with_openapi(ApiDoc::openapi())
        .merge(status::routes())
        .merge(devices::routes())
        .merge(scripts::routes())
        .merge(runs::routes())
        .merge(frames::routes())
}
