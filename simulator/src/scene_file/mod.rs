//! Scene files: TOML descriptions of the sample on the turntable (its size, relief and
//! material, and how frames of it are rendered). Every fixture is a scene; the built-in ones
//! are embedded from `simulator/scenes/` and the format is documented in
//! `simulator/scenes/README.md`.
//!
//! One concept per file: [`spec`] (the TOML schema), [`load`] (checks with file:line:col
//! errors), [`resolved`] (the checked scene), [`image`] (PNG height and material maps),
//! [`mesh`] (OBJ meshes as height fields), [`builtin`] (the embedded scenes) and [`error`].

pub mod builtin;
pub mod error;
pub mod image;
pub mod load;
pub mod mesh;
pub mod resolved;
pub mod spec;

pub use builtin::{BUILTIN_SCENES, builtin_scene};
pub use error::SceneError;
pub use load::{load_scene_file, parse_scene};
pub use resolved::{Meso, Param, Scene, SceneMaterial, SceneSource, Shape};

use std::path::Path;

/// The scene a fixture name stands for: a built-in scene by name, or the scene file at a
/// path ending in `.toml`. `Ok(None)` when the name is neither.
pub fn resolve_fixture(fixture: &str) -> Result<Option<Scene>, SceneError> {
    if let Some(text) = builtin_scene(fixture) {
        let origin = format!("scenes/{fixture}.toml");
        return parse_scene(text, &origin, None).map(Some);
    }
    if fixture.ends_with(".toml") {
        return load_scene_file(Path::new(fixture)).map(Some);
    }
    Ok(None)
}
