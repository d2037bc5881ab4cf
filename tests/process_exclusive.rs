//! One master and one slave per arm (issue 14): a second `h4-slave run` or `h4-master run`
//! on the same iceoryx2 services or Zenoh key expressions is refused with a clear message and
//! exit code 2, and the first pair keeps working.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use h4_shared::wire::SlaveState;
use h4_tests::procs::*;

/// Runs `bin args` and expects the refusal: exit 2, a message naming it.
fn refused(what: &str, bin: &std::path::Path, args: &[String], scratch: &Scratch) {
    let mut p = Running::spawn("second", bin, args, scratch);
    let status = p.wait_status(30.0);
    let log = p.log();
    assert_eq!(status.code(), Some(2), "{what} was not refused: {log}");
    assert!(log.contains("refused"), "{what}: {log}");
}

#[test]
fn a_second_slave_or_master_on_the_same_iceoryx2_services_is_refused() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("excl-iox");
    let mut sl = Running::spawn("slave", slave, &slave_args(&scratch, &[]), &scratch);
    let mut mon = spy(&scratch);
    watch_until(&mut mon, 20.0, "slave feedback", |_| true);
    refused(
        "a second slave",
        slave,
        &slave_args(&scratch, &["--duration-s", "3"]),
        &scratch,
    );
    let ms = scratch.path("master.json").display().to_string();
    let mut ma = Running::spawn(
        "master",
        master,
        &master_args(&scratch, &["--summary", &ms]),
        &scratch,
    );
    watch_until(&mut mon, 20.0, "the first master commands", |fb| {
        fb.state == SlaveState::Active as u8
    });
    refused(
        "a second master",
        master,
        &master_args(&scratch, &["--duration-s", "3"]),
        &scratch,
    );
    // The first pair still works.
    let before = watch_until(&mut mon, 5.0, "feedback", |_| true).echo_seq;
    watch_until(
        &mut mon,
        5.0,
        "the first master's commands still echoed",
        |fb| fb.state == SlaveState::Active as u8 && fb.echo_seq > before + 100,
    );
    ma.stop();
    sl.stop();
    let m = read_json(&scratch.path("master.json"));
    assert!(u(&m, "round_trip_samples") > 100, "{m:#}");
}

#[test]
fn a_second_slave_or_master_on_the_same_zenoh_keys_is_refused() {
    let _g = serial();
    let (master, slave) = binaries();
    let scratch = Scratch::new("excl-zenoh");
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("free port")
        .port();
    let endpoint = format!("tcp/127.0.0.1:{port}");
    let zenoh = |listen: bool| -> Vec<&str> {
        let flag = if listen {
            "--zenoh-listen"
        } else {
            "--zenoh-connect"
        };
        vec!["--transport", "zenoh", flag, &endpoint]
    };
    let mut sl = Running::spawn(
        "slave",
        slave,
        &slave_args(&scratch, &zenoh(true)),
        &scratch,
    );
    // The first slave listens, then claims its role (after Zenoh's settle time).
    let t = std::time::Instant::now();
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(t.elapsed().as_secs() < 20, "the first slave never listened");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    std::thread::sleep(std::time::Duration::from_secs(2));
    let mut second = zenoh(false);
    second.extend(["--duration-s", "3"]);
    refused(
        "a second slave",
        slave,
        &slave_args(&scratch, &second),
        &scratch,
    );
    let ms = scratch.path("master.json").display().to_string();
    let mut first = zenoh(false);
    first.extend(["--summary", ms.as_str()]);
    let mut ma = Running::spawn("master", master, &master_args(&scratch, &first), &scratch);
    // The first master claims its role (Zenoh's settle time) before the second starts.
    std::thread::sleep(std::time::Duration::from_secs(3));
    refused(
        "a second master",
        master,
        &master_args(&scratch, &second),
        &scratch,
    );
    ma.stop();
    sl.stop();
    let m = read_json(&scratch.path("master.json"));
    assert!(u(&m, "round_trip_samples") > 100, "{m:#}");
    assert_eq!(u(&m, "feedback_invalid"), 0, "{m:#}");
}
