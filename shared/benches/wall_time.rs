//! Wall time of the hot paths (criterion), beside the instruction counts that
//! `cargo xtask bench` takes with callgrind from `examples/hot_paths.rs`. Wall time depends on
//! the machine and its load; the instruction counts are the figures to compare.
//!
//! `cargo bench -p shared --bench wall_time`

// criterion_group! generates an undocumented public function.
#![allow(missing_docs)]

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

#[path = "../examples/hot_paths.rs"]
#[allow(dead_code)]
mod hot_paths;

fn hot_paths(c: &mut Criterion) {
    let mut group = c.benchmark_group("hot_paths");
    group.bench_function("validated_pair", |b| {
        let mut node = hot_paths::operational(33);
        let mut sink = hot_paths::Counter::default();
        let mut i = 0u64;
        b.iter(|| {
            i += 1;
            let (plain, inverted) = hot_paths::pair_frames(i);
            hot_paths::receive_pair(
                &mut node,
                shared::Instant::from_millis(10 * i),
                &plain,
                &inverted,
                &mut sink,
            );
        });
        assert!(node.is_working());
    });
    group.bench_function("produced_pair", |b| {
        let mut node = hot_paths::operational(1);
        let mut sink = hot_paths::Counter::default();
        let mut due = node.poll(shared::Instant::ZERO, &mut sink);
        b.iter(|| due = hot_paths::produce(&mut node, black_box(due), &mut sink));
    });
    group.bench_function("idle_poll", |b| {
        let mut node = hot_paths::operational(33);
        let mut sink = hot_paths::Counter::default();
        let now = shared::Instant::from_millis(1);
        node.poll(now, &mut sink);
        b.iter(|| hot_paths::idle(&mut node, black_box(now), &mut sink));
    });
    group.finish();
}

criterion_group!(benches, hot_paths);
criterion_main!(benches);
