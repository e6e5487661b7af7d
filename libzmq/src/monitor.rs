//! Telling a CURVE client that the broker refused it.
//!
//! A peer refused by the broker's [`crate::Authenticator`] never gets a reply: without
//! help its requests just time out. libzmq reports the refusal on the client's own
//! socket as a monitor event (`ZMQ_EVENT_HANDSHAKE_FAILED_AUTH`, with the ZAP status
//! code), and a failed CURVE handshake (for example a wrong broker public key) as
//! `ZMQ_EVENT_HANDSHAKE_FAILED_PROTOCOL`. [`HandshakeMonitor`] watches those events so a
//! client can wait for its reply *or* a refusal, whichever comes first.

use std::sync::atomic::{AtomicU64, Ordering};

/// Why the broker did not let this client in.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HandshakeFailure {
    /// The broker's authenticator refused the key (ZAP status, e.g. 400).
    #[error(
        "the broker at {endpoint} refused this client's key (fingerprint {fingerprint}, ZAP status {status}): \
         its public key is not in the broker's allowed client keys"
    )]
    Refused {
        endpoint: String,
        fingerprint: String,
        status: u32,
    },
    /// The CURVE handshake itself failed (libzmq's protocol error code).
    #[error(
        "the CURVE handshake with the broker at {endpoint} failed (key fingerprint {fingerprint}, \
         protocol error {code:#x}): check the broker's public key file and that the broker uses CURVE"
    )]
    Protocol {
        endpoint: String,
        fingerprint: String,
        code: u32,
    },
}

/// Handshake failure events of one socket (a PAIR socket on an inproc endpoint of the
/// same context). Create it before the watched socket connects.
pub struct HandshakeMonitor {
    events: zmq::Socket,
    fingerprint: String,
}

impl HandshakeMonitor {
    /// Watches `socket` (of `ctx`) whose CURVE public key is `public` (Z85).
    pub fn start(
        ctx: &zmq::Context,
        socket: &zmq::Socket,
        public: &str,
    ) -> Result<Self, zmq::Error> {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        let endpoint = format!(
            "inproc://paddock-handshake-{}-{}",
            std::process::id(),
            NEXT.fetch_add(1, Ordering::Relaxed)
        );
        let wanted = zmq::SocketEvent::HANDSHAKE_FAILED_AUTH as i32
            | zmq::SocketEvent::HANDSHAKE_FAILED_PROTOCOL as i32;
        socket.monitor(&endpoint, wanted)?;
        let events = ctx.socket(zmq::PAIR)?;
        events.set_linger(0)?;
        events.connect(&endpoint)?;
        Ok(Self {
            events,
            fingerprint: crate::fingerprint(public),
        })
    }

    /// The socket to poll (readable when an event is waiting).
    pub fn socket(&self) -> &zmq::Socket {
        &self.events
    }

    /// The fingerprint of the watched socket's key.
    pub fn fingerprint(&self) -> &str {
        &self.fingerprint
    }

    /// Reads the waiting events without blocking; the first handshake failure, if any.
    pub fn failure(&self) -> Option<HandshakeFailure> {
        let mut found = None;
        while let Ok(frames) = self.events.recv_multipart(zmq::DONTWAIT) {
            let (Some(head), Some(addr)) = (frames.first(), frames.get(1)) else {
                continue;
            };
            if head.len() < 6 || found.is_some() {
                continue;
            }
            let event = u16::from_le_bytes([head[0], head[1]]) as u32;
            let value = u32::from_le_bytes([head[2], head[3], head[4], head[5]]);
            let endpoint = String::from_utf8_lossy(addr).into_owned();
            let fingerprint = self.fingerprint.clone();
            if event == zmq::SocketEvent::HANDSHAKE_FAILED_AUTH as u32 {
                found = Some(HandshakeFailure::Refused {
                    endpoint,
                    fingerprint,
                    status: value,
                });
            } else if event == zmq::SocketEvent::HANDSHAKE_FAILED_PROTOCOL as u32 {
                found = Some(HandshakeFailure::Protocol {
                    endpoint,
                    fingerprint,
                    code: value,
                });
            }
        }
        found
    }
}
