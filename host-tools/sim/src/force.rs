//! Fingertip force simulator: 16 piezo-resistive pads (4 fingers × 4 pads), one
//! object held by friction, lifted with an acceleration pulse.
//!
//! Physics (all in SI inside, mN at the output; docs/simulator.md has the
//! equations and parameter ranges):
//! * grip normal force `N(t)`: first-order closing from first contact, a slow
//!   squeeze increase during the lift, opening at release;
//! * tangential load `T(t) = m (g + a(t))`, taken over from the table during
//!   the first 0.3 s of the lift; `a(t)` a raised-cosine pulse up, later a smaller
//!   one down;
//! * friction capacity `μ_eff N` with `μ_eff = μ_s (1 − λ s/L)`: the contact
//!   shrinks as the object slides out by `s` (contact length `L`);
//! * load ratio `ρ = T / (μ_eff N)`: stick below `ρ_ss = 0.85`; stick-slip
//!   (micro-slip at 3–5 Hz, pad force dips, slip creeps at `v0·x`) for
//!   `ρ_ss ≤ ρ < 1`; gross slip at `ρ ≥ 1` with kinetic friction `0.75 μ_s`, the
//!   object accelerating until `s ≥ L`, when it is lost (drop);
//! * contact redistribution without slip during the lift (false-alarm case);
//! * after a drop the fingers may close on each other (a pad far off the object
//!   reads 7–25 N), as in the real failures;
//! * sensor: per-pad gain, shear cross-talk, 20 ms first-order response,
//!   noise (10 mN + 1 %), idle-pad spikes, saturation at full scale, 12-bit ADC,
//!   repeated rows.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

use crate::{adc, normal, trial_rng, uniform};

/// The paper's (and the real trials') rate in f64, the simulator's time base.
pub const PAPER_RATE_HZ: f64 = EAGLE_RATE_MHZ as f64 / 1000.0;
use slipguard_data::eagle::EAGLE_RATE_MHZ;
use slipguard_data::labels::{LabelConfig, label_annotated};
use slipguard_data::trial::{Outcome, PhaseMarks, SensorKind, Trial, Unit};

const G: f64 = 9.81;
/// Onset of stick-slip as a fraction of the friction capacity.
pub const RHO_STICK_SLIP: f64 = 0.85;
/// Load ratio above which the stuck zone erodes (viscoelastic creep of the pad).
pub const EROSION_ONSET: f64 = 0.5;
/// Kinetic / static friction ratio.
pub const KINETIC_RATIO: f64 = 0.75;
/// Loss of friction capacity at full slide-out (`λ`).
pub const AREA_LOSS: f64 = 0.6;
/// Time constant of the force decay once the object has left the fingers (s).
pub const LOSS_TAU_S: f64 = 0.06;
/// Internal integration rate.
pub const INTERNAL_HZ: f64 = 1000.0;

/// Which outcome the drawn parameters aim for (physics decides the real one).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Intent {
    /// Comfortable grip (`ρ_hold` 0.25–0.6).
    Hold,
    /// Marginal grip (`ρ_hold` 0.86–0.97) with a weak squeeze: slips and drops.
    Drop,
}

/// Sensor and batch settings.
#[derive(Debug, Clone, PartialEq)]
pub struct ForceSimConfig {
    pub rate_hz: f64,
    pub duration_s: f64,
    pub n_channels: usize,
    pub full_scale_mn: f64,
    pub adc_bits: u32,
    /// Noise of a loaded pad: `noise_floor_mn + noise_rel * F` (1 σ).
    pub noise_floor_mn: f64,
    pub noise_rel: f64,
    /// Probability that an idle pad shows a spike in a sample, and the spike scale.
    pub idle_spike_prob: f64,
    pub idle_spike_mn: f64,
    /// Probability that a whole row repeats the previous one.
    pub repeat_prob: f64,
    /// Probability of a contact redistribution during the lift.
    pub redistribution_prob: f64,
    /// Probability that the fingers close on each other after a drop.
    pub squeeze_prob: f64,
    /// Pad response time constant (s).
    pub sensor_tau_s: f64,
}

impl Default for ForceSimConfig {
    fn default() -> Self {
        ForceSimConfig {
            rate_hz: PAPER_RATE_HZ,
            duration_s: 400.0 / PAPER_RATE_HZ,
            n_channels: 16,
            full_scale_mn: 33_000.0,
            adc_bits: 12,
            noise_floor_mn: 10.0,
            noise_rel: 0.01,
            idle_spike_prob: 0.06,
            idle_spike_mn: 120.0,
            repeat_prob: 0.07,
            redistribution_prob: 0.35,
            squeeze_prob: 0.5,
            sensor_tau_s: 0.02,
        }
    }
}

impl ForceSimConfig {
    /// Same physics sampled at another rate (e.g. 40 Hz, DoraHand), same duration.
    pub fn at_rate(rate_hz: f64) -> Self {
        ForceSimConfig {
            rate_hz,
            ..Default::default()
        }
    }

    /// Number of output samples.
    pub fn n_steps(&self) -> usize {
        (self.duration_s * self.rate_hz).round() as usize
    }
}

/// The drawn physical parameters of one trial (kept in `Trial::extra` as `sim_*`).
#[derive(Debug, Clone, PartialEq)]
pub struct ForceParams {
    pub intent: Intent,
    pub mass_kg: f64,
    pub mu_s: f64,
    /// Load ratio at a static hold without squeeze: `m g / (μ_s N_grip)`.
    pub rho_hold: f64,
    pub grip_n: f64,
    pub contacts: Vec<usize>,
    pub shares: Vec<f64>,
    pub gains: Vec<f64>,
    /// Shear cross-talk: fraction of the tangential load a pad reads.
    pub shear_coupling: f64,
    pub t_grasp: f64,
    pub t_contact: f64,
    pub close_tau: f64,
    pub t_lift: f64,
    pub t_open_mark: f64,
    pub t_release: f64,
    pub lift_accel: f64,
    pub accel_dur: f64,
    pub cruise_dur: f64,
    pub squeeze_gain: f64,
    pub stick_slip_hz: f64,
    pub vib_amp: f64,
    pub creep_mm_s: f64,
    /// Erosion rate of the stuck zone (1/s per unit of load ratio above 0.5).
    pub erosion_rate: f64,
    pub contact_len_mm: f64,
    pub wedge: f64,
    /// (channel, start time, factor) of a contact redistribution.
    pub redistribution: Option<(usize, f64, f64)>,
    /// (channel, force mN, start offset after the open mark, duration) of a finger squeeze.
    pub squeeze: Option<(usize, f64, f64, f64)>,
}

impl ForceParams {
    /// Draw parameters for `intent`.
    pub fn draw(rng: &mut ChaCha8Rng, intent: Intent, cfg: &ForceSimConfig) -> Self {
        let nch = cfg.n_channels;
        // Contact pads: first pads of fingers 0-2 (as in most real top/right
        // trials), or a random set of 1-5 pads.
        let contacts: Vec<usize> = if rng.random_bool(0.55) && nch >= 9 {
            let mut c = vec![0, 4, 8];
            let k = rng.random_range(2..=3);
            while c.len() > k {
                let i = rng.random_range(0..c.len());
                c.remove(i);
            }
            c
        } else {
            let k = rng.random_range(1..=5usize.min(nch));
            let mut c: Vec<usize> = Vec::new();
            while c.len() < k {
                let ch = rng.random_range(0..nch);
                if !c.contains(&ch) {
                    c.push(ch);
                }
            }
            c.sort_unstable();
            c
        };
        let raw: Vec<f64> = contacts
            .iter()
            .map(|_| uniform(rng, 0.15, 1.0).powi(2))
            .collect();
        let sum: f64 = raw.iter().sum();
        let shares = raw.iter().map(|w| w / sum).collect();
        let gains = (0..nch).map(|_| uniform(rng, 0.8, 1.2)).collect();
        let mass_kg = uniform(rng, 0.05, 0.5);
        let mu_s = uniform(rng, 0.4, 1.0);
        let lift_accel = uniform(rng, 1.5, 4.0);
        // Drop: the lift pulse brings the load ratio to 0.80-0.97 (stick-slip
        // zone, not yet gross slip); erosion of the stuck zone does the rest.
        let (rho_hold, squeeze_gain) = match intent {
            Intent::Hold => (uniform(rng, 0.25, 0.5), uniform(rng, 0.0, 0.6)),
            Intent::Drop => (
                uniform(rng, 0.81, 0.87) / (1.0 + lift_accel / G),
                uniform(rng, 0.0, 0.1),
            ),
        };
        let grip_n = mass_kg * G / (mu_s * rho_hold);
        let t_grasp = uniform(rng, 1.1, 4.2);
        let t_contact = t_grasp + uniform(rng, 0.3, 1.2);
        let t_lift = t_contact + uniform(rng, 1.2, 1.9);
        let open_steps = match intent {
            Intent::Drop => 50.0,
            Intent::Hold => [16.0, 33.0, 50.0][rng.random_range(0..3)],
        };
        let t_open_mark = t_lift + open_steps / PAPER_RATE_HZ;
        let t_release = t_lift + uniform(rng, 6.9, 8.5);
        let redistribution = (rng.random_bool(cfg.redistribution_prob) && contacts.len() >= 2)
            .then(|| {
                let ch = contacts[rng.random_range(0..contacts.len())];
                (ch, t_lift + uniform(rng, 0.3, 2.0), uniform(rng, 0.0, 0.15))
            });
        let squeeze = (intent == Intent::Drop && rng.random_bool(cfg.squeeze_prob)).then(|| {
            let free: Vec<usize> = (0..nch).filter(|c| !contacts.contains(c)).collect();
            let ch = if free.contains(&9) && rng.random_bool(0.5) {
                9
            } else {
                free[rng.random_range(0..free.len())]
            };
            (
                ch,
                uniform(rng, 7_000.0, 25_000.0),
                uniform(rng, 0.0, 0.5),
                uniform(rng, 0.8, 4.0),
            )
        });
        ForceParams {
            intent,
            mass_kg,
            mu_s,
            rho_hold,
            grip_n,
            contacts,
            shares,
            gains,
            shear_coupling: uniform(rng, 0.0, 0.3),
            t_grasp,
            t_contact,
            close_tau: uniform(rng, 0.3, 0.6),
            t_lift,
            t_open_mark,
            t_release,
            lift_accel,
            accel_dur: uniform(rng, 0.5, 1.0),
            cruise_dur: uniform(rng, 1.0, 2.0),
            squeeze_gain,
            stick_slip_hz: uniform(rng, 3.0, 5.0),
            vib_amp: uniform(rng, 0.15, 0.35),
            creep_mm_s: uniform(rng, 6.0, 14.0),
            erosion_rate: uniform(rng, 0.55, 0.8),
            contact_len_mm: uniform(rng, 10.0, 25.0),
            wedge: uniform(rng, 0.0, 0.5),
            redistribution,
            squeeze,
        }
    }

    /// Hand acceleration (m/s², up positive) at time `t`.
    pub fn accel(&self, t: f64) -> f64 {
        let up = t - self.t_lift;
        let down = up - self.accel_dur - self.cruise_dur;
        let pulse = |x: f64| {
            if (0.0..self.accel_dur).contains(&x) {
                (std::f64::consts::PI * x / self.accel_dur).sin().powi(2)
            } else {
                0.0
            }
        };
        self.lift_accel * pulse(up) - 0.7 * self.lift_accel * pulse(down)
    }

    /// Grip normal force (N) commanded by the hand at `t` (no slip effects).
    pub fn grip(&self, t: f64) -> f64 {
        if t < self.t_contact {
            return 0.0;
        }
        let mut n = self.grip_n * (1.0 - (-(t - self.t_contact) / self.close_tau).exp());
        if t > self.t_lift {
            n *= 1.0 + self.squeeze_gain * (1.0 - (-(t - self.t_lift) / 1.0).exp());
        }
        if t > self.t_release {
            n *= (-(t - self.t_release) / 0.08).exp();
        }
        n
    }

    /// Tangential load (N) the fingers must carry at `t`.
    pub fn load(&self, t: f64) -> f64 {
        if t < self.t_lift || t > self.t_release {
            return 0.0;
        }
        let x = ((t - self.t_lift) / 0.3).clamp(0.0, 1.0);
        let take_over = x * x * (3.0 - 2.0 * x);
        self.mass_kg * (G + self.accel(t)) * take_over
    }
}

/// Noise-free simulation result at the internal rate.
#[derive(Debug, Clone)]
pub struct ForceTruth {
    /// Pad forces (mN) at the internal rate, channel-major.
    pub pads: Vec<Vec<f64>>,
    /// Load ratio ρ per internal tick.
    pub rho: Vec<f64>,
    /// Slip displacement (mm) per tick.
    pub slip_mm: Vec<f64>,
    pub t_slip_onset: Option<f64>,
    pub t_gross_slip: Option<f64>,
    pub t_loss: Option<f64>,
}

/// The friction state of the held object (docs/simulator.md), advanced one 1 kHz tick at a
/// time. The one home of the slip physics: [`integrate`] steps it with the trial's grip
/// schedule, the closed loop with its controller's grip.
#[derive(Clone, Debug, Default)]
pub struct Contact {
    /// Slide of the object along the pads (mm).
    pub slip_mm: f64,
    v_mm_s: f64,
    phase: f64,
    /// In gross slip (kinetic friction).
    pub gross: bool,
    erosion: f64,
    /// Time the object was lost.
    pub t_loss: Option<f64>,
    n_at_loss: f64,
    /// Load ratio of the last tick before the loss.
    pub rho: f64,
    /// Time incipient slip (ρ ≥ [`RHO_STICK_SLIP`]) was first reached.
    pub t_slip: Option<f64>,
    /// Start of the last gross slip.
    pub t_gross: Option<f64>,
}

impl Contact {
    /// One tick at time `t` (s) with grip `grip` (N), tangential load `load` (N), object mass
    /// `mass_kg` and friction factor `mu_factor` (1 = the drawn μ_s); returns the normal force
    /// the pads read (N).
    pub fn tick(
        &mut self,
        p: &ForceParams,
        t: f64,
        grip: f64,
        load: f64,
        mass_kg: f64,
        mu_factor: f64,
    ) -> f64 {
        let dt = 1.0 / INTERNAL_HZ;
        if let Some(tl) = self.t_loss {
            return self.n_at_loss * (-(t - tl) / LOSS_TAU_S).exp();
        }
        let frac = (self.slip_mm / p.contact_len_mm).min(1.0);
        let mu_eff = p.mu_s * (1.0 - AREA_LOSS * frac) * (1.0 - self.erosion) * mu_factor;
        let cap = mu_eff * grip;
        let rho = if cap > 0.0 { load / cap } else { 0.0 };
        self.rho = rho;
        let mut factor = 1.0; // reading factor from slip and vibration
        if load > 0.0 {
            self.erosion =
                (self.erosion + p.erosion_rate * (rho - EROSION_ONSET).max(0.0) * dt).min(0.5);
            if rho >= RHO_STICK_SLIP {
                self.t_slip.get_or_insert(t);
            }
        }
        if !self.gross && load > 0.0 && rho >= 1.0 {
            self.gross = true;
            self.t_gross = Some(t);
        }
        if self.gross {
            let kin = KINETIC_RATIO * mu_eff * grip;
            let acc = (load - kin) / mass_kg * 1000.0; // mm/s²
            self.v_mm_s = (self.v_mm_s + acc * dt).max(0.0);
            if self.v_mm_s == 0.0 && acc <= 0.0 {
                self.gross = false; // re-stick
            }
            self.slip_mm += self.v_mm_s * dt;
            let w = 1.0 + p.wedge * (std::f64::consts::PI * frac).sin();
            factor = (1.0 - 0.5 * frac) * w;
        } else if load > 0.0 && rho >= RHO_STICK_SLIP {
            let x = ((rho - RHO_STICK_SLIP) / (1.0 - RHO_STICK_SLIP)).clamp(0.0, 1.0);
            self.phase += p.stick_slip_hz * dt;
            let cyc = 0.5 * (1.0 - (2.0 * std::f64::consts::PI * self.phase).cos());
            // Slip happens in the release part of each cycle.
            self.slip_mm += p.creep_mm_s * x * 2.0 * cyc * dt;
            factor = 1.0 - p.vib_amp * x * cyc;
        }
        if self.slip_mm >= p.contact_len_mm {
            self.t_loss = Some(t);
            self.n_at_loss = grip * factor;
        }
        grip * factor
    }
}

/// Integrate the physics at 1 kHz.
pub fn integrate(p: &ForceParams, cfg: &ForceSimConfig) -> ForceTruth {
    let dt = 1.0 / INTERNAL_HZ;
    let n = (cfg.duration_s * INTERNAL_HZ).ceil() as usize + 1;
    let nch = cfg.n_channels;
    let mut pads = vec![vec![0.0; n]; nch];
    let mut rho_v = vec![0.0; n];
    let mut slip_v = vec![0.0; n];
    let mut contact = Contact::default();
    let mut shares = p.shares.clone();
    let base_shares = p.shares.clone();
    let mut lag = vec![0.0; nch];
    let alpha = dt / (cfg.sensor_tau_s + dt);
    for (i, (rho_out, slip_out)) in rho_v.iter_mut().zip(slip_v.iter_mut()).enumerate() {
        let t = i as f64 * dt;
        let grip = p.grip(t);
        let load = p.load(t);
        let lost = contact.t_loss.is_some();
        let normal_n = contact.tick(p, t, grip, load, p.mass_kg, 1.0);
        if !lost {
            *rho_out = contact.rho;
        }
        *slip_out = contact.slip_mm;
        // Contact redistribution (no slip): one pad unloads over 0.3 s, the others take it.
        if let Some((ch, t0, f)) = p.redistribution {
            let k = p.contacts.iter().position(|&c| c == ch).expect("contact");
            let x = ((t - t0) / 0.3).clamp(0.0, 1.0);
            let w = base_shares[k] * (1.0 - (1.0 - f) * x);
            let rest: f64 = base_shares
                .iter()
                .enumerate()
                .filter(|&(j, _)| j != k)
                .map(|(_, w)| w)
                .sum();
            for j in 0..shares.len() {
                shares[j] = if j == k {
                    w
                } else {
                    base_shares[j] * (1.0 - w) / rest
                };
            }
        }
        let normal_mn = normal_n * 1000.0;
        let shear_mn = if lost {
            0.0
        } else {
            load * 1000.0 * p.shear_coupling
        };
        for (k, &ch) in p.contacts.iter().enumerate() {
            let f = shares[k] * (normal_mn + shear_mn) * p.gains[ch];
            lag[ch] += alpha * (f - lag[ch]);
        }
        if let Some((ch, f, off, dur)) = p.squeeze
            && let Some(tl) = contact.t_loss
        {
            let t0 = p.t_open_mark.max(tl + 0.5) + off;
            let target = if t >= t0 && t < t0 + dur { f } else { 0.0 };
            lag[ch] += (dt / (0.1 + dt)) * (target - lag[ch]);
        }
        for ch in 0..nch {
            pads[ch][i] = lag[ch];
        }
    }
    ForceTruth {
        pads,
        rho: rho_v,
        slip_mm: slip_v,
        t_slip_onset: contact.t_slip,
        t_gross_slip: contact.t_gross,
        t_loss: contact.t_loss,
    }
}

/// Simulate trial `index` of `seed` with the given intent (or drawn with
/// probability `failure_share` if `None`).
pub fn simulate_trial(
    seed: u64,
    index: u64,
    intent: Option<Intent>,
    failure_share: f64,
    cfg: &ForceSimConfig,
) -> Trial {
    let mut rng = trial_rng(seed, index);
    let intent = intent.unwrap_or_else(|| {
        if rng.random_bool(failure_share.clamp(0.0, 1.0)) {
            Intent::Drop
        } else {
            Intent::Hold
        }
    });
    let p = ForceParams::draw(&mut rng, intent, cfg);
    let truth = integrate(&p, cfg);
    sample(&p, &truth, cfg, &mut rng, seed, index)
}

/// Drop step as the labeller defines it, on the noise-free contact sum: the
/// first step after the loss at which it is below 5 % of its peak since lift start.
fn drop_step(p: &ForceParams, truth: &ForceTruth, t_loss: f64, rate: f64) -> usize {
    let sum = |i: usize| p.contacts.iter().map(|&c| truth.pads[c][i]).sum::<f64>();
    let i_lift = (p.t_lift * INTERNAL_HZ) as usize;
    let i_loss = (t_loss * INTERNAL_HZ) as usize;
    let peak = (i_lift..=i_loss).map(sum).fold(0.0, f64::max);
    let last = truth.pads[0].len() - 1;
    let mut k = step_of(t_loss, rate);
    loop {
        let i = (((k as f64) / rate) * INTERNAL_HZ).round() as usize;
        if i >= last || sum(i) < 0.05 * peak {
            return k;
        }
        k += 1;
    }
}

fn step_of(t: f64, rate: f64) -> usize {
    (t * rate).ceil() as usize
}

fn sample(
    p: &ForceParams,
    truth: &ForceTruth,
    cfg: &ForceSimConfig,
    rng: &mut ChaCha8Rng,
    seed: u64,
    index: u64,
) -> Trial {
    let n = cfg.n_steps();
    let nch = cfg.n_channels;
    let last = truth.pads[0].len() - 1;
    let mut rows: Vec<Vec<f32>> = Vec::with_capacity(n);
    for k in 0..n {
        if let Some(pr) = rows.last()
            && rng.random_bool(cfg.repeat_prob)
        {
            rows.push(pr.clone());
            continue;
        }
        let i = ((k as f64 / cfg.rate_hz) * INTERNAL_HZ).round() as usize;
        let i = i.min(last);
        let row: Vec<f32> = (0..nch)
            .map(|ch| {
                let f = truth.pads[ch][i];
                let x = if f > 1.0 {
                    f + normal(rng) * (cfg.noise_floor_mn + cfg.noise_rel * f)
                } else if rng.random_bool(cfg.idle_spike_prob) {
                    (normal(rng) * cfg.idle_spike_mn).abs()
                } else {
                    0.0
                };
                adc(x, cfg.full_scale_mn, cfg.adc_bits)
            })
            .collect();
        rows.push(row);
    }
    let samples: Vec<Vec<f32>> = (0..nch)
        .map(|ch| rows.iter().map(|r| r[ch]).collect())
        .collect();
    let rate = cfg.rate_hz;
    let clamp = |s: usize| s.min(n - 1);
    let outcome = if truth.t_loss.is_some() {
        Outcome::Failure
    } else {
        Outcome::Success
    };
    let mut trial = Trial::new(
        format!("sim-force-{seed}-{index:04}"),
        Unit::MilliNewton,
        rate as f32,
        samples,
    );
    trial.sensor = SensorKind::Force;
    trial.source = format!("slipguard simulate force seed={seed} index={index} rate_hz={rate}");
    trial.marks = PhaseMarks {
        grasp_start: Some(clamp(step_of(p.t_grasp, rate))),
        lift_start: Some(clamp(step_of(p.t_lift, rate))),
        open_start: Some(clamp(step_of(p.t_open_mark, rate))),
        release: None,
    };
    trial.outcome = outcome;
    trial.drop_step = truth.t_loss.map(|t| clamp(drop_step(p, truth, t, rate)));
    trial.slip_onset_step = match outcome {
        Outcome::Failure => truth.t_slip_onset.map(|t| clamp(step_of(t, rate))),
        _ => None,
    };
    let mut contact = vec![false; nch];
    for &c in &p.contacts {
        contact[c] = true;
    }
    trial.contact = contact;
    let lcfg = LabelConfig::default().scaled_to(rate as f32);
    let labels = label_annotated(&trial, &lcfg);
    if !labels.steps.is_empty() {
        let mut v = vec![None; n];
        for (j, l) in labels.steps.iter().enumerate() {
            v[labels.seq_start + j] = Some(*l);
        }
        trial.step_labels = Some(v);
    }
    let e = &mut trial.extra;
    let f = |x: f64| format!("{x:.4}");
    e.insert(
        "sim_intent".into(),
        format!("{:?}", p.intent).to_lowercase(),
    );
    e.insert("sim_mass_kg".into(), f(p.mass_kg));
    e.insert("sim_mu_s".into(), f(p.mu_s));
    e.insert("sim_rho_hold".into(), f(p.rho_hold));
    e.insert("sim_grip_n".into(), f(p.grip_n));
    e.insert("sim_lift_accel".into(), f(p.lift_accel));
    e.insert("sim_stick_slip_hz".into(), f(p.stick_slip_hz));
    e.insert(
        "sim_contacts".into(),
        format!("{:?}", p.contacts).replace(' ', ""),
    );
    e.insert(
        "sim_rho_max".into(),
        f(truth.rho.iter().copied().fold(0.0, f64::max)),
    );
    e.insert(
        "sim_slip_mm".into(),
        f(*truth.slip_mm.last().unwrap_or(&0.0)),
    );
    if let Some((ch, t0, _)) = p.redistribution {
        e.insert(
            "sim_redistribution".into(),
            format!("c{ch} at {}", clamp(step_of(t0, rate))),
        );
    }
    if let Some(t) = truth.t_gross_slip {
        e.insert(
            "sim_gross_slip_step".into(),
            clamp(step_of(t, rate)).to_string(),
        );
    }
    trial
}

/// Simulate `count` trials; `progress` is called after each.
pub fn simulate_batch(
    seed: u64,
    count: usize,
    failure_share: f64,
    cfg: &ForceSimConfig,
    mut progress: impl FnMut(usize),
) -> Vec<Trial> {
    (0..count)
        .map(|i| {
            let t = simulate_trial(seed, i as u64, None, failure_share, cfg);
            progress(i + 1);
            t
        })
        .collect()
}
