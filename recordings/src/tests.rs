use std::collections::BTreeMap;
use std::io::Cursor;

use super::*;

/// A finalised MCAP with `n` messages on /a and /b (alternating), 10 ms apart, in chunks
/// of about `chunk` bytes.
fn mcap_bytes(n: u64, chunk: u64) -> Vec<u8> {
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .chunk_size(Some(chunk))
        .profile("ros2")
        .create(Cursor::new(Vec::new()))
        .unwrap();
    let schema = w
        .add_schema("std_msgs/msg/Int32", "ros2msg", b"int32 data")
        .unwrap();
    let meta = BTreeMap::from([("offered_qos_profiles".to_string(), "- depth: 5".to_string())]);
    let a = w.add_channel(schema, "/a", "cdr", &meta).unwrap();
    let b = w
        .add_channel(schema, "/b", "cdr", &BTreeMap::new())
        .unwrap();
    for k in 0..n {
        let header = mcap::records::MessageHeader {
            channel_id: if k % 2 == 0 { a } else { b },
            sequence: k as u32,
            log_time: 1_000_000_000 + k * 10_000_000,
            publish_time: 0,
        };
        let mut data = vec![0, 1, 0, 0];
        data.extend_from_slice(&(k as i32).to_le_bytes());
        data.resize(200, 0);
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
    w.into_inner().into_inner()
}

fn index(m: &BagMessage) -> i32 {
    i32::from_le_bytes(m.data[4..8].try_into().unwrap())
}

#[test]
fn a_finalised_mcap_reads_whole_with_its_qos_metadata() {
    let bytes = mcap_bytes(100, 4096);
    let bag = read_mcap(&bytes, Path::new("run.mcap"), &["/a", "/b"]).unwrap();
    assert_eq!(bag.truncation, None);
    assert_eq!(bag.messages.len(), 100);
    assert!(
        bag.messages
            .iter()
            .enumerate()
            .all(|(k, m)| index(m) == k as i32)
    );
    assert_eq!(bag.topics["/a"].messages, 50);
    assert_eq!(bag.topics["/a"].type_name, "std_msgs/msg/Int32");
    assert_eq!(
        bag.topics["/a"].offered_qos_profiles.as_deref(),
        Some("- depth: 5")
    );
    assert_eq!(bag.topics["/b"].offered_qos_profiles, None);
    // only the topics asked for are kept, all are counted
    let only_a = read_mcap(&bytes, Path::new("run.mcap"), &["/a"]).unwrap();
    assert_eq!(only_a.messages.len(), 50);
    assert_eq!(only_a.topics["/b"].messages, 50);
}

#[test]
fn a_truncated_mcap_is_read_up_to_its_last_complete_chunk() {
    let bytes = mcap_bytes(400, 4096);
    let full = read_mcap(&bytes, Path::new("run.mcap"), &["/a", "/b"]).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let chunks = &summary.chunk_indexes;
    assert!(chunks.len() > 5, "{} chunks", chunks.len());
    // cut inside every chunk after the first (a power cut mid-write)
    for (k, c) in chunks.iter().enumerate().skip(1) {
        let cut = (c.chunk_start_offset + c.chunk_length / 2) as usize;
        let bag = read_mcap(&bytes[..cut], Path::new("cut.mcap"), &["/a", "/b"]).unwrap();
        let t = bag.truncation.as_ref().expect("reported as truncated");
        // every message of the complete chunks before the cut, and of the cut
        // (uncompressed) chunk those that are whole, in order: a prefix of the file
        let in_chunk = |c: &mcap::records::ChunkIndex| {
            (c.message_end_time - c.message_start_time) / 10_000_000 + 1
        };
        let before: u64 = chunks[..k].iter().map(in_chunk).sum();
        let got = t.messages;
        assert!(
            got >= before && got < before + in_chunk(c),
            "cut in chunk {k}: {got} messages, {before} before it"
        );
        assert_eq!(bag.messages[..], full.messages[..got as usize]);
        assert!((t.span_s - (got - 1) as f64 * 0.01).abs() < 1e-9);
        assert_eq!(t.file_bytes, cut as u64);
        let said = t.to_string();
        assert!(
            said.contains(&format!("recovered {got} messages")),
            "{said}"
        );
    }
    // nothing complete: an error naming the file
    let first = &chunks[0];
    let cut = first.chunk_start_offset as usize + 10;
    let e = read_mcap(&bytes[..cut], Path::new("cut.mcap"), &["/a"]).unwrap_err();
    assert!(
        e.to_string().contains("cut.mcap") && e.to_string().contains("not finalised"),
        "{e}"
    );
    // garbage is not an MCAP file
    let e = read_mcap(b"garbage!", Path::new("x.mcap"), &["/a"]).unwrap_err();
    assert!(e.to_string().contains("not an MCAP file"), "{e}");
}

#[test]
fn bag_folders_name_their_problems() {
    let dir = std::env::temp_dir().join(format!("paddock-recordings-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    assert!(!is_bag(&dir));
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n",
    )
    .unwrap();
    assert!(is_bag(&dir));
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("storage_identifier"), "{e}");
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  relative_file_paths:\n    - run_0.mcap\n",
    )
    .unwrap();
    std::fs::write(dir.join("run_0.mcap"), mcap_bytes(10, 4096)).unwrap();
    let bag = read_bag(&dir, &["/b"]).unwrap();
    assert_eq!(bag.messages.len(), 5);
    std::fs::write(
        dir.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  storage_identifier: fancy\n  relative_file_paths: [x]\n",
    )
    .unwrap();
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("\"fancy\""), "{e}");
    let e = read_db3(&dir.join("none.db3"), &["/a"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("none.db3"), "{e}");
    std::fs::write(dir.join("junk.db3"), b"not sqlite at all, not at all").unwrap();
    let e = read_db3(&dir.join("junk.db3"), &["/a"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("junk.db3"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// rosbag2's compression: whole files (`*.mcap.zstd`, also given bare) and each message,
/// as `metadata.yaml` says; what it does not say is refused by name.
#[test]
fn compressed_bags_are_read_as_metadata_says() {
    let dir = std::env::temp_dir().join(format!("paddock-recordings-z-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let meta = |file: &str, mode: &str, format: &str| {
        std::fs::write(
            dir.join("metadata.yaml"),
            format!(
                "rosbag2_bagfile_information:\n  storage_identifier: mcap\n  \
                 relative_file_paths: [{file}]\n  compression_mode: {mode}\n  \
                 compression_format: {format}\n"
            ),
        )
        .unwrap();
    };
    let plain = mcap_bytes(40, 4096);
    let want = read_mcap(&plain, Path::new("x"), &["/a", "/b"]).unwrap();

    // whole file
    let z = zstd::stream::encode_all(&plain[..], 3).unwrap();
    std::fs::write(dir.join("run_0.mcap.zstd"), &z).unwrap();
    meta("run_0.mcap.zstd", "file", "zstd");
    assert_eq!(
        read_bag(&dir, &["/a", "/b"]).unwrap().messages,
        want.messages
    );
    let bare = dir.join("run_0.mcap.zstd");
    assert!(is_bag(&bare));
    assert_eq!(
        read_bag(&bare, &["/a", "/b"]).unwrap().messages,
        want.messages
    );

    // each message (the MCAP itself plain)
    let mut w = mcap::WriteOptions::new()
        .compression(None)
        .profile("ros2")
        .create(Cursor::new(Vec::new()))
        .unwrap();
    let schema = w
        .add_schema("std_msgs/msg/Int32", "ros2msg", b"int32 data")
        .unwrap();
    let a = w
        .add_channel(schema, "/a", "cdr", &BTreeMap::new())
        .unwrap();
    for m in want.messages.iter().filter(|m| m.topic == "/a") {
        let header = mcap::records::MessageHeader {
            channel_id: a,
            sequence: 0,
            log_time: m.log_time,
            publish_time: 0,
        };
        let data = zstd::stream::encode_all(&m.data[..], 3).unwrap();
        w.write_to_known_channel(&header, &data).unwrap();
    }
    w.finish().unwrap();
    std::fs::write(dir.join("run_1.mcap"), w.into_inner().into_inner()).unwrap();
    meta("run_1.mcap", "message", "zstd");
    let got = read_bag(&dir, &["/a"]).unwrap();
    assert_eq!(got.messages.len(), 20);
    assert!(
        got.messages
            .iter()
            .zip(want.messages.iter().filter(|m| m.topic == "/a"))
            .all(|(g, w)| g.data == w.data && g.log_time == w.log_time)
    );

    // what metadata.yaml says and the files disagree with, or cannot be read
    meta("run_0.mcap.zstd", "message", "zstd");
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("run_0.mcap.zstd"), "{e}"); // not an MCAP: it is compressed whole
    meta("run_1.mcap", "file", "zstd");
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("run_1.mcap: not a whole zstd stream"), "{e}");
    meta("run_0.mcap", "message", "zstd");
    std::fs::write(dir.join("run_0.mcap"), &plain).unwrap();
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(
        e.contains("message 0 on /a: not zstd as compression_mode = message says"),
        "{e}"
    );
    meta("run_0.mcap.zstd", "file", "lz4");
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("compression_format = \"lz4\": only zstd"), "{e}");
    meta("run_0.mcap.zstd", "chunk", "zstd");
    let e = read_bag(&dir, &["/a"]).unwrap_err().to_string();
    assert!(e.contains("compression_mode = \"chunk\""), "{e}");
    // a bare compressed file that is not zstd
    std::fs::write(dir.join("junk.db3.zstd"), b"plain text").unwrap();
    let e = read_bag(&dir.join("junk.db3.zstd"), &["/a"])
        .unwrap_err()
        .to_string();
    assert!(e.contains("junk.db3.zstd: not a whole zstd stream"), "{e}");
    std::fs::remove_dir_all(&dir).ok();
}

/// A recording damaged anywhere (each byte of a small bag changed in turn, and a run of
/// zeros over each chunk of it) reads as messages or as an error, never a panic, and so
/// does the track read from what was recovered.
#[test]
fn a_damaged_bag_is_an_error_or_messages_never_a_panic() {
    use crate::msg::{AckermannDriveStamped, Odometry};
    use crate::track::{RecordingTopics, drive_commands, planar_track};
    use crate::write::McapBag;

    let topics = RecordingTopics::default();
    let mut bag = McapBag::new(Cursor::new(Vec::new()), "x.mcap", "test").unwrap();
    bag.add_topic::<AckermannDriveStamped>(&topics.drive)
        .unwrap();
    bag.add_topic::<Odometry>(&topics.odom).unwrap();
    for k in 0..6u64 {
        let mut o = Odometry::default();
        o.pose.pose.position.x = k as f64;
        o.twist.twist.linear.x = 1.0;
        let t = 1_000_000_000 + k * 25_000_000;
        bag.write(&topics.drive, &AckermannDriveStamped::default(), t, t)
            .unwrap();
        bag.write(&topics.odom, &o, t, t).unwrap();
    }
    let good = bag.finish().unwrap().into_inner();
    let path = Path::new("x.mcap");
    let names = ["/drive", "/odom"];
    let read = |bytes: &[u8]| {
        if let Ok(b) = read_mcap(bytes, path, &names) {
            let _ = drive_commands(&b, path, &topics);
            let _ = planar_track(&b, path, &topics);
        }
    };
    read(&good);
    let mut damaged = good.clone();
    for i in 0..good.len() {
        for v in [0x00, 0xFF, good[i] ^ 0x01] {
            damaged[i] = v;
            read(&damaged);
        }
        damaged[i] = good[i];
    }
    for start in (0..good.len()).step_by(16) {
        let mut d = good.clone();
        let end = (start + 64).min(d.len());
        d[start..end].fill(0);
        read(&d);
    }
}
