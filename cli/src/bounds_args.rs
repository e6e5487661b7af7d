//! The broker's bounds as flags of `paddock broker` and `paddock serve`: every resource a
//! client or worker can make the broker hold (docs/security.md has the table).

use std::time::Duration;

use clap::Args;
use paddock_broker::BrokerConfig;

use crate::args;

#[derive(Args, Debug, Clone)]
#[command(next_help_heading = "Bounds (what clients can make the broker hold)")]
pub struct BoundsArgs {
    /// Largest message (frame) in MiB, refused at the socket before it is read.
    #[arg(long, default_value_t = 64, value_parser = args::whole::<usize>(1, 1024))]
    pub max_message_mib: usize,
    /// Env sessions one client (CURVE key or client token) may hold.
    #[arg(long, default_value_t = 64, value_parser = args::whole::<usize>(1, 100_000))]
    pub sessions_per_client: usize,
    /// Env sessions in the whole broker.
    #[arg(long, default_value_t = 256, value_parser = args::whole::<usize>(1, 100_000))]
    pub sessions_total: usize,
    /// Seconds an env session may go without a request before it is closed (0: never).
    #[arg(long, default_value_t = 600, value_parser = args::whole::<u64>(0, 31_536_000))]
    pub session_idle_s: u64,
    /// MiB of replay log one env session may hold (beyond it the session is not
    /// rebuilt when its worker dies, until its next seeded reset).
    #[arg(long, default_value_t = 16, value_parser = args::whole::<usize>(1, 4096))]
    pub replay_log_mib: usize,
    /// Unfinished tasks one client may have queued or running.
    #[arg(long, default_value_t = 200_000, value_parser = args::whole::<usize>(1, 100_000_000))]
    pub tasks_per_client: usize,
    /// Unfinished tasks in the whole broker.
    #[arg(long, default_value_t = 1_000_000, value_parser = args::whole::<usize>(1, 100_000_000))]
    pub tasks_total: usize,
    /// A task's deadline on a worker: this many seconds ...
    #[arg(long, default_value_t = 60.0, value_parser = args::above(0.0, 86_400.0))]
    pub task_time_base_s: f64,
    /// ... plus this many per simulated second its episode may last; a worker holding a
    /// task past it is dropped and the task runs elsewhere.
    #[arg(long, default_value_t = 1.0, value_parser = args::number(0.0, 3600.0))]
    pub task_time_per_sim_s: f64,
    /// Jobs one client may have stored (finished ones count until deleted).
    #[arg(long, default_value_t = 1000, value_parser = args::whole::<usize>(1, 1_000_000))]
    pub jobs_per_client: usize,
    /// Bytes of a job's name.
    #[arg(long, default_value_t = 256, value_parser = args::whole::<usize>(1, 65_536))]
    pub job_name_bytes: usize,
    /// MiB of a job submission.
    #[arg(long, default_value_t = 16, value_parser = args::whole::<usize>(1, 1024))]
    pub job_submit_mib: usize,
    /// MiB of maps and model files clients may store.
    #[arg(long, default_value_t = 4096, value_parser = args::whole::<u64>(1, 1 << 24))]
    pub max_store_mib: u64,
    /// Characters of a client's input quoted in a log line.
    #[arg(long, default_value_t = 200, value_parser = args::whole::<usize>(16, 100_000))]
    pub log_field_chars: usize,
    /// Refused requests logged per second (the others are counted in the next line).
    #[arg(long, default_value_t = 20, value_parser = args::whole::<u32>(1, 100_000))]
    pub refusal_log_rate: u32,
}

impl BoundsArgs {
    /// Sets the broker's bounds from the flags.
    pub fn apply(&self, cfg: &mut BrokerConfig) {
        cfg.max_message_bytes = self.max_message_mib << 20;
        cfg.limits.max_tasks = self.tasks_total;
        cfg.limits.max_tasks_per_client = self.tasks_per_client;
        cfg.session_logs.max_bytes = self.replay_log_mib << 20;
        let b = &mut cfg.bounds;
        b.sessions_per_client = self.sessions_per_client;
        b.sessions_total = self.sessions_total;
        b.session_idle = Duration::from_secs(self.session_idle_s);
        b.task_time_base = Duration::from_secs_f64(self.task_time_base_s);
        b.task_time_per_sim_s = self.task_time_per_sim_s;
        b.max_jobs_per_client = self.jobs_per_client;
        b.max_job_name_bytes = self.job_name_bytes;
        b.max_job_submit_bytes = self.job_submit_mib << 20;
        b.max_store_bytes = self.max_store_mib << 20;
        b.log_field_chars = self.log_field_chars;
        b.refusal_log_rate = self.refusal_log_rate;
    }
}
