//! The deployment test: real images, real containers, real keys.
//!
//! Builds the images (deploy/build.sh), brings up a broker and 3 workers with
//! `docker compose` under a project name of its own, submits a tuning job from the host
//! CLI with CURVE keys, then `docker kill`s one worker, disconnects another from the
//! network, and kills and restarts the broker container mid-job. The job must finish with
//! the same result as the same job run locally, and `docker compose down -v` must leave
//! nothing behind. Needs a Docker engine with Compose (the CI machine has one); set
//! PADDOCK_SKIP_DOCKER=1 to skip it on a machine without Docker.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use serde_json::Value;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn paddock() -> PathBuf {
    paddock_e2e::paddock_bin()
}

fn run(cmd: &mut Command) -> Output {
    let shown = format!("{cmd:?}");
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("cannot run {shown}: {e}"));
    assert!(
        out.status.success(),
        "{shown} failed ({}):\n{}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .map(|a| a.port())
        .expect("a free loopback port")
}

struct Compose {
    project: String,
    env: Vec<(String, String)>,
}

/// `docker compose` (the plugin) where it is installed, else `docker-compose`.
fn compose_program() -> Command {
    let plugin = Command::new("docker")
        .args(["compose", "version"])
        .output()
        .is_ok_and(|o| o.status.success());
    if plugin {
        let mut c = Command::new("docker");
        c.arg("compose");
        c
    } else {
        Command::new("docker-compose")
    }
}

impl Compose {
    fn cmd(&self, args: &[&str]) -> Command {
        let mut c = compose_program();
        c.arg("-p")
            .arg(&self.project)
            .arg("-f")
            .arg(repo().join("deploy/compose.yaml"))
            .args(args);
        for (k, v) in &self.env {
            c.env(k, v);
        }
        c
    }

    fn containers(&self, service: &str) -> Vec<String> {
        let out = run(&mut self.cmd(&["ps", "-q", service]));
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(str::to_string)
            .collect()
    }
}

impl Drop for Compose {
    fn drop(&mut self) {
        let _ = self
            .cmd(&["down", "-v", "--remove-orphans", "-t", "2"])
            .output();
    }
}

fn tune_args(generations: &str) -> Vec<String> {
    [
        "tune",
        "--map",
        "lakeside",
        "--generations",
        generations,
        "--popsize",
        "8",
        "--seeds",
        "3",
        "--holdout",
        "6",
        "--seed",
        "11",
        "--json",
    ]
    .iter()
    .map(|s| s.to_string())
    .collect()
}

#[test]
fn compose_cluster_with_keys_survives_kills_and_matches_local() {
    if std::env::var("PADDOCK_SKIP_DOCKER").as_deref() == Ok("1") {
        eprintln!("PADDOCK_SKIP_DOCKER=1: deployment test skipped");
        return;
    }
    let started = Instant::now();
    run(Command::new("bash")
        .arg(repo().join("deploy/build.sh"))
        .env("PADDOCK_BIN", paddock()));
    eprintln!("images built in {:.0} s", started.elapsed().as_secs_f64());

    let dir = tempfile::tempdir().expect("temp dir");
    let keys = dir.path().join("keys");
    run(Command::new(paddock())
        .args(["keys", "generate", "--out"])
        .arg(&keys));
    // the containers run as uid 10001: let them read the keys
    run(Command::new("chmod").args(["-R", "a+rX"]).arg(&keys));
    let client_port = free_port();
    let worker_port = free_port();
    let project = format!("paddock-test-{}", std::process::id());
    let compose = Compose {
        project: project.clone(),
        env: vec![
            ("PADDOCK_KEYS".into(), keys.display().to_string()),
            ("PADDOCK_CLIENT_PORT".into(), client_port.to_string()),
            ("PADDOCK_WORKER_PORT".into(), worker_port.to_string()),
        ],
    };
    run(&mut compose.cmd(&["up", "-d", "--scale", "worker=3"]));
    let endpoint = format!("tcp://127.0.0.1:{client_port}");
    let with_keys = |c: &mut Command| {
        c.arg("--endpoint")
            .arg(&endpoint)
            .arg("--key")
            .arg(keys.join("client.key"))
            .arg("--broker-key")
            .arg(keys.join("broker.pub"));
    };

    // all three workers register
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let mut c = Command::new(paddock());
        c.args(["status", "--json"]);
        with_keys(&mut c);
        let out = c.output().expect("paddock status");
        if out.status.success() {
            let v: Value = serde_json::from_slice(&out.stdout).expect("status JSON");
            if v["workers"].as_array().map(|w| w.len()) == Some(3) {
                break;
            }
        }
        assert!(
            Instant::now() < deadline,
            "3 workers did not register within 60 s"
        );
        std::thread::sleep(Duration::from_millis(500));
    }

    // a client without keys, and one with a key the broker does not know, get nowhere
    let out = Command::new(paddock())
        .args(["status", "--endpoint", &endpoint])
        .output()
        .expect("paddock status");
    assert!(!out.status.success(), "a client without keys was let in");
    let stranger = dir.path().join("stranger");
    run(Command::new(paddock())
        .args(["keys", "generate", "--role", "client", "--out"])
        .arg(&stranger));
    let out = Command::new(paddock())
        .args(["status", "--endpoint", &endpoint, "--key"])
        .arg(stranger.join("client.key"))
        .arg("--broker-key")
        .arg(keys.join("broker.pub"))
        .output()
        .expect("paddock status");
    assert!(
        !out.status.success(),
        "a client with an unknown key was let in"
    );

    // throughput of the cluster: a batch of rollouts
    let t0 = Instant::now();
    let mut c = Command::new(paddock());
    c.args([
        "rollout",
        "--driver",
        "pure-pursuit",
        "--episodes",
        "96",
        "--seed",
        "5",
        "--json",
    ]);
    with_keys(&mut c);
    run(&mut c);
    let rate = 96.0 / t0.elapsed().as_secs_f64();
    eprintln!("compose cluster (3 workers): {rate:.1} rollouts/s");

    // the tuning job, detached
    let mut c = Command::new(paddock());
    c.args(tune_args("14")).arg("--detach");
    with_keys(&mut c);
    let out = run(&mut c);
    let job = String::from_utf8_lossy(&out.stdout).trim().to_string();
    assert!(!job.is_empty(), "no job id printed");
    let progress = |min_rounds: u64| {
        let deadline = Instant::now() + Duration::from_secs(120);
        loop {
            let mut c = Command::new(paddock());
            c.args(["jobs", "status", &job, "--json"]);
            with_keys(&mut c);
            if let Ok(out) = c.output()
                && out.status.success()
                && let Ok(v) = serde_json::from_slice::<Value>(&out.stdout)
                && v["rounds_done"].as_u64().unwrap_or(0) >= min_rounds
            {
                return;
            }
            assert!(Instant::now() < deadline, "job {job} made no progress");
            std::thread::sleep(Duration::from_millis(300));
        }
    };
    progress(2);
    let workers = compose.containers("worker");
    assert_eq!(workers.len(), 3, "{workers:?}");
    run(Command::new("docker").args(["kill", &workers[0]]));
    let network = format!("{project}_default");
    run(Command::new("docker").args(["network", "disconnect", "-f", &network, &workers[1]]));
    progress(5);
    // kill the broker container and start it again: the job resumes from its volume
    run(&mut compose.cmd(&["kill", "broker"]));
    run(&mut compose.cmd(&["start", "broker"]));
    let mut c = Command::new(paddock());
    c.args(["jobs", "wait", &job]);
    with_keys(&mut c);
    run(&mut c);
    let mut c = Command::new(paddock());
    c.args(["jobs", "result", &job]);
    with_keys(&mut c);
    let out = run(&mut c);
    let remote: Value = serde_json::from_slice(&out.stdout).expect("job result JSON");

    let out = run(Command::new(paddock())
        .args(tune_args("14"))
        .arg("--out")
        .arg(dir.path().join("local")));
    let local: Value = serde_json::from_slice(&out.stdout).expect("local tune JSON");
    for k in [
        "history",
        "default",
        "tuned",
        "best_fitness",
        "evaluations",
        "episodes_run",
        "chosen",
        "improvement_pct",
    ] {
        assert_eq!(
            remote[k], local[k],
            "the cluster's tuning result differs from the local run in {k}"
        );
    }
    let tuned: Vec<f64> = local["params"]["tuned"]
        .as_object()
        .expect("local tuned params")
        .values()
        .filter_map(Value::as_f64)
        .collect();
    for x in tuned {
        assert!(
            remote["tuned_params"]
                .as_array()
                .expect("remote tuned params")
                .iter()
                .any(|r| r.as_f64() == Some(x)),
            "tuned parameter {x} of the local run is not in the cluster's result"
        );
    }

    run(&mut compose.cmd(&["down", "-v", "-t", "2"]));
    let left = run(Command::new("docker").args([
        "ps",
        "-aq",
        "--filter",
        &format!("label=com.docker.compose.project={project}"),
    ]));
    assert!(left.stdout.is_empty(), "containers left after down -v");
    let vols = run(Command::new("docker").args([
        "volume",
        "ls",
        "-q",
        "--filter",
        &format!("label=com.docker.compose.project={project}"),
    ]));
    assert!(vols.stdout.is_empty(), "volumes left after down -v");
    eprintln!(
        "deployment test took {:.0} s",
        started.elapsed().as_secs_f64()
    );
}
