//! The fake observation both broker benches answer env steps with: the sizes a real
//! worker sends (states, rewards, flags, laps per env; a scan frame of f32 ranges).

use paddock_proto::{pack_f32, pack_f64};
use prost::Message;

/// The payload frames of an observation of `num_envs` envs: the message and the scans.
pub fn observation(num_envs: usize, beams: usize) -> Vec<Vec<u8>> {
    let meta = paddock_proto::EnvObservation {
        num_envs: num_envs as u32,
        states: pack_f64(&vec![0.25; num_envs * 7]),
        rewards: pack_f64(&vec![0.1; num_envs]),
        terminated: vec![0; num_envs],
        truncated: vec![0; num_envs],
        progress: pack_f64(&vec![1.0; num_envs]),
        laps: vec![0; 4 * num_envs],
        time: pack_f64(&vec![0.01; num_envs]),
        agent_collisions: vec![0; num_envs],
        agent_lap_counts: vec![0; 4 * num_envs],
        agent_lap_times: pack_f64(&vec![0.0; num_envs]),
    };
    vec![meta.encode_to_vec(), pack_f32(&vec![1.5; num_envs * beams])]
}
