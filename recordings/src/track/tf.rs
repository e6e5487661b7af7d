//! The pose of one frame in another from a recording's transforms (`/tf` and
//! `/tf_static`, `tf2_msgs/msg/TFMessage`), for a car whose localiser publishes only a
//! transform (slam_toolbox and Cartographer publish `map -> odom`, the VESC's odometry
//! `odom -> base_link`).
//!
//! The chain of transforms from the parent frame down to the child is found in the tree
//! the recording holds (a frame has one parent). The pose is sampled at the log times of
//! the chain's most frequent moving transform; every other moving transform of the chain
//! is interpolated there between its two messages around that time (the translation
//! linearly, the yaw along the shorter way), when they are at most [`MAX_TF_GAP_NS`]
//! apart; elsewhere the sample is left out and counted. Static transforms hold at all
//! times. Everything is planar: x, y and the yaw of each transform.

use std::collections::BTreeMap;
use std::path::Path;

use super::decode;
use crate::msg::{Quaternion, TFMessage};
use crate::{Bag, RecordingError};

/// The longest time between two messages of one transform that a sample between them
/// interpolates across [ns] (0.5 s: a localiser's correction may come at a few hertz).
pub const MAX_TF_GAP_NS: u64 = 500_000_000;

/// A planar transform: x, y, yaw.
type Planar = [f64; 3];

/// Poses by log time, and notes for the user.
type FramePoses = (Vec<(u64, Planar)>, Vec<String>);

/// `a` then `b`: `b` given in `a`'s child frame.
fn compose(a: Planar, b: Planar) -> Planar {
    let (s, c) = a[2].sin_cos();
    [
        a[0] + c * b[0] - s * b[1],
        a[1] + s * b[0] + c * b[1],
        wrap(a[2] + b[2]),
    ]
}

/// An angle in [-pi, pi).
fn wrap(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(std::f64::consts::TAU) - std::f64::consts::PI;
    if w >= std::f64::consts::PI {
        -std::f64::consts::PI
    } else {
        w
    }
}

fn planar(t: &crate::msg::Transform) -> Planar {
    let q: &Quaternion = &t.rotation;
    [t.translation.x, t.translation.y, q.yaw()]
}

/// A frame id without the leading `/` that older stacks write.
fn frame(id: &str) -> &str {
    id.trim_start_matches('/')
}

/// One edge of the tree: its samples by log time, or one static value.
#[derive(Default)]
struct Edge {
    parent: String,
    samples: Vec<(u64, Planar)>,
    fixed: Option<Planar>,
}

impl Edge {
    /// The transform at `t`: static, or interpolated between the samples around `t`.
    fn at(&self, t: u64) -> Option<Planar> {
        if let Some(f) = self.fixed {
            return Some(f);
        }
        let i = self.samples.partition_point(|s| s.0 <= t);
        let a = self.samples.get(i.checked_sub(1)?)?;
        if a.0 == t {
            return Some(a.1);
        }
        let b = self.samples.get(i)?;
        if b.0 - a.0 > MAX_TF_GAP_NS {
            return None;
        }
        let u = (t - a.0) as f64 / (b.0 - a.0) as f64;
        Some([
            a.1[0] + u * (b.1[0] - a.1[0]),
            a.1[1] + u * (b.1[1] - a.1[1]),
            wrap(a.1[2] + u * wrap(b.1[2] - a.1[2])),
        ])
    }
}

/// The poses of `child` in `parent` (see the module docs) from `topic` and the static
/// transforms of `static_topic`, by log time, with notes for the user.
pub(super) fn frame_poses(
    bag: &Bag,
    path: &Path,
    topic: &str,
    static_topic: &str,
    parent: &str,
    child: &str,
) -> Result<FramePoses, RecordingError> {
    let (parent, child) = (frame(parent), frame(child));
    // edges by child frame
    let mut edges: BTreeMap<String, Edge> = BTreeMap::new();
    let mut reparented: Option<String> = None;
    let mut n = [0usize; 2];
    for m in &bag.messages {
        let is_static = m.topic == static_topic;
        if !(is_static || m.topic == topic) {
            continue;
        }
        let k = usize::from(is_static);
        let msg: TFMessage = decode(path, &m.topic, n[k], &m.data)?;
        n[k] += 1;
        for t in &msg.transforms {
            let (p, c) = (frame(&t.header.frame_id), frame(&t.child_frame_id));
            let value = planar(&t.transform);
            if !value.iter().all(|v| v.is_finite()) {
                continue;
            }
            let e = edges.entry(c.to_string()).or_insert_with(|| Edge {
                parent: p.to_string(),
                ..Edge::default()
            });
            if e.parent != p {
                reparented
                    .get_or_insert_with(|| format!("{c} has two parents, {} and {p}", e.parent));
                continue;
            }
            if is_static {
                e.fixed = Some(value);
            } else {
                e.samples.push((m.log_time, value));
            }
        }
    }
    if let Some(r) = reparented {
        return Err(RecordingError::format(
            path,
            format!("the transforms on {topic} and {static_topic} are not a tree: {r}"),
        ));
    }
    for e in edges.values_mut() {
        e.samples.sort_by_key(|s| s.0);
    }
    // the chain from the child up to the parent
    let mut chain: Vec<&Edge> = Vec::new();
    let mut at = child;
    while at != parent {
        let Some(e) = edges.get(at).filter(|_| chain.len() <= edges.len()) else {
            let known: Vec<String> = edges
                .iter()
                .map(|(c, e)| format!("{} -> {c}", e.parent))
                .collect();
            return Err(RecordingError::format(
                path,
                format!(
                    "no chain of transforms from {parent:?} to {child:?} on {topic} and \
                     {static_topic} (the pose's frames: --pose-frames PARENT,CHILD); the \
                     transforms recorded: {}",
                    if known.is_empty() {
                        "none".to_string()
                    } else {
                        known.join(", ")
                    }
                ),
            ));
        };
        chain.push(e);
        at = &e.parent;
    }
    chain.reverse(); // parent first
    let Some(clock) = chain
        .iter()
        .filter(|e| e.fixed.is_none())
        .max_by_key(|e| e.samples.len())
    else {
        return Err(RecordingError::format(
            path,
            format!(
                "the transforms from {parent:?} to {child:?} are all static: the car does not \
                 move in them"
            ),
        ));
    };
    let mut poses = Vec::with_capacity(clock.samples.len());
    let mut missing = 0usize;
    for &(t, _) in &clock.samples {
        let pose = chain
            .iter()
            .try_fold([0.0, 0.0, 0.0], |acc, e| e.at(t).map(|v| compose(acc, v)));
        match pose {
            Some(p) => poses.push((t, p)),
            None => missing += 1,
        }
    }
    let mut notes = Vec::new();
    if missing > 0 {
        notes.push(format!(
            "{missing} of {} {child} poses in {parent} left out: a transform of the chain has \
             no messages around them within {:.1} s",
            clock.samples.len(),
            MAX_TF_GAP_NS as f64 * 1e-9
        ));
    }
    Ok((poses, notes))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn planar_transforms_compose_and_wrap() {
        let a = [1.0, 2.0, std::f64::consts::FRAC_PI_2];
        let b = [1.0, 0.0, 3.0];
        let c = compose(a, b);
        assert!((c[0] - 1.0).abs() < 1e-12 && (c[1] - 3.0).abs() < 1e-12);
        assert!((c[2] - wrap(3.0 + std::f64::consts::FRAC_PI_2)).abs() < 1e-12);
        assert!(c[2] < 0.0);
        assert_eq!(wrap(std::f64::consts::PI), -std::f64::consts::PI);
    }

    #[test]
    fn a_transform_is_interpolated_the_shorter_way_round() {
        let e = Edge {
            parent: "map".into(),
            samples: vec![(0, [0.0, 0.0, 3.0]), (100, [1.0, 2.0, -3.0])],
            fixed: None,
        };
        let m = e.at(50).unwrap();
        assert_eq!((m[0], m[1]), (0.5, 1.0));
        // from 3 rad to -3 rad through pi, not through 0
        assert!((m[2].abs() - std::f64::consts::PI).abs() < 1e-12, "{m:?}");
        assert_eq!(e.at(0).unwrap(), [0.0, 0.0, 3.0]);
        assert_eq!(e.at(101), None);
        let far = Edge {
            samples: vec![(0, [0.0; 3]), (MAX_TF_GAP_NS + 1, [1.0, 0.0, 0.0])],
            ..e
        };
        assert_eq!(far.at(10), None);
    }
}

#[cfg(test)]
mod hostile {
    use crate::cdr::from_cdr;
    use crate::msg::TFMessage;

    /// A transform list whose length says four billion, in a few bytes: an error, not an
    /// allocation of that size.
    #[test]
    fn a_lying_length_is_refused() {
        let mut data = vec![0, 1, 0, 0];
        data.extend_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
        data.extend_from_slice(&[0; 16]);
        assert!(from_cdr::<TFMessage>(&data).is_err());
    }
}
