//! Many worlds stepped as one batch ([`Worlds`]) give the very bits of each world stepped
//! alone, with some worlds idle or reset mid-run, whether the batch is stepped whole or in
//! parts; the packed observations are each world's observation in the wire layout; a bad
//! request changes nothing.

use paddock_sim::circuit::Circuits;
use paddock_sim::collision::CollisionMode;
use paddock_sim::world::{
    Action, PackedObservations, Starts, StepEvents, World, WorldConfig, WorldError, Worlds,
};

const N: usize = 5;
const CARS: usize = 2;

/// Two cars with scans that see each other, obstacles, Stop mode: every code path of a
/// step (a collision puts a car back).
fn template() -> World {
    let circuit = Circuits::new().default_circuit().unwrap();
    let mut cfg = WorldConfig::with_agents(CARS);
    cfg.collision_mode = CollisionMode::Stop;
    cfg.lidar.num_beams = 270;
    cfg.obstacles.count = 2;
    World::new(circuit, cfg).unwrap()
}

/// Actions that vary by world, car and step; some cars steer into walls.
fn actions(step: usize) -> Vec<Action> {
    (0..N * CARS)
        .map(|k| {
            let steer = 0.35 * (((k * 5 + step) % 9) as f64 / 8.0 - 0.5);
            Action::new(steer, 1.0 + ((k + step) % 6) as f64)
        })
        .collect()
}

/// Worlds idle on some steps.
fn active(step: usize) -> Vec<bool> {
    (0..N).map(|i| !(i + step).is_multiple_of(4)).collect()
}

/// The packed buffers of `N` worlds.
struct Buffers {
    scans: Vec<u8>,
    states: Vec<u8>,
    collisions: Vec<u8>,
    lap_counts: Vec<u8>,
    lap_times: Vec<u8>,
    time: Vec<u8>,
}

impl Buffers {
    fn new(worlds: usize, beams: usize) -> Self {
        Self {
            scans: vec![0; worlds * CARS * beams * 4],
            states: vec![0; worlds * CARS * 7 * 8],
            collisions: vec![0; worlds * CARS],
            lap_counts: vec![0; worlds * CARS * 4],
            lap_times: vec![0; worlds * CARS * 8],
            time: vec![0; worlds * 8],
        }
    }

    fn out(&mut self) -> PackedObservations<'_> {
        PackedObservations {
            scans: &mut self.scans,
            scan_cars: CARS,
            states: &mut self.states,
            collisions: &mut self.collisions,
            lap_counts: &mut self.lap_counts,
            lap_times: &mut self.lap_times,
            time: &mut self.time,
        }
    }

    /// What the buffers must hold for `worlds`, packed by hand from each observation.
    fn expected(worlds: &[World], beams: usize) -> Self {
        let mut b = Self::new(worlds.len(), beams);
        b.scans.clear();
        b.states.clear();
        b.collisions.clear();
        b.lap_counts.clear();
        b.lap_times.clear();
        b.time.clear();
        for w in worlds {
            let s = w.state().unwrap();
            let o = &s.observation;
            for &r in &o.scans {
                b.scans.extend((r.max(0.0) as f32).to_le_bytes());
            }
            for a in 0..CARS {
                for v in [
                    o.poses_x[a],
                    o.poses_y[a],
                    o.poses_theta[a],
                    o.linear_vels_x[a],
                    o.linear_vels_y[a],
                    o.ang_vels_z[a],
                    o.steering_angles[a],
                ] {
                    b.states.extend(v.to_le_bytes());
                }
                b.collisions.push(u8::from(o.collisions[a]));
                b.lap_counts.extend(o.lap_counts[a].to_le_bytes());
                b.lap_times.extend(o.lap_times[a].to_le_bytes());
            }
            b.time.extend(s.time.to_le_bytes());
        }
        b
    }

    fn assert_eq(&self, other: &Self, what: &str) {
        assert!(self.scans == other.scans, "{what}: scans differ");
        assert!(self.states == other.states, "{what}: states differ");
        assert_eq!(self.collisions, other.collisions, "{what}: collisions");
        assert_eq!(self.lap_counts, other.lap_counts, "{what}: lap counts");
        assert_eq!(self.lap_times, other.lap_times, "{what}: lap times");
        assert_eq!(self.time, other.time, "{what}: time");
    }
}

/// Runs the batch next to lone worlds for `steps` steps, resetting worlds 1 and 3
/// mid-run, and checks every step; returns a digest of everything the batch wrote.
fn run_side_by_side(steps: usize) -> u64 {
    let t = template();
    let beams = t.config().lidar.num_beams;
    let mut batch = Worlds::of(&t, N);
    let mut alone: Vec<World> = vec![t.clone(); N];
    for (i, w) in alone.iter_mut().enumerate() {
        batch.reset(i, 40 + i as u64, &Starts::Random).unwrap();
        w.reset(40 + i as u64, &Starts::Random).unwrap();
    }
    let mut buf = Buffers::new(N, beams);
    batch.pack(&mut buf.out()).unwrap();
    buf.assert_eq(&Buffers::expected(&alone, beams), "after reset");
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut events = vec![StepEvents::default(); N];
    for step in 0..steps {
        if step == steps / 2 {
            for i in [1, 3] {
                let seed = 900 + step as u64 + i as u64;
                batch.reset(i, seed, &Starts::Grid { s: 5.0 }).unwrap();
                alone[i].reset(seed, &Starts::Grid { s: 5.0 }).unwrap();
            }
        }
        let (acts, on) = (actions(step), active(step));
        batch.step(&acts, &on, Some(&mut buf.out())).unwrap();
        for i in 0..N {
            if on[i] {
                events[i] = alone[i].step(&acts[i * CARS..(i + 1) * CARS]).unwrap();
                assert_eq!(batch.events(i), &events[i], "step {step} world {i} events");
            }
            assert_eq!(
                batch.world(i).state().unwrap(),
                alone[i].state().unwrap(),
                "step {step} world {i}"
            );
            assert_eq!(
                batch.world(i).observation().unwrap().digest(),
                alone[i].observation().unwrap().digest(),
                "step {step} world {i} observation bits"
            );
        }
        buf.assert_eq(&Buffers::expected(&alone, beams), &format!("step {step}"));
        for b in buf.scans.iter().chain(&buf.states).chain(&buf.time) {
            h = (h ^ u64::from(*b)).wrapping_mul(0x0100_0000_01b3);
        }
    }
    h
}

#[test]
fn a_batch_step_is_each_world_stepped_alone() {
    let a = run_side_by_side(150);
    // the same run again: the same bits
    assert_eq!(a, run_side_by_side(150));
}

#[test]
fn stepping_parts_of_the_batch_is_stepping_the_whole() {
    let t = template();
    let beams = t.config().lidar.num_beams;
    let mut whole = Worlds::of(&t, N);
    let mut parts = Worlds::of(&t, N);
    for i in 0..N {
        whole.reset(i, i as u64, &Starts::Random).unwrap();
        parts.reset(i, i as u64, &Starts::Random).unwrap();
    }
    let (mut a, mut b) = (Buffers::new(N, beams), Buffers::new(N, beams));
    for step in 0..40 {
        let (acts, on) = (actions(step), active(step));
        whole.step(&acts, &on, Some(&mut a.out())).unwrap();
        let (mut w0, mut w1) = parts.batch_mut().split_at(2);
        let (mut o0, mut o1) = b.out().split_at(2, CARS, beams);
        w0.step(&acts[..2 * CARS], &on[..2], Some(&mut o0)).unwrap();
        w1.step(&acts[2 * CARS..], &on[2..], Some(&mut o1)).unwrap();
        a.assert_eq(&b, &format!("step {step}"));
    }
}

#[test]
fn a_bad_request_changes_no_world() {
    let t = template();
    let beams = t.config().lidar.num_beams;
    let mut batch = Worlds::of(&t, N);
    for i in 0..N {
        batch.reset(i, i as u64, &Starts::Random).unwrap();
    }
    let before: Vec<_> = batch.iter().map(|w| w.snapshot().unwrap()).collect();
    let mut acts = actions(0);
    acts[3 * CARS + 1].speed = f64::NAN;
    let e = batch.step(&acts, &[], None).unwrap_err();
    assert!(
        matches!(
            e,
            WorldError::NonFiniteAction {
                agent: 1,
                field: "speed",
                ..
            }
        ),
        "{e:?}"
    );
    // an idle world's actions are not read
    let mut on = vec![true; N];
    on[3] = false;
    batch.step(&acts, &on, None).unwrap();
    assert_eq!(batch.world(3).state().unwrap(), &before[3]);
    assert_ne!(batch.world(0).state().unwrap(), &before[0]);
    for (i, s) in before.iter().enumerate() {
        batch.world_mut(i).restore(s).unwrap();
    }
    let e = batch.step(&actions(0)[1..], &[], None).unwrap_err();
    assert!(matches!(e, WorldError::ActionCount { .. }), "{e:?}");
    let e = batch.step(&actions(0), &[true; 2], None).unwrap_err();
    assert!(e.to_string().contains("active"), "{e}");
    let mut short = vec![0; N * CARS * beams * 4 - 4];
    let e = batch
        .step(
            &actions(0),
            &[],
            Some(&mut PackedObservations::scans(&mut short, CARS)),
        )
        .unwrap_err();
    assert!(e.to_string().contains("scans"), "{e}");
    let mut scans = vec![0; N * 3 * beams * 4];
    let e = batch
        .step(
            &actions(0),
            &[],
            Some(&mut PackedObservations::scans(&mut scans, 3)),
        )
        .unwrap_err();
    assert!(e.to_string().contains("scan_cars"), "{e}");
    for (w, s) in batch.iter().zip(&before) {
        assert_eq!(w.state().unwrap(), s);
    }
    // a world never reset
    let mut fresh = Worlds::of(&t, 2);
    fresh.reset(0, 1, &Starts::Random).unwrap();
    let e = fresh.step(&actions(0)[..2 * CARS], &[], None).unwrap_err();
    assert_eq!(e, WorldError::NotReset);
    assert_eq!(fresh.world(0).state().unwrap().steps, 0);
}
