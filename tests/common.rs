//! Shared fixtures.

use std::process::{Command, Output};

use plumenet::frame::Frame;
use plumenet::layout::{Layout, WindFrom};

/// The shipped paper arena.
pub fn wind_tunnel() -> Layout {
    Layout::load(&repo_path("data/layouts/wind-tunnel.json")).expect("shipped layout is valid")
}

/// The paper arena without obstacles.
pub fn empty_tunnel() -> Layout {
    Layout::from_json(r#"{"width_m":18,"height_m":4,"cell_m":0.125,"wind":{"speed_mps":0.75}}"#)
        .expect("empty arena is valid")
}

/// `canonical` (wind from the west) turned so that its wind comes from `from`: the layout whose
/// canonical frame is `canonical`.
pub fn turned(canonical: &Layout, from: WindFrom) -> Layout {
    Frame::turning(canonical, from)
        .layout_from_canonical(canonical)
        .unwrap()
}

/// A path inside the repository.
pub fn repo_path(rel: &str) -> std::path::PathBuf {
    std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join(rel)
}

/// The binary, to run in the repository root with its bank cache in Cargo's scratch folder
/// for integration tests (never the checkout's `data/cache`).
pub fn command() -> Command {
    let mut command = Command::new(env!("CARGO_BIN_EXE_plumenet"));
    command.current_dir(repo_path("")).env(
        "PLUMENET_CACHE_DIR",
        std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("bank-cache"),
    );
    command
}

/// Runs the binary (see [`command`]).
pub fn plumenet(args: &[&str]) -> Output {
    command().args(args).output().expect("binary runs")
}

/// Runs the binary and asserts that it succeeded.
pub fn plumenet_ok(args: &[&str]) -> Output {
    let out = plumenet(args);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

/// Asserts that a run failed cleanly (no panic) with `needle` in its error.
pub fn assert_clean_failure(out: &Output, needle: &str) {
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success(),
        "expected failure ({needle}), got success; stderr {stderr}"
    );
    assert!(!stderr.contains("panicked"), "panic: {stderr}");
    assert!(stderr.contains(needle), "expected {needle:?} in {stderr}");
}

/// The JSON document in a file a command wrote.
pub fn read_json(path: impl AsRef<std::path::Path>) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// Asserts that `result` is an error whose message holds `needle`.
#[track_caller]
pub fn assert_err<T, E: std::fmt::Display>(result: Result<T, E>, needle: &str) {
    match result {
        Ok(_) => panic!("expected an error with {needle:?}, got a value"),
        Err(e) => {
            let message = e.to_string();
            assert!(
                message.contains(needle),
                "expected {needle:?} in: {message}"
            );
        }
    }
}

/// Property-test settings: `cases` cases, and a failing case reported in the test's output
/// only (never saved into the checkout).
pub fn proptest_config(cases: u32) -> proptest::test_runner::Config {
    proptest::test_runner::Config {
        cases,
        failure_persistence: None,
        ..proptest::test_runner::Config::default()
    }
}

/// Starts `plumenet serve ... --listen 127.0.0.1:0` with `args` and returns the process and
/// the address it printed.
pub fn spawn_server(args: &[&std::ffi::OsStr]) -> (std::process::Child, String) {
    use std::io::BufRead;
    let mut child = command()
        .arg("serve")
        .args(args)
        .args(["--listen", "127.0.0.1:0"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let at = line
        .trim()
        .strip_prefix("listening on ")
        .unwrap()
        .to_string();
    (child, at)
}
