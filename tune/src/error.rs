//! Errors of the tuning API. Each names the offending field or index and its value.

use std::fmt;

use crate::StopReason;

/// What went wrong in an [`Optimizer`](crate::Optimizer) call.
#[derive(Debug, Clone, PartialEq)]
pub enum TuneError {
    /// An [`Options`](crate::Options) field is invalid.
    InvalidOption {
        field: &'static str,
        value: String,
        reason: &'static str,
    },
    /// `ask` was called while the previous generation still awaits its `tell`.
    TellPending { generation: u64 },
    /// `tell` was called without a preceding `ask`.
    NoPendingAsk,
    /// `ask` was called after the optimiser stopped.
    Finished(StopReason),
    /// `tell` got a different number of candidates or fitness values than were asked.
    WrongCount {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A told candidate has the wrong dimension.
    WrongDimension {
        index: usize,
        expected: usize,
        got: usize,
    },
    /// A told candidate is not the one `ask` handed out at that index.
    CandidateMismatch {
        index: usize,
        coordinate: usize,
        expected: f64,
        got: f64,
    },
    /// A fitness value is NaN or -inf (+inf is allowed and means "failed").
    InvalidFitness { index: usize, value: f64 },
}

impl fmt::Display for TuneError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            TuneError::InvalidOption {
                field,
                value,
                reason,
            } => write!(f, "invalid option `{field}` = {value}: {reason}"),
            TuneError::TellPending { generation } => write!(
                f,
                "ask called again before tell for generation {generation}; \
                 tell the pending generation first"
            ),
            TuneError::NoPendingAsk => write!(f, "tell called without a pending ask"),
            TuneError::Finished(reason) => {
                write!(f, "the optimiser has stopped ({reason}); nothing to ask")
            }
            TuneError::WrongCount {
                what,
                expected,
                got,
            } => write!(f, "tell got {got} {what}, expected {expected}"),
            TuneError::WrongDimension {
                index,
                expected,
                got,
            } => write!(
                f,
                "candidates[{index}] has {got} coordinates, expected {expected}"
            ),
            TuneError::CandidateMismatch {
                index,
                coordinate,
                expected,
                got,
            } => write!(
                f,
                "candidates[{index}][{coordinate}] = {got:e} is not the asked value {expected:e}; \
                 tell the candidates in the order ask returned them"
            ),
            TuneError::InvalidFitness { index, value } => write!(
                f,
                "fitness[{index}] = {value}: must be a number or +inf (failed evaluation)"
            ),
        }
    }
}

impl std::error::Error for TuneError {}
