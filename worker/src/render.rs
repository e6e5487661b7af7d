//! `EnvRender`: top-down frames of an env session's copies, drawn by `paddock-render`
//! from each copy's world as it is now. The session is only read.
//!
//! Renderers (each holds its circuit's background at one width) are kept for the last
//! [`MAX_RENDERERS`] (circuit, width) pairs used, shared by every session on them.

use std::sync::Arc;

use paddock_proto::{EnvImage, EnvRender, Error, ErrorCode, error};
use paddock_render::{DEFAULT_WIDTH, Renderer, Scene};
use paddock_rollout::env::VecEnv;
use paddock_sim::circuit::Circuit;

/// Renderers kept (a background of 800 x 542 pixels is 1.3 MB).
pub const MAX_RENDERERS: usize = 8;
/// Most bytes of frames in one reply.
pub const MAX_IMAGE_BYTES: usize = 32 << 20;

/// The renderers last used, most recent last.
#[derive(Debug, Default)]
pub struct Renderers {
    kept: Vec<(Arc<Circuit>, u32, Renderer)>,
}

fn invalid(field: &str, message: String) -> Error {
    error(ErrorCode::InvalidArgument, field, message)
}

impl Renderers {
    fn get(&mut self, env: &VecEnv, width: u32) -> Result<&Renderer, Error> {
        let circuit = env.circuit();
        let k = match self
            .kept
            .iter()
            .position(|(c, w, _)| Arc::ptr_eq(c, circuit) && *w == width)
        {
            Some(k) => k,
            None => {
                let r = Renderer::new(env.circuit(), width)
                    .map_err(|e| invalid("env_render.width", e.to_string()))?;
                if self.kept.len() >= MAX_RENDERERS {
                    self.kept.remove(0);
                }
                self.kept.push((circuit.clone(), width, r));
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

    /// The frames `r` asks for, of session `env`: the image's size and its pixels (the
    /// payload frame after it).
    pub fn render(&mut self, env: &VecEnv, r: &EnvRender) -> Result<(EnvImage, Vec<u8>), Error> {
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
        Ok((
            EnvImage {
                width: renderer.width(),
                height: renderer.height(),
            },
            rgb,
        ))
    }
}

#[cfg(test)]
mod tests {
    use paddock_proto::{EnvOp, EnvOpen, EnvStep, Lidar, MapRef};
    use paddock_sim::circuit::Circuits;
    use prost::Message;

    use crate::sessions::Sessions;

    use super::*;

    fn lakeside() -> MapRef {
        paddock_wire::map_ref(&paddock_wire::local_map(&Circuits::new(), "lakeside").unwrap())
    }

    fn open(s: &mut Sessions, id: u64, num_envs: u32) {
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
        let r = s.handle(id, EnvOp::EnvOpen as i32, &o.encode_to_vec());
        assert!(r.header.error.is_none(), "{:?}", r.header.error);
    }

    /// (width, height, pixels) of a render, or its error.
    fn render(s: &mut Sessions, id: u64, r: EnvRender) -> Result<(u32, u32, Vec<u8>), Error> {
        let reply = s.handle(id, EnvOp::EnvRender as i32, &r.encode_to_vec());
        if let Some(e) = reply.header.error {
            return Err(e);
        }
        let image = EnvImage::decode(reply.frames[0].as_slice()).unwrap();
        Ok((image.width, image.height, reply.frames[1].clone()))
    }

    fn step(s: &mut Sessions, id: u64) -> Vec<Vec<u8>> {
        let step = EnvStep {
            actions: [0.0f32, 2.0]
                .repeat(3)
                .iter()
                .flat_map(|v| v.to_le_bytes())
                .collect(),
            reset_envs: vec![],
        };
        s.handle(id, EnvOp::EnvStep as i32, &step.encode_to_vec())
            .frames
    }

    #[test]
    fn frames_of_the_asked_envs_leave_the_session_unchanged() {
        let mut s = Sessions::new();
        let id = 11;
        open(&mut s, id, 3);
        for _ in 0..20 {
            step(&mut s, id);
        }
        let ask = |envs: Vec<u32>, width| EnvRender { envs, width };
        let one = render(&mut s, id, ask(vec![], 0)).unwrap();
        assert_eq!(one.0, DEFAULT_WIDTH);
        assert_eq!(one.2.len(), (one.0 * one.1 * 3) as usize);
        let again = render(&mut s, id, ask(vec![0], 0)).unwrap();
        assert_eq!(one, again, "rendering reads the session only");
        let three = render(&mut s, id, ask(vec![2, 0, 1], 320)).unwrap();
        assert_eq!(three.0, 320);
        let frame = (three.0 * three.1 * 3) as usize;
        assert_eq!(three.2.len(), 3 * frame);
        // the copies started in different places: different pictures
        assert_ne!(three.2[..frame], three.2[frame..2 * frame]);
        let env0 = render(&mut s, id, ask(vec![0], 320)).unwrap();
        assert_eq!(env0.2, three.2[frame..2 * frame]);
        // the next step is the step it would have been without the renders
        let mut t = Sessions::new();
        open(&mut t, id, 3);
        for _ in 0..20 {
            step(&mut t, id);
        }
        assert_eq!(step(&mut s, id), step(&mut t, id));
    }

    #[test]
    fn bad_renders_name_the_field() {
        let mut s = Sessions::new();
        let id = 12;
        open(&mut s, id, 2);
        let e = render(
            &mut s,
            id,
            EnvRender {
                envs: vec![2],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.envs[0]");
        assert!(e.message.contains("2 envs"), "{}", e.message);
        let e = render(
            &mut s,
            id,
            EnvRender {
                envs: vec![1, 1],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.envs[1]");
        let e = render(
            &mut s,
            id,
            EnvRender {
                envs: vec![],
                width: 9000,
            },
        )
        .unwrap_err();
        assert_eq!(e.field, "env_render.width");
        assert!(e.message.contains("9000"), "{}", e.message);
        let e = render(
            &mut s,
            id + 1,
            EnvRender {
                envs: vec![],
                width: 0,
            },
        )
        .unwrap_err();
        assert_eq!(e.code, ErrorCode::NotFound as i32);
    }
}
