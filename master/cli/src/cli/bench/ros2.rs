//! `h4-master bench --only ros2` (issue 35, benchmarks; not tests: the figures depend on the
//! host and its load):
//!
//! * **CRTK device round trip through Zenoh at 1 kHz**, on one host: a device node publishes
//!   `measured_cp` (PoseStamped, CDR, rmw_zenoh's key and 33-byte attachment) every 1 ms; a
//!   server node, subscribed by rmw_zenoh's key, decodes it and answers at once with
//!   `servo_cf` (WrenchStamped carrying the pose's stamp); the device decodes the answer and
//!   takes the time. Two `Ros2Node`s, each its own Zenoh peer session over TCP on 127.0.0.1,
//!   as two processes would have. Against the bare Zenoh link's round trip in the same run
//!   ([`super::bare_zenoh`]); ratio at p99, goal ≤ 1.2.
//! * **The telemetry's cost to the 1 kHz loop**: a 1 kHz pacer hands a `SlaveSample` to the
//!   ROS 2 cell every cycle, as `Ros2Tee` does, while the publishing thread (`--ros2`, 100 Hz)
//!   takes it and publishes the five slave topics to a subscribed node; the hand-off's time
//!   and the loop's lateness, against the same loop without `--ros2` (no cell: the hand-off
//!   is skipped, as in the server).

use std::sync::atomic::Ordering;
use std::sync::{Arc, Mutex, mpsc};
use std::time::{Duration, Instant};

use h4_telemetry::rt::{Histogram, Pacer};
use h4_transport::ros2::keys::Distro;
use h4_transport::ros2::msgs::{Header, PoseStamped, Ros2Message, Time, WrenchStamped};
use h4_transport::ros2::node::{NodeConfig, Ros2Node, spawn_publisher};
use h4_transport::ros2::telemetry::{LatestCell, SlaveSample};
use h4_transport::ros2::{CrtkTopic, Ros2Names};

use super::{
    BenchReport, LABEL, PERIOD, REPLY_TIMEOUT, Ratio, Row, SPIN, WARM_UP, bare_zenoh, enter_fifo,
    figure, quantiles_us,
};

fn free_port() -> Result<u16, String> {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .map_err(|e| format!("a free port: {e}"))
}

/// Two nodes that reach each other: the first listens on a free loopback port, the second
/// connects to it.
fn node_pair(ns: &str) -> Result<(NodeConfig, NodeConfig), String> {
    let (p, q) = (free_port()?, free_port()?);
    let cfg = |name: &str, listen: u16, connect: u16| -> Result<NodeConfig, String> {
        Ok(NodeConfig {
            domain_id: 0,
            connect: format!("tcp/127.0.0.1:{connect}"),
            names: Ros2Names::new(ns).map_err(|e| e.to_string())?,
            node_name: name.to_owned(),
            distro: Distro::Jazzy,
            rate_hz: 100.0,
            listen: Some(format!("tcp/127.0.0.1:{listen}")),
        })
    };
    Ok((cfg("bench_device", p, q)?, cfg("bench_server", q, p)?))
}

fn stamp_of(seq: u64) -> Time {
    Time::from_ns(i64::try_from(seq).unwrap_or(i64::MAX)).unwrap_or_default()
}

/// The CRTK round trip, measured on this thread for `duration_s` after [`WARM_UP`] answers.
fn crtk_round_trip(duration_s: f64, realtime: bool) -> Result<(Histogram, u64), String> {
    let (device_cfg, server_cfg) = node_pair("/bench_device")?;
    let names = device_cfg.names.clone();
    let (cp, cf) = (
        names.topic(CrtkTopic::MeasuredCp),
        names.topic(CrtkTopic::ServoCf),
    );
    let e = |e: h4_transport::ros2::node::Ros2Error| e.to_string();
    // The server: decodes each pose and answers with a wrench carrying its stamp.
    let mut server = Ros2Node::open(&server_cfg).map_err(e)?;
    let (answer, _) = server
        .declare_raw_publisher(&cf, WrenchStamped::TYPE_NAME)
        .map_err(e)?;
    let answer = Mutex::new(answer);
    server
        .declare_subscription(&cp, PoseStamped::TYPE_NAME, move |_, payload, _| {
            let Ok(pose) = PoseStamped::decode(payload) else {
                return;
            };
            let w = WrenchStamped {
                header: pose.header,
                wrench: Default::default(),
            };
            if let (Ok(bytes), Ok(mut p)) = (w.encode(), answer.lock()) {
                let _ = p.put(bytes, 0);
            }
        })
        .map_err(e)?;
    // The device: publishes poses, hears the answers' stamps.
    let mut device = Ros2Node::open(&device_cfg).map_err(e)?;
    let (mut pose_pub, _) = device
        .declare_raw_publisher(&cp, PoseStamped::TYPE_NAME)
        .map_err(e)?;
    let (tx, rx) = mpsc::sync_channel::<u64>(64);
    device
        .declare_subscription(&cf, WrenchStamped::TYPE_NAME, move |_, payload, _| {
            if let Ok(w) = WrenchStamped::decode(payload) {
                let ns = i64::from(w.header.stamp.sec) * 1_000_000_000
                    + i64::from(w.header.stamp.nanosec);
                let _ = tx.try_send(u64::try_from(ns).unwrap_or(0));
            }
        })
        .map_err(e)?;
    enter_fifo(realtime);
    let mut pacer = Pacer::new(PERIOD, SPIN);
    let mut rtt = Histogram::new();
    let (mut seq, mut answered, mut lost) = (0u64, 0u64, 0u64);
    let first_deadline = Instant::now() + Duration::from_secs(20);
    let measured = (duration_s * 1e3) as u64;
    while rtt.count() < measured {
        pacer.wait();
        seq += 1;
        let pose = PoseStamped {
            header: Header {
                stamp: stamp_of(seq),
                frame_id: "bench_device_base".to_owned(),
            },
            pose: Default::default(),
        };
        let t0 = Instant::now();
        let bytes = pose.encode().map_err(|e| e.to_string())?;
        pose_pub.put(bytes, 0).map_err(e)?;
        let deadline = t0 + REPLY_TIMEOUT;
        let mut got = false;
        while !got {
            match rx.recv_timeout(deadline.saturating_duration_since(Instant::now())) {
                Ok(s) => got = s == seq,
                Err(_) => break,
            }
        }
        if !got {
            if answered == 0 && Instant::now() > first_deadline {
                return Err("no answer within 20 s".into());
            }
            if answered >= WARM_UP {
                lost += 1;
            }
            continue;
        }
        answered += 1;
        if answered > WARM_UP {
            rtt.record(u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX));
        }
    }
    Ok((rtt, lost))
}

/// A 1 kHz loop handing a sample to `cell` each cycle (none: skipped): the hand-off's time
/// and the loop's lateness, ns.
fn loop_with_cell(
    duration_s: f64,
    realtime: bool,
    cell: Option<&LatestCell<SlaveSample>>,
) -> (Histogram, Histogram) {
    enter_fifo(realtime);
    let mut pacer = Pacer::new(PERIOD, SPIN);
    let (mut handoff, mut late) = (Histogram::new(), Histogram::new());
    let cycles = (duration_s * 1e3) as u64;
    for i in 0..cycles {
        let tick = pacer.wait();
        late.record(tick.lateness_ns);
        let t0 = Instant::now();
        if let Some(c) = cell {
            c.offer(SlaveSample {
                stamp_unix_ns: i,
                pose_mm_rad: [i as f64 * 1e-3, 0.0, 300.0, 0.0],
                ..SlaveSample::default()
            });
        }
        handoff.record(u64::try_from(t0.elapsed().as_nanos()).unwrap_or(u64::MAX));
    }
    (handoff, late)
}

/// The telemetry's cost, with `--ros2` (a publishing thread at 100 Hz to a subscribed node)
/// and without, each on a thread of its own.
fn telemetry_cost(duration_s: f64, realtime: bool) -> Result<[(Histogram, Histogram); 2], String> {
    let (pub_cfg, sub_cfg) = node_pair("/h4")?;
    let e = |e: h4_transport::ros2::node::Ros2Error| e.to_string();
    let mut listener = Ros2Node::open(&sub_cfg).map_err(e)?;
    let heard = Arc::new(std::sync::atomic::AtomicU64::new(0));
    for t in CrtkTopic::SLAVE {
        let h = Arc::clone(&heard);
        listener
            .declare_subscription(&pub_cfg.names.topic(t), t.type_name(), move |_, _, _| {
                h.fetch_add(1, Ordering::Relaxed);
            })
            .map_err(e)?;
    }
    let cell = Arc::new(LatestCell::new());
    let publishing = spawn_publisher(&pub_cfg, Arc::clone(&cell)).map_err(e)?;
    let c = Arc::clone(&cell);
    let with = std::thread::spawn(move || loop_with_cell(duration_s, realtime, Some(&c)))
        .join()
        .map_err(|_| "the loop thread panicked".to_string())?;
    let report = publishing.stop();
    drop(listener);
    if report.messages == 0 || heard.load(Ordering::Relaxed) == 0 {
        return Err(format!(
            "the publishing thread published {} messages, {} heard",
            report.messages,
            heard.load(Ordering::Relaxed)
        ));
    }
    let without = std::thread::spawn(move || loop_with_cell(duration_s, realtime, None))
        .join()
        .map_err(|_| "the loop thread panicked".to_string())?;
    Ok([with, without])
}

/// Adds the ROS 2 rows and ratios to `report`.
pub(super) fn rows(report: &mut BenchReport, d: f64, realtime: bool, no_zenoh_bare: bool) {
    eprintln!("{LABEL}: ROS 2 CRTK device round trip through Zenoh, {d} s");
    let crtk = crtk_round_trip(d, realtime);
    let bare = if no_zenoh_bare {
        None
    } else {
        eprintln!("{LABEL}: Zenoh bare round trip (the reference), {d} s");
        Some(bare_zenoh(d, realtime))
    };
    let row = |name: &str, h: &Histogram, lost: u64| {
        let mut figures = quantiles_us(h);
        figures.push(("lost".into(), lost as f64));
        Row {
            name: name.into(),
            unit: "us",
            figures,
            target: String::new(),
            met: None,
        }
    };
    match (crtk, bare) {
        (Ok((h, lost)), Some(Ok((bh, blost)))) => {
            let mut c = row(
                "ros2: CRTK device round trip (measured_cp -> servo_cf), two nodes",
                &h,
                lost,
            );
            let b = row("ros2: bare Zenoh link round trip, same run", &bh, blost);
            let ratio = figure(&c, "p99") / figure(&b, "p99");
            c.target = "p99 <= 1.2 x bare Zenoh".into();
            c.met = Some(ratio <= 1.2);
            report.ratios.push(Ratio {
                name: "ros2 CRTK round trip p99 / bare Zenoh p99".into(),
                value: ratio,
                at_most: Some(1.2),
            });
            report.rows.extend([c, b]);
        }
        (Ok((h, lost)), other) => {
            report.rows.push(row(
                "ros2: CRTK device round trip (measured_cp -> servo_cf), two nodes",
                &h,
                lost,
            ));
            if let Some(Err(e)) = other {
                report.skipped.push(format!("ros2: bare Zenoh: {e}"));
            }
        }
        (Err(e), _) => report.skipped.push(format!("ros2 CRTK round trip: {e}")),
    }
    eprintln!(
        "{LABEL}: ROS 2 telemetry's cost to the 1 kHz loop, with and without --ros2, {d} s each"
    );
    match telemetry_cost(d, realtime) {
        Ok([(h_with, l_with), (h_without, l_without)]) => {
            let mut with = row(
                "ros2: loop hand-off, --ros2 (publishing 100 Hz)",
                &h_with,
                0,
            );
            with.target = "p99 <= 5 us".into();
            with.met = Some(figure(&with, "p99") <= 5.0);
            let without = row("ros2: loop hand-off, without --ros2", &h_without, 0);
            let lw = row("ros2: loop lateness, --ros2", &l_with, 0);
            let lwo = row("ros2: loop lateness, without --ros2", &l_without, 0);
            report.ratios.push(Ratio {
                name: "ros2 loop lateness p99: --ros2 / without".into(),
                value: figure(&lw, "p99") / figure(&lwo, "p99"),
                at_most: None,
            });
            report.rows.extend([with, without, lw, lwo]);
        }
        Err(e) => report.skipped.push(format!("ros2 telemetry cost: {e}")),
    }
}
