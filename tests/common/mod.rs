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
