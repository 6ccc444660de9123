//! Helpers shared by the CLI tests: the binary and scratch directories.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `radiant` binary of this build.
pub fn radiant() -> Command {
    Command::new(env!("CARGO_BIN_EXE_radiant"))
}

/// A scratch directory's path, unique to this process; the directory is removed when this is
/// dropped, also when the test fails.
pub struct Scratch(PathBuf);

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// A fresh scratch directory path (removed if it exists, and again when dropped).
pub fn tmp(name: &str) -> Scratch {
    let dir = std::env::temp_dir().join(format!("radiant-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    Scratch(dir)
}

/// Runs `radiant` with `args` and `--out out`; returns its stdout, failing the test with its
/// stderr when it fails.
pub fn run_ok(args: &[&str], out: &std::path::Path) -> String {
    let st = radiant()
        .args(args)
        .arg("--out")
        .arg(out)
        .output()
        .expect("runs");
    assert!(
        st.status.success(),
        "{args:?}: stderr: {}",
        String::from_utf8_lossy(&st.stderr)
    );
    String::from_utf8_lossy(&st.stdout).into_owned()
}
