//! The built-in scenes, one per fixture name, embedded in the binary so a rig's `sim.sample`
//! or a script's `prompt(fixture=...)` can name them without any files.

/// Every built-in scene as (fixture name, TOML text); the names are [`FIXTURES`].
pub const BUILTIN_SCENES: [(&str, &str); 14] = [
    ("flat", include_str!("../../scenes/flat.toml")),
    ("bumps", include_str!("../../scenes/bumps.toml")),
    ("steps", include_str!("../../scenes/steps.toml")),
    ("weave", include_str!("../../scenes/weave.toml")),
    (
        "checkerboard",
        include_str!("../../scenes/checkerboard.toml"),
    ),
    (
        "colorchecker",
        include_str!("../../scenes/colorchecker.toml"),
    ),
    ("planes", include_str!("../../scenes/planes.toml")),
    ("marble", include_str!("../../scenes/marble.toml")),
    (
        "brushed_metal",
        include_str!("../../scenes/brushed_metal.toml"),
    ),
    ("plastic_ggx", include_str!("../../scenes/plastic_ggx.toml")),
    (
        "glossy_blinn",
        include_str!("../../scenes/glossy_blinn.toml"),
    ),
    ("felt_quasi", include_str!("../../scenes/felt_quasi.toml")),
    ("cavity", include_str!("../../scenes/cavity.toml")),
    (
        "opal_reference",
        include_str!("../../scenes/opal_reference.toml"),
    ),
];

/// Fixtures that can lie on the stage (procedural samples and calibration targets): the names
/// of the built-in scenes. The rig's `sim.sample`, operator prompts and the renderer all draw
/// from this one list.
pub const FIXTURES: [&str; BUILTIN_SCENES.len()] = {
    let mut names = [""; BUILTIN_SCENES.len()];
    let mut i = 0;
    while i < names.len() {
        names[i] = BUILTIN_SCENES[i].0;
        i += 1;
    }
    names
};

/// The text of the built-in scene `name`, if there is one.
pub fn builtin_scene(name: &str) -> Option<&'static str> {
    BUILTIN_SCENES
        .iter()
        .find(|(n, _)| *n == name)
        .map(|(_, text)| *text)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_scene_parses_and_is_named_after_its_fixture() {
        for (name, text) in BUILTIN_SCENES {
            let scene = super::super::parse_scene(text, &format!("scenes/{name}.toml"), None)
                .unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(scene.source.name, name);
            assert!(!scene.description.is_empty(), "{name} has a description");
        }
    }
}
