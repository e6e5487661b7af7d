use paddock_proto::{
    EnvObservation, EnvOpen, EnvOpened, EnvReply, EnvStep, Lidar, MapRef, pack_f32,
};

use super::*;

/// Calls through the C ABI with no buffer for the scans: the status and the frames.
fn call(h: *mut Embedded, kind: u32, session: u64, op: i32, payload: &[u8]) -> (i64, Vec<Vec<u8>>) {
    call_into(h, kind, session, op, payload, &mut [])
}

/// Calls through the C ABI, as the Python package does, offering `scans` for the scans
/// of a step or reset: the status and the frames.
fn call_into(
    h: *mut Embedded,
    kind: u32,
    session: u64,
    op: i32,
    payload: &[u8],
    scans: &mut [u8],
) -> (i64, Vec<Vec<u8>>) {
    // SAFETY: a live handle of this test; `payload` and `scans` are valid slices.
    let status = unsafe {
        paddock_embed_call(
            h,
            kind,
            session,
            op,
            payload.as_ptr(),
            payload.len(),
            scans.as_mut_ptr(),
            scans.len(),
        )
    };
    let mut frames = Vec::new();
    for i in 0.. {
        let mut data = std::ptr::null();
        // SAFETY: as above; `data` is writable.
        let len = unsafe { paddock_embed_frame(h, i, &mut data) };
        if data.is_null() {
            break;
        }
        // SAFETY: the library keeps `len` bytes at `data` until the next call.
        frames.push(unsafe { std::slice::from_raw_parts(data, len) }.to_vec());
    }
    // all at once, as the Python package reads them: the same frames
    let (mut data, mut lens) = ([std::ptr::null(); 4], [0usize; 4]);
    // SAFETY: a live handle; four writable elements at each.
    let count = unsafe { paddock_embed_frames(h, data.as_mut_ptr(), lens.as_mut_ptr(), 4) };
    assert_eq!(count, frames.len());
    for (i, f) in frames.iter().enumerate().take(4) {
        // SAFETY: as above.
        assert_eq!(
            unsafe { std::slice::from_raw_parts(data[i], lens[i]) },
            &f[..]
        );
    }
    (status, frames)
}

fn refusal(status: i64, frames: &[Vec<u8>]) -> Error {
    assert_eq!(status, -1);
    assert_eq!(frames.len(), 1);
    Error::decode(frames[0].as_slice()).unwrap() // ok: test
}

fn shipped(h: *mut Embedded, name: &str) -> MapRef {
    let (status, frames) = call(h, SHIPPED, 0, 0, &[]);
    assert_eq!(status, 1);
    let status = BrokerStatus::decode(frames[0].as_slice()).unwrap(); // ok: test
    status
        .maps
        .into_iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("{name} ships"))
}

fn open_msg(map: MapRef) -> EnvOpen {
    EnvOpen {
        map: Some(map),
        num_envs: 3,
        seed: 9,
        lidar: Some(Lidar {
            num_beams: 1080,
            fov: 4.7,
            max_range: 30.0,
            noise_std: 0.01,
            mount_offset: 0.0,
        }),
        laps: 1,
        time_limit: 60.0,
        frame_skip: 1,
        ..Default::default()
    }
}

#[test]
fn sessions_in_process_reply_as_a_worker_does() {
    let h = paddock_embed_new();
    assert!(!h.is_null());
    let map = shipped(h, "lakeside");
    let open = open_msg(map).encode_to_vec();
    let (status, frames) = call(h, ENV, 0, EnvOp::EnvOpen as i32, &open);
    assert_eq!(status, 2, "header and EnvOpened");
    let header = EnvReply::decode(frames[0].as_slice()).unwrap(); // ok: test
    assert!(header.error.is_none(), "{:?}", header.error);
    let session = header.session_id;
    assert_ne!(session, 0);
    let opened = EnvOpened::decode(frames[1].as_slice()).unwrap(); // ok: test
    assert_eq!((opened.num_envs, opened.num_beams), (3, 1080));

    // the same requests to a worker's sessions directly: the same frames, bit for bit
    let mut worker = Sessions::new();
    worker.set_circuits(Circuits::new());
    let r = worker.handle(session, EnvOp::EnvOpen as i32, &open);
    assert_eq!(r.frames[0], frames[1]);
    let step = EnvStep {
        actions: pack_f32(&[0.1, 2.0, -0.05, 3.0, 0.0, 1.0]),
        reset_envs: Vec::new(),
    }
    .encode_to_vec();
    let reset = paddock_proto::EnvReset::default().encode_to_vec();
    for (op, payload) in [
        (EnvOp::EnvReset, &reset),
        (EnvOp::EnvStep, &step),
        (EnvOp::EnvStep, &step),
    ] {
        let (status, frames) = call(h, ENV, session, op as i32, payload);
        assert_eq!(status, 3, "header, observation, scans");
        let want = worker.handle(session, op as i32, payload);
        let header = EnvReply::decode(frames[0].as_slice()).unwrap(); // ok: test
        assert_ne!(want.header.fingerprint, 0);
        assert_eq!(
            header.fingerprint, 0,
            "nothing rebuilds an in-process session"
        );
        assert_eq!(
            EnvReply {
                fingerprint: want.header.fingerprint,
                ..header
            },
            want.header
        );
        assert_eq!(frames[1..], want.frames[..]);
        let obs = EnvObservation::decode(frames[1].as_slice()).unwrap(); // ok: test
        assert_eq!(obs.num_envs, 3);
        assert_eq!(frames[2].len(), 3 * 1080 * 4, "the scans, f32");
    }

    // the scans written into the caller's buffer: the same bits, an empty scans frame
    let mut scans = vec![0xa5u8; 3 * 1080 * 4];
    for (op, payload) in [
        (EnvOp::EnvStep, &step),
        (EnvOp::EnvReset, &reset),
        (EnvOp::EnvStep, &step),
    ] {
        let (status, frames) = call_into(h, ENV, session, op as i32, payload, &mut scans);
        assert_eq!(status, 3);
        let want = worker.handle(session, op as i32, payload);
        assert_eq!(frames[1], want.frames[0], "the same observation");
        assert!(frames[2].is_empty(), "the scans are in the buffer");
        assert!(
            scans == want.frames[1],
            "the buffer holds the worker's scans"
        );
    }
    // a buffer of another size is left alone: the scans come as a frame
    let mut short = vec![0xa5u8; 3 * 1080 * 4 - 4];
    let (status, frames) = call_into(h, ENV, session, EnvOp::EnvStep as i32, &step, &mut short);
    assert_eq!(status, 3);
    let want = worker.handle(session, EnvOp::EnvStep as i32, &step);
    assert_eq!(frames[1..], want.frames[..]);
    assert!(short.iter().all(|&b| b == 0xa5), "untouched");

    // a refusal names the field, and the session keeps serving
    let (status, frames) = call(h, ENV, session, EnvOp::EnvStep as i32, b"\x0a\x03abc");
    let header = EnvReply::decode(frames[0].as_slice()).unwrap(); // ok: test
    assert_eq!(status, 1);
    let e = header.error.expect("short actions are refused");
    assert!(e.field.contains("actions"), "{e:?}");
    let (status, _) = call(h, ENV, session, EnvOp::EnvStep as i32, &step);
    assert_eq!(status, 3);
    let (status, _) = call(h, ENV, session, EnvOp::EnvClose as i32, &[]);
    assert_eq!(status, 1);
    // SAFETY: the handle from `paddock_embed_new`, freed once.
    unsafe { paddock_embed_free(h) };
}

#[test]
fn bad_requests_are_refused_with_the_field_named() {
    let h = paddock_embed_new();
    let (status, frames) = call(h, 9, 0, 0, &[]);
    let e = refusal(status, &frames);
    assert_eq!(e.field, "kind");
    assert!(e.message.contains("kind = 9"), "{e:?}");

    let (status, frames) = call(h, PUT_MAP, 0, 0, b"\xff\xff\xff");
    let e = refusal(status, &frames);
    assert_eq!(e.code, ErrorCode::BadMessage as i32);
    assert_eq!(e.field, "put_map.bundle");

    let (status, frames) = call(h, PUT_BLOB, 0, 0, b"not a model");
    let e = refusal(status, &frames);
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
    assert!(e.field.starts_with("put_blob.data"), "{e:?}");

    let big = vec![0u8; paddock_policy::onnx::MAX_MODEL_BYTES + 1];
    let (status, frames) = call(h, PUT_BLOB, 0, 0, &big);
    let e = refusal(status, &frames);
    assert_eq!(e.code, ErrorCode::InvalidArgument as i32);
    assert_eq!(e.field, "put_blob.data");
    assert!(e.message.contains("over the"), "{e:?}");

    // an unknown map hash, and a session that is not open
    let unknown = MapRef {
        name: "nowhere".into(),
        hash: "ab".repeat(32),
    };
    let (_, frames) = call(
        h,
        ENV,
        0,
        EnvOp::EnvOpen as i32,
        &open_msg(unknown).encode_to_vec(),
    );
    let e = EnvReply::decode(frames[0].as_slice())
        .unwrap()
        .error
        .unwrap(); // ok: test
    assert_eq!(e.code, ErrorCode::NotFound as i32);
    assert_eq!(e.field, "env_open.map.hash");
    let (_, frames) = call(h, ENV, 77, EnvOp::EnvStep as i32, &[]);
    let e = EnvReply::decode(frames[0].as_slice())
        .unwrap()
        .error
        .unwrap(); // ok: test
    assert_eq!(e.field, "env_request.session_id");

    // past the last frame, and a null handle
    let mut data = std::ptr::null();
    // SAFETY: a live handle; `data` is writable.
    assert_eq!(unsafe { paddock_embed_frame(h, 5, &mut data) }, 0);
    assert!(data.is_null());
    // SAFETY: a null handle has no frames; nothing is written with no room.
    unsafe {
        assert_eq!(
            paddock_embed_frames(
                std::ptr::null(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                0
            ),
            0
        );
        assert_eq!(
            paddock_embed_frames(h, std::ptr::null_mut(), std::ptr::null_mut(), 0),
            1
        );
    }
    // SAFETY: a null handle is answered -2; nothing is read.
    assert_eq!(
        unsafe {
            paddock_embed_call(
                std::ptr::null_mut(),
                ENV,
                0,
                0,
                std::ptr::null(),
                0,
                std::ptr::null_mut(),
                0,
            )
        },
        -2
    );
    // SAFETY: the handle from `paddock_embed_new`, freed once; null is ignored.
    unsafe {
        paddock_embed_free(h);
        paddock_embed_free(std::ptr::null_mut());
    }
}

#[test]
fn a_map_put_by_bundle_opens_by_hash_and_goes_with_the_handle() {
    let mut h = Embedded::new();
    assert!(h.cache.is_none(), "nothing is written before a map is put");
    let bundle = paddock_wire::local_map(&Circuits::new(), "harbour").unwrap(); // ok: test
    let frames = h
        .call(PUT_MAP, 0, 0, &bundle.encode_to_vec(), None)
        .unwrap(); // ok: test
    let map = MapRef::decode(frames[0].as_slice()).unwrap(); // ok: test
    assert_eq!(map.hash, bundle.hash);
    let (cache, _) = h.cache.as_ref().expect("made by the put");
    let root = cache.root().to_path_buf();
    assert!(cache.get(&map.hash).is_some());
    let frames = h
        .call(
            ENV,
            0,
            EnvOp::EnvOpen as i32,
            &open_msg(map).encode_to_vec(),
            None,
        )
        .unwrap(); // ok: test
    let header = EnvReply::decode(frames[0].as_slice()).unwrap(); // ok: test
    assert!(header.error.is_none(), "{:?}", header.error);
    assert_eq!(header.session_id, 1);
    assert!(root.is_dir());
    drop(h);
    assert!(!root.exists(), "the map cache goes with the handle");
}

#[test]
fn handles_share_the_process_pool_and_a_handle_knows_its_process() {
    let (a, b) = (Embedded::new(), Embedded::new());
    assert!(Arc::ptr_eq(&process_pool(), &process_pool()));
    assert!(process_pool().current_num_threads() >= 1);
    assert!(!a.forked() && !b.forked());
    // a handle of another process (as a forked child sees its parent's) is refused,
    // naming why, and freeing it leaves its map cache alone
    let mut other = Embedded::new();
    other.cache().unwrap();
    let dir = other.cache.as_ref().unwrap().1.path().to_path_buf();
    other.pid = other.pid.wrapping_add(1);
    let e = other.call(SHIPPED, 0, 0, &[], None).unwrap_err();
    assert_eq!(e.field, "handle");
    assert!(e.message.contains("before it forked"), "{}", e.message);
    let h = Box::into_raw(Box::new(other));
    // SAFETY: a live handle of this test, freed once.
    unsafe { paddock_embed_free(h) };
    assert!(dir.is_dir(), "the parent's map cache was removed");
    std::fs::remove_dir_all(&dir).unwrap();
}
