//! Env-step round trips through a broker and a worker on loopback: p50 / p99 latency
//! of one `EnvStep` -> `EnvObservation` for a session of 1 env and of 64 envs, with the
//! full 1080-beam scan and with a 1-beam scan (which leaves mostly the transport).
//! Against `paddock serve` this is the topology Python learners use: the client on TCP,
//! the worker on `inproc://` in the broker's process. Like a Python client, this one
//! blocks in `recv` (no spinning).
//!
//! ```text
//! paddock serve --bind tcp://127.0.0.1:5555 &
//! cargo run --release -p paddock-worker --example env_latency -- tcp://127.0.0.1:5555 [steps]
//! ```

// links libzmq (built with CURVE by paddock-libzmq) into this binary
use paddock_libzmq as _;
use std::time::{Duration, Instant};

use paddock_proto::{
    Body, EnvOp, EnvOpen, EnvReply, EnvRequest, EnvReset, EnvStep, Lidar, MapRef, PutMap, decode,
    encode, pack_f32,
};
use paddock_sim::circuit::Circuits;
use prost::Message;

/// Sends a request (and its payload frame) and waits for its reply: (body, payload).
fn request(
    sock: &zmq::Socket,
    id: &mut u64,
    body: Body,
    payload: Option<Vec<u8>>,
) -> Result<(Body, Vec<Vec<u8>>), String> {
    *id += 1;
    let mut frames = vec![encode(*id, body)];
    frames.extend(payload);
    sock.send_multipart(frames, 0)
        .map_err(|e| format!("send: {e}"))?;
    loop {
        let mut parts = sock
            .recv_multipart(0)
            .map_err(|e| format!("no reply within the timeout: {e}"))?;
        let payload = parts.split_off(1);
        let (rid, body) = decode(&parts[0]).map_err(|(_, e)| e.to_string())?;
        if rid != *id {
            continue;
        }
        return match body {
            Body::Error(e) | Body::EnvReply(EnvReply { error: Some(e), .. }) => Err(format!(
                "{} [{}]: {}",
                paddock_proto::code_name(e.code),
                e.field,
                e.message
            )),
            b => Ok((b, payload)),
        };
    }
}

/// An env request on session `sid` (0: open one).
fn env(
    sock: &zmq::Socket,
    id: &mut u64,
    sid: u64,
    op: EnvOp,
    payload: Option<Vec<u8>>,
) -> Result<(EnvReply, Vec<Vec<u8>>), String> {
    let header = Body::EnvRequest(EnvRequest {
        session_id: sid,
        op: op as i32,
    });
    match request(sock, id, header, payload)? {
        (Body::EnvReply(r), frames) => Ok((r, frames)),
        (other, _) => Err(format!(
            "an env request answered with {}",
            paddock_proto::body_name(&other)
        )),
    }
}

fn percentile(sorted: &[Duration], p: f64) -> f64 {
    let k = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[k].as_secs_f64() * 1e6
}

fn main() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let endpoint = args.next().ok_or(
        "usage: env_latency ENDPOINT [steps] (e.g. tcp://127.0.0.1:5555 from `paddock serve`)",
    )?;
    let steps: usize = match args.next() {
        Some(s) => s.parse().map_err(|e| format!("steps = {s:?}: {e}"))?,
        None => 2000,
    };
    let ctx = zmq::Context::new();
    let sock = ctx.socket(zmq::DEALER).map_err(|e| e.to_string())?;
    sock.set_linger(0).map_err(|e| e.to_string())?;
    sock.set_rcvtimeo(30_000).map_err(|e| e.to_string())?;
    sock.connect(&endpoint)
        .map_err(|e| format!("{endpoint}: {e}"))?;
    let mut id = 0u64;
    let bundle =
        paddock_wire::local_map(&Circuits::new(), "lakeside").map_err(|e| e.message.clone())?;
    let map = MapRef {
        name: bundle.name.clone(),
        hash: bundle.hash.clone(),
    };
    request(
        &sock,
        &mut id,
        Body::PutMap(PutMap {
            bundle: Some(bundle),
        }),
        None,
    )?;
    println!("| envs | beams | steps | p50 µs | p99 µs | mean µs | env-steps/s |");
    println!("|---:|---:|---:|---:|---:|---:|---:|");
    for (num_envs, beams) in [(1u32, 1080u32), (64, 1080), (1, 1), (64, 1)] {
        let open = EnvOpen {
            map: Some(map.clone()),
            num_envs,
            seed: 1,
            lidar: Some(Lidar {
                num_beams: beams,
                fov: 4.7,
                max_range: 30.0,
                noise_std: 0.01,
                mount_offset: 0.0,
            }),
            laps: 100,
            time_limit: 36_000.0,
            frame_skip: 1,
            ..Default::default()
        };
        let (opened, _) = env(
            &sock,
            &mut id,
            0,
            EnvOp::EnvOpen,
            Some(open.encode_to_vec()),
        )?;
        let sid = opened.session_id;
        let reset = EnvReset::default().encode_to_vec();
        env(&sock, &mut id, sid, EnvOp::EnvReset, Some(reset))?;
        // standing cars: every step still runs the dynamics and the scan, and none crashes
        let step = EnvStep {
            actions: pack_f32(
                &(0..num_envs)
                    .flat_map(|_| [0.0f32, 0.0])
                    .collect::<Vec<_>>(),
            ),
            reset_envs: vec![],
        }
        .encode_to_vec();
        let mut times = Vec::with_capacity(steps);
        let t0 = Instant::now();
        for _ in 0..steps {
            let t = Instant::now();
            env(&sock, &mut id, sid, EnvOp::EnvStep, Some(step.clone()))?;
            times.push(t.elapsed());
        }
        let total = t0.elapsed().as_secs_f64();
        env(&sock, &mut id, sid, EnvOp::EnvClose, None)?;
        times.sort();
        println!(
            "| {num_envs} | {beams} | {steps} | {:.0} | {:.0} | {:.0} | {:.0} |",
            percentile(&times, 0.5),
            percentile(&times, 0.99),
            total / steps as f64 * 1e6,
            steps as f64 * f64::from(num_envs) / total
        );
    }
    Ok(())
}
