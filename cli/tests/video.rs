//! `--video` end to end: `paddock rollout` and `paddock benchmark` write GIFs that decode
//! back to one frame per trajectory sample, the same bytes on every run.

mod common;

use common::paddock;

use std::path::Path;
use std::process::Command;

/// (screen width, screen height, frames, the last frame composited as RGB).
fn decode(path: &Path) -> (u32, u32, usize, Vec<u8>) {
    let mut opts = gif::DecodeOptions::new();
    opts.set_color_output(gif::ColorOutput::RGBA);
    let mut d = opts.read_info(std::fs::File::open(path).unwrap()).unwrap();
    let (w, h) = (u32::from(d.width()), u32::from(d.height()));
    let mut screen = vec![0u8; (w * h * 3) as usize];
    let mut frames = 0;
    while let Some(f) = d.read_next_frame().unwrap() {
        frames += 1;
        for y in 0..usize::from(f.height) {
            for x in 0..usize::from(f.width) {
                let p = &f.buffer[(y * usize::from(f.width) + x) * 4..][..4];
                if p[3] == 0 {
                    continue; // transparent: unchanged since the previous frame
                }
                let (sx, sy) = (x + usize::from(f.left), y + usize::from(f.top));
                let k = (sy * w as usize + sx) * 3;
                screen[k..k + 3].copy_from_slice(&p[..3]);
            }
        }
    }
    (w, h, frames, screen)
}

#[test]
fn rollout_writes_a_gif_with_one_frame_per_sample_deterministically() {
    let dir = tempfile::tempdir().unwrap();
    let gif = dir.path().join("lap.gif");
    let gif_s = gif.to_str().unwrap();
    let args = [
        "rollout",
        "--episodes",
        "2",
        "--video-episode",
        "1",
        "--seed",
        "3",
        "--time-limit",
        "3",
        "--fps",
        "25",
        "--json",
        "--video",
        gif_s,
    ];
    let (ok, out, err) = paddock(&args);
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let samples = v["episodes"][1]["trajectory"]["t"]
        .as_array()
        .unwrap()
        .len();
    assert_eq!(v["episodes"][1]["trajectory"]["decimation"], 4);
    assert!(
        v["episodes"][0]["trajectory"].is_null(),
        "only the video's episode is recorded"
    );
    assert_eq!(samples, 76, "3 s at 25 frames per second, both ends");
    let (w, h, frames, last) = decode(&gif);
    assert_eq!((w, h % 2), (800, 0));
    assert_eq!(frames, samples);
    // the learner's car (red, the palette's nearest to the renderer's) is on the last frame
    let red = last
        .chunks_exact(3)
        .filter(|p| p[0] > 200 && p[1] < 80 && p[2] < 80)
        .count();
    assert!(red >= 20, "{red} red pixels");
    // the same flags, the same bytes
    let first = std::fs::read(&gif).unwrap();
    let (ok, _, err) = paddock(&args);
    assert!(ok, "{err}");
    assert_eq!(first, std::fs::read(&gif).unwrap());

    let small = dir.path().join("small.gif");
    let (ok, _, err) = paddock(&[
        "rollout",
        "--episodes",
        "1",
        "--time-limit",
        "0.5",
        "--fps",
        "10",
        "--video-width",
        "320",
        "--video",
        small.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    let (w, h, frames, _) = decode(&small);
    assert_eq!((w, frames), (320, 6));
    assert!(h > 100 && h % 2 == 0, "height {h}");
}

#[test]
fn benchmark_writes_every_race_into_a_directory() {
    let dir = tempfile::tempdir().unwrap();
    let videos = dir.path().join("races");
    let (ok, _, err) = paddock(&[
        "benchmark",
        "b3",
        "--episodes",
        "2",
        "--laps",
        "1",
        "--time-limit",
        "1",
        "--fps",
        "20",
        "--video-width",
        "400",
        "--video",
        videos.to_str().unwrap(),
    ]);
    assert!(ok, "{err}");
    for k in 0..2 {
        let (w, _, frames, _) = decode(&videos.join(format!("b3-{k:03}.gif")));
        assert_eq!(w, 400);
        assert!((2..=21).contains(&frames), "race {k}: {frames} frames");
    }
}

#[test]
fn video_flags_are_checked_before_anything_runs() {
    let dir = tempfile::tempdir().unwrap();
    let bad = |args: &[&str], want: &str| {
        let (ok, _, err) = paddock(args);
        assert!(!ok, "{args:?} succeeded");
        assert!(err.contains(want), "{args:?}: {err}");
    };
    let avi = dir.path().join("a.avi");
    bad(&["rollout", "--video", avi.to_str().unwrap()], ".gif");
    let gif = dir.path().join("a.gif");
    let g = gif.to_str().unwrap();
    bad(
        &["rollout", "--fps", "30", "--video", g],
        "for '--fps <N>': 30 is out of range: must be a whole number that divides 100",
    );
    bad(
        &["rollout", "--video-width", "5", "--video", g],
        "for '--video-width <PX>': 5 is out of range: must be a whole number in [160, 2048]",
    );
    bad(
        &["rollout", "--video-width", "801", "--video", g],
        "--video-width 801: must be even",
    );
    bad(
        &[
            "rollout",
            "--episodes",
            "2",
            "--video-episode",
            "2",
            "--video",
            g,
        ],
        "--video-episode 2 is out of range: must be a whole number in [0, 1] (there are 2 episodes)",
    );
    let d = dir.path().to_str().unwrap();
    bad(
        &["benchmark", "b3", "--video-format", "avi", "--video", d],
        "--video-format avi",
    );
    let ffmpeg = Command::new("ffmpeg").arg("-version").output().is_ok();
    if !ffmpeg {
        let mp4 = dir.path().join("a.mp4");
        bad(
            &["rollout", "--video", mp4.to_str().unwrap()],
            "needs ffmpeg on PATH",
        );
    }
    assert!(!gif.exists());
}
