//! Videos of recorded episodes: `--video` on `paddock rollout` and `paddock benchmark`.
//!
//! Each frame is a scene of the episode's trajectory (see `paddock_render::replay`)
//! drawn by the same renderer the env's `render()` uses. GIF is written here (a
//! 255-colour palette fitted to the first frame, and each frame stored as the rectangle
//! that changed since the previous one, with unchanged pixels transparent: a lap at 25
//! frames per second is about two megabytes); other
//! formats (MP4, WebM, MKV, MOV) are encoded by `ffmpeg` from raw RGB frames on its
//! standard input, when it is on PATH.

use std::borrow::Cow;
use std::collections::HashMap;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU64, Ordering};

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use paddock_render::replay::Replay;
use paddock_render::{Frame, Renderer};
use paddock_rollout::{EpisodeResult, Scenario};
use paddock_sim::circuit::Circuits;

use crate::args;

/// Physics steps per second (the simulator's 0.01 s timestep).
const STEPS_PER_S: u32 = 100;

/// Video options shared by `rollout` and `benchmark`.
#[derive(Args, Debug, Clone)]
pub struct VideoOptions {
    /// Video frames per second of simulated time; must divide 100 (1, 2, 4, 5, 10, 20,
    /// 25, 50 or 100).
    #[arg(long, default_value_t = 25, value_name = "N", value_parser = fps)]
    pub fps: u32,
    /// Video frame width in pixels (even, 160..=2048); the height follows the track's shape.
    #[arg(
        long,
        default_value_t = paddock_render::DEFAULT_WIDTH,
        value_name = "PX",
        value_parser = args::whole::<u32>(paddock_render::MIN_WIDTH as i128, paddock_render::MAX_WIDTH as i128)
    )]
    pub video_width: u32,
}

/// What `--fps` may be: a whole number that divides [`STEPS_PER_S`] (one frame every
/// whole number of 0.01 s steps).
const FPS_RANGE: &str = "must be a whole number that divides 100 (one frame every whole number of 0.01 s steps): 1, 2, 4, 5, 10, 20, 25, 50 or 100";

/// Whether `fps` frames a second fall on whole 0.01 s steps.
fn fps_divides(fps: u32) -> bool {
    fps != 0 && STEPS_PER_S.is_multiple_of(fps)
}

/// The parser of `--fps`, in the wording of every numeric flag (`args`).
fn fps(text: &str) -> Result<u32, String> {
    text.trim()
        .parse()
        .ok()
        .filter(|&v| fps_divides(v))
        .ok_or_else(|| format!("{text} is out of range: {FPS_RANGE}"))
}

impl VideoOptions {
    /// The trajectory decimation that gives one sample per frame. (The flags' parsers
    /// check the same; this checks options made in code.)
    pub fn decimation(&self) -> Result<u32> {
        if !fps_divides(self.fps) {
            bail!("--fps {} is out of range: {FPS_RANGE}", self.fps);
        }
        if !(paddock_render::MIN_WIDTH..=paddock_render::MAX_WIDTH).contains(&self.video_width) {
            bail!(
                "--video-width {} is out of range: must be a whole number in [{}, {}]",
                self.video_width,
                paddock_render::MIN_WIDTH,
                paddock_render::MAX_WIDTH
            );
        }
        if !self.video_width.is_multiple_of(2) {
            bail!(
                "--video-width {}: must be even (video encoders take even sizes)",
                self.video_width
            );
        }
        Ok(STEPS_PER_S / self.fps)
    }
}

/// The container a path asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    Gif,
    /// Encoded by ffmpeg (mp4, webm, mkv, mov).
    Ffmpeg,
}

impl Format {
    pub fn of(path: &Path) -> Result<Self> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase);
        match ext.as_deref() {
            Some("gif") => Ok(Format::Gif),
            Some("mp4" | "webm" | "mkv" | "mov") => Ok(Format::Ffmpeg),
            _ => bail!(
                "--video {}: the file name must end in .gif, or .mp4, .webm, .mkv or .mov (encoded by ffmpeg)",
                path.display()
            ),
        }
    }
}

/// Fails early, with the remedy, when `path` needs ffmpeg and it is not on PATH.
pub fn check_encoder(path: &Path) -> Result<()> {
    if Format::of(path)? == Format::Ffmpeg && !ffmpeg_available() {
        bail!(
            "--video {}: writing this format needs ffmpeg on PATH, and none was found; install ffmpeg, or write a GIF instead (--video {})",
            path.display(),
            path.with_extension("gif").display()
        );
    }
    Ok(())
}

fn ffmpeg_available() -> bool {
    Command::new("ffmpeg")
        .arg("-version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// A progress bar counting rendered frames.
pub fn frames_bar(total: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(total);
    bar.set_style(
        ProgressStyle::with_template("{msg} [{bar:30}] {pos}/{len} frames, {per_sec}, eta {eta}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.set_message(what.to_string());
    bar
}

/// Render `episode` (of `scenario`, recorded with [`VideoOptions::decimation`]) to
/// `path`; `done` counts frames as they are written. Returns the number of frames.
pub fn write_episode(
    circuits: &Circuits,
    path: &Path,
    scenario: &Scenario,
    episode: &EpisodeResult,
    opts: &VideoOptions,
    done: &AtomicU64,
) -> Result<usize> {
    let format = Format::of(path)?;
    let replay = Replay::new(circuits, scenario, episode)?;
    let renderer = Renderer::new(replay.circuit(), opts.video_width)?;
    let (w, h) = (renderer.width(), renderer.height());
    let mut sink: Box<dyn FrameSink> = match format {
        Format::Gif => Box::new(GifSink::create(path, w, opts.fps)?),
        Format::Ffmpeg => Box::new(FfmpegSink::spawn(path, w, h, opts.fps)?),
    };
    for k in 0..replay.len() {
        let frame = renderer.render(&replay.scene(k));
        sink.push(&frame)
            .with_context(|| format!("writing {}", path.display()))?;
        done.fetch_add(1, Ordering::Relaxed);
    }
    sink.finish()
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(replay.len())
}

/// Renders the given episodes into files in parallel, with one progress bar.
pub fn write_episodes(
    circuits: &Circuits,
    jobs: &[(PathBuf, &Scenario, &EpisodeResult)],
    opts: &VideoOptions,
) -> Result<()> {
    use rayon::prelude::*;
    let total: u64 = jobs
        .iter()
        .map(|(_, _, e)| e.trajectory.as_ref().map_or(0, |t| t.t.len() as u64))
        .sum();
    let bar = frames_bar(total, "video");
    let done = AtomicU64::new(0);
    let stop = std::sync::atomic::AtomicBool::new(false);
    let result = std::thread::scope(|s| {
        let ticker = s.spawn(|| {
            while !stop.load(Ordering::Relaxed) {
                bar.set_position(done.load(Ordering::Relaxed));
                std::thread::sleep(std::time::Duration::from_millis(100));
            }
        });
        let r = jobs
            .par_iter()
            .map(|(path, scenario, episode)| {
                write_episode(circuits, path, scenario, episode, opts, &done).map(|_| ())
            })
            .collect::<Result<Vec<()>>>();
        stop.store(true, Ordering::Relaxed);
        let _ = ticker.join();
        r
    });
    bar.finish_and_clear();
    result.map(|_| ())
}

trait FrameSink {
    fn push(&mut self, frame: &Frame) -> Result<()>;
    fn finish(self: Box<Self>) -> Result<()>;
}

/// Palette index of pixels unchanged since the previous frame.
const TRANSPARENT: u8 = 255;

/// A GIF palette fitted to a video: the car colours, black and white, then the most
/// frequent colours of its first frame (the background, the driving line, the scan's
/// blends, the overlay: most of what any frame shows), 255 in all. Other colours go to
/// their nearest entry, remembered per colour.
struct Palette {
    rgb: Vec<[u8; 3]>,
    index: HashMap<[u8; 3], u8>,
}

impl Palette {
    fn fit(frame: &Frame) -> Self {
        let mut rgb: Vec<[u8; 3]> = paddock_render::CAR_COLOURS
            .iter()
            .map(|c| [c.0, c.1, c.2])
            .collect();
        rgb.extend([[0, 0, 0], [255, 255, 255]]);
        let mut counts: HashMap<[u8; 3], u32> = HashMap::new();
        for p in frame.rgb.chunks_exact(3) {
            *counts.entry([p[0], p[1], p[2]]).or_default() += 1;
        }
        let mut frequent: Vec<([u8; 3], u32)> = counts.into_iter().collect();
        // most frequent first; ties by colour, so the palette is the same on every run
        frequent.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        for (c, _) in frequent {
            if rgb.len() >= usize::from(TRANSPARENT) {
                break;
            }
            if !rgb.contains(&c) {
                rgb.push(c);
            }
        }
        let index = rgb.iter().enumerate().map(|(i, &c)| (c, i as u8)).collect();
        Self { rgb, index }
    }

    /// The flat palette for the GIF header: the entries, padded, the transparent last.
    fn table(&self) -> Vec<u8> {
        let mut t: Vec<u8> = self.rgb.iter().flatten().copied().collect();
        t.resize(usize::from(TRANSPARENT) * 3, 0);
        t.extend_from_slice(&[255, 0, 255]);
        t
    }

    fn index_of(&mut self, c: [u8; 3]) -> u8 {
        if let Some(&i) = self.index.get(&c) {
            return i;
        }
        let d2 = |p: &[u8; 3]| -> i32 {
            (0..3)
                .map(|k| (i32::from(p[k]) - i32::from(c[k])).pow(2))
                .sum()
        };
        let mut best = 0;
        for (i, p) in self.rgb.iter().enumerate() {
            if d2(p) < d2(&self.rgb[best]) {
                best = i;
            }
        }
        self.index.insert(c, best as u8);
        best as u8
    }
}

struct GifSink {
    path: PathBuf,
    encoder: Option<(gif::Encoder<BufWriter<File>>, Palette)>,
    previous: Option<Vec<u8>>,
    width: usize,
    delay: u16,
}

impl GifSink {
    fn create(path: &Path, w: u32, fps: u32) -> Result<Self> {
        Ok(Self {
            path: path.to_path_buf(),
            encoder: None,
            previous: None,
            width: w as usize,
            delay: (100 / fps) as u16,
        })
    }
}

impl FrameSink for GifSink {
    fn push(&mut self, frame: &Frame) -> Result<()> {
        let w = self.width;
        if self.encoder.is_none() {
            let palette = Palette::fit(frame);
            let file = File::create(&self.path)
                .with_context(|| format!("creating {}", self.path.display()))?;
            let (fw, fh) = (frame.width as u16, frame.height as u16);
            let mut encoder = gif::Encoder::new(BufWriter::new(file), fw, fh, &palette.table())?;
            encoder.set_repeat(gif::Repeat::Infinite)?;
            self.encoder = Some((encoder, palette));
        }
        let (encoder, palette) = self.encoder.as_mut().expect("created above");
        let indices: Vec<u8> = frame
            .rgb
            .chunks_exact(3)
            .map(|p| palette.index_of([p[0], p[1], p[2]]))
            .collect();
        let h = indices.len() / w;
        // the rectangle that changed since the previous frame (all of the first)
        let (mut x0, mut y0, mut x1, mut y1) = (0, 0, w, h);
        if let Some(prev) = &self.previous {
            (x0, y0, x1, y1) = (w, h, 0, 0);
            for y in 0..h {
                for x in 0..w {
                    if prev[y * w + x] != indices[y * w + x] {
                        x0 = x0.min(x);
                        y0 = y0.min(y);
                        x1 = x1.max(x + 1);
                        y1 = y1.max(y + 1);
                    }
                }
            }
            if x0 >= x1 {
                (x0, y0, x1, y1) = (0, 0, 1, 1); // nothing changed: one transparent pixel
            }
        }
        let mut patch = Vec::with_capacity((x1 - x0) * (y1 - y0));
        for y in y0..y1 {
            for x in x0..x1 {
                let i = indices[y * w + x];
                let same = self.previous.as_ref().is_some_and(|p| p[y * w + x] == i);
                patch.push(if same { TRANSPARENT } else { i });
            }
        }
        let gif_frame = gif::Frame {
            left: x0 as u16,
            top: y0 as u16,
            width: (x1 - x0) as u16,
            height: (y1 - y0) as u16,
            delay: self.delay,
            dispose: gif::DisposalMethod::Keep,
            transparent: self.previous.as_ref().map(|_| TRANSPARENT),
            buffer: Cow::Owned(patch),
            ..gif::Frame::default()
        };
        encoder.write_frame(&gif_frame)?;
        self.previous = Some(indices);
        Ok(())
    }

    fn finish(self: Box<Self>) -> Result<()> {
        if let Some((encoder, _)) = self.encoder {
            encoder.into_inner()?.flush()?;
        }
        Ok(())
    }
}

struct FfmpegSink {
    child: Child,
}

impl FfmpegSink {
    fn spawn(path: &Path, w: u32, h: u32, fps: u32) -> Result<Self> {
        let child = Command::new("ffmpeg")
            .args(["-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24"])
            .args(["-s", &format!("{w}x{h}"), "-r", &fps.to_string(), "-i", "-"])
            .args(["-pix_fmt", "yuv420p"])
            .arg(path)
            .stdin(Stdio::piped())
            .stdout(Stdio::null())
            .spawn()
            .with_context(|| {
                format!(
                    "--video {}: starting ffmpeg (needed for this format; write a .gif instead where it is missing)",
                    path.display()
                )
            })?;
        Ok(Self { child })
    }
}

impl FrameSink for FfmpegSink {
    fn push(&mut self, frame: &Frame) -> Result<()> {
        let stdin = self
            .child
            .stdin
            .as_mut()
            .context("ffmpeg's standard input")?;
        stdin
            .write_all(&frame.rgb)
            .context("ffmpeg stopped reading frames")?;
        Ok(())
    }

    fn finish(mut self: Box<Self>) -> Result<()> {
        drop(self.child.stdin.take());
        let status = self.child.wait()?;
        if !status.success() {
            bail!("ffmpeg failed ({status})");
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_palette_holds_a_frames_colours_exactly_and_the_rest_nearly() {
        let mut rgb = Vec::new();
        for k in 0..300u32 {
            // 300 distinct colours, the first ones most frequent
            for _ in 0..(300 - k) {
                rgb.extend_from_slice(&[(k % 256) as u8, (k / 256) as u8 * 100, 7]);
            }
        }
        let frame = Frame {
            width: (rgb.len() / 3) as u32,
            height: 1,
            rgb,
        };
        let mut p = Palette::fit(&frame);
        assert_eq!(p.rgb.len(), 255);
        assert_eq!(p.table().len(), 256 * 3);
        let c = paddock_render::CAR_COLOURS[0];
        let i = usize::from(p.index_of([c.0, c.1, c.2]));
        assert_eq!(p.rgb[i], [c.0, c.1, c.2]);
        let i = usize::from(p.index_of([3, 0, 7]));
        assert_eq!(p.rgb[i], [3, 0, 7]);
        // a colour left out goes to its nearest entry, never to the transparent index
        let i = p.index_of([250, 100, 7]);
        assert!(i < TRANSPARENT);
        let got = p.rgb[usize::from(i)];
        assert!(got[0].abs_diff(250) < 40, "{got:?}");
    }

    #[test]
    fn fps_and_formats_are_checked() {
        let opts = |fps| VideoOptions {
            fps,
            video_width: 800,
        };
        assert_eq!(opts(25).decimation().unwrap(), 4);
        assert_eq!(opts(100).decimation().unwrap(), 1);
        let odd = VideoOptions {
            fps: 25,
            video_width: 801,
        };
        assert!(odd.decimation().unwrap_err().to_string().contains("even"));
        for bad in [0, 3, 30, 200] {
            let e = opts(bad).decimation().unwrap_err().to_string();
            assert!(
                e.starts_with(&format!("--fps {bad} is out of range:")),
                "{e}"
            );
        }
        // the flag's parser: the same rule, in the wording of every numeric flag
        assert_eq!(fps("25"), Ok(25));
        assert_eq!(fps("100"), Ok(100));
        for bad in ["0", "7", "30", "200", "-1", "2.5", "x"] {
            let e = fps(bad).unwrap_err();
            assert!(
                e.starts_with(&format!(
                    "{bad} is out of range: must be a whole number that divides 100"
                )),
                "{e}"
            );
        }
        assert_eq!(Format::of(Path::new("a/b.GIF")).unwrap(), Format::Gif);
        assert_eq!(Format::of(Path::new("b.mp4")).unwrap(), Format::Ffmpeg);
        let e = Format::of(Path::new("b.avi")).unwrap_err().to_string();
        assert!(e.contains(".gif"), "{e}");
    }
}
