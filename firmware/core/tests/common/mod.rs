//! Helpers shared by slipguard-core's integration tests.
#![allow(dead_code)]

use rand::{Rng, SeedableRng};
use slipguard_core::blob::{InputUnit, ModelConfig, Variant};
use slipguard_core::features::stft::StftConfig;
use slipguard_core::float::FloatModel;
use slipguard_core::units::Millihertz;

/// Header of a fingertip-force model as the paper sets it up (16.7 Hz, 0..10 000 mN).
pub fn config(variant: Variant, hidden: u16, force_diff: bool) -> ModelConfig {
    let dual = variant == Variant::LstmStftLstm;
    ModelConfig {
        model_id: 0x5eed_0001,
        name: *b"test\0\0\0\0\0\0\0\0",
        variant,
        force_diff,
        sample_rate_mhz: Millihertz(16_700),
        input_unit: InputUnit::MilliNewton,
        input_offset: 0,
        input_full_scale: 10_000,
        stft: if variant.uses_bands() {
            StftConfig::PAPER
        } else {
            StftConfig::NONE
        },
        hidden: [hidden, if dual { hidden } else { 0 }],
        cell_frac_bits: [0, 0],
        threshold_q15: 16_384,
        raise_after: 1,
        clear_after: 1,
        hand_rule: None,
    }
}

/// A smooth random force trace in mN: a slow random walk (grip changes), 0.5–8 Hz
/// components (vibration, including the 3–5 Hz slip band), occasional steps, and sensor
/// noise; mostly within 0..10 000 mN with rare excursions past full scale.
pub fn smooth_force(seed: u64, steps: usize) -> Vec<f32> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let fs = 16.7f32;
    let tones: Vec<(f32, f32, f32)> = (0..4)
        .map(|_| {
            (
                rng.random_range(0.5..8.0),
                rng.random_range(50.0..600.0),
                rng.random_range(0.0..std::f32::consts::TAU),
            )
        })
        .collect();
    let mut level: f32 = rng.random_range(1000.0..5000.0);
    (0..steps)
        .map(|t| {
            level += rng.random_range(-120.0..120.0);
            if rng.random_bool(0.01) {
                level += rng.random_range(-3000.0..3000.0);
            }
            level = level.clamp(-500.0, 10_500.0);
            let tt = t as f32 / fs;
            let vib: f32 = tones
                .iter()
                .map(|(f, a, p)| a * (std::f32::consts::TAU * f * tt + p).sin())
                .sum();
            level + vib + rng.random_range(-30.0..30.0)
        })
        .collect()
}

/// A random model at PyTorch's init scale with normalisation fitted on a few traces.
pub fn random_model(variant: Variant, hidden: u16, force_diff: bool, seed: u64) -> FloatModel {
    let mut m = FloatModel::init_like_pytorch(config(variant, hidden, force_diff), seed);
    let traces: Vec<Vec<f32>> = (0..4)
        .map(|i| smooth_force(seed ^ (100 + i), 400))
        .collect();
    let refs: Vec<&[f32]> = traces.iter().map(|t| t.as_slice()).collect();
    m.fit_normalisation(&refs);
    m
}

/// Whether this run re-writes the golden fixtures (`SLIPGUARD_BLESS` set). Refused under CI
/// (`CI` set): CI checks the committed fixtures, it never re-blesses them.
pub fn blessing() -> bool {
    let bless = std::env::var_os("SLIPGUARD_BLESS").is_some();
    assert!(
        !(bless && std::env::var_os("CI").is_some()),
        "SLIPGUARD_BLESS is set under CI: re-bless fixtures locally and commit them, never in CI"
    );
    bless
}
