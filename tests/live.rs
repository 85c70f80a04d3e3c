//! The live view (`[live] listen`): a Foxglove WebSocket client connects to a running flyd,
//! subscribes, and receives images, flies and decisions.
//!
//! The client is Foxglove's own (`@foxglove/ws-protocol`'s `FoxgloveClient` over `ws`, under
//! node: tests/live/client.js); what it received is decoded by Python's protobuf with the
//! descriptors the server advertised, and by `json` (tests/live/decode.py). scripts/prereqs
//! installs node's packages in target/node and Python's in target/py; without them the test
//! fails with a message, unless FLYD_ALLOW_NO_NODE is set (then it prints SKIP).

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn node_ready() -> bool {
    repo("target/node/node_modules/@foxglove/ws-protocol").is_dir()
        && Command::new("node")
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
        && repo("target/py/bin/python3").exists()
}

#[test]
fn a_foxglove_client_receives_images_flies_and_decisions_from_the_running_daemon() {
    if !node_ready() {
        if std::env::var_os("FLYD_ALLOW_NO_NODE").is_some() {
            println!(
                "SKIP: node or target/node (@foxglove/ws-protocol) missing: run scripts/prereqs"
            );
            return;
        }
        panic!(
            "node with target/node/node_modules/@foxglove/ws-protocol, and target/py, are \
             needed: run scripts/prereqs (or set FLYD_ALLOW_NO_NODE=1 to skip)"
        );
    }
    let dir = tempfile::tempdir().expect("tempdir");
    let text = std::fs::read_to_string(repo("config/demo.toml")).expect("demo config");
    let config = dir.path().join("live.toml");
    // Port 0: the kernel picks a free one; flyd logs the address it listens on.
    std::fs::write(
        &config,
        format!("{text}\n[live]\nlisten = \"127.0.0.1:0\"\n"),
    )
    .expect("write config");
    let mut flyd = Command::new(env!("CARGO_BIN_EXE_flyd"))
        .arg("run")
        .arg("--config")
        .arg(&config)
        .args(["--can-log", "/dev/null"])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("flyd starts");
    let stdout = flyd.stdout.take().expect("stdout");
    let mut lines = BufReader::new(stdout).lines();
    let started = Instant::now();
    let url = loop {
        let Some(Ok(line)) = lines.next() else {
            panic!("flyd ended before its live view listened");
        };
        if let Ok(v) = serde_json::from_str::<serde_json::Value>(&line)
            && let Some(listen) = v["listen"].as_str()
        {
            break format!("ws://{listen}");
        }
        assert!(started.elapsed() < Duration::from_secs(20), "no live view");
    };
    // Keep reading flyd's logs so that its stdout never fills.
    let drain = std::thread::Builder::new()
        .name("drain".into())
        .spawn(move || lines.count())
        .expect("thread");

    let out = Command::new("node")
        .arg(repo("tests/live/client.js"))
        .arg(&url)
        .arg("4")
        .args(["/camera/left/image", "/flyd/flies", "/flyd/decision"])
        .env("NODE_PATH", repo("target/node/node_modules"))
        .output()
        .expect("node runs");
    let received = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "client: {received}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let file = dir.path().join("received.json");
    std::fs::write(&file, &received).expect("write");
    let out = Command::new(repo("target/py/bin/python3"))
        .arg(repo("tests/live/decode.py"))
        .arg(&file)
        .output()
        .expect("python runs");
    let decoded = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{decoded}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    println!("decoded: {decoded}");
    let v: serde_json::Value = serde_json::from_str(&decoded).expect("json");
    let t = &v["topics"];
    assert_eq!(t["/camera/left/image"]["width"], 640, "{v}");
    assert_eq!(t["/camera/left/image"]["height"], 480, "{v}");
    assert_eq!(t["/camera/left/image"]["encoding"], "rgb8", "{v}");
    assert_eq!(t["/flyd/flies"]["points"], 5000, "{v}");
    assert_eq!(
        t["/flyd/flies"]["fields"],
        serde_json::json!(["x", "y", "z", "fitness", "warning"])
    );
    let command = t["/flyd/decision"]["first"]["command"]
        .as_str()
        .unwrap_or("");
    assert!(["CLEAR", "SLOW", "STOP"].contains(&command), "{v}");
    assert!(v["server"].as_str().is_some_and(|s| s.starts_with("flyd")));

    let status = flyd.wait().expect("flyd ends");
    assert!(status.success(), "flyd exit {status}");
    let _ = drain.join();
}
