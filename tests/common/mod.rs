//! Helpers shared by the CLI tests: the binary and scratch directories.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::Command;

/// The `radiant` binary of this build.
pub fn radiant() -> Command {
    Command::new(env!("CARGO_BIN_EXE_radiant"))
}

/// A fresh scratch directory path (removed if it exists), unique to this process.
pub fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("radiant-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
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
