//! End-to-end reaction benchmark of the threaded daemon on hw-mock (until `flyd bench
//! --end-to-end` is wired): `cargo run --release --example end_to_end -- [RUNS] [CONFIG]`.
//! Prints the report as JSON.

use std::path::Path;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let runs: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(10);
    let report = match args.next() {
        Some(path) => {
            let config = flyd::config::DaemonConfig::load(Path::new(&path))?;
            flyd::daemon::bench_end_to_end_with(&config, runs)?
        }
        None => flyd::daemon::bench_end_to_end(runs)?,
    };
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
