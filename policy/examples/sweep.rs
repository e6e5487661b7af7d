//! A driver on every shipped map and every real track (../shared/maps, or
//! `$PADDOCK_SHARED/maps`), one lap each: `cargo run --release -p paddock-policy --example
//! sweep -- <driver> [seeds] [name=value ...]`. Prints each failure and the lap times.

use std::path::PathBuf;
use std::sync::Mutex;

use paddock_sim::circuit::{Circuits, list_circuit_dirs};
use paddock_sim::world::Starts;

#[path = "../tests/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args.first().cloned().unwrap_or_else(|| "lattice".into());
    let seeds: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(1);
    let overrides: Vec<(String, f64)> = args
        .iter()
        .skip(1)
        .filter_map(|a| a.split_once('='))
        .map(|(k, v)| (k.to_string(), v.parse().expect("number")))
        .collect();
    let shared = std::env::var("PADDOCK_SHARED")
        .map(PathBuf::from)
        .unwrap_or_else(|_| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared"));
    let mut maps: Vec<String> = common::MAPS.iter().map(|s| s.to_string()).collect();
    maps.extend(
        list_circuit_dirs(&shared.join("maps"))
            .iter()
            .map(|d| d.display().to_string()),
    );
    let jobs: Vec<(String, u64)> = maps
        .iter()
        .flat_map(|m| (0..seeds).map(move |s| (m.clone(), s)))
        .collect();
    let next = Mutex::new(0usize);
    let results = Mutex::new(Vec::new());
    let threads: usize = std::env::var("THREADS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(2);
    std::thread::scope(|sc| {
        for _ in 0..threads {
            sc.spawn(|| {
                loop {
                    let k = {
                        let mut n = next.lock().unwrap();
                        *n += 1;
                        *n - 1
                    };
                    let Some((map, seed)) = jobs.get(k) else {
                        break;
                    };
                    let c = Circuits::new().get(map).expect("map");
                    let o: Vec<(&str, f64)> =
                        overrides.iter().map(|(k, v)| (k.as_str(), *v)).collect();
                    let d = common::driver(&name, &c, &o);
                    let max_time = 20.0 + c.track.length() / 1.2;
                    let out = common::run(&c, vec![d], *seed, &Starts::Random, 1, 0, max_time);
                    results
                        .lock()
                        .unwrap()
                        .push((k, c.name.clone(), *seed, out));
                }
            });
        }
    });
    let mut results = results.into_inner().unwrap();
    results.sort_by_key(|r| r.0);
    let mut fails = 0;
    let mut total = 0.0;
    for (_, map, seed, out) in &results {
        if out.finished(0) {
            total += out.lap_times[0][0];
            println!("{map:>14} seed {seed}: {:.2}", out.lap_times[0][0]);
        } else {
            fails += 1;
            println!(
                "{map:>14} seed {seed}: FAIL {:?} at {:.1} s",
                out.status[0], out.time
            );
        }
    }
    println!(
        "{name}: {fails} failures of {}; total lap time of the rest {total:.1} s",
        results.len()
    );
}
