//! The built-in scenes: the files of `scenes/`, embedded at compile time so that `sieve run
//! NAME` works from any directory and always matches the files in the repository.

/// One built-in scene.
#[derive(Debug, Clone, Copy)]
pub struct Builtin {
    /// Scene name (the file stem).
    pub name: &'static str,
    /// The TOML text of `scenes/<name>.toml`.
    pub toml: &'static str,
}

macro_rules! builtins {
    ($($name:literal),* $(,)?) => {
        /// All built-in scenes, in catalogue order.
        pub const BUILTINS: &[Builtin] = &[
            $(Builtin { name: $name, toml: include_str!(concat!("../../../scenes/", $name, ".toml")) },)*
        ];
    };
}

builtins!(
    "column-a",
    "column-b",
    "column-c",
    "column-d",
    "gray-thornton-plug",
    "gray-thornton-shear",
    "gray-thornton-plug-inverse",
    "gray-thornton-shear-inverse",
    "shear-cell-mixed",
    "shear-cell-inverse",
    "shear-cell",
    "column-collapse",
    "silo",
    "silo-3d",
    "hopper",
    "chute",
    "drum-settling",
    "tumbler",
    "tumbler-75",
    "tumbler-square",
    "tumbler-3d",
    "tumbler-3d-walls",
);

/// The scene `sieve run` runs without a SCENE argument: 2D, segregates visibly (mixes, then
/// re-segregates) and finishes in well under a second in release builds.
pub const DEFAULT_SCENE: &str = "shear-cell-inverse";

/// The built-in scene called `name`.
pub fn find(name: &str) -> Option<&'static Builtin> {
    BUILTINS.iter().find(|b| b.name == name)
}

/// Names of all built-in scenes.
pub fn names() -> Vec<&'static str> {
    BUILTINS.iter().map(|b| b.name).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_is_valid_and_named_like_its_file() {
        for b in BUILTINS {
            let (scene, _) = crate::scene::load(b.name, &[]).unwrap();
            assert_eq!(scene.name, b.name);
        }
        assert!(find(DEFAULT_SCENE).is_some());
    }
}
