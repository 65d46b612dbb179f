//! The quantized-vs-float agreement (`calib::compare`, the quantized model batched and the
//! batches in parallel): the same report on 1 and 2 threads, and the figures a plain
//! one-sequence-at-a-time pass over `Model::step` and the float model gives.
use slipguard_core::blob::{AlignedBlob, InputUnit, ModelConfig, Variant};
use slipguard_core::features::stft::StftConfig;
use slipguard_core::float::FloatModel;
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::quantize::quantize;
use slipguard_core::units::Millihertz;
use slipguard_export::calib::{compare, unlabelled};

fn config() -> ModelConfig {
    ModelConfig {
        model_id: 0,
        name: *b"agree\0\0\0\0\0\0\0",
        variant: Variant::DataStftLstm,
        force_diff: true,
        sample_rate_mhz: Millihertz(16_700),
        input_unit: InputUnit::MilliNewton,
        input_offset: 0,
        input_full_scale: 32_768,
        stft: StftConfig::PAPER,
        hidden: [12, 0],
        cell_frac_bits: [0, 0],
        threshold_q15: 16_384,
        raise_after: 1,
        clear_after: 1,
        hand_rule: None,
    }
}

#[test]
fn agreement_is_the_same_on_one_and_two_threads_and_as_a_plain_pass() {
    // 150 sequences of different lengths: three batches, the last one partial.
    let seqs: Vec<Vec<f32>> = (0..150)
        .map(|i| {
            (0..40 + (i * 7) % 90)
                .map(|t| {
                    let t = t as f32;
                    3000.0 + 1500.0 * (0.3 * t + i as f32).sin() + 400.0 * (1.7 * t).cos()
                })
                .collect()
        })
        .collect();
    let mut float = FloatModel::init_like_pytorch(config(), 9);
    let refs: Vec<&[f32]> = seqs.iter().map(Vec::as_slice).collect();
    float.fit_normalisation(&refs);
    let (blob, _) = quantize(&float, &refs[..10], None).unwrap();
    let data = unlabelled(&seqs);
    let on = |n: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap();
        let a = pool
            .install(|| compare(&float, &blob, &data, true))
            .unwrap();
        serde_json::to_string(&a).unwrap()
    };
    let one = on(1);
    assert_eq!(one, on(2));

    // The plain pass: every sequence from a reset state, step by step.
    let aligned = AlignedBlob::new(&blob);
    let model = Model::from_bytes(aligned.as_bytes()).unwrap();
    let (mut steps, mut disagree, mut max_dp) = (0usize, 0usize, 0f32);
    for s in &seqs {
        let (mut fs, mut qs) = (float.new_channel(), ChannelState::new());
        for &raw in s {
            let f = float.step(&mut fs, raw);
            let q = model.step(&mut qs, raw.round() as i32);
            max_dp = max_dp.max((q.p_unstable_q15 as f32 / 32768.0 - f.p_unstable).abs());
            disagree += usize::from(f.unstable != q.unstable);
            steps += 1;
        }
    }
    let a: serde_json::Value = serde_json::from_str(&one).unwrap();
    assert_eq!(a["steps"], steps);
    assert_eq!(a["sequences"], seqs.len());
    assert_eq!(a["flag_disagreements"], disagree);
    assert_eq!(a["max_abs_dp"].as_f64().unwrap() as f32, max_dp);
}
