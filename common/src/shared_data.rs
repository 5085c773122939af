//! Where the tests find the project's real recordings (`../shared/data`, next to the workspace).
//!
//! Every test that reads them goes through [`locate`], so the rule is kept in one place: outside
//! CI a missing folder skips the test with a printed notice; under CI (`CI=true`), where the data
//! is always provided, a missing folder fails the test instead of letting it pass unseen.

use std::path::{Path, PathBuf};

/// The workspace root: the nearest ancestor of `start` (a crate's `CARGO_MANIFEST_DIR`, or the
/// root itself) that holds `Cargo.lock`.
pub fn workspace_root(start: &Path) -> Option<PathBuf> {
    start
        .ancestors()
        .find(|d| d.join("Cargo.lock").is_file())
        .map(Path::to_path_buf)
}

/// Whether this run is CI's (`CI=true`).
pub fn in_ci() -> bool {
    std::env::var("CI").as_deref() == Ok("true")
}

/// `../shared/data/<sub>` beside the workspace that contains `manifest_dir`, or `None` with a
/// notice naming `what` when it is absent.
///
/// # Panics
/// Under CI (`CI=true`) when the folder is absent.
pub fn locate(manifest_dir: &str, sub: &str, what: &str) -> Option<PathBuf> {
    let root = workspace_root(Path::new(manifest_dir)).unwrap_or_else(|| manifest_dir.into());
    let dir = root.join("../shared/data").join(sub);
    if dir.is_dir() {
        return Some(dir);
    }
    assert!(
        !in_ci(),
        "{what} needs {}, which CI always has: it is missing",
        dir.display()
    );
    println!("skipping {what}: {} is absent", dir.display());
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_root_is_found_from_a_crate_and_a_missing_folder_is_none_outside_ci() {
        let root = workspace_root(Path::new(env!("CARGO_MANIFEST_DIR"))).expect("root");
        assert!(root.join("Cargo.lock").is_file());
        if !in_ci() {
            assert!(locate(env!("CARGO_MANIFEST_DIR"), "no-such-folder", "this test").is_none());
        }
    }
}
