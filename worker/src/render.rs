//! `EnvRender`: top-down frames of an env session's copies, drawn by `paddock-render`
//! from each copy's world as it is now. The session is only read.
//!
//! Renderers (each holds its circuit's background at one width) are kept for the last
//! [`MAX_RENDERERS`] (circuit, width) pairs used, shared by every session on them.

use std::path::PathBuf;

use paddock_proto::{EnvImage, EnvRender, Error, ErrorCode, error};
use paddock_render::{DEFAULT_WIDTH, Renderer, Scene};
use paddock_rollout::env::VecEnv;

/// Renderers kept (a background of 800 x 542 pixels is 1.3 MB).
pub const MAX_RENDERERS: usize = 8;
/// Most bytes of frames in one reply.
pub const MAX_IMAGE_BYTES: usize = 32 << 20;

/// The renderers last used, most recent last.
#[derive(Debug, Default)]
pub struct Renderers {
    kept: Vec<(PathBuf, u32, Renderer)>,
}

fn invalid(field: &str, message: String) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

impl Renderers {
    fn get(&mut self, env: &VecEnv, width: u32) -> Result<&Renderer, Error> {
        let dir = env.circuit().dir.clone();
        let k = match self
            .kept
            .iter()
            .position(|(d, w, _)| *d == dir && *w == width)
        {
            Some(k) => k,
            None => {
                let r = Renderer::new(env.circuit(), width)
                    .map_err(|e| invalid("env_render.width", e.to_string()))?;
                if self.kept.len() >= MAX_RENDERERS {
                    self.kept.remove(0);
                }
                self.kept.push((dir, width, r));
                self.kept.len() - 1
            }
        };
        // the one used last goes to the back: the front is evicted first
        self.kept[k..].rotate_left(1);
        self.kept
            .last()
            .map(|(_, _, r)| r)
            .ok_or_else(|| error(ErrorCode::Internal, "env_render", "no renderer kept"))
    }

    /// The frames `r` asks for, of session `env`.
    pub fn render(&mut self, env: &VecEnv, r: &EnvRender) -> Result<EnvImage, Error> {
        let n = env.num_envs();
        let envs: Vec<usize> = if r.envs.is_empty() {
            vec![0]
        } else {
            r.envs.iter().map(|&i| i as usize).collect()
        };
        for (j, &i) in envs.iter().enumerate() {
            if i >= n {
                return Err(invalid(
                    &format!("env_render.envs[{j}]"),
                    format!(
                        "env_render.envs[{j}] = {i}: the session has {n} envs (indices 0..{n})"
                    ),
                ));
            }
            if envs[..j].contains(&i) {
                return Err(invalid(
                    &format!("env_render.envs[{j}]"),
                    format!("env_render.envs[{j}] = {i}: named twice"),
                ));
            }
        }
        let width = if r.width == 0 { DEFAULT_WIDTH } else { r.width };
        let renderer = self.get(env, width)?;
        let frame_bytes = renderer.width() as usize * renderer.height() as usize * 3;
        if frame_bytes * envs.len() > MAX_IMAGE_BYTES {
            return Err(invalid(
                "env_render.envs",
                format!(
                    "env_render.envs: {} frames of {} x {} pixels are {} bytes, over the {} byte limit of one reply; ask for fewer envs or a smaller width",
                    envs.len(),
                    renderer.width(),
                    renderer.height(),
                    frame_bytes * envs.len(),
                    MAX_IMAGE_BYTES
                ),
            ));
        }
        let mut rgb = Vec::with_capacity(frame_bytes * envs.len());
        for &i in &envs {
            let world = env.world(i).ok_or_else(|| {
                invalid(
                    "env_render.envs",
                    format!("env_render.envs: env {i} is not in the session"),
                )
            })?;
            let scene = Scene::from_world(world)
                .map_err(|e| error(ErrorCode::Internal, "env_render", e.to_string()))?;
            rgb.extend_from_slice(&renderer.render(&scene).rgb);
        }
        Ok(EnvImage {
            session_id: r.session_id,
            width: renderer.width(),
            height: renderer.height(),
            rgb,
        })
    }
}

#[cfg(test)]
mod tests {
    use paddock_proto::{Body, EnvOpen, EnvStep, Lidar, MapRef};
    use paddock_sim::track::Circuit;

    use crate::sessions::Sessions;

    use super::*;

    fn lakeside() -> MapRef {
        let dir = Circuit::resolve("lakeside", &[]).unwrap().dir.clone();
        let b = paddock_proto::read_map_dir(&dir, "lakeside").unwrap();
        paddock_proto::convert::map_ref(&b)
    }

    fn open(s: &mut Sessions, num_envs: u32) -> u64 {
        let o = EnvOpen {
            map: Some(lakeside()),
            num_envs,
            seed: 4,
            lidar: Some(Lidar {
                num_beams: 108,
                fov: 4.7,
                max_range: 30.0,
                noise_std: 0.01,
                mount_offset: 0.0,
            }),
            laps: 1,
            time_limit: 60.0,
            frame_skip: 1,
            ..Default::default()
        };
        match s.handle(1, Body::EnvOpen(o)) {
            Some(Body::EnvOpened(o)) => o.session_id,
            other => panic!("{other:?}"),
        }
    }

    fn render(s: &mut Sessions, r: EnvRender) -> Result<EnvImage, Error> {
        match s.handle(2, Body::EnvRender(r)) {
            Some(Body::EnvImage(i)) => Ok(i),
            Some(Body::Error(e)) => Err(e),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn frames_of_the_asked_envs_leave_the_session_unchanged() {
        let mut s = Sessions::new();
        let id = open(&mut s, 3);
        let step = EnvStep {
            session_id: id,
            actions: [0.0f32, 2.0]
                .repeat(3)
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect(),
            reset_envs: vec![],
        };
        for _ in 0..20 {
            s.handle(3, Body::EnvStep(step.clone()));
        }
        let ask = |envs: Vec<u32>, width| EnvRender {
            session_id: id,
            envs,
            width,
        };
        let one = render(&mut s, ask(vec![], 0)).unwrap();
        assert_eq!((one.session_id, one.width), (id, DEFAULT_WIDTH));
        assert_eq!(one.rgb.len(), (one.width * one.height * 3) as usize);
        let again = render(&mut s, ask(vec![0], 0)).unwrap();
        assert_eq!(one, again, "rendering reads the session only");
        let three = render(&mut s, ask(vec![2, 0, 1], 320)).unwrap();
        assert_eq!(three.width, 320);
        let frame = (three.width * three.height * 3) as usize;
        assert_eq!(three.rgb.len(), 3 * frame);
        // the copies started in different places: different pictures
        assert_ne!(three.rgb[..frame], three.rgb[frame..2 * frame]);
        let env0 = render(&mut s, ask(vec![0], 320)).unwrap();
        assert_eq!(env0.rgb, three.rgb[frame..2 * frame]);
        // the next step is the step it would have been without the renders
        let mut t = Sessions::new();
        let tid = open(&mut t, 3);
        let tstep = EnvStep {
            session_id: tid,
            ..step.clone()
        };
        for _ in 0..20 {
            t.handle(3, Body::EnvStep(tstep.clone()));
        }
        match (
            s.handle(4, Body::EnvStep(step)),
            t.handle(4, Body::EnvStep(tstep)),
        ) {
            (Some(Body::EnvObservation(a)), Some(Body::EnvObservation(b))) => {
                assert_eq!(a.states, b.states)
            }
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn bad_renders_name_the_field() {
        let mut s = Sessions::new();
        let id = open(&mut s, 2);
        let e = render(
            &mut s,
            EnvRender {
                session_id: id,
                envs: vec![2],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.envs[0]");
        assert!(e.message.contains("2 envs"), "{}", e.message);
        let e = render(
            &mut s,
            EnvRender {
                session_id: id,
                envs: vec![1, 1],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.envs[1]");
        let e = render(
            &mut s,
            EnvRender {
                session_id: id,
                envs: vec![],
                width: 9000,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.width");
        assert!(e.message.contains("9000"), "{}", e.message);
        let e = render(
            &mut s,
            EnvRender {
                session_id: id + 1,
                envs: vec![],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.code, ErrorCode::NotFound as i32);
    }
}
