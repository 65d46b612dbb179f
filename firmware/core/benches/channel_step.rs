//! Host benchmark of one channel step, variant (c) (force + 10 STFT bands), hidden 128:
//! `cargo bench -p slipguard-core --features std --bench channel_step`.
//! Reports the quantized step, its parts, and the f32 reference for a ratio measured in one run.
use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;

use slipguard_core::blob::AlignedBlob;
use slipguard_core::features::stft::{StftConfig, StftPlan, StftState};
use slipguard_core::model::{ChannelState, Model};

const BLOB: &[u8] = include_bytes!("../tests/fixtures/bench/model.bin");
const INPUT: &[u8] = include_bytes!("../tests/fixtures/bench/input.bin");

fn bench(c: &mut Criterion) {
    let blob = AlignedBlob::new(BLOB);
    let model = Model::from_bytes(blob.as_bytes()).expect("bench model");
    let input: Vec<i32> = INPUT
        .chunks_exact(4)
        .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let mut g = c.benchmark_group("channel_step_variant_c_h128");
    g.bench_function("quantized step (STFT + LSTM + dense + decision)", |b| {
        let mut st = ChannelState::new();
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % input.len();
            black_box(model.step(&mut st, black_box(input[i])))
        })
    });
    g.bench_function("STFT only (20-sample window, 10 bands)", |b| {
        let plan = StftPlan::new(StftConfig::PAPER).unwrap();
        let mut st = StftState::new();
        let mut out = [0i16; 10];
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % input.len();
            plan.step(&mut st, black_box((input[i] * 3) as i16), &mut out);
            black_box(out[3])
        })
    });
    g.bench_function("f32 reference step (same shape, for the ratio)", |b| {
        let float = slipguard_core::float::FloatModel::init_like_pytorch(*model.config(), 1);
        let mut st = float.new_channel();
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % input.len();
            black_box(float.step(&mut st, black_box(input[i] as f32)))
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
