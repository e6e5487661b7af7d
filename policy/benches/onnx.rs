//! What a model file costs a rollout and the car: one action from an ONNX policy
//! (`OnnxPolicy::infer`: the observation's inputs gathered, the network run by tract, the
//! action read back) and a model's load (parse, type, optimise, plan).
//!
//! The networks are multi-layer perceptrons on the 1080-beam scan, as learners export
//! them: 64 x 64 tanh (Stable-Baselines3's default `MlpPolicy`) and 256 x 256 ReLU, with
//! seeded weights (written as ONNX protobuf here, so no Python is needed).
//! `cargo bench -p paddock-policy --bench onnx`; docs/onnx.md records figures.

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use paddock_policy::onnx::OnnxPolicy;
use paddock_policy::onnx::write::{D, Model, f32_input, f32_tensor, node};
use paddock_sim::rng::Rng;
use paddock_sim::world::Observation;
use std::hint::black_box;

const BEAMS: usize = 1080;

/// An MLP `scans -> hidden -> hidden -> action` with activation `act` ("Tanh" or "Relu")
/// and weights drawn from a seeded generator, scaled as a default initialisation would.
fn mlp(hidden: usize, act: &str) -> Model {
    let mut rng = Rng::new(7);
    let mut weights = |rows: usize, cols: usize| -> Vec<f32> {
        let scale = (1.0 / rows as f64).sqrt();
        (0..rows * cols)
            .map(|_| (rng.normal() * scale) as f32)
            .collect()
    };
    let dims = [(BEAMS, hidden), (hidden, hidden), (hidden, 2)];
    let mut nodes = Vec::new();
    let mut model_inits = Vec::new();
    let mut x = "scans".to_string();
    for (k, &(rows, cols)) in dims.iter().enumerate() {
        let (w, b, wx, y) = (
            format!("w{k}"),
            format!("b{k}"),
            format!("wx{k}"),
            format!("y{k}"),
        );
        nodes.push(node("MatMul", &[&x, &w], &[&wx]));
        let last = k + 1 == dims.len();
        let sum = if last {
            "action".to_string()
        } else {
            y.clone()
        };
        nodes.push(node("Add", &[&wx, &b], &[&sum]));
        model_inits.push(f32_tensor(
            &w,
            &[rows as i64, cols as i64],
            &weights(rows, cols),
        ));
        model_inits.push(f32_tensor(&b, &[cols as i64], &vec![0.01; cols]));
        if !last {
            let h = format!("h{k}");
            nodes.push(node(act, &[&y], &[&h]));
            x = h;
        }
    }
    let mut m = Model::new(
        nodes,
        vec![f32_input("scans", &[D::Batch, D::N(BEAMS as i64)])],
    );
    for t in model_inits {
        m = m.init(t);
    }
    m
}

/// One car's observation with a scan of plausible ranges.
fn observation() -> Observation {
    Observation {
        linear_vels_x: vec![3.0],
        ..Observation::one_car(
            (0..BEAMS)
                .map(|i| 1.0 + 4.0 * (i as f64 * 0.01).sin().abs())
                .collect(),
        )
    }
}

fn bench(c: &mut Criterion) {
    let obs = observation();
    let nets = [
        ("64x64 tanh", mlp(64, "Tanh")),
        ("256x256 relu", mlp(256, "Relu")),
    ];
    let mut infer = c.benchmark_group("onnx_infer");
    for (name, model) in &nets {
        let policy = OnnxPolicy::from_bytes(&model.bytes(), name).expect("the model loads");
        assert_eq!(policy.beams(), Some(BEAMS));
        infer.bench_function(BenchmarkId::from_parameter(name), |b| {
            b.iter(|| black_box(policy.infer(black_box(&obs), 0, [0.0; 2]).expect("runs")))
        });
    }
    infer.finish();
    let mut load = c.benchmark_group("onnx_load");
    load.sample_size(20);
    for (name, model) in &nets {
        let bytes = model.bytes();
        load.bench_function(BenchmarkId::from_parameter(name), |b| {
            b.iter(|| OnnxPolicy::from_bytes(black_box(&bytes), name).expect("the model loads"))
        });
    }
    load.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
