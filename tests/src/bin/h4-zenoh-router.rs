//! `h4-zenoh-router ENDPOINT [CONFIG.json5]`: a Zenoh router built from the project's own
//! zenoh crate, for the tests that need one (a router restart under clients) without a
//! `zenohd` download at test time. Listens on ENDPOINT (e.g. `tcp/10.77.0.1:7447`), scouting
//! off, until SIGTERM/SIGINT; prints `ready` on stdout once listening.

use std::process::ExitCode;
use std::time::Duration;

use zenoh::Wait;

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let endpoint = args
        .next()
        .ok_or("usage: h4-zenoh-router ENDPOINT [CONFIG.json5]")?;
    let mut config = match args.next() {
        Some(path) => zenoh::Config::from_file(&path).map_err(|e| format!("{path}: {e}"))?,
        None => zenoh::Config::default(),
    };
    for (key, value) in [
        ("mode", "\"router\"".to_string()),
        ("listen/endpoints", format!("[{endpoint:?}]")),
        ("scouting/multicast/enabled", "false".to_string()),
    ] {
        config
            .insert_json5(key, &value)
            .map_err(|e| format!("{key}: {e}"))?;
    }
    h4_telemetry::process::install_stop_handlers().map_err(|e| e.to_string())?;
    let session = zenoh::open(config).wait().map_err(|e| e.to_string())?;
    println!("ready");
    while !h4_telemetry::process::stop_requested() {
        std::thread::sleep(Duration::from_millis(20));
    }
    session.close().wait().map_err(|e| e.to_string())
}

fn main() -> ExitCode {
    match run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("h4-zenoh-router: {e}");
            ExitCode::from(2)
        }
    }
}
