//! `report`: PNG figures, `metrics.json` and an `index.html` from a recording (MCAP) of an
//! experiment (`h4-slave experiment --record`), a session (`h4-master sim --record`) or the
//! processes (`h4-slave run` / `h4-master run` / `loopback --record`).
//!
//! The recording is read field by field (JSON messages), so a recording from an older or newer
//! build still gives the figures whose fields it has. A file cut short (a process killed while
//! recording) is read up to the last complete message and the report says so.
//!
//! Figures, by what the recording holds:
//! * `/slave/force` (experiments): the true and measured normal force against time with the
//!   set-point and a ±tolerance band (the paper's figs 6–7), the force along the tool's path,
//!   and the force and position tracking errors;
//! * `/master/cycle` + `/slave/cycle` (sessions and processes): the force rendered to the
//!   operator against the slave's true and measured contact force, both passivity observers,
//!   and the link: the round trip the master measured each cycle (`round_trip_us`) and, for
//!   sessions, the messages lost per 100 ms in each direction (`/link/events`).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use plotters::prelude::*;
use serde::Serialize;
use serde_json::Value;

/// Why a report could not be made.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The recording could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not an MCAP recording, or has no message this report knows.
    #[error("{path}: {message}")]
    Recording {
        /// The file.
        path: String,
        /// What is wrong.
        message: String,
    },
    /// An output file could not be written.
    #[error("cannot write {path}: {message}")]
    Write {
        /// The file.
        path: String,
        /// Why.
        message: String,
    },
}

/// Settings of a report.
#[derive(Clone, Debug)]
pub struct ReportOptions {
    /// Where the files go (created if missing).
    pub out_dir: PathBuf,
    /// Half-width of the band drawn around the force set-point, N.
    pub tolerance_n: f64,
    /// A cutting session's part folder (`h4-master sim --out DIR`): its cutting fields
    /// (`cut.json`: the mesh judge's among them) join the metrics as `cut/<field>`, its
    /// `deviation.png` and `height.png` the figures, and `part.stl` is linked.
    pub part_dir: Option<PathBuf>,
}

/// What a report wrote.
#[derive(Clone, Debug, Serialize)]
pub struct ReportOutput {
    /// The figures, file names inside the output folder.
    pub figures: Vec<String>,
    /// The metrics (also in `metrics.json`).
    pub metrics: BTreeMap<String, Value>,
}

/// One topic's messages: time since the recording's first message (s) and the message.
type Topic = Vec<(f64, Value)>;

/// Reads every complete message; a cut-short file gives what it has, with `truncated` set.
fn read_topics(path: &Path) -> Result<(BTreeMap<String, Topic>, bool), ReportError> {
    let bytes = std::fs::read(path).map_err(|source| ReportError::Read {
        path: path.display().to_string(),
        source,
    })?;
    let stream = mcap::MessageStream::new(&bytes).map_err(|e| ReportError::Recording {
        path: path.display().to_string(),
        message: format!("not an MCAP file: {e}"),
    })?;
    let mut topics: BTreeMap<String, Topic> = BTreeMap::new();
    let mut first_ns: Option<u64> = None;
    let mut truncated = false;
    for msg in stream {
        let msg = match msg {
            Ok(m) => m,
            Err(_) => {
                truncated = true;
                break;
            }
        };
        let Ok(value) = serde_json::from_slice::<Value>(&msg.data) else {
            continue;
        };
        let t0 = *first_ns.get_or_insert(msg.log_time);
        let t_s = msg.log_time.saturating_sub(t0) as f64 * 1e-9;
        topics
            .entry(msg.channel.topic.clone())
            .or_default()
            .push((t_s, value));
    }
    // A channel the recording declares but never wrote to (a session's `/link/events` on a
    // link that lost nothing) is an empty topic, not a missing one. A file cut short has no
    // summary: its topics are the ones with messages.
    if let Ok(Some(summary)) = mcap::Summary::read(&bytes) {
        for channel in summary.channels.values() {
            topics.entry(channel.topic.clone()).or_default();
        }
    }
    Ok((topics, truncated))
}

fn num(v: &Value, key: &str) -> Option<f64> {
    v.get(key).and_then(Value::as_f64)
}

fn comp(v: &Value, key: &str, i: usize) -> Option<f64> {
    v.get(key)?.as_array()?.get(i)?.as_f64()
}

fn norm3_of(v: &Value, key: &str) -> Option<f64> {
    let a = v.get(key)?.as_array()?;
    let mut s = 0.0;
    for x in a.iter().take(3) {
        let x = x.as_f64()?;
        s += x * x;
    }
    Some(s.sqrt())
}

/// `(t, f(message))` for every message where `f` has a value.
fn series(topic: &Topic, f: impl Fn(&Value) -> Option<f64>) -> Vec<(f64, f64)> {
    topic
        .iter()
        .filter_map(|(t, v)| f(v).map(|y| (*t, y)))
        .filter(|(_, y)| y.is_finite())
        .collect()
}

/// A line of a figure.
struct Line {
    label: &'static str,
    color: RGBColor,
    points: Vec<(f64, f64)>,
}

/// Keeps at most `2 · buckets` points: the smallest and the largest of each bucket, in order,
/// so peaks and oscillations survive the thinning.
fn min_max_thin(points: &[(f64, f64)], buckets: usize) -> Vec<(f64, f64)> {
    if points.len() <= 2 * buckets {
        return points.to_vec();
    }
    let per = points.len().div_ceil(buckets);
    let mut out = Vec::with_capacity(2 * buckets);
    for chunk in points.chunks(per) {
        let lo = chunk.iter().min_by(|a, b| a.1.total_cmp(&b.1));
        let hi = chunk.iter().max_by(|a, b| a.1.total_cmp(&b.1));
        if let (Some(lo), Some(hi)) = (lo, hi) {
            if lo.0 <= hi.0 {
                out.extend([*lo, *hi]);
            } else {
                out.extend([*hi, *lo]);
            }
        }
    }
    out
}

fn bounds(lines: &[Line], extra_y: &[f64]) -> Option<((f64, f64), (f64, f64))> {
    bounds_of(&lines.iter().collect::<Vec<_>>(), extra_y)
}

fn bounds_of(lines: &[&Line], extra_y: &[f64]) -> Option<((f64, f64), (f64, f64))> {
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = (f64::INFINITY, f64::NEG_INFINITY);
    for (px, py) in lines.iter().flat_map(|l| l.points.iter()) {
        x = (x.0.min(*px), x.1.max(*px));
        y = (y.0.min(*py), y.1.max(*py));
    }
    for v in extra_y {
        y = (y.0.min(*v), y.1.max(*v));
    }
    if !(x.0.is_finite() && y.0.is_finite()) {
        return None;
    }
    if x.1 - x.0 < 1e-9 {
        x.1 = x.0 + 1.0;
    }
    // A flat line (a constant round trip) gets a readable axis around it.
    let pad = if y.1 - y.0 < 1e-9 {
        (y.0.abs() * 0.1).max(1.0)
    } else {
        (y.1 - y.0) * 0.05
    };
    Some((x, (y.0 - pad, y.1 + pad)))
}

/// A figure: title, axis names with units, lines, and an optional band `(x, low, high)`;
/// optionally a second panel below on the same time axis (its own y axis and lines).
struct Figure<'a> {
    file: &'a str,
    title: String,
    x_desc: &'a str,
    y_desc: &'a str,
    lines: Vec<Line>,
    band: Vec<(f64, f64, f64)>,
    lower: Option<Panel<'a>>,
}

/// The lower panel of a [`Figure`]: y axis name with its unit, lines.
struct Panel<'a> {
    y_desc: &'a str,
    lines: Vec<Line>,
}

const WIDTH: u32 = 1200;
const HEIGHT: u32 = 560;
/// Height of the lower panel of a two-panel figure (added to [`HEIGHT`]).
const LOWER_HEIGHT: u32 = 300;
const BAND_COLOR: RGBColor = RGBColor(120, 200, 120);

type Area<'a> = DrawingArea<BitMapBackend<'a>, plotters::coord::Shift>;

/// A point of a band: `(x, low, high)`.
type BandPoint = (f64, f64, f64);

/// One chart of a figure on `area`: `caption` on top, x range `xs` (the y range from the
/// lines, the band and `extra_y`), axes, lines `stroke` px wide, band, legend.
fn draw_panel(
    area: &Area<'_>,
    caption: Option<&str>,
    xs: (f64, f64),
    (x_desc, y_desc): (&str, &str),
    (lines, band, extra_y): (&[Line], &[BandPoint], &[f64]),
    stroke: u32,
) -> Result<(), String> {
    let mut band_y: Vec<f64> = band.iter().flat_map(|b| [b.1, b.2]).collect();
    band_y.extend_from_slice(extra_y);
    let Some((_, (y0, y1))) = bounds(lines, &band_y) else {
        return Ok(());
    };
    let mut builder = ChartBuilder::on(area);
    if let Some(c) = caption {
        builder.caption(c, ("sans-serif", 26));
    }
    let mut chart = builder
        .margin(16)
        .x_label_area_size(48)
        .y_label_area_size(72)
        .build_cartesian_2d(xs.0..xs.1, y0..y1)
        .map_err(|e| e.to_string())?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 16))
        .axis_desc_style(("sans-serif", 18))
        .light_line_style(RGBColor(235, 235, 235))
        .draw()
        .map_err(|e| e.to_string())?;
    if !band.is_empty() {
        let mut outline: Vec<(f64, f64)> = band.iter().map(|b| (b.0, b.2)).collect();
        outline.extend(band.iter().rev().map(|b| (b.0, b.1)));
        chart
            .draw_series(std::iter::once(Polygon::new(
                outline,
                BAND_COLOR.mix(0.35).filled(),
            )))
            .map_err(|e| e.to_string())?
            .label("set-point ± tolerance")
            .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 20, y + 6)], BAND_COLOR.filled()));
    }
    for line in lines {
        let color = line.color;
        chart
            .draw_series(LineSeries::new(
                min_max_thin(&line.points, 3000),
                color.stroke_width(stroke),
            ))
            .map_err(|e| e.to_string())?
            .label(line.label)
            .legend(move |(x, y)| PathElement::new([(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    chart
        .configure_series_labels()
        .label_font(("sans-serif", 16))
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .position(SeriesLabelPosition::UpperRight)
        .draw()
        .map_err(|e| e.to_string())?;
    Ok(())
}

fn draw(fig: &Figure<'_>, dir: &Path) -> Result<bool, ReportError> {
    let path = dir.join(fig.file);
    let err = |e: &dyn std::fmt::Display| ReportError::Write {
        path: path.display().to_string(),
        message: e.to_string(),
    };
    // One time axis for both panels.
    let lower_lines = fig.lower.as_ref().map_or(&[][..], |p| &p.lines[..]);
    let band_y: Vec<f64> = fig.band.iter().flat_map(|b| [b.1, b.2]).collect();
    let all: Vec<&Line> = fig.lines.iter().chain(lower_lines).collect();
    let Some(((x0, x1), _)) = bounds_of(&all, &band_y) else {
        return Ok(false);
    };
    let height = HEIGHT + fig.lower.as_ref().map_or(0, |_| LOWER_HEIGHT);
    let root = BitMapBackend::new(&path, (WIDTH, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let (upper, lower) = root.split_vertically(HEIGHT);
    draw_panel(
        &upper,
        Some(&fig.title),
        (x0, x1),
        (fig.x_desc, fig.y_desc),
        (&fig.lines, &fig.band, &[]),
        1,
    )
    .map_err(|e| err(&e))?;
    if let Some(p) = &fig.lower {
        // Counts from 0, at least 0–1 (a link that lost nothing is a line at 0).
        draw_panel(
            &lower,
            None,
            (x0, x1),
            (fig.x_desc, p.y_desc),
            (&p.lines, &[], &[0.0, 1.0]),
            2,
        )
        .map_err(|e| err(&e))?;
    }
    root.present().map_err(|e| err(&e))?;
    Ok(true)
}

const C_TRUE: RGBColor = RGBColor(200, 30, 30);
const C_MEAS: RGBColor = RGBColor(30, 90, 200);
const C_SET: RGBColor = RGBColor(20, 120, 20);
const C_MASTER: RGBColor = RGBColor(230, 130, 0);
const C_OTHER: RGBColor = RGBColor(120, 60, 160);

/// Percentile (0–100) of `v` by nearest rank; NaN for no values.
fn percentile(v: &[f64], p: f64) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let rank = ((p / 100.0) * s.len() as f64).ceil() as usize;
    s[rank.clamp(1, s.len()) - 1]
}

fn max_of(points: &[(f64, f64)]) -> f64 {
    points.iter().map(|p| p.1).fold(f64::NAN, f64::max)
}

fn min_of(points: &[(f64, f64)]) -> f64 {
    points.iter().map(|p| p.1).fold(f64::NAN, f64::min)
}

/// Experiments: force against time with the set-point band, force along the path, errors.
fn experiment_figures(
    topics: &BTreeMap<String, Topic>,
    opts: &ReportOptions,
    figures: &mut Vec<Figure<'static>>,
    metrics: &mut BTreeMap<String, Value>,
) {
    let Some(force) = topics.get("/slave/force") else {
        return;
    };
    let f_true = series(force, |v| num(v, "fn_true_n"));
    let f_meas = series(force, |v| num(v, "fn_measured_n"));
    let set = series(force, |v| num(v, "setpoint_n"));
    let tol = opts.tolerance_n;
    let band: Vec<(f64, f64, f64)> = set.iter().map(|(t, s)| (*t, s - tol, s + tol)).collect();
    figures.push(Figure {
        file: "force.png",
        title: "Contact force against time (set-point ± tolerance)".into(),
        x_desc: "time (s)",
        y_desc: "normal force (N)",
        lines: vec![
            Line {
                label: "measured force (filtered sensor)",
                color: C_MEAS,
                points: f_meas,
            },
            Line {
                label: "true force",
                color: C_TRUE,
                points: f_true.clone(),
            },
            Line {
                label: "set-point",
                color: C_SET,
                points: set.clone(),
            },
        ],
        band,
        lower: None,
    });
    // Errors over the whole contact, from the first time the true force reaches half the
    // set-point: the first touch's transient is kept.
    let contact_from = f_true
        .iter()
        .zip(&set)
        .find(|((_, f), (_, s))| *s > 0.0 && *f >= 0.5 * s)
        .map(|((t, _), _)| *t);
    let err: Vec<(f64, f64)> = f_true
        .iter()
        .zip(&set)
        .filter(|((t, _), _)| contact_from.is_some_and(|c| *t >= c))
        .map(|((t, f), (_, s))| (*t, f - s))
        .collect();
    let abs: Vec<f64> = err.iter().map(|e| e.1.abs()).collect();
    metrics.insert("first_contact_s".into(), opt_json(contact_from));
    metrics.insert(
        "force_error_max_n".into(),
        json_f(abs.iter().copied().fold(f64::NAN, f64::max)),
    );
    metrics.insert("force_error_p99_n".into(), json_f(percentile(&abs, 99.0)));
    metrics.insert(
        "force_error_rms_n".into(),
        json_f((abs.iter().map(|e| e * e).sum::<f64>() / abs.len().max(1) as f64).sqrt()),
    );
    metrics.insert("max_force_n".into(), json_f(max_of(&f_true)));
    metrics.insert("tolerance_n".into(), json_f(tol));
    if let Some(pose) = topics.get("/slave/pose") {
        let pos_err = series(pose, |v| {
            let mut s = 0.0;
            for i in 0..3 {
                let d = comp(v, "measured", i)? - comp(v, "commanded", i)?;
                s += d * d;
            }
            Some(s.sqrt())
        });
        // Force along the path: distance travelled by the measured tool position.
        let mut path = Vec::with_capacity(pose.len());
        let mut dist = 0.0;
        let mut last: Option<[f64; 3]> = None;
        for ((_, v), (_, f)) in pose.iter().zip(force.iter()) {
            let (Some(x), Some(y), Some(z), Some(fv)) = (
                comp(v, "measured", 0),
                comp(v, "measured", 1),
                comp(v, "measured", 2),
                num(f, "fn_true_n"),
            ) else {
                continue;
            };
            if let Some(l) = last {
                dist += ((x - l[0]).powi(2) + (y - l[1]).powi(2) + (z - l[2]).powi(2)).sqrt();
            }
            last = Some([x, y, z]);
            path.push((dist, fv));
        }
        metrics.insert("path_length_mm".into(), json_f(dist));
        figures.push(Figure {
            file: "force_along_path.png",
            title: "Contact force along the tool's path".into(),
            x_desc: "distance travelled (mm)",
            y_desc: "true normal force (N)",
            lines: vec![Line {
                label: "true force",
                color: C_TRUE,
                points: path,
            }],
            band: Vec::new(),
            lower: None,
        });
        figures.push(Figure {
            file: "tracking_error.png",
            title: "Tracking errors".into(),
            x_desc: "time (s)",
            y_desc: "force error (N) / position error (mm)",
            lines: vec![
                Line {
                    label: "force error, true − set-point (N)",
                    color: C_TRUE,
                    points: err,
                },
                Line {
                    label: "|measured − commanded position| (mm)",
                    color: C_OTHER,
                    points: pos_err,
                },
            ],
            band: Vec::new(),
            lower: None,
        });
    }
}

/// Sessions and processes: rendered against slave force, observers, round trip, losses.
fn teleop_figures(
    topics: &BTreeMap<String, Topic>,
    figures: &mut Vec<Figure<'static>>,
    metrics: &mut BTreeMap<String, Value>,
) {
    let master = topics.get("/master/cycle");
    let slave = topics.get("/slave/cycle");
    if master.is_none() && slave.is_none() {
        return;
    }
    let mut lines = Vec::new();
    if let Some(m) = master {
        let rendered = series(m, |v| norm3_of(v, "rendered_wrench"));
        metrics.insert("max_master_force_n".into(), json_f(max_of(&rendered)));
        lines.push(Line {
            label: "rendered to the operator",
            color: C_MASTER,
            points: rendered,
        });
    }
    if let Some(s) = slave {
        // Session: `true_force_n` (vector) and `wrench_measured`; process: scalars.
        let true_f = series(s, |v| {
            norm3_of(v, "true_force_n").or_else(|| num(v, "force_true_n"))
        });
        let meas = series(s, |v| {
            norm3_of(v, "wrench_measured").or_else(|| num(v, "force_measured_n"))
        });
        metrics.insert("max_force_n".into(), json_f(max_of(&true_f)));
        lines.push(Line {
            label: "slave, measured force",
            color: C_MEAS,
            points: meas,
        });
        lines.push(Line {
            label: "slave, true contact force",
            color: C_TRUE,
            points: true_f,
        });
    }
    figures.push(Figure {
        file: "forces.png",
        title: "Force rendered to the operator and contact force at the slave".into(),
        x_desc: "time (s)",
        y_desc: "force magnitude (N)",
        lines,
        band: Vec::new(),
        lower: None,
    });
    // Session: `observed_j`; process: `energy_observed_j`.
    let observed = |v: &Value| num(v, "observed_j").or_else(|| num(v, "energy_observed_j"));
    let m_obs = master.map(|m| series(m, observed));
    let s_obs = slave.map(|s| series(s, observed));
    let has_obs = m_obs.as_ref().is_some_and(|o| !o.is_empty())
        || s_obs.as_ref().is_some_and(|o| !o.is_empty());
    if has_obs {
        let to_mj = |o: Option<Vec<(f64, f64)>>| -> Vec<(f64, f64)> {
            o.unwrap_or_default()
                .into_iter()
                .map(|(t, e)| (t, e * 1e3))
                .collect()
        };
        let (m_mj, s_mj) = (to_mj(m_obs), to_mj(s_obs));
        metrics.insert("master_observer_min_mj".into(), json_f(min_of(&m_mj)));
        metrics.insert("slave_observer_min_mj".into(), json_f(min_of(&s_mj)));
        figures.push(Figure {
            file: "observers.png",
            title: "Passivity observers (energy the link may still release)".into(),
            x_desc: "time (s)",
            y_desc: "observed energy (mJ)",
            lines: vec![
                Line {
                    label: "master port",
                    color: C_MASTER,
                    points: m_mj,
                },
                Line {
                    label: "slave port",
                    color: C_MEAS,
                    points: s_mj,
                },
            ],
            band: Vec::new(),
            lower: None,
        });
    }
    link_figure(topics, master, duration_s(topics), figures, metrics);
}

/// Messages lost per 100 ms bin of the recording (every bin, the empty ones too), of the
/// link events of `direction` (`command` or `feedback`), and their total.
fn losses(events: &Topic, direction: &str, duration_s: f64) -> (Vec<(f64, f64)>, u64) {
    let mut lost: BTreeMap<i64, f64> = BTreeMap::new();
    let mut total = 0u64;
    for (t, v) in events {
        let kind = v
            .get("event")
            .and_then(|e| e.get("kind"))
            .and_then(Value::as_str)
            .unwrap_or("");
        let dir = v.get("direction").and_then(Value::as_str).unwrap_or("");
        if dir == direction && matches!(kind, "lost" | "blacked_out" | "overflowed") {
            *lost.entry((t / 0.1).floor() as i64).or_default() += 1.0;
            total += 1;
        }
    }
    let bins = (duration_s / 0.1).ceil() as i64;
    for b in 0..bins {
        lost.entry(b).or_default();
    }
    let points = lost.into_iter().map(|(b, n)| (b as f64 * 0.1, n)).collect();
    (points, total)
}

/// Feedback lost per 100 ms bin (every bin) from the running count `feedback_lost` of a
/// process's `/master/cycle`, and the count at the end; None when the recording has no count.
fn feedback_losses(master: &Topic, duration_s: f64) -> Option<(Vec<(f64, f64)>, u64)> {
    let counts = series(master, |v| num(v, "feedback_lost"));
    let last = counts.last()?.1;
    let mut lost: BTreeMap<i64, f64> = BTreeMap::new();
    let bins = (duration_s / 0.1).ceil() as i64;
    for b in 0..bins {
        lost.entry(b).or_default();
    }
    let mut prev = 0.0;
    for (t, n) in counts {
        *lost.entry((t / 0.1).floor() as i64).or_default() += (n - prev).max(0.0);
        prev = n;
    }
    let points = lost.into_iter().map(|(b, n)| (b as f64 * 0.1, n)).collect();
    Some((points, last as u64))
}

/// Commands the slave did not act on, per 100 ms bin (every bin), from the sequence numbers
/// of the commands a process's `/slave/cycle` acted on (`command_seq`): a jump of k > 1
/// between consecutive records is k − 1 commands lost, rejected or overtaken within one
/// cycle; and their total. None when the recording has no sequence numbers.
fn commands_missed(slave: &Topic, duration_s: f64) -> Option<(Vec<(f64, f64)>, u64)> {
    let seqs = series(slave, |v| num(v, "command_seq"));
    seqs.first()?;
    let mut missed: BTreeMap<i64, f64> = BTreeMap::new();
    let bins = (duration_s / 0.1).ceil() as i64;
    for b in 0..bins {
        missed.entry(b).or_default();
    }
    let mut total = 0u64;
    let mut prev: Option<f64> = None;
    for (t, seq) in seqs {
        // 0: nothing acted on yet; a smaller number: a new master (a new sequence).
        if seq > 0.0 {
            if let Some(p) = prev.filter(|p| seq > *p) {
                let gap = (seq - p - 1.0).max(0.0);
                *missed.entry((t / 0.1).floor() as i64).or_default() += gap;
                total += gap as u64;
            }
            prev = Some(seq);
        }
    }
    let points = missed
        .into_iter()
        .map(|(b, n)| (b as f64 * 0.1, n))
        .collect();
    Some((points, total))
}

/// The link: the round trip the master measured each cycle (`round_trip_us` of
/// `/master/cycle`: sessions and processes), and below it the messages lost per 100 ms: in
/// each direction for sessions (`/link/events`); for processes the feedback (`feedback_lost`
/// of `/master/cycle`) and, when the slave's record is there, the commands it did not act on
/// (`command_seq` of `/slave/cycle`).
fn link_figure(
    topics: &BTreeMap<String, Topic>,
    master: Option<&Topic>,
    duration_s: f64,
    figures: &mut Vec<Figure<'static>>,
    metrics: &mut BTreeMap<String, Value>,
) {
    let mut lines = Vec::new();
    if let Some(m) = master {
        let rtt_ms = series(m, |v| {
            num(v, "round_trip_us")
                .map(|us| us * 1e-3)
                .or_else(|| num(v, "round_trip_ms"))
        });
        let rtt: Vec<f64> = rtt_ms.iter().map(|p| p.1).filter(|r| *r > 0.0).collect();
        if !rtt.is_empty() {
            metrics.insert("round_trip_p50_ms".into(), json_f(percentile(&rtt, 50.0)));
            metrics.insert("round_trip_p99_ms".into(), json_f(percentile(&rtt, 99.0)));
            metrics.insert(
                "round_trip_max_ms".into(),
                json_f(rtt.iter().copied().fold(f64::NAN, f64::max)),
            );
            lines.push(Line {
                label: "round trip measured by the master",
                color: C_OTHER,
                points: rtt_ms,
            });
        }
    }
    let (lower, what_lost) = if let Some(events) = topics.get("/link/events") {
        let (cmd, cmd_total) = losses(events, "command", duration_s);
        let (fb, fb_total) = losses(events, "feedback", duration_s);
        metrics.insert("messages_lost".into(), Value::from(cmd_total + fb_total));
        metrics.insert("commands_lost".into(), Value::from(cmd_total));
        metrics.insert("feedback_lost".into(), Value::from(fb_total));
        let lines = vec![
            Line {
                label: "commands lost (master → slave)",
                color: C_TRUE,
                points: cmd,
            },
            Line {
                label: "feedback lost (slave → master)",
                color: C_MEAS,
                points: fb,
            },
        ];
        (
            Some(lines),
            format!("losses ({} messages)", cmd_total + fb_total),
        )
    } else if let Some((fb, fb_total)) = master.and_then(|m| feedback_losses(m, duration_s)) {
        // The processes: the master counts the feedback it missed; the commands the slave
        // did not act on are read from the slave's record when the recording has it
        // (`loopback --record`, or the slave's own recording).
        metrics.insert("feedback_lost".into(), Value::from(fb_total));
        let mut lines = vec![Line {
            label: "feedback lost or rejected (slave → master)",
            color: C_MEAS,
            points: fb,
        }];
        let mut what = format!("feedback losses ({fb_total} messages)");
        if let Some((cmd, cmd_total)) = topics
            .get("/slave/cycle")
            .and_then(|t| commands_missed(t, duration_s))
        {
            metrics.insert("commands_lost".into(), Value::from(cmd_total));
            lines.insert(
                0,
                Line {
                    label: "commands the slave did not act on (master → slave)",
                    color: C_TRUE,
                    points: cmd,
                },
            );
            what = format!("losses ({cmd_total} commands, {fb_total} feedback)");
        }
        (Some(lines), what)
    } else {
        (None, String::new())
    };
    let lower = lower.map(|lines| Panel {
        y_desc: "messages lost per 100 ms",
        lines,
    });
    // The figures at a glance, in the title.
    let rtt = match metrics.get("round_trip_p50_ms").and_then(Value::as_f64) {
        Some(p50) => format!("round trip (median {p50:.1} ms)"),
        None => String::new(),
    };
    let (title, y_desc, lines, lower) = match (lines.is_empty(), lower) {
        (true, None) => return,
        // A recording without the round trip: the losses alone.
        (true, Some(p)) => (format!("The link: {what_lost}"), p.y_desc, p.lines, None),
        (false, None) => (
            format!("The link: {rtt} (losses not recorded)"),
            "round trip (ms)",
            lines,
            None,
        ),
        (false, Some(p)) => (
            format!("The link: {rtt} and {what_lost}"),
            "round trip (ms)",
            lines,
            Some(p),
        ),
    };
    figures.push(Figure {
        file: "link.png",
        title,
        x_desc: "time (s)",
        y_desc,
        lines,
        band: Vec::new(),
        lower,
    });
}

/// Time of the recording's last message, s.
fn duration_s(topics: &BTreeMap<String, Topic>) -> f64 {
    topics
        .values()
        .filter_map(|t| t.last().map(|m| m.0))
        .fold(0.0, f64::max)
}

fn json_f(v: f64) -> Value {
    if v.is_finite() {
        Value::from(v)
    } else {
        Value::Null
    }
}

fn opt_json(v: Option<f64>) -> Value {
    v.map_or(Value::Null, json_f)
}

fn write_file(path: &Path, text: &str) -> Result<(), ReportError> {
    std::fs::write(path, text).map_err(|e| ReportError::Write {
        path: path.display().to_string(),
        message: e.to_string(),
    })
}

fn html_escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn index_html(
    title: &str,
    figures: &[String],
    links: &[String],
    metrics: &BTreeMap<String, Value>,
) -> String {
    let rows: String = metrics
        .iter()
        .map(|(k, v)| {
            format!(
                "<tr><td>{}</td><td>{}</td></tr>\n",
                html_escape(k),
                html_escape(&v.to_string())
            )
        })
        .collect();
    let imgs: String = figures
        .iter()
        .map(|f| format!("<figure><img src=\"{f}\" alt=\"{f}\"></figure>\n"))
        .collect();
    let links: String = links
        .iter()
        .map(|f| format!("<p><a href=\"{f}\">{f}</a></p>\n"))
        .collect();
    format!(
        "<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{t}</title>\n\
         <style>body{{font-family:sans-serif;margin:2em;max-width:1250px}}\
         table{{border-collapse:collapse}}td{{border:1px solid #ccc;padding:2px 8px}}\
         img{{max-width:100%}}</style></head>\n<body><h1>{t}</h1>\n\
         <h2>Metrics</h2><table>\n{rows}</table>\n<h2>Figures</h2>\n{imgs}{links}</body></html>\n",
        t = html_escape(title)
    )
}

/// A cutting session's part folder into the report: `cut.json`'s fields as `cut/<field>`
/// metrics, `deviation.png` and `height.png` copied beside the figures, `part.stl` copied
/// and linked. A folder without `cut.json` is an error naming it.
fn part_outputs(
    dir: &Path,
    out_dir: &Path,
    figures: &mut Vec<String>,
    links: &mut Vec<String>,
    metrics: &mut BTreeMap<String, Value>,
) -> Result<(), ReportError> {
    let cut = dir.join(crate::plant::cutting::judge::CUT_JSON);
    let text = std::fs::read_to_string(&cut).map_err(|source| ReportError::Read {
        path: cut.display().to_string(),
        source,
    })?;
    let fields: BTreeMap<String, Value> =
        serde_json::from_str(&text).map_err(|e| ReportError::Recording {
            path: cut.display().to_string(),
            message: format!("not the cutting fields of a summary: {e}"),
        })?;
    for (k, v) in fields {
        metrics.insert(format!("cut/{k}"), v);
    }
    for (name, figure) in [
        ("deviation.png", true),
        ("height.png", true),
        ("part.stl", false),
    ] {
        let from = dir.join(name);
        if !from.exists() {
            continue;
        }
        let to = out_dir.join(name);
        std::fs::copy(&from, &to).map_err(|e| ReportError::Write {
            path: to.display().to_string(),
            message: e.to_string(),
        })?;
        if figure {
            figures.push(name.to_string());
        } else {
            links.push(name.to_string());
        }
    }
    Ok(())
}

/// Makes the report of `recording` into `opts.out_dir`.
pub fn report(recording: &Path, opts: &ReportOptions) -> Result<ReportOutput, ReportError> {
    register_fonts();
    let (topics, truncated) = read_topics(recording)?;
    let mut figures = Vec::new();
    let mut metrics = BTreeMap::new();
    experiment_figures(&topics, opts, &mut figures, &mut metrics);
    teleop_figures(&topics, &mut figures, &mut metrics);
    if figures.is_empty() {
        let found: Vec<&str> = topics.keys().map(String::as_str).collect();
        return Err(ReportError::Recording {
            path: recording.display().to_string(),
            message: format!(
                "no topic this report draws (found: {}); expected /slave/force or /master/cycle and /slave/cycle",
                if found.is_empty() {
                    "none".to_string()
                } else {
                    found.join(", ")
                }
            ),
        });
    }
    metrics.insert("duration_s".into(), json_f(duration_s(&topics)));
    metrics.insert("truncated".into(), Value::from(truncated));
    for (name, t) in &topics {
        metrics.insert(format!("messages{name}"), Value::from(t.len()));
    }
    std::fs::create_dir_all(&opts.out_dir).map_err(|e| ReportError::Write {
        path: opts.out_dir.display().to_string(),
        message: e.to_string(),
    })?;
    let mut written = Vec::new();
    for fig in &figures {
        if draw(fig, &opts.out_dir)? {
            written.push(fig.file.to_string());
        }
    }
    let mut links = Vec::new();
    if let Some(dir) = &opts.part_dir {
        part_outputs(dir, &opts.out_dir, &mut written, &mut links, &mut metrics)?;
    }
    let metrics_text = serde_json::to_string_pretty(&metrics).unwrap_or_default() + "\n";
    write_file(&opts.out_dir.join("metrics.json"), &metrics_text)?;
    let title = format!(
        "h4-teleop report: {}",
        recording
            .file_name()
            .map_or_else(String::new, |n| n.to_string_lossy().into_owned())
    );
    write_file(
        &opts.out_dir.join("index.html"),
        &index_html(&title, &written, &links, &metrics),
    )?;
    Ok(ReportOutput {
        figures: written,
        metrics,
    })
}

/// `report <recording.mcap> [--out DIR] [--tolerance-n N] [--part DIR]`, the same in both
/// binaries.
#[derive(Clone, Debug, clap::Args)]
pub struct ReportArgs {
    /// The recording (MCAP) of an experiment, a session or the processes.
    pub recording: PathBuf,
    /// Output folder (default: `<recording>-report` beside the recording).
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
    /// Half-width of the band drawn around the force set-point, N.
    #[arg(long, default_value_t = 1.0, value_parser = positive_finite)]
    pub tolerance_n: f64,
    /// A cutting session's part folder (`h4-master sim --out DIR`): its cutting fields
    /// (`cut.json`, the mesh judge's among them) join the metrics as `cut/<field>`, its
    /// deviation and height maps the figures, and its `part.stl` is linked.
    #[arg(long, value_name = "DIR")]
    pub part: Option<PathBuf>,
}

fn positive_finite(text: &str) -> Result<f64, String> {
    match text.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 => Ok(v),
        Ok(v) => Err(format!("must be a positive finite number, got {v}")),
        Err(e) => Err(e.to_string()),
    }
}

impl ReportArgs {
    /// Makes the report and prints one line saying where it is.
    pub fn run(&self) -> Result<ReportOutput, ReportError> {
        let out_dir = self.out.clone().unwrap_or_else(|| {
            let stem = self
                .recording
                .file_stem()
                .map_or_else(|| "recording".into(), |s| s.to_string_lossy().into_owned());
            self.recording.with_file_name(format!("{stem}-report"))
        });
        let out = report(
            &self.recording,
            &ReportOptions {
                out_dir: out_dir.clone(),
                tolerance_n: self.tolerance_n,
                part_dir: self.part.clone(),
            },
        )?;
        println!(
            "report: {} figures, metrics.json and index.html in {}",
            out.figures.len(),
            out_dir.display()
        );
        Ok(out)
    }
}

/// Registers the embedded font (DejaVu Sans) as plotters' `sans-serif`, so the figures have
/// text on any machine (once per process; `h4-master matrix` draws with it too).
pub fn register_fonts() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        // A font that fails to register leaves the figures without text, never without lines.
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thinning_keeps_the_peaks() {
        let pts: Vec<(f64, f64)> = (0..10_000)
            .map(|i| (i as f64, if i == 5_001 { 100.0 } else { (i % 7) as f64 }))
            .collect();
        let thin = min_max_thin(&pts, 100);
        assert!(thin.len() <= 200);
        assert_eq!(max_of(&thin), 100.0);
        assert_eq!(min_of(&thin), 0.0);
        assert!(thin.windows(2).all(|w| w[0].0 <= w[1].0));
    }

    /// The processes' running count of missed feedback becomes losses per 100 ms bin, every
    /// bin drawn; a session's link events are counted by direction and by kind.
    #[test]
    fn losses_per_bin_from_counts_and_events() {
        let master: Topic = (0..1000)
            .map(|i| {
                let t = i as f64 * 1e-3;
                // 3 lost at 0.25 s, 2 more at 0.72 s.
                let n = if t >= 0.72 {
                    5
                } else if t >= 0.25 {
                    3
                } else {
                    0
                };
                (t, serde_json::json!({ "feedback_lost": n }))
            })
            .collect();
        let (points, total) = feedback_losses(&master, 1.0).unwrap();
        assert_eq!(total, 5);
        assert_eq!(points.len(), 10);
        let per_bin: Vec<f64> = points.iter().map(|p| p.1).collect();
        assert_eq!(per_bin, [0.0, 0.0, 3.0, 0.0, 0.0, 0.0, 0.0, 2.0, 0.0, 0.0]);
        assert!(feedback_losses(&vec![(0.0, serde_json::json!({}))], 1.0).is_none());

        // The slave acted on commands 1..=349, missed 350-352 at 0.35 s and one at 0.55 s;
        // a new master (its sequence starting again at 1) at 0.8 s is no loss.
        let mut seq = 0u64;
        let slave: Topic = (0..1000)
            .map(|i| {
                let t = i as f64 * 1e-3;
                seq = match i {
                    0 => 0,
                    350 => seq + 4,
                    550 => seq + 2,
                    800 => 1,
                    _ => seq + 1,
                };
                (t, serde_json::json!({ "command_seq": seq }))
            })
            .collect();
        let (points, total) = commands_missed(&slave, 1.0).unwrap();
        assert_eq!(total, 4);
        let per_bin: Vec<f64> = points.iter().map(|p| p.1).collect();
        assert_eq!(per_bin, [0.0, 0.0, 0.0, 3.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0]);
        assert!(commands_missed(&vec![(0.0, serde_json::json!({}))], 1.0).is_none());

        let ev = |t: f64, dir: &str, kind: &str| {
            (
                t,
                serde_json::json!({ "direction": dir, "event": { "kind": kind } }),
            )
        };
        let events: Topic = vec![
            ev(0.05, "command", "lost"),
            ev(0.06, "command", "duplicated"),
            ev(0.31, "command", "blacked_out"),
            ev(0.32, "feedback", "overflowed"),
        ];
        let (cmd, n_cmd) = losses(&events, "command", 0.5);
        let (fb, n_fb) = losses(&events, "feedback", 0.5);
        assert_eq!((n_cmd, n_fb), (2, 1));
        assert_eq!(
            cmd.iter().map(|p| p.1).collect::<Vec<_>>(),
            [1.0, 0.0, 0.0, 1.0, 0.0]
        );
        assert_eq!(fb.iter().map(|p| p.1).sum::<f64>(), 1.0);
    }

    #[test]
    fn percentile_by_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        assert_eq!(percentile(&v, 99.0), 99.0);
        assert_eq!(percentile(&v, 50.0), 50.0);
        assert!(percentile(&[], 50.0).is_nan());
    }
}
