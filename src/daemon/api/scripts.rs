//! scripts endpoints.

use utoipa_axum::router::OpenApiRouter;

use crate::daemon::state::AppState;

pub fn routes() -> OpenApiRouter<AppState> {
    OpenApiRouter::new()
}
