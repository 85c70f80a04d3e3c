//! Host side of the VM tests: runs one scenario (a guest shell script plus the binaries under
//! test) in a QEMU guest with vcan0 and two v4l2loopback cameras, or natively on a host that
//! has them, and hands the test the console markers and the files the scenario left.
//!
//! The machinery is in the shell scripts beside this file (prepare.sh: kernel, modules and base
//! initramfs, cached; run.sh: one boot; native.sh: one native run); this module calls them,
//! turns their failures into loud panics (a VM suite that cannot boot fails, it never skips),
//! and parses what comes back. See README.md.

use std::collections::BTreeMap;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

const HERE: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/vm");

/// Where a scenario runs. Chosen with `FLYD_VM_BACKEND` (`qemu`, the default, or `native`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    /// A QEMU (TCG) guest booted from the cached Debian kernel and a built initramfs.
    Qemu,
    /// This host, which must already have vcan0 and the two labelled v4l2loopback devices.
    Native,
}

impl Backend {
    fn from_env() -> Backend {
        match std::env::var("FLYD_VM_BACKEND").as_deref() {
            Err(_) | Ok("") | Ok("qemu") => Backend::Qemu,
            Ok("native") => Backend::Native,
            Ok(other) => panic!("FLYD_VM_BACKEND={other:?}: expected qemu or native"),
        }
    }

    fn name(self) -> &'static str {
        match self {
            Backend::Qemu => "qemu",
            Backend::Native => "native",
        }
    }
}

/// What prepare.sh printed: the kernel to boot and the base initramfs.
struct Prepared {
    kernel_release: String,
    kernel: String,
    base: String,
}

/// Runs prepare.sh once per test process (it locks its cache against other processes itself).
fn prepared() -> &'static Prepared {
    static PREPARED: OnceLock<Prepared> = OnceLock::new();
    PREPARED.get_or_init(|| {
        let started = Instant::now();
        let out = Command::new(format!("{HERE}/prepare.sh"))
            .output()
            .unwrap_or_else(|e| panic!("cannot run {HERE}/prepare.sh: {e}"));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success(),
            "VM setup failed ({}): the VM suite cannot run.\n{stderr}",
            out.status
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        let field = |key: &str| -> String {
            stdout
                .lines()
                .find_map(|l| l.strip_prefix(key)?.strip_prefix('='))
                .unwrap_or_else(|| panic!("prepare.sh printed no {key}=:\n{stdout}\n{stderr}"))
                .to_string()
        };
        let prepared = Prepared {
            kernel_release: field("KVER"),
            kernel: field("KERNEL"),
            base: field("BASE"),
        };
        say(&format!(
            "vm: guest kernel {} ready in {:.1} s{}",
            prepared.kernel_release,
            started.elapsed().as_secs_f64(),
            if stderr.trim().is_empty() {
                " (cache warm)".to_string()
            } else {
                format!(":\n{}", stderr.trim_end())
            }
        ));
        prepared
    })
}

/// The Debian 12 root file system image the systemd scenario boots (tests/vm/systemd/rootfs.sh:
/// mmdebstrap, cached under target/vm-systemd), built once per test process.
fn systemd_rootfs() -> &'static Path {
    static ROOTFS: OnceLock<PathBuf> = OnceLock::new();
    ROOTFS.get_or_init(|| {
        prepared(); // .ci/vm-prereqs: mmdebstrap
        let started = Instant::now();
        let cache = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .parent()
            .expect("CARGO_TARGET_TMPDIR is target/tmp")
            .join("vm-systemd");
        let out = Command::new(format!("{HERE}/systemd/rootfs.sh"))
            .arg(&cache)
            .output()
            .unwrap_or_else(|e| panic!("cannot run {HERE}/systemd/rootfs.sh: {e}"));
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success(),
            "building the systemd guest's root file system failed ({}): the systemd scenario \
             cannot run.\n{stderr}",
            out.status
        );
        let stdout = String::from_utf8_lossy(&out.stdout);
        let image = stdout
            .lines()
            .find_map(|l| l.strip_prefix("ROOTFS="))
            .unwrap_or_else(|| panic!("rootfs.sh printed no ROOTFS=:\n{stdout}\n{stderr}"));
        say(&format!(
            "vm: systemd root file system {image} ready in {:.1} s{}",
            started.elapsed().as_secs_f64(),
            if stderr.trim().is_empty() {
                " (cache warm)".to_string()
            } else {
                format!(":\n{}", stderr.trim_end())
            }
        ));
        PathBuf::from(image)
    })
}

/// The path of a binary of the `flyd-vm-guest` crate (tests/vm/guest), built on first use with
/// the profile this test was built with.
pub fn guest_tool(name: &str) -> PathBuf {
    static TOOLS: OnceLock<BTreeMap<String, PathBuf>> = OnceLock::new();
    let tools = TOOLS.get_or_init(|| {
        if Backend::from_env() == Backend::Qemu {
            // .ci/vm-prereqs (run by prepare.sh) installs libclang, which `v4l` needs to build.
            prepared();
        }
        build_guest_tools()
    });
    tools
        .get(name)
        .unwrap_or_else(|| panic!("flyd-vm-guest has no binary {name:?}: {tools:?}"))
        .clone()
}

fn build_guest_tools() -> BTreeMap<String, PathBuf> {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let mut cmd = Command::new(cargo);
    cmd.current_dir(env!("CARGO_MANIFEST_DIR")).args([
        "build",
        "-p",
        "flyd-vm-guest",
        "--bins",
        "--message-format=json-render-diagnostics",
    ]);
    if !cfg!(debug_assertions) {
        cmd.arg("--release");
    }
    let out = crate::flyd_cli::output_ok(&mut cmd, "cargo build -p flyd-vm-guest");
    let mut tools = BTreeMap::new();
    for line in String::from_utf8_lossy(&out.stdout).lines() {
        let Ok(msg) = serde_json::from_str::<serde_json::Value>(line) else {
            continue;
        };
        if let (Some(name), Some(exe)) =
            (msg["target"]["name"].as_str(), msg["executable"].as_str())
        {
            tools.insert(name.to_string(), PathBuf::from(exe));
        }
    }
    tools
}

/// Writes a line to the real stderr, past the test harness's capture: the suite's timings and
/// checks show in every CI log, not only on failure.
fn say(line: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// One scenario: `tests/vm/scenarios/<name>.sh` run in the guest, with binaries under test.
pub struct Scenario {
    name: String,
    script: PathBuf,
    bins: Vec<PathBuf>,
    inputs: Vec<PathBuf>,
    timeout: Duration,
    rootfs: Option<PathBuf>,
}

impl Scenario {
    pub fn new(name: &str) -> Scenario {
        Scenario {
            name: name.to_string(),
            script: Path::new(HERE).join("scenarios").join(format!("{name}.sh")),
            bins: Vec::new(),
            inputs: Vec::new(),
            timeout: Duration::from_secs(180),
            rootfs: None,
        }
    }

    /// Puts a binary on the guest's PATH under its file name (with its shared libraries).
    pub fn bin(mut self, path: impl Into<PathBuf>) -> Scenario {
        self.bins.push(path.into());
        self
    }

    /// Copies a data file (a config, a calibration) to `$RESULTS/input/<file name>` before the
    /// run, for the scenario to read: unlike `.bin`, it need not be executable.
    #[allow(dead_code)] // used by the flyd scenarios only
    pub fn input(mut self, path: impl Into<PathBuf>) -> Scenario {
        self.inputs.push(path.into());
        self
    }

    /// Hard wall-clock limit for the boot (QEMU is killed) or the native run.
    #[allow(dead_code)] // for scenarios longer than the default
    pub fn timeout(mut self, timeout: Duration) -> Scenario {
        self.timeout = timeout;
        self
    }

    /// Boots the Debian 12 root file system of [`systemd_rootfs`] with systemd as PID 1: the
    /// busybox /init sets up as always, then switches root, and flyd-vm-scenario.service runs
    /// the scenario (tests/vm/systemd). QEMU only.
    #[allow(dead_code)] // used by the systemd scenario only
    pub fn under_systemd(mut self) -> Scenario {
        self.rootfs = Some(systemd_rootfs().to_path_buf());
        self
    }

    /// Boots (or runs natively) and waits. Panics when the scenario could not be run to its
    /// end: no QEMU, a setup failure in the guest, a timeout. The scenario's own exit code is
    /// in the returned [`Run`], for the test to assert.
    pub fn run(self) -> Run {
        let backend = Backend::from_env();
        assert!(
            self.script.is_file(),
            "no scenario script {}",
            self.script.display()
        );
        let results = Path::new(env!("CARGO_TARGET_TMPDIR"))
            .join("vm")
            .join(&self.name);
        if results.exists() {
            std::fs::remove_dir_all(&results)
                .unwrap_or_else(|e| panic!("cannot clear {}: {e}", results.display()));
        }
        std::fs::create_dir_all(&results)
            .unwrap_or_else(|e| panic!("cannot create {}: {e}", results.display()));
        if !self.inputs.is_empty() {
            let dir = results.join("input");
            std::fs::create_dir_all(&dir)
                .unwrap_or_else(|e| panic!("cannot create {}: {e}", dir.display()));
            for input in &self.inputs {
                let name = input.file_name().expect("an input is a file");
                std::fs::copy(input, dir.join(name))
                    .unwrap_or_else(|e| panic!("cannot copy {}: {e}", input.display()));
            }
        }

        let mut cmd = match backend {
            Backend::Qemu => {
                let prepared = prepared();
                let mut cmd = Command::new(format!("{HERE}/run.sh"));
                cmd.arg("--kernel")
                    .arg(&prepared.kernel)
                    .arg("--base")
                    .arg(&prepared.base);
                if let Some(rootfs) = &self.rootfs {
                    cmd.arg("--rootfs").arg(rootfs);
                }
                cmd
            }
            Backend::Native => {
                assert!(
                    self.rootfs.is_none(),
                    "{}: the systemd scenario boots its own root file system: QEMU only \
                     (FLYD_VM_BACKEND=native cannot run it)",
                    self.name
                );
                Command::new(format!("{HERE}/native.sh"))
            }
        };
        cmd.arg("--script")
            .arg(&self.script)
            .arg("--results")
            .arg(&results)
            .arg("--timeout")
            .arg(self.timeout.as_secs().to_string());
        for bin in &self.bins {
            cmd.arg("--bin").arg(bin);
        }

        let started = Instant::now();
        let out = cmd
            .output()
            .unwrap_or_else(|e| panic!("cannot run the {} backend: {e}", backend.name()));
        let wall = started.elapsed();
        let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
        let console = std::fs::read_to_string(results.join("console.log")).unwrap_or_default();
        let markers = parse_markers(&console);
        let run = Run {
            name: self.name,
            backend,
            results,
            console,
            markers,
            wall,
            exit_code: None,
        };
        match out.status.code() {
            Some(124) => run.fail(&format!(
                "TIMEOUT after {} s (hard limit)\n{stderr}",
                self.timeout.as_secs()
            )),
            Some(125) | None => run.fail(&format!(
                "the {} backend did not run the scenario to its end ({})\n{stderr}",
                backend.name(),
                out.status
            )),
            Some(code) => {
                let reported = run
                    .event("exit")
                    .and_then(|m| m.get("code"))
                    .and_then(|c| c.parse::<i32>().ok());
                if reported != Some(code) {
                    run.fail(&format!(
                        "exit status {code} but the console says {reported:?}\n{stderr}"
                    ));
                }
                Run {
                    exit_code: Some(code),
                    ..run
                }
            }
        }
    }
}

/// A marker line from the console: `@@KIND k=v k=v@@`.
#[derive(Debug, Clone)]
pub struct Marker {
    pub kind: String,
    pub fields: BTreeMap<String, String>,
}

fn parse_markers(console: &str) -> Vec<Marker> {
    let mut markers = Vec::new();
    for line in console.lines() {
        // A kernel message can share a line with a marker: look for the marker anywhere.
        let Some(start) = line.find("@@") else {
            continue;
        };
        let rest = &line[start + 2..];
        let Some(end) = rest.find("@@") else { continue };
        let mut words = rest[..end].split_whitespace();
        let Some(kind) = words.next() else { continue };
        let fields = words
            .filter_map(|w| w.split_once('='))
            .map(|(k, v)| (k.to_string(), v.to_string()))
            .collect();
        markers.push(Marker {
            kind: kind.to_string(),
            fields,
        });
    }
    markers
}

/// What came back from one scenario.
pub struct Run {
    pub name: String,
    pub backend: Backend,
    /// The host directory the scenario saw as `$RESULTS`; console.log is there too.
    pub results: PathBuf,
    pub console: String,
    pub markers: Vec<Marker>,
    /// Wall time of the boot (or native run), from launch to exit.
    pub wall: Duration,
    /// The scenario script's exit code.
    pub exit_code: Option<i32>,
}

impl Run {
    fn fail(&self, why: &str) -> ! {
        let tail: Vec<&str> = self.console.lines().rev().take(60).collect();
        let tail: Vec<&str> = tail.into_iter().rev().collect();
        panic!(
            "vm[{}] {}: {why}\n--- console (last 60 lines; all in {}) ---\n{}",
            self.backend.name(),
            self.name,
            self.results.join("console.log").display(),
            tail.join("\n")
        );
    }

    /// Panics, with the console, unless the scenario script exited 0.
    pub fn assert_success(&self) -> &Run {
        if self.exit_code != Some(0) {
            self.fail(&format!("scenario exited {:?}", self.exit_code));
        }
        self
    }

    /// The run that a scenario started itself with native.sh, whose results (and console.log)
    /// it left in the subdirectory `dir` of its own results.
    pub fn nested_native(&self, dir: &str) -> Run {
        let results = self.results.join(dir);
        let console = std::fs::read_to_string(results.join("console.log"))
            .unwrap_or_else(|e| self.fail(&format!("no console.log in {dir}: {e}")));
        let markers = parse_markers(&console);
        let mut run = Run {
            name: format!("{}/{dir}", self.name),
            backend: Backend::Native,
            results,
            console,
            markers,
            wall: Duration::ZERO,
            exit_code: None,
        };
        run.exit_code = run
            .event("exit")
            .and_then(|m| m.get("code"))
            .and_then(|c| c.parse().ok());
        run
    }

    /// The harness's own `@@VM event=...@@` marker.
    fn event(&self, event: &str) -> Option<&BTreeMap<String, String>> {
        self.markers
            .iter()
            .find(|m| m.kind == "VM" && m.fields.get("event").map(String::as_str) == Some(event))
            .map(|m| &m.fields)
    }

    /// The fields of the one `@@RESULT name=NAME ...@@` the scenario printed (`vm_result`).
    pub fn result(&self, name: &str) -> &BTreeMap<String, String> {
        let found: Vec<_> = self
            .markers
            .iter()
            .filter(|m| {
                m.kind == "RESULT" && m.fields.get("name").map(String::as_str) == Some(name)
            })
            .collect();
        match found[..] {
            [one] => &one.fields,
            _ => self.fail(&format!(
                "expected one @@RESULT name={name}@@, found {}",
                found.len()
            )),
        }
    }

    /// A file the scenario wrote to `$RESULTS`.
    pub fn read(&self, file: &str) -> Vec<u8> {
        std::fs::read(self.results.join(file))
            .unwrap_or_else(|e| self.fail(&format!("reading {file} from the results: {e}")))
    }

    pub fn read_to_string(&self, file: &str) -> String {
        String::from_utf8(self.read(file))
            .unwrap_or_else(|e| self.fail(&format!("{file} is not UTF-8: {e}")))
    }

    /// Seconds of guest time from the end of setup (modules, vcan0, share) to the scenario's end.
    fn scenario_secs(&self) -> Option<f64> {
        let at = |event: &str| self.event(event)?.get("uptime")?.parse::<f64>().ok();
        Some(at("exit")? - at("ready")?)
    }

    /// Prints, past the test capture, one line: what was checked and how long it took.
    pub fn report(&self, checked: &str) {
        let uptime = match self.backend {
            Backend::Qemu => self
                .event("exit")
                .and_then(|m| m.get("uptime"))
                .map(|u| format!(", guest uptime {u} s"))
                .unwrap_or_default(),
            Backend::Native => String::new(),
        };
        say(&format!(
            "vm[{}] {}: ok, {:.1} s wall (scenario {:.1} s{uptime}); checked: {checked}",
            self.backend.name(),
            self.name,
            self.wall.as_secs_f64(),
            self.scenario_secs().unwrap_or(f64::NAN),
        ));
    }
}
