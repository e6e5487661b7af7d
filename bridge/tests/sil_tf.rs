//! The SIL car's TF over ROS 2 on loopback: `/tf` carries each car's pose with every
//! odometry message (same stamp, same numbers), and `/tf_static` the LIDAR mount, which a
//! subscriber that joins late still receives (transient local, like tf2's static QoS).

use std::thread;
use std::time::{Duration, Instant};

use paddock_bridge::msg::{AckermannDriveStamped, Odometry, TFMessage};
use paddock_bridge::ros::{Frames, RosConfig, RosNode, publish, take_latest};
use paddock_bridge::sil::{Opponent, SilOptions};
use paddock_sim::lidar::LidarConfig;

mod common;
use common::SilThread;

/// Every message waiting on `sub`, oldest first.
fn take_all<M: paddock_bridge::msg::RosMessage>(
    sub: &paddock_bridge::ros::Subscription<M>,
    out: &mut Vec<M>,
) {
    while let Ok(Some((m, _))) = sub.take() {
        out.push(m);
    }
}

#[test]
fn sil_tf_matches_odometry_and_static_laser_reaches_a_late_subscriber() {
    let ros = RosConfig {
        domain_id: 64,
        frames: Frames::f1tenth_gym_ros(),
        ..RosConfig::default()
    };
    let lidar = LidarConfig {
        mount_offset: 0.275,
        ..LidarConfig::default()
    };
    let sil = SilThread::start(
        SilOptions {
            map: "lakeside".into(),
            rate: 2.0,
            seconds: Some(60.0),
            lidar: lidar.clone(),
            opponent: Some(Opponent::Ros),
            ..SilOptions::default()
        },
        &ros,
    );
    let mut node = RosNode::new("tf_listener", &ros).unwrap();
    let odom = node.subscription::<Odometry>("/odom").unwrap();
    let opp_odom = node.subscription::<Odometry>("/opp_odom").unwrap();
    let tf = node.subscription::<TFMessage>("/tf").unwrap();
    let drive = node.publisher::<AckermannDriveStamped>("/drive").unwrap();
    let (mut odoms, mut opp_odoms, mut tfs) = (Vec::new(), Vec::new(), Vec::new());
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(15) && (odoms.len() < 200 || tfs.len() < 200) {
        let mut cmd = AckermannDriveStamped::default();
        cmd.drive.speed = 2.0;
        cmd.drive.steering_angle = 0.05;
        publish(&drive, "/drive", cmd);
        thread::sleep(Duration::from_millis(10));
        take_all(&odom, &mut odoms);
        take_all(&opp_odom, &mut opp_odoms);
        take_all(&tf, &mut tfs);
    }
    assert!(odoms.len() >= 200, "{} odometry messages", odoms.len());
    assert!(tfs.len() >= 200, "{} /tf messages", tfs.len());

    // every /tf message: both cars, parent = the odometry frame, the odometry's numbers
    let mut matched = 0;
    for m in &tfs {
        assert_eq!(m.transforms.len(), 2, "{m:?}");
        let (ego, opp) = (&m.transforms[0], &m.transforms[1]);
        assert_eq!(ego.header.frame_id, "map");
        assert_eq!(ego.child_frame_id, "ego_racecar/base_link");
        assert_eq!(opp.header.frame_id, "map");
        assert_eq!(opp.child_frame_id, "opp_racecar/base_link");
        for (tr, list) in [(ego, &odoms), (opp, &opp_odoms)] {
            let Some(o) = list.iter().find(|o| o.header.stamp == tr.header.stamp) else {
                continue;
            };
            matched += 1;
            assert_eq!(o.child_frame_id, tr.child_frame_id);
            assert_eq!(o.header.frame_id, tr.header.frame_id);
            let p = &o.pose.pose;
            assert_eq!(tr.transform.translation.x, p.position.x);
            assert_eq!(tr.transform.translation.y, p.position.y);
            assert_eq!(tr.transform.translation.z, 0.0);
            assert_eq!(tr.transform.rotation, p.orientation);
        }
    }
    assert!(
        matched >= 300,
        "{matched} transforms matched odometry by stamp"
    );
    let (first, last) = (&odoms[0].pose.pose, &odoms[odoms.len() - 1].pose.pose);
    let moved = (last.position.x - first.position.x).hypot(last.position.y - first.position.y);
    assert!(moved > 1.0, "the ego car drove {moved} m");

    // a subscriber that joins now, long after the SIL published /tf_static once
    let mut late = RosNode::new("late_tf_static_listener", &ros).unwrap();
    let statics = late.static_subscription::<TFMessage>("/tf_static").unwrap();
    let t1 = Instant::now();
    let mut got = None;
    while got.is_none() && t1.elapsed() < Duration::from_secs(5) {
        got = take_latest(&statics, "/tf_static");
        thread::sleep(Duration::from_millis(10));
    }
    let summary = sil.stop();
    let got = got.expect("transient local: /tf_static reaches a late subscriber");
    assert_eq!(got.transforms.len(), 2, "{got:?}");
    for (tr, parent, child) in [
        (
            &got.transforms[0],
            "ego_racecar/base_link",
            "ego_racecar/laser",
        ),
        (
            &got.transforms[1],
            "opp_racecar/base_link",
            "opp_racecar/laser",
        ),
    ] {
        assert_eq!(tr.header.frame_id, parent);
        assert_eq!(tr.child_frame_id, child);
        assert_eq!(tr.transform.translation.x, lidar.mount_offset);
        assert_eq!(tr.transform.translation.y, 0.0);
        assert_eq!(tr.transform.rotation.w, 1.0);
        assert!(!tr.header.stamp.is_zero());
    }
    assert!(summary.tfs_published >= tfs.len() as u64, "{summary:?}");
}

/// `tf: false` publishes no `/tf`.
#[test]
fn sil_without_tf_publishes_none() {
    let ros = RosConfig {
        domain_id: 65,
        ..RosConfig::default()
    };
    let sil = SilThread::start(
        SilOptions {
            map: "lakeside".into(),
            rate: 2.0,
            seconds: Some(30.0),
            tf: false,
            ..SilOptions::default()
        },
        &ros,
    );
    let mut node = RosNode::new("tf_listener", &ros).unwrap();
    let odom = node.subscription::<Odometry>("/odom").unwrap();
    let tf = node.subscription::<TFMessage>("/tf").unwrap();
    let (mut odoms, mut tfs) = (Vec::new(), Vec::new());
    let t0 = Instant::now();
    while t0.elapsed() < Duration::from_secs(10) && odoms.len() < 100 {
        thread::sleep(Duration::from_millis(10));
        take_all(&odom, &mut odoms);
        take_all(&tf, &mut tfs);
    }
    let summary = sil.stop();
    assert!(odoms.len() >= 100, "odometry flows: {}", odoms.len());
    assert!(tfs.is_empty(), "{} /tf messages", tfs.len());
    assert_eq!(summary.tfs_published, 0);
}
