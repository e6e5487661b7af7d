//! Recordings of a real (or synthetic) car: commands sent and states measured.
//!
//! Commands and states are kept as two event lists, because a ROS 2 bag logs them on
//! separate topics at separate times; a CSV row carries both at one time. A command holds
//! from its own time until the next one; the physics step at `t_k = k dt` uses the last
//! command with `t <= t_k` (0 before the first).

use std::collections::BTreeMap;
use std::io::Cursor;
use std::path::Path;

use crate::SysidError;

/// Columns a CSV recording must have (any order; extra columns are ignored).
pub const CSV_COLUMNS: [&str; 9] = [
    "t",
    "steer_cmd",
    "speed_cmd",
    "x",
    "y",
    "yaw",
    "vx",
    "vy",
    "yaw_rate",
];

/// Shortest recording the analysis accepts [s].
pub const MIN_DURATION_S: f64 = 5.0;
/// Fewest state samples the analysis accepts.
pub const MIN_SAMPLES: usize = 100;

/// A command as sent to the car.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Command {
    pub t: f64,
    /// Steering angle command [rad].
    pub steer: f64,
    /// Speed command [m/s].
    pub speed: f64,
}

/// A measured state of the centre of gravity.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct StateSample {
    pub t: f64,
    pub x: f64,
    pub y: f64,
    /// [rad], wrapped to [-pi, pi).
    pub yaw: f64,
    /// Body-frame velocities [m/s].
    pub vx: f64,
    pub vy: f64,
    pub yaw_rate: f64,
}

/// The six compared channels, in report order.
pub const CHANNELS: [&str; 6] = ["x", "y", "yaw", "vx", "vy", "yaw_rate"];

impl StateSample {
    /// The channels in [`CHANNELS`] order.
    pub fn channels(&self) -> [f64; 6] {
        [self.x, self.y, self.yaw, self.vx, self.vy, self.yaw_rate]
    }
}

/// A loaded recording.
#[derive(Debug, Clone, Default)]
pub struct Recording {
    pub commands: Vec<Command>,
    pub states: Vec<StateSample>,
    /// Problems that did not stop the load (for the report).
    pub warnings: Vec<String>,
}

/// Topic names of a ROS 2 bag.
#[derive(Debug, Clone)]
pub struct McapTopics {
    pub drive: String,
    pub odom: String,
}

impl Default for McapTopics {
    fn default() -> Self {
        Self {
            drive: "/drive".into(),
            odom: "/odom".into(),
        }
    }
}

/// Wrap an angle to [-pi, pi): the simulator's own wrap.
pub use paddock_sim::geometry::wrap_angle as wrap_pi;

impl Recording {
    /// Load a recording: a ROS 2 bag (an `.mcap` file, one never finalised read up to its
    /// last complete chunk; a rosbag2 bag folder in SQLite3 or MCAP storage; a `.db3`
    /// file), or else a CSV file.
    pub fn load(path: &Path, topics: &McapTopics) -> Result<Self, SysidError> {
        let rec = if paddock_recordings::is_bag(path) {
            let bag = paddock_recordings::read_bag(path, &[&topics.drive, &topics.odom]).map_err(
                |e| SysidError::Format {
                    message: e.to_string(),
                },
            )?;
            Self::from_bag(bag, topics)?
        } else {
            let bytes = std::fs::read(path).map_err(|source| SysidError::Io {
                path: path.display().to_string(),
                source,
            })?;
            let text = String::from_utf8(bytes).map_err(|e| SysidError::Format {
                message: format!(
                    "{} is not UTF-8 text (byte {}): not a CSV recording",
                    path.display(),
                    e.utf8_error().valid_up_to()
                ),
            })?;
            Self::from_csv_str(&text)?
        };
        rec.check()?;
        Ok(rec)
    }

    /// Parse CSV text with the header [`CSV_COLUMNS`] (extra columns ignored).
    pub fn from_csv_str(text: &str) -> Result<Self, SysidError> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let Some((_, header)) = lines.next() else {
            return Err(SysidError::Format {
                message: "the CSV recording is empty (no header row)".into(),
            });
        };
        let names: Vec<&str> = header.split(',').map(|s| s.trim()).collect();
        let mut idx = [0usize; 9];
        for (k, col) in CSV_COLUMNS.iter().enumerate() {
            idx[k] =
                names
                    .iter()
                    .position(|n| n == col)
                    .ok_or_else(|| SysidError::MissingColumn {
                        column: (*col).to_string(),
                        header: header.trim().to_string(),
                    })?;
        }
        let mut rec = Recording::default();
        let mut prev_t = f64::NEG_INFINITY;
        for (line_no, line) in lines {
            let row = line_no + 1;
            let fields: Vec<&str> = line.split(',').map(|s| s.trim()).collect();
            if fields.len() != names.len() {
                return Err(SysidError::Row {
                    row,
                    message: format!(
                        "has {} fields, the header has {}",
                        fields.len(),
                        names.len()
                    ),
                });
            }
            let mut v = [0.0; 9];
            for (k, col) in CSV_COLUMNS.iter().enumerate() {
                let s = fields[idx[k]];
                let x: f64 = s.parse().map_err(|_| SysidError::Row {
                    row,
                    message: format!("column {col} = {s:?} is not a number"),
                })?;
                if !x.is_finite() {
                    return Err(SysidError::Row {
                        row,
                        message: format!("column {col} = {s} is not a finite number"),
                    });
                }
                v[k] = x;
            }
            let t = v[0];
            if t <= prev_t {
                return Err(SysidError::Row {
                    row,
                    message: format!("t = {t} does not increase (previous row t = {prev_t})"),
                });
            }
            if t < 0.0 {
                return Err(SysidError::Row {
                    row,
                    message: format!("t = {t} is negative (time runs from 0)"),
                });
            }
            prev_t = t;
            rec.commands.push(Command {
                t,
                steer: v[1],
                speed: v[2],
            });
            rec.states.push(StateSample {
                t,
                x: v[3],
                y: v[4],
                yaw: v[5],
                vx: v[6],
                vy: v[7],
                yaw_rate: v[8],
            });
        }
        Ok(rec)
    }

    /// Refuse recordings too short to say anything; warn on gaps.
    pub fn check(&self) -> Result<(), SysidError> {
        let n = self.states.len();
        let duration = self.duration();
        if n < MIN_SAMPLES || duration < MIN_DURATION_S {
            return Err(SysidError::TooShort {
                samples: n,
                duration_s: duration,
                min_samples: MIN_SAMPLES,
                min_duration_s: MIN_DURATION_S,
            });
        }
        if self.commands.is_empty() {
            return Err(SysidError::Format {
                message: "the recording has no commands".into(),
            });
        }
        Ok(())
    }

    /// Time of the last state sample [s].
    pub fn duration(&self) -> f64 {
        self.states.last().map_or(0.0, |s| s.t)
    }

    /// Commands held onto the physics grid: entry k is the command acting at `k dt`.
    pub fn commands_on_grid(&self, dt: f64, steps: usize) -> Vec<(f64, f64)> {
        let mut out = Vec::with_capacity(steps);
        let mut j = 0usize;
        let mut cur = (0.0, 0.0);
        for k in 0..steps {
            // a small tolerance so a row logged at exactly k dt counts for step k
            let tk = k as f64 * dt + 1e-9;
            while j < self.commands.len() && self.commands[j].t <= tk {
                cur = (self.commands[j].steer, self.commands[j].speed);
                j += 1;
            }
            out.push(cur);
        }
        out
    }

    /// Write the CSV form (one row per state sample, with the command in force then).
    pub fn to_csv_string(&self) -> String {
        let mut s = CSV_COLUMNS.join(",");
        s.push('\n');
        let mut j = 0usize;
        let mut cur = (0.0, 0.0);
        for st in &self.states {
            while j < self.commands.len() && self.commands[j].t <= st.t {
                cur = (self.commands[j].steer, self.commands[j].speed);
                j += 1;
            }
            s.push_str(&format!(
                "{:.4},{:.6},{:.5},{:.5},{:.5},{:.6},{:.5},{:.5},{:.5}\n",
                st.t, cur.0, cur.1, st.x, st.y, st.yaw, st.vx, st.vy, st.yaw_rate
            ));
        }
        s
    }

    /// Decode a ROS 2 bag: `ackermann_msgs/msg/AckermannDriveStamped` on the drive topic,
    /// `nav_msgs/msg/Odometry` on the odometry topic, both CDR. Time is the log time,
    /// from the first message of either topic.
    pub fn from_mcap(bytes: &[u8], topics: &McapTopics) -> Result<Self, SysidError> {
        let bag = paddock_recordings::read_mcap(
            bytes,
            Path::new("the MCAP recording"),
            &[&topics.drive, &topics.odom],
        )
        .map_err(|e| SysidError::Format {
            message: e.to_string(),
        })?;
        Self::from_bag(bag, topics)
    }

    fn from_bag(bag: paddock_recordings::Bag, topics: &McapTopics) -> Result<Self, SysidError> {
        let mut drive = Vec::new();
        let mut odom = Vec::new();
        for msg in &bag.messages {
            if msg.topic == topics.drive {
                let (steer, speed) =
                    decode_ackermann(&msg.data).map_err(|m| SysidError::Format {
                        message: format!("{} message {}: {m}", topics.drive, drive.len()),
                    })?;
                drive.push((msg.log_time, steer, speed));
            } else if msg.topic == topics.odom {
                let s = decode_odometry(&msg.data).map_err(|m| SysidError::Format {
                    message: format!("{} message {}: {m}", topics.odom, odom.len()),
                })?;
                odom.push((msg.log_time, s));
            }
        }
        let known = bag.topics.keys().cloned().collect::<Vec<_>>().join(", ");
        if drive.is_empty() {
            return Err(SysidError::Format {
                message: format!(
                    "no messages on the drive topic {:?} (topics in the file: {known})",
                    topics.drive
                ),
            });
        }
        if odom.is_empty() {
            return Err(SysidError::Format {
                message: format!(
                    "no messages on the odometry topic {:?} (topics in the file: {known})",
                    topics.odom
                ),
            });
        }
        drive.sort_by_key(|d| d.0);
        odom.sort_by_key(|o| o.0);
        let t0 = drive[0].0.min(odom[0].0);
        let secs = |ns: u64| (ns - t0) as f64 * 1e-9;
        let mut rec = Recording::default();
        if let Some(t) = &bag.truncation {
            rec.warnings.push(t.to_string());
        }
        for (t, steer, speed) in drive {
            if !(steer.is_finite() && speed.is_finite()) {
                rec.warnings.push(format!(
                    "non-finite drive command at t = {:.3} s skipped",
                    secs(t)
                ));
                continue;
            }
            rec.commands.push(Command {
                t: secs(t),
                steer,
                speed,
            });
        }
        let mut prev = f64::NEG_INFINITY;
        for (t, mut s) in odom {
            s.t = secs(t);
            let finite = s.channels().iter().all(|v| v.is_finite());
            if !finite || s.t <= prev {
                rec.warnings.push(format!(
                    "odometry at t = {:.3} s skipped ({})",
                    s.t,
                    if finite {
                        "repeated time"
                    } else {
                        "non-finite"
                    }
                ));
                continue;
            }
            prev = s.t;
            rec.states.push(s);
        }
        Ok(rec)
    }

    /// Write a ROS 2 bag (uncompressed MCAP) with the drive and odometry topics.
    pub fn to_mcap(&self, topics: &McapTopics) -> Result<Vec<u8>, SysidError> {
        let err = |e: mcap::McapError| SysidError::Format {
            message: format!("writing MCAP: {e}"),
        };
        let mut w = mcap::WriteOptions::new()
            .compression(None)
            .profile("ros2")
            .create(Cursor::new(Vec::new()))
            .map_err(err)?;
        let s_drive = w
            .add_schema(
                "ackermann_msgs/msg/AckermannDriveStamped",
                "ros2msg",
                ACKERMANN_SCHEMA.as_bytes(),
            )
            .map_err(err)?;
        let s_odom = w
            .add_schema(
                "nav_msgs/msg/Odometry",
                "ros2msg",
                ODOMETRY_SCHEMA.as_bytes(),
            )
            .map_err(err)?;
        let meta = BTreeMap::new();
        let c_drive = w
            .add_channel(s_drive, &topics.drive, "cdr", &meta)
            .map_err(err)?;
        let c_odom = w
            .add_channel(s_odom, &topics.odom, "cdr", &meta)
            .map_err(err)?;
        // merge both streams in time order
        let mut events: Vec<(u64, bool, usize)> = self
            .commands
            .iter()
            .enumerate()
            .map(|(i, c)| (secs_to_ns(c.t), true, i))
            .chain(
                self.states
                    .iter()
                    .enumerate()
                    .map(|(i, s)| (secs_to_ns(s.t), false, i)),
            )
            .collect();
        events.sort();
        for (seq, (ns, is_drive, i)) in events.into_iter().enumerate() {
            let (channel_id, data) = if is_drive {
                let c = self.commands[i];
                (c_drive, encode_ackermann(ns, c.steer, c.speed))
            } else {
                (c_odom, encode_odometry(ns, &self.states[i]))
            };
            let header = mcap::records::MessageHeader {
                channel_id,
                sequence: seq as u32,
                log_time: ns,
                publish_time: ns,
            };
            w.write_to_known_channel(&header, &data).map_err(err)?;
        }
        w.finish().map_err(err)?;
        Ok(w.into_inner().into_inner())
    }
}

fn secs_to_ns(t: f64) -> u64 {
    (t * 1e9).round().max(0.0) as u64
}

const ACKERMANN_SCHEMA: &str = "std_msgs/Header header\nAckermannDrive drive\n";
const ODOMETRY_SCHEMA: &str = "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\ngeometry_msgs/TwistWithCovariance twist\n";

/// A little-endian CDR reader (XCDR1, the ROS 2 default): alignment counts from the end
/// of the 4-byte encapsulation header.
struct Cdr<'a> {
    buf: &'a [u8],
    pos: usize,
}

impl<'a> Cdr<'a> {
    fn new(buf: &'a [u8]) -> Result<Self, String> {
        if buf.len() < 4 {
            return Err(format!("{} bytes: too short for CDR", buf.len()));
        }
        match buf[1] {
            0x01 => {}
            0x00 => return Err("big-endian CDR is not supported".into()),
            k => return Err(format!("unknown CDR encapsulation kind {k:#04x}")),
        }
        Ok(Self {
            buf: &buf[4..],
            pos: 0,
        })
    }

    fn take(&mut self, n: usize) -> Result<&'a [u8], String> {
        let pad = (n.min(8) - self.pos % n.min(8)) % n.min(8);
        let start = self.pos + pad;
        let end = start + n;
        if end > self.buf.len() {
            return Err(format!(
                "truncated: needs {end} bytes, has {}",
                self.buf.len()
            ));
        }
        self.pos = end;
        Ok(&self.buf[start..end])
    }

    fn u32(&mut self) -> Result<u32, String> {
        let b = self.take(4)?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
    }

    fn f32(&mut self) -> Result<f64, String> {
        Ok(f32::from_bits(self.u32()?) as f64)
    }

    fn f64(&mut self) -> Result<f64, String> {
        let b = self.take(8)?;
        let mut a = [0u8; 8];
        a.copy_from_slice(b);
        Ok(f64::from_le_bytes(a))
    }

    fn string(&mut self) -> Result<(), String> {
        let n = self.u32()? as usize;
        if self.pos + n > self.buf.len() {
            return Err(format!("string of {n} bytes runs past the message"));
        }
        self.pos += n;
        Ok(())
    }

    fn header(&mut self) -> Result<(), String> {
        self.u32()?; // stamp.sec
        self.u32()?; // stamp.nanosec
        self.string() // frame_id
    }
}

/// `(steering_angle, speed)` of an `AckermannDriveStamped`.
fn decode_ackermann(data: &[u8]) -> Result<(f64, f64), String> {
    let mut c = Cdr::new(data)?;
    c.header()?;
    let steer = c.f32()?;
    let _steer_vel = c.f32()?;
    let speed = c.f32()?;
    Ok((steer, speed))
}

/// The state of an `Odometry` (twist in the child, i.e. body, frame).
fn decode_odometry(data: &[u8]) -> Result<StateSample, String> {
    let mut c = Cdr::new(data)?;
    c.header()?;
    c.string()?; // child_frame_id
    let x = c.f64()?;
    let y = c.f64()?;
    let _z = c.f64()?;
    let (qx, qy, qz, qw) = (c.f64()?, c.f64()?, c.f64()?, c.f64()?);
    for _ in 0..36 {
        c.f64()?;
    }
    let vx = c.f64()?;
    let vy = c.f64()?;
    let _vz = c.f64()?;
    let _wx = c.f64()?;
    let _wy = c.f64()?;
    let wz = c.f64()?;
    let yaw = libm::atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz));
    Ok(StateSample {
        t: 0.0,
        x,
        y,
        yaw: wrap_pi(yaw),
        vx,
        vy,
        yaw_rate: wz,
    })
}

/// A little-endian CDR writer matching [`Cdr`].
struct CdrOut(Vec<u8>);

impl CdrOut {
    fn new() -> Self {
        Self(vec![0x00, 0x01, 0x00, 0x00])
    }
    fn align(&mut self, n: usize) {
        while !(self.0.len() - 4).is_multiple_of(n) {
            self.0.push(0);
        }
    }
    fn u32(&mut self, v: u32) {
        self.align(4);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f32(&mut self, v: f64) {
        self.align(4);
        self.0.extend_from_slice(&(v as f32).to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.align(8);
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.0.extend_from_slice(s.as_bytes());
        self.0.push(0);
    }
    fn header(&mut self, ns: u64, frame: &str) {
        self.u32((ns / 1_000_000_000) as u32);
        self.u32((ns % 1_000_000_000) as u32);
        self.string(frame);
    }
}

fn encode_ackermann(ns: u64, steer: f64, speed: f64) -> Vec<u8> {
    let mut c = CdrOut::new();
    c.header(ns, "base_link");
    for v in [steer, 0.0, speed, 0.0, 0.0] {
        c.f32(v);
    }
    c.0
}

fn encode_odometry(ns: u64, s: &StateSample) -> Vec<u8> {
    let mut c = CdrOut::new();
    c.header(ns, "map");
    c.string("base_link");
    let (sz, cz) = (libm::sin(s.yaw / 2.0), libm::cos(s.yaw / 2.0));
    for v in [s.x, s.y, 0.0, 0.0, 0.0, sz, cz] {
        c.f64(v);
    }
    for _ in 0..36 {
        c.f64(0.0);
    }
    for v in [s.vx, s.vy, 0.0, 0.0, 0.0, s.yaw_rate] {
        c.f64(v);
    }
    for _ in 0..36 {
        c.f64(0.0);
    }
    c.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn csv(rows: usize) -> String {
        let mut s = String::from("t,steer_cmd,speed_cmd,x,y,yaw,vx,vy,yaw_rate,extra\n");
        for i in 0..rows {
            let t = i as f64 * 0.025;
            s.push_str(&format!("{t},0.1,2.0,{t},0,0,1.0,0,0,7\n"));
        }
        s
    }

    #[test]
    fn csv_loads_with_extra_columns_and_any_order() {
        let r = Recording::from_csv_str(&csv(300)).unwrap();
        r.check().unwrap();
        assert_eq!(r.states.len(), 300);
        assert_eq!(r.commands[3].speed, 2.0);
        let swapped = "yaw_rate,t,steer_cmd,speed_cmd,x,y,yaw,vx,vy\n0.5,0,0.1,2,0,0,0,0,0\n";
        let r = Recording::from_csv_str(swapped).unwrap();
        assert_eq!(r.states[0].yaw_rate, 0.5);
    }

    #[test]
    fn csv_errors_name_the_problem() {
        let e = Recording::from_csv_str("t,steer_cmd,x\n0,0,0\n").unwrap_err();
        assert!(e.to_string().contains("speed_cmd"), "{e}");
        let mut bad = csv(10);
        bad.push_str("0.3,abc,2,0,0,0,0,0,0,0\n");
        let e = Recording::from_csv_str(&bad).unwrap_err();
        assert!(
            e.to_string().contains("row 12") && e.to_string().contains("abc"),
            "{e}"
        );
        let mut nan = csv(10);
        nan.push_str("0.3,0,NaN,0,0,0,0,0,0,0\n");
        let e = Recording::from_csv_str(&nan).unwrap_err();
        assert!(e.to_string().contains("speed_cmd"), "{e}");
        let mut back = csv(10);
        back.push_str("0.1,0,0,0,0,0,0,0,0,0\n");
        let e = Recording::from_csv_str(&back).unwrap_err();
        assert!(e.to_string().contains("does not increase"), "{e}");
        let e = Recording::from_csv_str(&csv(20))
            .unwrap()
            .check()
            .unwrap_err();
        assert!(e.to_string().contains("too short"), "{e}");
    }

    #[test]
    fn commands_hold_until_the_next_row() {
        let r = Recording {
            commands: vec![
                Command {
                    t: 0.0,
                    steer: 0.1,
                    speed: 1.0,
                },
                Command {
                    t: 0.025,
                    steer: 0.2,
                    speed: 2.0,
                },
                Command {
                    t: 0.05,
                    steer: 0.3,
                    speed: 3.0,
                },
            ],
            ..Recording::default()
        };
        let g = r.commands_on_grid(0.01, 7);
        let speeds: Vec<f64> = g.iter().map(|c| c.1).collect();
        assert_eq!(speeds, vec![1.0, 1.0, 1.0, 2.0, 2.0, 3.0, 3.0]);
    }

    #[test]
    fn mcap_round_trip() {
        let r = Recording::from_csv_str(&csv(200)).unwrap();
        let topics = McapTopics {
            drive: "/car/drive".into(),
            odom: "/car/odom".into(),
        };
        let bytes = r.to_mcap(&topics).unwrap();
        let back = Recording::from_mcap(&bytes, &topics).unwrap();
        assert_eq!(back.states.len(), 200);
        assert_eq!(back.commands.len(), 200);
        assert!((back.states[50].x - r.states[50].x).abs() < 1e-9);
        assert!((back.states[50].t - r.states[50].t).abs() < 1e-9);
        assert!((back.commands[7].steer - 0.1).abs() < 1e-6);
        let e = Recording::from_mcap(&bytes, &McapTopics::default()).unwrap_err();
        assert!(e.to_string().contains("/car/drive"), "{e}");
        let e = Recording::from_mcap(b"\x89MCAP0\r\ngarbage", &topics).unwrap_err();
        assert!(e.to_string().contains("MCAP"), "{e}");
    }

    #[test]
    fn wrap_pi_range() {
        for a in [-10.0, -3.2, 0.0, 3.1, 3.2, 7.0] {
            let w = wrap_pi(a);
            assert!((-std::f64::consts::PI..std::f64::consts::PI).contains(&w));
            assert!((libm::sin(w) - libm::sin(a)).abs() < 1e-12);
        }
    }
}
