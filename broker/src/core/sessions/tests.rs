use super::*;

const OPEN: i32 = EnvOp::EnvOpen as i32;
const STEP: i32 = EnvOp::EnvStep as i32;
const RENDER: i32 = EnvOp::EnvRender as i32;

fn step(a: u8) -> Logged {
    Logged {
        op: STEP,
        payload: vec![a; 8],
    }
}

fn head(op: i32, fingerprint: u64) -> ReplyHead {
    ReplyHead {
        op,
        fingerprint,
        restart: false,
        error: false,
    }
}

fn secs(x: f64) -> Duration {
    Duration::from_secs_f64(x)
}

/// A test client's principal: its routing id as text.
fn own(client: &[u8]) -> String {
    String::from_utf8_lossy(client).into_owned()
}

fn live(s: &mut Sessions, id: u64, client: &[u8], worker: &[u8]) {
    s.open(
        id,
        (client.to_vec(), own(client)),
        worker.to_vec(),
        b"open".to_vec(),
        1,
        secs(0.0),
    );
    assert_eq!(
        s.reply(id, worker, head(OPEN, 0)),
        Reply::Forward {
            client: client.to_vec(),
            request: 1
        }
    );
}

#[test]
fn replies_route_back_in_order_and_only_from_the_sessions_worker() {
    let mut s = Sessions::new(LogLimits::default());
    live(&mut s, 10, b"c1", b"w1");
    live(&mut s, 20, b"c2", b"w2");
    assert_eq!(
        s.route(10, b"c2", &own(b"c2"), secs(0.0)),
        Route::Unknown,
        "a session belongs to its client"
    );
    assert_eq!(
        s.route(10, b"c1", &own(b"c1"), secs(0.0)),
        Route::Send(b"w1".to_vec())
    );
    s.sent(
        10,
        Pending {
            client_request: 7,
            sent: Sent::Change(step(1)),
        },
    );
    s.sent(
        10,
        Pending {
            client_request: 8,
            sent: Sent::Read,
        },
    );
    assert_eq!(
        s.reply(10, b"w2", head(STEP, 5)),
        Reply::Ignore,
        "only its worker answers"
    );
    assert_eq!(
        s.reply(10, b"w1", head(STEP, 5)),
        Reply::Forward {
            client: b"c1".to_vec(),
            request: 7
        }
    );
    assert_eq!(
        s.reply(10, b"w1", head(RENDER, 9)),
        Reply::Forward {
            client: b"c1".to_vec(),
            request: 8
        }
    );
    assert_eq!(
        s.reply(10, b"w1", head(STEP, 5)),
        Reply::Ignore,
        "nothing waits"
    );
    assert_eq!(
        s.session(10).unwrap().log.len(), // ok: test
        1,
        "the step is logged, the render not"
    );
    assert_eq!((s.count_on(b"w1"), s.count_on(b"w2")), (1, 1));
}

#[test]
fn a_refused_open_leaves_no_session_and_an_opening_one_dies_with_its_worker() {
    let mut s = Sessions::new(LogLimits::default());
    s.open(
        1,
        (b"c".to_vec(), own(b"c")),
        b"w".to_vec(),
        vec![],
        4,
        secs(0.0),
    );
    let refused = ReplyHead {
        error: true,
        ..head(OPEN, 0)
    };
    assert_eq!(
        s.reply(1, b"w", refused),
        Reply::Forward {
            client: b"c".to_vec(),
            request: 4
        }
    );
    assert!(s.is_empty());
    s.open(
        2,
        (b"c".to_vec(), own(b"c")),
        b"w".to_vec(),
        vec![],
        5,
        secs(0.0),
    );
    let orphans = s.worker_gone(b"w", secs(1.0));
    assert_eq!(orphans.lost.len(), 1);
    assert_eq!(orphans.lost[0].requests, vec![5]);
    assert_eq!(s.stats().lost, 0, "an open never counts as a lost session");
}

/// A session with a logged history on w1; w1 dies with one step and one render in
/// flight and a step arrives while the session is stalled.
fn stalled_session() -> (Sessions, u64) {
    let mut s = Sessions::new(LogLimits::default());
    let id = 77;
    live(&mut s, id, b"c", b"w1");
    for k in 1..=3u8 {
        s.sent(
            id,
            Pending {
                client_request: u64::from(k) + 1,
                sent: Sent::Change(step(k)),
            },
        );
        assert!(matches!(
            s.reply(id, b"w1", head(STEP, u64::from(k))),
            Reply::Forward { .. }
        ));
    }
    s.sent(
        id,
        Pending {
            client_request: 5,
            sent: Sent::Change(step(4)),
        },
    );
    s.sent(
        id,
        Pending {
            client_request: 6,
            sent: Sent::Read,
        },
    );
    let orphans = s.worker_gone(b"w1", secs(10.0));
    assert_eq!(orphans.stalled, vec![id]);
    assert!(orphans.lost.is_empty());
    assert_eq!(s.route(id, b"c", &own(b"c"), secs(0.0)), Route::Hold);
    s.hold(
        id,
        Held {
            client_request: 7,
            op: STEP,
            payload: vec![5; 8],
        },
    );
    (s, id)
}

#[test]
fn a_stalled_session_is_replayed_on_another_worker_then_its_held_requests_go() {
    let (mut s, id) = stalled_session();
    assert_eq!(s.stalled(), vec![id]);
    assert!(s.tick(secs(14.9)).is_empty(), "still within the wait");
    assert_eq!(
        s.start_replay(id, b"w2".to_vec()).as_deref(),
        Some(&b"open"[..])
    );
    assert!(s.stalled().is_empty());
    assert!(
        s.tick(secs(100.0)).is_empty(),
        "a running replay does not expire"
    );
    let Reply::Send(sends) = s.reply(id, b"w2", head(OPEN, 0)) else {
        panic!("the log is sent after the open");
    };
    assert_eq!(sends.len(), 3);
    assert_eq!(sends[1], (1, step(2)));
    s.replay_sent(id, sends.iter().map(|(i, _)| *i));
    assert_eq!(s.reply(id, b"w2", head(STEP, 1)), Reply::Continue);
    assert_eq!(s.reply(id, b"w2", head(STEP, 2)), Reply::Continue);
    let Reply::Done(held) = s.reply(id, b"w2", head(STEP, 3)) else {
        panic!("rebuilt");
    };
    let order: Vec<(u64, i32)> = held.iter().map(|h| (h.client_request, h.op)).collect();
    assert_eq!(
        order,
        vec![(5, STEP), (6, RENDER), (7, STEP)],
        "in flight first, then held"
    );
    assert_eq!(held[0].payload, step(4).payload);
    assert_eq!(
        s.route(id, b"c", &own(b"c"), secs(0.0)),
        Route::Send(b"w2".to_vec())
    );
    assert_eq!(
        s.stats(),
        ReplayStats {
            replayed: 1,
            lost: 0
        }
    );
    assert_eq!(
        s.reply(id, b"w2", head(STEP, 3)),
        Reply::Ignore,
        "a late duplicate is dropped"
    );
}

#[test]
fn a_replay_that_diverges_or_fails_loses_the_session() {
    let (mut s, id) = stalled_session();
    s.start_replay(id, b"w2".to_vec());
    let Reply::Send(sends) = s.reply(id, b"w2", head(OPEN, 0)) else {
        panic!("sent");
    };
    s.replay_sent(id, sends.iter().map(|(i, _)| *i));
    let Reply::Failed(lost) = s.reply(id, b"w2", head(STEP, 99)) else {
        panic!("a different observation fails the replay");
    };
    assert!(
        lost.reason
            .contains("different observation at request 1 of 3"),
        "{}",
        lost.reason
    );
    assert_eq!(
        lost.requests,
        vec![5, 6, 7],
        "the held requests are answered with the loss"
    );
    assert!(s.get(id, "c").is_none());

    let (mut s, id) = stalled_session();
    s.start_replay(id, b"w2".to_vec());
    let Reply::Failed(lost) = s.reply(
        id,
        b"w2",
        ReplyHead {
            error: true,
            ..head(OPEN, 0)
        },
    ) else {
        panic!("an error fails the replay");
    };
    assert!(lost.reason.contains("refused"), "{}", lost.reason);
    assert_eq!(s.stats().lost, 1);
}

#[test]
fn the_replay_worker_dying_too_stalls_the_session_again() {
    let (mut s, id) = stalled_session();
    s.start_replay(id, b"w2".to_vec());
    let orphans = s.worker_gone(b"w2", secs(12.0));
    assert_eq!(orphans.stalled, vec![id]);
    assert_eq!(s.session(id).unwrap().held(), 3, "held requests kept"); // ok: test
    // no third worker within the wait: lost, naming why
    assert!(s.tick(secs(16.9)).is_empty());
    let lost = s.tick(secs(17.0));
    assert_eq!(lost.len(), 1);
    assert!(
        lost[0].reason.contains("no other worker"),
        "{}",
        lost[0].reason
    );
    assert_eq!(lost[0].requests.len(), 3);
    assert!(s.is_empty());
}

#[test]
fn a_session_past_its_log_bound_is_lost_with_its_worker() {
    let mut s = Sessions::new(LogLimits {
        max_entries: 2,
        ..LogLimits::default()
    });
    live(&mut s, 5, b"c", b"w1");
    for k in 0..3 {
        s.sent(
            5,
            Pending {
                client_request: 2,
                sent: Sent::Change(step(k)),
            },
        );
        s.reply(5, b"w1", head(STEP, 0));
    }
    s.sent(
        5,
        Pending {
            client_request: 9,
            sent: Sent::Change(step(9)),
        },
    );
    let orphans = s.worker_gone(b"w1", secs(1.0));
    assert!(orphans.stalled.is_empty());
    assert_eq!(orphans.lost.len(), 1);
    assert!(
        orphans.lost[0]
            .reason
            .contains("replay log reached its bound"),
        "{}",
        orphans.lost[0].reason
    );
    assert_eq!(
        orphans.lost[0].requests,
        vec![9],
        "its request in flight is answered"
    );
    assert_eq!(s.stats().lost, 1);
}

#[test]
fn only_the_owner_reaches_a_session_and_a_reconnected_owner_gets_the_replies() {
    let mut s = Sessions::new(LogLimits::default());
    s.open(
        7,
        (b"r1".to_vec(), "key:A".into()),
        b"w".to_vec(),
        vec![],
        1,
        secs(0.0),
    );
    assert!(matches!(
        s.reply(7, b"w", head(OPEN, 0)),
        Reply::Forward { .. }
    ));
    // another principal on the first connection's routing id (a peer that took over a
    // departed client's routing id) does not reach it
    assert_eq!(s.route(7, b"r1", "key:B", secs(1.0)), Route::Unknown);
    assert_eq!(s.owned_by("key:A"), 1);
    assert_eq!(s.owned_by("key:B"), 0);
    // the owner from a new connection does, and the replies follow it there
    assert_eq!(
        s.route(7, b"r2", "key:A", secs(2.0)),
        Route::Send(b"w".to_vec())
    );
    s.sent(
        7,
        Pending {
            client_request: 9,
            sent: Sent::Change(step(1)),
        },
    );
    assert_eq!(
        s.reply(7, b"w", head(STEP, 1)),
        Reply::Forward {
            client: b"r2".to_vec(),
            request: 9
        }
    );
}

#[test]
fn idle_sessions_are_listed_oldest_first_and_expire() {
    let mut s = Sessions::new(LogLimits::default());
    for (id, t) in [(1u64, 0.0), (2, 5.0), (3, 8.0)] {
        s.open(
            id,
            (b"c".to_vec(), own(b"c")),
            b"w".to_vec(),
            vec![],
            id,
            secs(t),
        );
        assert!(matches!(
            s.reply(id, b"w", head(OPEN, 0)),
            Reply::Forward { .. }
        ));
    }
    // session 3 is being stepped: not idle while its step is on the way
    assert_eq!(s.route(3, b"c", "c", secs(9.0)), Route::Send(b"w".to_vec()));
    s.sent(
        3,
        Pending {
            client_request: 4,
            sent: Sent::Change(step(1)),
        },
    );
    assert_eq!(s.idle(secs(10.0), secs(4.0)), vec![1, 2]);
    assert_eq!(s.idle(secs(10.0), secs(6.0)), vec![1]);
    assert!(s.idle(secs(100.0), secs(6.0)).iter().all(|&id| id != 3));
    let (lost, worker) = s.expire(1, "expired".into()).unwrap(); // ok: test
    assert_eq!(
        (lost.session, worker, lost.requests),
        (1, b"w".to_vec(), vec![])
    );
    assert!(!s.contains(1));
    assert!(s.expire(1, "again".into()).is_none());
}
