//! # paddock-sysid: the reality-gap tool
//!
//! Given a recording of a real car (commands sent, states measured), find where the
//! simulator and reality part, name the physics the simulator left out, fit it, and show
//! the fit improve on held-out data.
//!
//! ## Why it works this way
//! - **Short re-anchored windows** ([`replay`]): the recorded commands are replayed
//!   through the real sim-core dynamics ([`paddock_sim::dynamics::Vehicle::step`]), and at
//!   every window start the simulated state is reset to the (smoothed) recorded state.
//!   Errors cannot compound, so a residual says something about the physics in that
//!   window, and one continuous pass keeps the command path's memory (delay line, lags,
//!   wheel angle) exactly as the simulator would hold it.
//! - **Candidates are sim-core's own optional effects** ([`effects`]), so the fitted
//!   vehicle YAML is loadable by the simulator as is; there is no second model.
//! - **Held-out evidence** ([`fit`]): an effect is kept only if, fitted on the other time
//!   blocks, it lowers the held-out residual by more than a margin per parameter (3 % by
//!   default), in at least two blocks and in none worse (a block the effect cannot touch,
//!   such as one where the car never reached a friction patch, counts as neither).
//!   Effects are added greedily and refitted jointly; a recording with nothing missing
//!   keeps nothing.
//! - **Noise-normalised residuals**: each channel's residual is divided by the
//!   measurement noise estimated from the recording itself, so the fit is a weighted
//!   least-squares fit and the report can say how close to the noise floor the fit gets.
//!
//! Outputs ([`report`]): `report.json` = `{"effects": [{"name", "params", "significant",
//! "evidence", "round"}], "fit": {"rmse_before", "rmse_after", "rmse_fitted_in_sample",
//! "noise_floor"}, "mismatch": [{"kind": "time"|"regime"|"region", ...}], ...}`, with the
//! RMSEs per channel (`x, y, yaw, vx, vy, yaw_rate`) and `rmse_after` measured on
//! held-out blocks; `report.md` in words; `vehicle.yaml` that sim-core loads.

pub mod analysis;
pub mod effects;
pub mod explain;
pub mod fit;
pub mod locate;
pub mod recording;
pub mod replay;
pub mod report;
pub mod uncertainty;

pub use analysis::{Analysis, AnalysisOptions, Stage, analyze};
pub use effects::EffectKind;
pub use recording::{Recording, RecordingTopics};

/// Run the analyses of this process on `n` worker threads (call once, before the first).
pub fn set_threads(n: usize) -> Result<(), SysidError> {
    rayon::ThreadPoolBuilder::new()
        .num_threads(n)
        .build_global()
        .map_err(|e| SysidError::Option {
            field: "threads".into(),
            value: n.to_string(),
            requirement: format!("the thread pool could not start: {e}"),
        })
}

/// Why an analysis could not run.
#[derive(Debug, thiserror::Error)]
pub enum SysidError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        #[source]
        source: std::io::Error,
    },
    #[error("recording is missing column `{column}` (header: {header})")]
    MissingColumn { column: String, header: String },
    #[error("recording row {row}: {message}")]
    Row { row: usize, message: String },
    #[error("{message}")]
    Format { message: String },
    #[error(
        "recording too short to say anything: {samples} samples over {duration_s:.2} s in {runs} run(s) (need at least {min_samples} samples and {min_duration_s} s in all, each run at least 2 s); {hint}"
    )]
    TooShort {
        samples: usize,
        duration_s: f64,
        runs: usize,
        min_samples: usize,
        min_duration_s: f64,
        hint: String,
    },
    #[error("invalid option {field} = {value}: {requirement}")]
    Option {
        field: String,
        value: String,
        requirement: String,
    },
    #[error(transparent)]
    Params(#[from] paddock_sim::params::ParamsError),
    #[error("optimiser: {0}")]
    Tune(#[from] paddock_tune::TuneError),
}
