//! Shared by the SIL tests: the SIL car on its own thread.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::{self, JoinHandle};

use paddock_bridge::BridgeError;
use paddock_bridge::ros::RosConfig;
use paddock_bridge::sil::{SilOptions, SilSummary, run_sil};

/// `run_sil(options)` on a thread of its own until [`SilThread::stop`] (or its own end).
pub struct SilThread {
    stop: Arc<AtomicBool>,
    handle: JoinHandle<Result<SilSummary, BridgeError>>,
}

impl SilThread {
    pub fn start(options: SilOptions, ros: &RosConfig) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let (ros, flag) = (ros.clone(), stop.clone());
        let handle = thread::spawn(move || {
            run_sil(
                &paddock_sim::circuit::Circuits::new(),
                &options,
                &ros,
                &flag,
            )
        });
        Self { stop, handle }
    }

    /// Whether the SIL has ended by itself (its laps or its time are done).
    #[allow(dead_code)] // each test file compiles this module; not all of them ask
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Stops the SIL and returns its summary.
    pub fn stop(self) -> SilSummary {
        self.stop.store(true, Ordering::Relaxed);
        self.handle
            .join()
            .expect("the SIL thread")
            .expect("the SIL run")
    }
}
