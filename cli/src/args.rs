//! What every command's flags share: numeric ranges checked with one wording, the
//! thread cap, negative numbers reaching those checks, and output that ends quietly
//! when its reader goes away.
//!
//! A numeric flag takes its parser from here (`value_parser = args::whole(1, 100)`), so
//! a bad value always reads `error: invalid value '-3' for '--episodes <N>': -3 is out of
//! range: must be a whole number in [1, 1000000]`.

use std::fmt::Display;

use paddock_sim::params::VehicleParams;

/// The parser of a whole-number flag in `[lo, hi]`.
pub fn whole<T>(
    lo: i128,
    hi: i128,
) -> impl Fn(&str) -> Result<T, String> + Clone + Send + Sync + 'static
where
    T: TryFrom<i128> + Clone + Send + Sync + 'static,
{
    move |text: &str| {
        let v: i128 = text
            .trim()
            .parse()
            .map_err(|_| format!("{text:?} is not a whole number in [{lo}, {hi}]"))?;
        if !(lo..=hi).contains(&v) {
            return Err(out_of_range(text, "a whole number", lo, hi));
        }
        T::try_from(v).map_err(|_| out_of_range(text, "a whole number", lo, hi))
    }
}

/// The parser of a number flag in `[lo, hi]`.
pub fn number(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |text: &str| {
        let v = parse_f64(text, lo, hi, "[")?;
        if !(lo..=hi).contains(&v) {
            return Err(out_of_range(text, "a number", lo, hi));
        }
        Ok(v)
    }
}

/// The parser of a number flag in `(lo, hi]` (strictly above `lo`: durations, rates).
pub fn above(
    lo: f64,
    hi: f64,
) -> impl Fn(&str) -> Result<f64, String> + Clone + Send + Sync + 'static {
    move |text: &str| {
        let v = parse_f64(text, lo, hi, "(")?;
        if !(v > lo && v <= hi) {
            return Err(format!(
                "{text} is out of range: must be a number in ({lo}, {hi}]"
            ));
        }
        Ok(v)
    }
}

fn parse_f64(text: &str, lo: f64, hi: f64, open: &str) -> Result<f64, String> {
    let v: f64 = text
        .trim()
        .parse()
        .map_err(|_| format!("{text:?} is not a number in {open}{lo}, {hi}]"))?;
    if !v.is_finite() {
        return Err(format!(
            "{text} is out of range: must be a number in {open}{lo}, {hi}]"
        ));
    }
    Ok(v)
}

fn out_of_range(text: &str, what: &str, lo: impl Display, hi: impl Display) -> String {
    format!("{text} is out of range: must be {what} in [{lo}, {hi}]")
}

/// Threads a process may ask for: 4 per core (more only adds switching).
pub fn max_threads() -> usize {
    4 * std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// The parser of `--threads`: 0 (one per core) up to [`max_threads`].
pub fn threads() -> impl Fn(&str) -> Result<usize, String> + Clone + Send + Sync + 'static {
    whole(0, max_threads() as i128)
}

/// Every seed flag: any u64.
pub fn seed() -> impl Fn(&str) -> Result<u64, String> + Clone + Send + Sync + 'static {
    whole(0, u64::MAX as i128)
}

/// The vehicle of `--vehicle FILE` (a vehicle YAML: f1tenth_gym keys and `effects:`, as
/// `paddock sysid` writes it), or the f1tenth_gym default vehicle.
pub fn vehicle(path: Option<&std::path::Path>) -> anyhow::Result<VehicleParams> {
    match path {
        Some(p) => VehicleParams::load(p).map_err(|e| anyhow::anyhow!("--vehicle: {e}")),
        None => Ok(VehicleParams::default()),
    }
}

/// `cmd` and all its subcommands with negative numbers accepted as values (so `--laps -1`
/// reaches the range check instead of reading as an unknown flag `-1`).
/// The parser of `--pose-frames PARENT,CHILD`: two frame ids (a leading `/` is dropped
/// when the transforms are read).
pub fn frame_pair(text: &str) -> Result<[String; 2], String> {
    match text.split(',').map(str::trim).collect::<Vec<_>>()[..] {
        [p, c] if !p.is_empty() && !c.is_empty() && p != c => Ok([p.to_string(), c.to_string()]),
        _ => Err(format!(
            "{text:?}: two different frame ids, PARENT,CHILD (map,base_link)"
        )),
    }
}

pub fn allow_negative_numbers(cmd: clap::Command) -> clap::Command {
    let cmd = cmd.mut_args(|a| {
        if a.get_action().takes_values() {
            a.allow_negative_numbers(true)
        } else {
            a
        }
    });
    cmd.mut_subcommands(allow_negative_numbers)
}

/// Whether an error comes from writing to a closed pipe (the reader, e.g. `head`, is
/// done): the command then ends quietly with status 0, as Unix tools do.
pub fn is_broken_pipe(e: &anyhow::Error) -> bool {
    e.chain().any(|c| {
        c.downcast_ref::<std::io::Error>()
            .is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe)
    })
}

/// An error and its causes on one line, `outer: cause: ...`, each cause left out when the
/// message before it already says it (many error types put their source's text in their
/// own message, and the plain chain then read "No such file (os error 2): No such file
/// (os error 2)").
pub fn error_line(e: &anyhow::Error) -> String {
    let mut out = String::new();
    let mut last = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if !last.is_empty() && last.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
        last = text;
    }
    out
}

/// `println!` that returns a closed pipe as an error (`?`) instead of panicking.
macro_rules! outln {
    () => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock())?;
    }};
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        writeln!(std::io::stdout().lock(), $($arg)*)?;
    }};
}

/// `print!` that returns a closed pipe as an error (`?`) instead of panicking.
macro_rules! out {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        write!(std::io::stdout().lock(), $($arg)*)?;
    }};
}

pub(crate) use {out, outln};

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_error_line_says_each_cause_once() {
        /// An error that says its source in its own message and gives it as its source.
        #[derive(Debug)]
        struct Read {
            path: String,
            source: std::io::Error,
        }
        impl std::fmt::Display for Read {
            fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                write!(f, "cannot read {}: {}", self.path, self.source)
            }
        }
        impl std::error::Error for Read {
            fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
                Some(&self.source)
            }
        }
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let e = anyhow::Error::new(Read {
            path: "day".into(),
            source: io,
        })
        .context("loading the recording day");
        assert_eq!(
            error_line(&e),
            "loading the recording day: cannot read day: no such file"
        );
        // causes not already said are all kept
        let e = anyhow::anyhow!("inner").context("middle").context("outer");
        assert_eq!(error_line(&e), "outer: middle: inner");
    }

    #[test]
    fn ranges_have_one_wording() {
        let p = whole::<usize>(1, 100);
        assert_eq!(p("7"), Ok(7));
        assert_eq!(
            p("-3").unwrap_err(),
            "-3 is out of range: must be a whole number in [1, 100]"
        );
        assert_eq!(
            p("101").unwrap_err(),
            "101 is out of range: must be a whole number in [1, 100]"
        );
        assert!(p("x").unwrap_err().contains("not a whole number"));
        let f = number(0.0, 1.0);
        assert_eq!(f("0.5"), Ok(0.5));
        assert_eq!(
            f("-0.5").unwrap_err(),
            "-0.5 is out of range: must be a number in [0, 1]"
        );
        assert!(f("nan").unwrap_err().contains("out of range"));
        let a = above(0.0, 10.0);
        assert_eq!(
            a("0").unwrap_err(),
            "0 is out of range: must be a number in (0, 10]"
        );
        assert_eq!(a("10"), Ok(10.0));
        assert_eq!(seed()("18446744073709551615"), Ok(u64::MAX));
        assert!(seed()("-1").unwrap_err().contains("out of range"));
    }

    #[test]
    fn threads_are_capped_at_four_per_core() {
        let max = max_threads();
        assert_eq!(threads()(&max.to_string()), Ok(max));
        let e = threads()(&(max + 1).to_string()).unwrap_err();
        assert!(e.contains(&format!("[0, {max}]")), "{e}");
    }
}
