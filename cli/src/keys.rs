//! `paddock keys generate` and `paddock health`: CURVE key files for a broker open to
//! the network, and the container health check.
//!
//! `paddock keys generate --out DIR` writes one key set:
//! - `DIR/broker.key` (the broker's secret key file) and `DIR/broker.pub`;
//! - `DIR/worker.key` and its public key in `DIR/workers/worker.pub`;
//! - `DIR/client.key` and its public key in `DIR/clients/client.pub`.
//!
//! The broker is given `broker.key` and the two directories of allowed public keys;
//! a worker or client is given its `.key` and `broker.pub`. `--role worker|client
//! --name NAME` adds one more worker or client key (`DIR/NAME.key` and
//! `DIR/workers|clients/NAME.pub`); deleting a `.pub` file revokes that peer.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use crate::args::{self, outln};
use anyhow::{Context, Result, bail};
use clap::{Args, Subcommand, ValueEnum};
use paddock_libzmq::{KeyPair, public_file};

#[derive(Subcommand)]
pub enum KeysCommand {
    /// Write CURVE key pairs (broker, worker, client by default).
    Generate(GenerateArgs),
}

#[derive(Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Role {
    /// The broker, one worker and one client key.
    All,
    /// The broker's key only.
    Broker,
    /// One worker key (named by --name).
    Worker,
    /// One client key (named by --name).
    Client,
}

#[derive(Args)]
pub struct GenerateArgs {
    /// Directory for the key files (created if missing).
    #[arg(long, default_value = "keys")]
    pub out: PathBuf,
    /// Whose keys to write.
    #[arg(long, value_enum, default_value_t = Role::All)]
    pub role: Role,
    /// File name for a worker or client key (default: the role's name).
    #[arg(long)]
    pub name: Option<String>,
    /// Overwrite existing key files.
    #[arg(long)]
    pub force: bool,
    /// Print the written files and public keys as JSON.
    #[arg(long)]
    pub json: bool,
}

/// Writes a key file atomically (mode 0600 from its creation for a secret key).
fn write_new(path: &Path, text: &str, force: bool, secret: bool) -> Result<()> {
    paddock_libzmq::write_key_file(path, text, secret, force)?;
    Ok(())
}

pub fn run(cmd: &KeysCommand) -> Result<()> {
    let KeysCommand::Generate(args) = cmd;
    if let Some(name) = &args.name
        && (name.is_empty() || name.contains(['/', '\\']) || name.starts_with('.'))
    {
        bail!("--name {name:?} must be a plain file name");
    }
    let mut made: Vec<(String, PathBuf, String)> = Vec::new();
    let mut one = |role: &str, name: &str, pub_dir: Option<&str>| -> Result<()> {
        let kp = KeyPair::generate().context("generating a CURVE key pair")?;
        let key_path = args.out.join(format!("{name}.key"));
        write_new(&key_path, &kp.to_secret_file(), args.force, true)?;
        let pub_path = match pub_dir {
            Some(d) => args.out.join(d).join(format!("{name}.pub")),
            None => args.out.join(format!("{name}.pub")),
        };
        write_new(&pub_path, &public_file(&kp.public), args.force, false)?;
        made.push((role.to_string(), key_path, kp.public));
        Ok(())
    };
    let name = |default: &str| args.name.clone().unwrap_or_else(|| default.to_string());
    match args.role {
        Role::All => {
            one("broker", "broker", None)?;
            one("worker", "worker", Some("workers"))?;
            one("client", "client", Some("clients"))?;
        }
        Role::Broker => one("broker", &name("broker"), None)?,
        Role::Worker => one("worker", &name("worker"), Some("workers"))?,
        Role::Client => one("client", &name("client"), Some("clients"))?,
    }
    if args.json {
        let v: Vec<serde_json::Value> = made
            .iter()
            .map(|(role, path, public)| {
                serde_json::json!({"role": role, "key_file": path, "public": public})
            })
            .collect();
        outln!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        for (role, path, public) in &made {
            outln!("{role:<7} {}  public {public}", path.display());
        }
    }
    Ok(())
}

#[derive(Args)]
pub struct HealthArgs {
    /// The health file a broker or worker touches while it is alive (--health-file).
    #[arg(long)]
    pub file: PathBuf,
    /// Seconds after which the file counts as stale.
    #[arg(long, default_value_t = 5.0, value_parser = args::above(0.0, 86_400.0))]
    pub max_age: f64,
}

/// Exit status 0 when the health file was touched within `--max-age` seconds.
pub fn health(args: &HealthArgs) -> Result<()> {
    let modified = std::fs::metadata(&args.file)
        .and_then(|m| m.modified())
        .with_context(|| format!("reading {}", args.file.display()))?;
    let age = SystemTime::now()
        .duration_since(modified)
        .unwrap_or(Duration::ZERO)
        .as_secs_f64();
    if age > args.max_age {
        bail!(
            "{} is {age:.1} s old (limit {} s): the process is not making progress",
            args.file.display(),
            args.max_age
        );
    }
    outln!("healthy ({age:.1} s)");
    Ok(())
}

/// Touches `path` (creating it): what a live broker or worker does every heartbeat.
pub fn touch(path: &Path) {
    if let Err(e) = std::fs::write(path, b"ok\n") {
        tracing::warn!(path = %path.display(), error = %e, "cannot write the health file");
    }
}
