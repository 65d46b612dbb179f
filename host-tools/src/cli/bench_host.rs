//! `slipguard bench-host`: host throughput of the bit-exact core in channel-steps per second,
//! the batched path (`slipguard_batch`) at batches of 1, 16, 256 and 4096 lanes on 1
//! and 2 threads against the single-step path (`Model::step`), and PyTorch's offline
//! `nn.LSTM` of the same shape when measured in the same run (`--run-torch`, or a result file
//! from `scripts/bench_torch_lstm.py` given with `--torch`).
//!
//! Each thread steps its own state of `batch` lanes for `--seconds`; a thread count of T
//! counts T × batch channels. Before the summary, one line times the LSTM's matrix product
//! alone on every kernel path this CPU has (AVX-512 VNNI, AVX2, portable), in alternating
//! turns, so that their ratio holds under a changing load. The last line is the summary:
//! `host throughput: batched N channel-steps/s (2 threads), single M, ratio R`, N the best
//! batch on 2 threads, M the single-step path on 2 threads.
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::{Duration, Instant};

use anyhow::{Context, bail};
use slipguard_batch::kernels::{PairSumsPath, batch_pair_sums_on};
use slipguard_batch::{BatchModel, CHUNK_LANES};
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model::{ChannelState, Model, StepOutput};

/// Variant (c) (force + d(t) + 10 STFT bands), hidden 128, random PyTorch-like weights: the
/// core's bench model (also the criterion benches').
const BENCH_BLOB: &[u8] = include_bytes!("../../../firmware/core/tests/fixtures/bench/model.bin");
/// Raw samples (mN) the lanes read, each from its own offset.
const BENCH_INPUT: &[u8] = include_bytes!("../../../firmware/core/tests/fixtures/bench/input.bin");

#[derive(Debug, clap::Args)]
pub struct Args {
    /// A model blob to bench instead of the built-in variant (c), hidden 128 model.
    #[arg(long)]
    pub model: Option<PathBuf>,
    /// Seconds per measurement (at least one step is always run).
    #[arg(long, default_value_t = 1.0)]
    pub seconds: f64,
    /// Batch sizes (lanes per thread), comma-separated.
    #[arg(long, value_delimiter = ',', default_value = "1,16,256,4096")]
    pub batch: Vec<usize>,
    /// Thread counts, comma-separated (the summary line needs 2).
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub threads: Vec<usize>,
    /// PyTorch result (JSON written by scripts/bench_torch_lstm.py) to show side by side.
    #[arg(long, conflicts_with = "run_torch")]
    pub torch: Option<PathBuf>,
    /// Measure PyTorch in this run: python3 scripts/bench_torch_lstm.py (needs torch).
    #[arg(long)]
    pub run_torch: bool,
}

/// One PyTorch measurement of the script's JSON.
#[derive(Debug, serde::Deserialize)]
struct TorchResult {
    batch: usize,
    threads: usize,
    channel_steps_per_s: f64,
}

#[derive(Debug, serde::Deserialize)]
struct TorchFile {
    torch: String,
    results: Vec<TorchResult>,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(b) = a.batch.iter().find(|&&b| b == 0 || b > 1 << 20) {
        bail!("--batch {b}: a batch is 1 to 1048576 lanes");
    }
    if let Some(t) = a.threads.iter().find(|&&t| t == 0 || t > 256) {
        bail!("--threads {t}: give 1 to 256 threads");
    }
    if !(a.seconds.is_finite() && a.seconds > 0.0 && a.seconds <= 3600.0) {
        bail!(
            "--seconds {}: give a duration above 0 and at most 3600",
            a.seconds
        );
    }
    let bytes = match &a.model {
        Some(p) => std::fs::read(p).with_context(|| format!("reading {}", p.display()))?,
        None => BENCH_BLOB.to_vec(),
    };
    let aligned = AlignedBlob::new(&bytes);
    let model = Model::from_bytes(aligned.as_bytes())
        .map_err(|e| anyhow::anyhow!("the model does not parse: {e:?}"))?;
    let batch = BatchModel::new(&model)?;
    let input: Vec<i32> = BENCH_INPUT
        .chunks_exact(4)
        .map(|b| i32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    let cfg = model.config();
    let name = a
        .model
        .as_ref()
        .map_or("built-in bench model".to_string(), |p| {
            p.display().to_string()
        });
    println!(
        "model: {name}: variant {}, d(t) {}, hidden {:?}, {} MACs per channel step; {:.2} s per measurement",
        cfg.variant,
        cfg.force_diff,
        &cfg.hidden[..cfg.variant.lstm_count()],
        cfg.macs_per_step(),
        a.seconds
    );
    let dur = Duration::from_secs_f64(a.seconds);
    let mut single = Vec::new();
    for &t in &a.threads {
        let r = measure(t, dur, || {
            let mut st = vec![ChannelState::new(); 16];
            let mut i = 0usize;
            let (model, input) = (&model, &input);
            move || {
                for (c, s) in st.iter_mut().enumerate() {
                    std::hint::black_box(model.step(s, input[(i + 7 * c) % input.len()]));
                }
                i += 1;
                16
            }
        });
        println!("single-step path (Model::step), {t} thread(s): {}", rate(r));
        single.push((t, r));
    }
    let mut batched = Vec::new();
    for &b in &a.batch {
        for &t in &a.threads {
            let r = measure(t, dur, || {
                let mut st = batch.state(b);
                let mut out = vec![
                    StepOutput {
                        p_unstable_q15: 0,
                        unstable: false
                    };
                    b
                ];
                let mut raw = vec![0i32; b];
                let mut i = 0usize;
                let input = &input;
                let batch = &batch;
                move || {
                    for (l, r) in raw.iter_mut().enumerate() {
                        *r = input[(i + 7 * l) % input.len()];
                    }
                    batch.step(&mut st, &raw, &mut out);
                    std::hint::black_box(&out);
                    i += 1;
                    b as u64
                }
            });
            println!(
                "batched (BatchModel::step), batch {b:>4}, {t} thread(s): {}",
                rate(r)
            );
            batched.push((b, t, r));
        }
    }
    let torch = if a.run_torch {
        let cfg = model.config();
        let inputs = cfg.lstm_inputs(0);
        if cfg.variant.lstm_count() != 1 {
            bail!("--run-torch measures one nn.LSTM: give a model with one LSTM");
        }
        Some(run_torch_script(&a, inputs, cfg.hidden[0] as usize)?)
    } else {
        a.torch.as_deref().map(read_torch).transpose()?
    };
    let best_batched = |t: usize| {
        batched
            .iter()
            .filter(|r| r.1 == t)
            .max_by(|x, y| x.2.total_cmp(&y.2))
            .map(|r| (r.0, r.2))
    };
    if let Some(tf) = &torch {
        for r in &tf.results {
            println!(
                "pytorch {} nn.LSTM (float32, offline), batch {:>4}, {} thread(s): {}",
                tf.torch,
                r.batch,
                r.threads,
                rate(r.channel_steps_per_s)
            );
        }
        for &t in &a.threads {
            let best_torch = tf
                .results
                .iter()
                .filter(|r| r.threads == t)
                .max_by(|x, y| x.channel_steps_per_s.total_cmp(&y.channel_steps_per_s));
            if let (Some(tr), Some((bb, br))) = (best_torch, best_batched(t)) {
                println!(
                    "batched vs pytorch, {t} thread(s), best batch each ({bb} vs {}): ratio {:.2}",
                    tr.batch,
                    br / tr.channel_steps_per_s
                );
            }
        }
    }
    let Some((bb, n)) = best_batched(2) else {
        bail!("no 2-thread measurement: the summary line compares on 2 threads (--threads 2)");
    };
    let m = single
        .iter()
        .find(|s| s.0 == 2)
        .map(|s| s.1)
        .unwrap_or(f64::NAN);
    if let Some(&h) = cfg.hidden[..cfg.variant.lstm_count()].first() {
        kernel_line(h as usize, dur);
    }
    println!("best batch on 2 threads: {bb}");
    println!(
        "host throughput: batched {:.0} channel-steps/s (2 threads), single {:.0}, ratio {:.1}",
        n,
        m,
        n / m
    );
    Ok(())
}

/// The first LSTM's h-part matrix product alone (`slipguard_batch::kernels::batch_pair_sums_on`:
/// 4H rows × H/2 input pairs × one chunk of lanes) on 1 thread, on every path this CPU has, in
/// ten turns each of a tenth of `dur` (so that a changing load meets the paths alike):
/// multiply-adds per second of each, and the ratio of the first (fastest) path to the second.
fn kernel_line(hidden: usize, dur: Duration) {
    let (rows, pairs, lanes) = (4 * hidden, hidden.div_ceil(2), CHUNK_LANES);
    let mut seed = 0x2545_f491_u32;
    let mut next = move || {
        seed ^= seed << 13;
        seed ^= seed >> 17;
        seed ^= seed << 5;
        seed
    };
    // int8 weights as i16 pairs, activations over the whole i16 range.
    let w: Vec<u32> = (0..rows * pairs)
        .map(|_| {
            let r = next();
            (r as i8 as i16 as u16 as u32) | ((r >> 8) as i8 as i16 as u16 as u32) << 16
        })
        .collect();
    let x: Vec<u32> = (0..pairs * lanes).map(|_| next()).collect();
    let mut out = vec![0i32; rows * lanes];
    let paths: Vec<PairSumsPath> = [
        PairSumsPath::Avx512Vnni,
        PairSumsPath::Avx2,
        PairSumsPath::Portable,
    ]
    .into_iter()
    .filter(|p| p.available())
    .collect();
    let turn = dur / (10 * paths.len() as u32);
    let mut done = vec![(0u64, Duration::ZERO); paths.len()];
    for _ in 0..10 {
        for (&p, d) in paths.iter().zip(done.iter_mut()) {
            let t0 = Instant::now();
            while t0.elapsed() < turn {
                batch_pair_sums_on(p, &w, pairs, &x, lanes, lanes, &mut out);
                std::hint::black_box(&mut out);
                d.0 += 1;
            }
            d.1 += t0.elapsed();
        }
    }
    let macs = (rows * pairs * 2 * lanes) as f64;
    let g: Vec<f64> = done
        .iter()
        .map(|d| d.0 as f64 * macs / d.1.as_secs_f64() / 1e9)
        .collect();
    let each: Vec<String> = paths
        .iter()
        .zip(&g)
        .map(|(p, g)| format!("{} {g:.1} GMAC/s", p.name()))
        .collect();
    let ratio = match g.as_slice() {
        [a, b, ..] => format!("; {}/{} {:.2}", paths[0].name(), paths[1].name(), a / b),
        _ => String::new(),
    };
    println!(
        "pair-sum kernel ({rows} rows × {pairs} pairs × {lanes} lanes, 1 thread): {}{ratio}",
        each.join(", ")
    );
}

fn rate(r: f64) -> String {
    format!("{r:>12.0} channel-steps/s")
}

/// Channel-steps per second of `threads` threads each running `make()`'s closure (which
/// returns the channel-steps it did) until `dur` has passed, at least once each.
fn measure<M, F>(threads: usize, dur: Duration, make: M) -> f64
where
    M: Fn() -> F + Sync,
    F: FnMut() -> u64,
{
    let barrier = std::sync::Barrier::new(threads);
    let start = std::sync::OnceLock::new();
    let total: u64 = std::thread::scope(|s| {
        let hs: Vec<_> = (0..threads)
            .map(|_| {
                s.spawn(|| {
                    let mut f = make();
                    f(); // warm-up: caches, first-touch pages
                    barrier.wait();
                    let t0 = *start.get_or_init(Instant::now);
                    let mut n = 0;
                    loop {
                        n += f();
                        if t0.elapsed() >= dur {
                            break n;
                        }
                    }
                })
            })
            .collect();
        hs.into_iter().map(|h| h.join().unwrap_or(0)).sum()
    });
    let t0 = start.get().copied().unwrap_or_else(Instant::now);
    total as f64 / t0.elapsed().as_secs_f64()
}

fn read_torch(p: &Path) -> anyhow::Result<TorchFile> {
    let text = std::fs::read_to_string(p).with_context(|| format!("reading {}", p.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{}: not a bench_torch_lstm.py result", p.display()))
}

/// scripts/bench_torch_lstm.py, built into the binary (an installed one has no source tree).
const TORCH_SCRIPT: &str = include_str!("../../../scripts/bench_torch_lstm.py");

/// Runs scripts/bench_torch_lstm.py (written to a temporary file) with the same batches,
/// threads and duration, for the model's input and hidden sizes.
fn run_torch_script(a: &Args, inputs: usize, hidden: usize) -> anyhow::Result<TorchFile> {
    let script = std::env::temp_dir().join(format!("slipguard-torch-{}.py", std::process::id()));
    std::fs::write(&script, TORCH_SCRIPT)
        .with_context(|| format!("writing {}", script.display()))?;
    let out = std::env::temp_dir().join(format!("slipguard-torch-{}.json", std::process::id()));
    let join = |v: &[usize]| {
        v.iter()
            .map(|x| x.to_string())
            .collect::<Vec<_>>()
            .join(",")
    };
    let status = Command::new("python3")
        .arg(&script)
        .args(["--batch", &join(&a.batch), "--threads", &join(&a.threads)])
        .args(["--seconds", &a.seconds.to_string()])
        .args([
            "--inputs",
            &inputs.to_string(),
            "--hidden",
            &hidden.to_string(),
        ])
        .arg("--quiet")
        .arg("--out")
        .arg(&out)
        .status()
        .context("running python3 (needed for --run-torch)");
    let _ = std::fs::remove_file(&script);
    let status = status?;
    if !status.success() {
        bail!(
            "scripts/bench_torch_lstm.py failed ({status}): is torch installed (pip install torch)?"
        );
    }
    let r = read_torch(&out);
    let _ = std::fs::remove_file(&out);
    r
}
