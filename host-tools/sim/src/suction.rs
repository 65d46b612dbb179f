//! Suction-cup gripper simulator: 4 cups with vacuum sensors read as 16-bit
//! counts (baseline near 6,400 = no vacuum), sampled at 71 Hz and decimated
//! by 4 (boxcar mean) to 17.75 Hz, as the paper's pick-and-place data.
//!
//! Physics per cup `i` (vacuum `p_i` in kPa gauge, docs/simulator.md):
//! `dp_i/dt = (p_sup − p_i)/τ_pump − k_i(t) p_i` while the valve is on and the
//! cup seals; holding force `η Σ p_i A`; the object detaches when the load
//! `m (g + a(t))` exceeds it, then every cup vents (`τ = 30 ms`) and stays at 0.
//! Events: a *leak* (a cup lip lifts: `k_i` ramps up, with 3–5 Hz lip flutter)
//! and a *deformation* (the object flexes: a damped 2–6 Hz pressure transient
//! on some cups, no detachment: the false-alarm case).
//! Sensor: `counts = baseline_i + 500 · p_i`, 5 ms response, noise 10 counts
//! (1 σ), clamp to 0..65535, integer counts.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::{adc, normal, trial_rng, uniform};
use slipguard_data::labels::{LabelConfig, label_annotated};
use slipguard_data::trial::{Outcome, PhaseMarks, SensorKind, Trial, Unit};

const G: f64 = 9.81;
const INTERNAL_HZ: f64 = 1000.0;

/// Sensor and timing settings.
#[derive(Debug, Clone, PartialEq)]
pub struct SuctionSimConfig {
    pub rate_hz: f64,
    /// Decimation factor for the low-rate output (4: 71 → 17.75 Hz).
    pub decimate: usize,
    pub duration_s: f64,
    /// Zero-vacuum readings of the 4 sensors (the paper's 6458, 6263, 6357, 6458).
    pub baselines: [f64; 4],
    pub counts_per_kpa: f64,
    pub noise_counts: f64,
    pub sensor_tau_s: f64,
    /// Probability of a deformation event in a trial.
    pub deformation_prob: f64,
}

impl Default for SuctionSimConfig {
    fn default() -> Self {
        SuctionSimConfig {
            rate_hz: 71.0,
            decimate: 4,
            duration_s: 12.0,
            baselines: [6458.0, 6263.0, 6357.0, 6458.0],
            counts_per_kpa: 500.0,
            noise_counts: 10.0,
            sensor_tau_s: 0.005,
            deformation_prob: 0.4,
        }
    }
}

/// Drawn parameters of one suction trial.
#[derive(Debug, Clone, PartialEq)]
pub struct SuctionParams {
    pub drop_intent: bool,
    pub mass_kg: f64,
    pub supply_kpa: f64,
    pub pump_tau: f64,
    pub cup_area_m2: f64,
    pub efficiency: f64,
    pub base_leak: [f64; 4],
    pub t_attach: f64,
    pub t_lift: f64,
    pub t_place: f64,
    pub lift_accel: f64,
    pub accel_dur: f64,
    /// (cups mask, start, ramp duration, final leak rate 1/s, flutter Hz)
    pub leak: Option<([bool; 4], f64, f64, f64, f64)>,
    /// (cups mask, start, amplitude kPa, frequency Hz)
    pub deformation: Option<([bool; 4], f64, f64, f64)>,
}

impl SuctionParams {
    pub fn draw(rng: &mut ChaCha8Rng, drop_intent: bool, cfg: &SuctionSimConfig) -> Self {
        let supply_kpa = uniform(rng, 50.0, 75.0);
        let cup_area_m2 = std::f64::consts::PI * uniform(rng, 0.010, 0.016).powi(2);
        let efficiency = uniform(rng, 0.5, 0.7);
        let hold_force = efficiency * 4.0 * supply_kpa * 1000.0 * cup_area_m2;
        // Safety factor of the static hold: 1.8-4 (hold) or 1.1-1.4 (drop, needs a leak).
        let sf = if drop_intent {
            uniform(rng, 1.1, 1.4)
        } else {
            uniform(rng, 1.8, 4.0)
        };
        let mass_kg = hold_force / (G * sf);
        let t_attach = uniform(rng, 0.5, 1.5);
        let t_lift = t_attach + uniform(rng, 0.6, 1.0);
        let t_place = t_lift + uniform(rng, 5.0, 7.0);
        let pick = |rng: &mut ChaCha8Rng, k: usize| {
            let mut m = [false; 4];
            let mut n = 0;
            while n < k {
                let i = rng.random_range(0..4);
                if !m[i] {
                    m[i] = true;
                    n += 1;
                }
            }
            m
        };
        let leak = if drop_intent {
            let k = rng.random_range(2..=3);
            Some((
                pick(rng, k),
                t_lift + uniform(rng, 0.2, 3.0),
                uniform(rng, 0.2, 1.0),
                uniform(rng, 15.0, 40.0),
                uniform(rng, 3.0, 5.0),
            ))
        } else if rng.random_bool(0.25) {
            // A mild leak the grip survives.
            Some((
                pick(rng, 1),
                t_lift + uniform(rng, 0.2, 3.0),
                uniform(rng, 0.2, 1.0),
                uniform(rng, 0.5, 2.0),
                uniform(rng, 3.0, 5.0),
            ))
        } else {
            None
        };
        let deformation = rng.random_bool(cfg.deformation_prob).then(|| {
            let k = rng.random_range(1..=3);
            (
                pick(rng, k),
                t_lift + uniform(rng, 0.3, 4.0),
                uniform(rng, 3.0, 10.0),
                uniform(rng, 2.0, 6.0),
            )
        });
        SuctionParams {
            drop_intent,
            mass_kg,
            supply_kpa,
            pump_tau: uniform(rng, 0.08, 0.2),
            cup_area_m2,
            efficiency,
            base_leak: std::array::from_fn(|_| uniform(rng, 0.0, 0.3)),
            t_attach,
            t_lift,
            t_place,
            lift_accel: uniform(rng, 2.0, 6.0),
            accel_dur: uniform(rng, 0.3, 0.6),
            leak,
            deformation,
        }
    }

    fn accel(&self, t: f64) -> f64 {
        let x = t - self.t_lift;
        if (0.0..self.accel_dur).contains(&x) {
            self.lift_accel * (std::f64::consts::PI * x / self.accel_dur).sin().powi(2)
        } else {
            0.0
        }
    }
}

/// Noise-free vacuum (kPa) per cup at 1 kHz, and the detachment time.
pub fn integrate(p: &SuctionParams, cfg: &SuctionSimConfig) -> (Vec<[f64; 4]>, Option<f64>) {
    let dt = 1.0 / INTERNAL_HZ;
    let n = (cfg.duration_s * INTERNAL_HZ).ceil() as usize + 1;
    let mut vac = [0.0f64; 4];
    let mut out = Vec::with_capacity(n);
    let mut t_detach = None;
    for i in 0..n {
        let t = i as f64 * dt;
        let valve = t >= p.t_attach && t < p.t_place;
        for (c, v) in vac.iter_mut().enumerate() {
            if t_detach.is_some() || !valve {
                *v += (0.0 - *v) * dt / 0.03;
                continue;
            }
            let mut k = p.base_leak[c];
            if let Some((mask, t0, ramp, kmax, _)) = p.leak
                && mask[c]
                && t >= t0
            {
                k += kmax * ((t - t0) / ramp).min(1.0);
            }
            *v += ((p.supply_kpa - *v) / p.pump_tau - k * *v) * dt;
        }
        // Readings: add lip flutter and deformation transients (they change the
        // cup volume, not the mean seal).
        let mut read = vac;
        if t_detach.is_none() {
            if let Some((mask, t0, ramp, kmax, f)) = p.leak
                && t >= t0
            {
                let x = ((t - t0) / ramp).min(1.0) * (kmax / 30.0).min(1.0);
                for c in 0..4 {
                    if mask[c] {
                        read[c] -= 0.15
                            * vac[c]
                            * x
                            * (0.5 - 0.5 * (2.0 * std::f64::consts::PI * f * (t - t0)).cos());
                    }
                }
            }
            if let Some((mask, t0, amp, f)) = p.deformation
                && t >= t0
            {
                let e = (-(t - t0) * 2.0 * std::f64::consts::PI * f * 0.2).exp();
                let s = (2.0 * std::f64::consts::PI * f * (t - t0)).sin();
                for c in 0..4 {
                    if mask[c] {
                        read[c] -= amp * e * s;
                    }
                }
            }
        }
        // Detachment check once lifted.
        if t_detach.is_none() && t >= p.t_lift && t < p.t_place {
            let hold: f64 = vac.iter().sum::<f64>() * 1000.0 * p.cup_area_m2 * p.efficiency;
            if p.mass_kg * (G + p.accel(t)) > hold {
                t_detach = Some(t);
            }
        }
        out.push(read.map(|v| v.max(0.0)));
    }
    (out, t_detach)
}

/// Simulate suction trial `index` of `seed`; returns the 71 Hz trial and its
/// decimated 17.75 Hz version (same physics, same noise).
pub fn simulate_trial(
    seed: u64,
    index: u64,
    drop_intent: Option<bool>,
    failure_share: f64,
    cfg: &SuctionSimConfig,
) -> (Trial, Trial) {
    let mut rng = trial_rng(seed, index);
    let drop_intent = drop_intent.unwrap_or_else(|| rng.random_bool(failure_share.clamp(0.0, 1.0)));
    let p = SuctionParams::draw(&mut rng, drop_intent, cfg);
    let (vac, t_detach) = integrate(&p, cfg);
    let n = (cfg.duration_s * cfg.rate_hz).round() as usize;
    let n = n - n % cfg.decimate;
    let alpha = (1.0 / INTERNAL_HZ) / (cfg.sensor_tau_s + 1.0 / INTERNAL_HZ);
    // Sensor lag at the internal rate.
    let mut lag = [0.0f64; 4];
    let mut lagged = Vec::with_capacity(vac.len());
    for v in &vac {
        for c in 0..4 {
            lag[c] += alpha * (v[c] - lag[c]);
        }
        lagged.push(lag);
    }
    let mut hi = vec![vec![0.0f32; n]; 4];
    let mut hi_f = vec![vec![0.0f64; n]; 4];
    for k in 0..n {
        let i = ((k as f64 / cfg.rate_hz) * INTERNAL_HZ).round() as usize;
        let i = i.min(lagged.len() - 1);
        for c in 0..4 {
            let x = cfg.baselines[c]
                + cfg.counts_per_kpa * lagged[i][c]
                + normal(&mut rng) * cfg.noise_counts;
            hi_f[c][k] = x.clamp(0.0, 65535.0);
            hi[c][k] = adc(x, 65535.0, 16);
        }
    }
    let lo_n = n / cfg.decimate;
    let lo: Vec<Vec<f32>> = hi_f
        .iter()
        .map(|ch| {
            (0..lo_n)
                .map(|j| {
                    let s: f64 = ch[j * cfg.decimate..(j + 1) * cfg.decimate].iter().sum();
                    adc(s / cfg.decimate as f64, 65535.0, 16)
                })
                .collect()
        })
        .collect();
    let make = |samples: Vec<Vec<f32>>, rate: f64, tag: &str| {
        let steps = samples[0].len();
        let st = |t: f64| ((t * rate).ceil() as usize).min(steps - 1);
        let mut tr = Trial::new(
            format!("sim-suction-{seed}-{index:04}-{tag}"),
            Unit::Counts,
            rate as f32,
            samples,
        );
        tr.sensor = SensorKind::Pressure;
        tr.source = format!("slipguard simulate suction seed={seed} index={index} rate_hz={rate}");
        tr.marks = PhaseMarks {
            grasp_start: Some(st(p.t_attach)),
            lift_start: Some(st(p.t_lift)),
            open_start: Some(st(p.t_place)),
            release: None,
        };
        tr.outcome = if t_detach.is_some() {
            Outcome::Failure
        } else {
            Outcome::Success
        };
        tr.drop_step = t_detach.map(st);
        // Slip begins where the seal starts to leak, or at the detachment itself when the cup
        // lets go first (a heavy object on lift): never after the drop.
        if let Some((_, t0, ..)) = p.leak
            && let Some(td) = t_detach
        {
            tr.slip_onset_step = Some(st(t0.min(td)));
        }
        // All four cups seal on the object.
        tr.contact = vec![true; 4];
        let lcfg = LabelConfig {
            sequence_len: steps,
            ..LabelConfig::default()
        };
        let l = label_annotated(&tr, &lcfg);
        if !l.steps.is_empty() {
            let mut v = vec![None; steps];
            for (j, s) in l.steps.iter().enumerate() {
                v[l.seq_start + j] = Some(*s);
            }
            tr.step_labels = Some(v);
        }
        let e = &mut tr.extra;
        e.insert(
            "sim_intent".into(),
            if p.drop_intent { "drop" } else { "hold" }.into(),
        );
        e.insert("sim_mass_kg".into(), format!("{:.4}", p.mass_kg));
        e.insert("sim_supply_kpa".into(), format!("{:.2}", p.supply_kpa));
        let cups = |m: [bool; 4]| {
            (0..4)
                .filter(|&c| m[c])
                .map(|c| format!("c{c}"))
                .collect::<Vec<_>>()
                .join("+")
        };
        if let Some((m, t0, ..)) = p.leak {
            e.insert(
                "sim_leak".into(),
                format!("leak on {} from step {}", cups(m), st(t0)),
            );
        }
        if let Some((m, t0, ..)) = p.deformation {
            e.insert(
                "sim_deformation".into(),
                format!("deformation on {} at step {}", cups(m), st(t0)),
            );
        }
        tr
    };
    let rate_lo = cfg.rate_hz / cfg.decimate as f64;
    (make(hi, cfg.rate_hz, "71hz"), make(lo, rate_lo, "17hz"))
}
