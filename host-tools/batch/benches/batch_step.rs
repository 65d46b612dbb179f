//! Host benchmark of the batched path ([`slipguard_batch`]), variant (c) (force + 10
//! STFT bands), hidden 128, one step of every lane for batches of 1, 16, 256 and 4096 lanes,
//! one thread: `cargo bench -p slipguard-batch --bench batch_step`.
//! Criterion reports elements (channel-steps) per second; `slipguard bench-host` adds two
//! threads, the single-step path and PyTorch in one run.
use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use std::hint::black_box;

use slipguard_batch::BatchModel;
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model::{Model, StepOutput};

const BLOB: &[u8] = include_bytes!("../../../firmware/core/tests/fixtures/bench/model.bin");
const INPUT: &[u8] = include_bytes!("../../../firmware/core/tests/fixtures/bench/input.bin");

fn bench(c: &mut Criterion) {
    let blob = AlignedBlob::new(BLOB);
    let model = Model::from_bytes(blob.as_bytes()).expect("bench model");
    let batch = BatchModel::new(&model).expect("bench model batches");
    let input: Vec<i32> = INPUT
        .chunks_exact(4)
        .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let mut g = c.benchmark_group("batch_step_variant_c_h128");
    for lanes in [1usize, 16, 256, 4096] {
        g.throughput(Throughput::Elements(lanes as u64));
        g.bench_with_input(
            BenchmarkId::new("batched step", lanes),
            &lanes,
            |b, &lanes| {
                let mut st = batch.state(lanes);
                let mut out = vec![
                    StepOutput {
                        p_unstable_q15: 0,
                        unstable: false
                    };
                    lanes
                ];
                // Lane l starts l samples into the recording, so the lanes differ.
                let mut raw: Vec<i32> = vec![0; lanes];
                let mut t = 0;
                b.iter(|| {
                    t += 1;
                    for (l, r) in raw.iter_mut().enumerate() {
                        *r = input[(t + l) % input.len()];
                    }
                    batch.step(&mut st, black_box(&raw), &mut out);
                    black_box(out[0])
                })
            },
        );
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
