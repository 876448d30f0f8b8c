//! Simulation speed (SIM-16): the first 60 s of `marsyard-25m` with the flight software in the
//! loop and flat-grey cameras (no rendering). Real-time factor = 60 s / measured time.

use criterion::{criterion_group, criterion_main, Criterion};
use sim_host::closed_loop::{run, RunOptions};
use sim_host::devices::world::CounterMode;
use sim_host::scenario::Scenario;
use std::path::Path;

fn marsyard_60s(c: &mut Criterion) {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../scenarios/marsyard-25m.toml");
    let mut scenario = Scenario::load(&path).expect("scenario");
    scenario.duration_s = 60.0;
    let mut group = c.benchmark_group("sim_speed");
    group.sample_size(10);
    group.bench_function("marsyard_25m_first_60s", |b| {
        b.iter(|| {
            let r = run(
                &scenario,
                RunOptions {
                    counter: CounterMode::SimTime,
                    ..RunOptions::default()
                },
            )
            .expect("run");
            assert!(r.sim_time_s > 59.0);
            r.distance_m
        })
    });
    group.finish();
}

criterion_group!(benches, marsyard_60s);
criterion_main!(benches);
