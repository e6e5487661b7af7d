//! Lap times of a driver on the shipped maps: `cargo run --release -p paddock-policy
//! --example laps -- <driver> [seeds] [name=value ...]`; `h2h` as the second argument runs the
//! head-to-head against a slower pure-pursuit car instead.

#[path = "../tests/common/mod.rs"]
mod common;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let name = args
        .first()
        .cloned()
        .unwrap_or_else(|| "follow-the-gap".into());
    let h2h = args.get(1).is_some_and(|a| a == "h2h");
    let rest = if h2h {
        &args[2..]
    } else {
        &args[1.min(args.len())..]
    };
    let seeds: u64 = rest.first().and_then(|s| s.parse().ok()).unwrap_or(3);
    let overrides: Vec<(String, f64)> = rest
        .iter()
        .filter_map(|a| a.split_once('='))
        .map(|(k, v)| (k.to_string(), v.parse().expect("number")))
        .collect();
    let o: Vec<(&str, f64)> = overrides.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    if h2h {
        let mut ok = 0;
        for seed in 0..seeds {
            let out = common::head_to_head("lakeside", &name, seed, 3.0, 0.6, 2);
            ok += out.finished(0) as u32;
            println!(
                "seed {seed}: {:?} laps {:?} t {:.1}",
                out.status, out.lap_times, out.time
            );
        }
        println!("finished {ok}/{seeds}");
        return;
    }
    for map in common::MAPS {
        for seed in 0..seeds {
            let out = common::solo(map, &name, &o, seed, 1);
            println!(
                "{map} seed {seed}: {:?} laps {:?} t {:.2}",
                out.status[0], out.lap_times[0], out.time
            );
        }
    }
}
