//! The batched path's kernels (`slipguard_batch::kernels`, with their callers in the crate's
//! root and `stft`): each run-time-chosen path (AVX-512 VNNI and AVX2 where the CPU
//! has them; for the pair sums every path the CPU has, each shown to have run) against the
//! portable code, on random inputs over the admitted ranges, edge values and shapes with
//! partial tiles. `batch_vs_single.rs` checks the whole batched step against the single
//! path; these check the portable code other targets run, too.
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use slipguard_batch::kernels::{
    PairSumsPath, batch_pair_sums, batch_pair_sums_on, batch_pair_sums_portable, stft_bin_sums,
    stft_bin_sums_portable,
};
use slipguard_batch::stft::{StftLanes, step_lanes};
use slipguard_batch::{cell_update, cell_update_portable, gate_rows, gate_rows_portable};
use slipguard_core::blob::LstmRowParams;
use slipguard_core::features::stft::{StftConfig, StftPlan, StftState, WindowShape};
use slipguard_core::lstm::CellShifts;

fn pair(a: i16, b: i16) -> u32 {
    a as u16 as u32 | (b as u16 as u32) << 16
}

#[test]
fn pair_sums_equal_the_portable_sums() {
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let mut ran_on = std::collections::BTreeMap::new();
    // (rows, pairs, lanes, extra stride): whole and partial tiles of 6 and 4 rows, 16 lanes.
    for (rows, pairs, lanes, extra) in [
        (512, 70, 64, 0),
        (24, 7, 16, 5),
        (20, 3, 37, 0),
        (8, 64, 5, 11),
        (4, 1, 16, 0),
        (2, 9, 33, 2),
        (36, 6, 48, 16),
        (44, 5, 80, 3),
        (12, 130, 112, 0),
    ] {
        let stride = lanes + extra;
        // int8 weights (−128 included) as i16 pairs, activations over the whole i16 range.
        let w: Vec<u32> = (0..rows * pairs)
            .map(|_| pair(rng.random_range(-128..=127), rng.random_range(-128..=127)))
            .collect();
        let x: Vec<u32> = (0..pairs * stride)
            .map(|k| match k % 97 {
                0 => pair(i16::MIN, i16::MIN),
                1 => pair(i16::MAX, i16::MIN),
                _ => rng.random(),
            })
            .collect();
        let mut fast = vec![0i32; rows * lanes];
        let mut slow = vec![1i32; rows * lanes];
        batch_pair_sums(&w, pairs, &x, stride, lanes, &mut fast);
        batch_pair_sums_portable(&w, pairs, &x, stride, lanes, &mut slow);
        assert_eq!(
            fast, slow,
            "rows {rows} pairs {pairs} lanes {lanes} stride {stride}"
        );
        // Every path this CPU has, each one shown to have run (whole tiles exist here).
        for path in PAIR_PATHS {
            let mut got = vec![2i32; rows * lanes];
            let ran = batch_pair_sums_on(path, &w, pairs, &x, stride, lanes, &mut got);
            assert_eq!(
                got, slow,
                "{path:?}: rows {rows} pairs {pairs} lanes {lanes}"
            );
            let tiles = rows >= 4 && lanes >= 16;
            if path.available() && tiles {
                assert_eq!(ran, path, "rows {rows} lanes {lanes}");
                *ran_on.entry(path.name()).or_insert(0) += 1;
            } else if !tiles {
                assert_eq!(ran, PairSumsPath::Portable, "rows {rows} lanes {lanes}");
            }
        }
        // One cell by hand: the definition.
        let (r, l) = (rows - 1, lanes - 1);
        let want: i64 = (0..pairs)
            .map(|p| {
                let (a, b) = (w[r * pairs + p], x[p * stride + l]);
                (a as u16 as i16 as i64) * (b as u16 as i16 as i64)
                    + ((a >> 16) as u16 as i16 as i64) * ((b >> 16) as u16 as i16 as i64)
            })
            .sum();
        assert_eq!(fast[r * lanes + l] as i64, want);
    }
    // The kernels this CPU has did run (on an AVX-512 VNNI machine both x86 paths), and the
    // default path is the best one.
    for path in PAIR_PATHS.into_iter().filter(|p| p.available()) {
        assert!(
            ran_on.get(path.name()).copied().unwrap_or(0) >= 5,
            "{ran_on:?}"
        );
    }
    let best = PairSumsPath::best();
    assert!(best.available());
    #[cfg(target_arch = "x86_64")]
    if std::is_x86_feature_detected!("avx512f") && std::is_x86_feature_detected!("avx512vnni") {
        assert_eq!(best, PairSumsPath::Avx512Vnni);
    }
    eprintln!("pair-sum paths run: {ran_on:?}, default {}", best.name());
}

const PAIR_PATHS: [PairSumsPath; 3] = [
    PairSumsPath::Portable,
    PairSumsPath::Avx2,
    PairSumsPath::Avx512Vnni,
];

#[test]
fn gate_rows_equal_the_portable_gate_rows() {
    let mut rng = ChaCha8Rng::seed_from_u64(2);
    for (hn, lanes) in [(16, 64), (7, 19), (3, 8), (5, 5)] {
        let rows = 4 * hn;
        // Every shift 1..=62 (the wide form below 33), multipliers and biases over their
        // ranges with edges, sums within the admitted bounds (x part < 2^26, h part < 2^29).
        let params: Vec<LstmRowParams> = (0..rows)
            .map(|r| LstmRowParams {
                mx: rng.random_range(0..i32::MAX),
                mh: rng.random_range(0..i32::MAX),
                bias_q12: match r % 5 {
                    0 => i32::MAX,
                    1 => i32::MIN,
                    2 => rng.random_range(-40_000..40_000),
                    _ => rng.random(),
                },
                shift: if r % 3 == 0 {
                    rng.random_range(1..=62)
                } else {
                    rng.random_range(33..=62)
                },
            })
            .collect();
        for round in 0..20 {
            let ax: Vec<i32> = (0..rows * lanes)
                .map(|k| {
                    if k % 31 == round {
                        -(1 << 26) + 1
                    } else {
                        rng.random_range(-(1 << 26)..(1 << 26))
                    }
                })
                .collect();
            let ah: Vec<i32> = (0..rows * lanes)
                .map(|k| {
                    if k % 29 == round {
                        (1 << 29) - 1
                    } else {
                        rng.random_range(-(1 << 29)..(1 << 29))
                    }
                })
                .collect();
            let mut fast = vec![0i16; rows * lanes];
            let mut slow = vec![1i16; rows * lanes];
            gate_rows(&ax, &ah, &params, hn, lanes, &mut fast);
            gate_rows_portable(&ax, &ah, &params, hn, lanes, &mut slow);
            assert_eq!(fast, slow, "hn {hn} lanes {lanes} round {round}");
        }
    }
}

#[test]
fn cell_updates_equal_the_portable_cell_updates() {
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    for (hn, lanes, stride, c0) in [
        (16usize, 64, 80, 16),
        (7, 19, 19, 0),
        (3, 8, 24, 8),
        (1, 5, 5, 0),
    ] {
        for cb in [1, 5, 11, 12, 13, 15] {
            let k = CellShifts::new(cb);
            // Gates over the whole i16 range (σ and tanh give less), some lanes off.
            let gates: Vec<i16> = (0..4 * hn * lanes).map(|_| rng.random()).collect();
            let on: Vec<bool> = (0..lanes).map(|i| i % 4 != 1).collect();
            let h0: Vec<u32> = (0..hn.div_ceil(2) * stride).map(|_| rng.random()).collect();
            let c_init: Vec<i16> = (0..hn * stride).map(|_| rng.random()).collect();
            let (mut hf, mut cf) = (h0.clone(), c_init.clone());
            let (mut hs, mut cs) = (h0.clone(), c_init.clone());
            cell_update(&gates, hn, lanes, k, &on, &mut hf, &mut cf, stride, c0);
            cell_update_portable(&gates, hn, lanes, k, &on, &mut hs, &mut cs, stride, c0);
            assert_eq!(cf, cs, "c: hn {hn} lanes {lanes} C {cb}");
            assert_eq!(hf, hs, "h: hn {hn} lanes {lanes} C {cb}");
            assert_ne!(cf, c_init, "the update changed something");
        }
    }
}

#[test]
fn stft_bin_sums_equal_the_portable_sums() {
    let mut rng = ChaCha8Rng::seed_from_u64(4);
    for lanes in [64, 17, 3] {
        let xw: Vec<i32> = (0..lanes)
            .map(|_| rng.random_range(-(1 << 30)..=(1 << 30)))
            .collect();
        let (c, s) = (rng.random::<i16>(), i16::MIN);
        let re0: Vec<i64> = (0..lanes)
            .map(|_| rng.random_range(-(1 << 50)..(1 << 50)))
            .collect();
        let (mut rf, mut imf) = (re0.clone(), re0.clone());
        let (mut rs, mut ims) = (re0.clone(), re0.clone());
        stft_bin_sums(&xw, c, s, &mut rf, &mut imf);
        stft_bin_sums_portable(&xw, c, s, &mut rs, &mut ims);
        assert_eq!((rf, imf), (rs, ims), "lanes {lanes}");
    }
}

/// `step_lanes` against `StftPlan::step` run lane by lane (the board's single path): both window
/// shapes, short, paper and longest windows, bins from DC to Nyquist, lanes switched off now
/// and then (their state must not move, their output is 0), inputs over the whole i16 range.
#[test]
fn stft_lanes_equal_the_single_step() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let configs = [
        StftConfig::PAPER,
        StftConfig {
            window_len: 4,
            first_bin: 0,
            n_bins: 3,
            shape: WindowShape::Hann,
        },
        StftConfig {
            window_len: 48,
            first_bin: 14,
            n_bins: 10,
            shape: WindowShape::Hann,
        },
        StftConfig {
            window_len: 21,
            first_bin: 0,
            n_bins: 10,
            shape: WindowShape::Rectangular,
        },
    ];
    let lanes = 19;
    for config in configs {
        let plan = StftPlan::new(config).expect("a valid STFT setting");
        let bins = usize::from(config.n_bins);
        let mut buf = StftLanes::new(lanes);
        let mut batched = vec![StftState::new(); lanes];
        let mut single = vec![StftState::new(); lanes];
        let mut out = vec![0i16; bins * lanes];
        let mut moved = false;
        for t in 0..150 {
            let x: Vec<i16> = (0..lanes)
                .map(|i| match (t + i) % 41 {
                    0 => i16::MIN,
                    1 => i16::MAX,
                    _ => rng.random(),
                })
                .collect();
            let on: Vec<bool> = (0..lanes).map(|_| rng.random_range(0..5) != 0).collect();
            out.fill(-1);
            step_lanes(&plan, &mut buf, &mut batched, &x, &on, &mut out);
            for i in 0..lanes {
                let mut want = vec![0i16; bins];
                if on[i] {
                    plan.step(&mut single[i], x[i], &mut want);
                }
                let got: Vec<i16> = (0..bins).map(|b| out[b * lanes + i]).collect();
                assert_eq!(got, want, "{config:?} step {t} lane {i}");
                assert_eq!(batched[i], single[i], "{config:?} step {t} lane {i} state");
                moved |= want.iter().any(|&v| v > 100);
            }
        }
        assert!(moved, "{config:?}: the bands saw signal");
    }
}
