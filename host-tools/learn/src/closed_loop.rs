//! Closed-loop grasp simulation: a hand lifts an object with a deliberately light grip, the
//! firmware (the real front end and app of `slipguard-app`, bit-exact model included) watches
//! the fingertip forces, and a grip controller raises the grip by a fixed step every time a
//! flag frame says "unstable", with the firmware's real latency. The paper's DoraHand tests
//! (section III.C): heavy object, sudden added weight, gradually added weight, in-hand rotation.
//!
//! Physics: the force simulator's friction model, stepped tick by tick
//! (`slipguard_sim::force::Contact`, docs/simulator.md), with the same drawn object/hand
//! parameters (`ForceParams::draw`: contact pads, shares, gains, μ_s, lift pulse via
//! `ForceParams::accel`, stick-slip, creep, erosion, contact length, wedging). What differs is
//! that the grip is an input (the controller's) and the load, mass and friction follow the
//! situation. docs/integration.md ("closed loop")
//! documents the situations, the controller and the results.

use rand::Rng;
use rand_chacha::ChaCha8Rng;
use slipguard_core::units::Millihertz;

use slipguard_app::MAX_CHANNELS;
use slipguard_app::app::App;
use slipguard_app::decimate::RATIO;
use slipguard_app::frontend::Frontend;
use slipguard_app::profile::{AdcCode, Profile};
use slipguard_core::decision::Q15;
use slipguard_core::protocol::{self, Command, Deframer, Frame, MAX_WIRE, Message, status};
use slipguard_core::sample::PAPER_RATE_MHZ;

use crate::evaluation::Sequence;
pub use slipguard_sim::force::Contact;
use slipguard_sim::force::{ForceParams, ForceSimConfig, INTERNAL_HZ, Intent, RHO_STICK_SLIP};
use slipguard_sim::{normal, trial_rng, uniform};

const G: f64 = 9.81;

/// Trial length (s).
pub const DURATION_S: f64 = 8.0;
/// Fingers touch the object.
pub const T_CONTACT_S: f64 = 0.3;
/// Lift starts.
pub const T_LIFT_S: f64 = 1.5;
/// Grip actuator time constant (s): the grip force follows the commanded one to first order.
pub const ACTUATOR_TAU_S: f64 = 0.08;
/// Strongest grip the hand can apply (N).
pub const MAX_GRIP_N: f64 = 40.0;
/// UART speed (docs/protocol.md), for the transmission time of a frame.
pub const BAUD: f64 = 921_600.0;
/// Wire time of a 16-channel flag frame (56 bytes, 10 bits each at [`BAUD`]): 0.61 ms.
pub const FLAG_FRAME_S: f64 = 56.0 * 10.0 / BAUD;
/// Modelled `App::infer` time of one frame with all 16 channels of the hand profile in contact
/// (the worst case: the firmware runs the model only on the channels in contact) on the 168 MHz
/// STM32F405: 42.9 % of a 40 Hz period in estimated Cortex-M4 cycles (`scripts/budgets.sh`, the
/// cycle model with flash wait states and the flash's fetch bandwidth), 1.803 M cycles =
/// 10.7 ms (11.0 ms with sequential fetch free and the earlier straight-line LSTM kernel). The
/// firmware infers a frame as soon as its last scan is in and sends it right after
/// (`firmware/src/main.rs`). `scripts/budgets.sh` prints this value beside its estimate and
/// says when they part by > 5 %.
pub const INFERENCE_S: f64 = 0.0107;

/// When a frame's flags reach the controller, counted from the frame's last sample.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Latency {
    /// The firmware's deadline, the bound docs/protocol.md guarantees: one period + the frame's
    /// wire time. The closed-loop training chains of `models/hand-force-40hz` ran with it.
    Deadline,
    /// As the firmware runs: inference of this many seconds (at most one period: a frame that
    /// would take longer is late and goes out at the deadline) + the frame's wire time.
    Inference(f64),
}

impl Latency {
    /// The firmware as modelled: [`INFERENCE_S`].
    pub const MODELLED: Latency = Latency::Inference(INFERENCE_S);

    /// Seconds from a frame's last sample to its arrival at the controller, at `period_s`.
    pub fn delay_s(self, period_s: f64) -> f64 {
        let compute = match self {
            Latency::Deadline => period_s,
            Latency::Inference(s) => s.clamp(0.0, period_s),
        };
        compute + FLAG_FRAME_S
    }
}

/// The paper's four test situations.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Situation {
    /// Grasp a heavy item with an initial light force.
    Heavy,
    /// A light item suddenly gains weight.
    SuddenWeight,
    /// Weight is added gradually.
    GradualWeight,
    /// The item is rotated inside the hand.
    Rotation,
}

impl Situation {
    /// All four, in the paper's order.
    pub const ALL: [Situation; 4] = [
        Situation::Heavy,
        Situation::SuddenWeight,
        Situation::GradualWeight,
        Situation::Rotation,
    ];

    /// Short name.
    pub fn name(self) -> &'static str {
        match self {
            Situation::Heavy => "heavy",
            Situation::SuddenWeight => "sudden-weight",
            Situation::GradualWeight => "gradual-weight",
            Situation::Rotation => "rotation",
        }
    }
}

/// One drawn trial: object, hand and situation parameters.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Situation.
    pub situation: Situation,
    /// Object and hand parameters from the force simulator (its timing fields are overwritten:
    /// contact at [`T_CONTACT_S`], lift at [`T_LIFT_S`]).
    pub p: ForceParams,
    /// Mass the grip was set for (kg).
    pub nominal_mass_kg: f64,
    /// Initial (light) grip (N): `nominal mass · g / (μ_s · ρ0)`, ρ0 U(0.35, 0.45).
    pub initial_grip_n: f64,
    /// Mass of the object at the start (kg).
    pub mass_kg: f64,
    /// Added mass (kg) and when (s) / over how long (s; 0 = at once).
    pub added: Option<(f64, f64, f64)>,
    /// In-hand rotation: start (s), duration (s), extra tangential load as a fraction of m·g
    /// and loss of friction capacity (fraction) at mid-rotation, both rising and falling as
    /// sin(π τ / duration).
    pub rotation: Option<(f64, f64, f64, f64)>,
}

impl Scenario {
    /// Draws trial `index` of `seed` for `situation`.
    pub fn draw(seed: u64, index: u64, situation: Situation) -> Self {
        let mut rng = trial_rng(seed, 0x5EED_0000 + 10_000 * situation as u64 + index);
        let cfg = ForceSimConfig::default();
        let mut p = ForceParams::draw(&mut rng, Intent::Hold, &cfg);
        p.t_grasp = 0.0;
        p.t_contact = T_CONTACT_S;
        p.t_lift = T_LIFT_S;
        p.t_open_mark = DURATION_S;
        p.t_release = DURATION_S + 1.0;
        p.redistribution = None;
        p.squeeze = None;
        let a_peak = p.lift_accel;
        let rho0 = uniform(&mut rng, 0.35, 0.45);
        if situation == Situation::Rotation {
            // "Grasping something with low friction".
            p.mu_s = uniform(&mut rng, 0.3, 0.5);
        }
        let nominal = p.mass_kg;
        let grip = nominal * G / (p.mu_s * rho0);
        // Mass giving load ratio `rho` at the initial grip under acceleration `a`.
        let mass_for = |rho: f64, a: f64| rho * p.mu_s * grip / (G + a);
        let (mut mass, mut added, mut rotation) = (nominal, None, None);
        match situation {
            Situation::Heavy => mass = mass_for(uniform(&mut rng, 0.86, 0.97), a_peak),
            Situation::SuddenWeight => {
                let m1 = mass_for(uniform(&mut rng, 0.84, 0.94), 0.0);
                added = Some((m1 - nominal, uniform(&mut rng, 3.5, 4.5), 0.0));
            }
            Situation::GradualWeight => {
                let m1 = mass_for(uniform(&mut rng, 1.0, 1.2), 0.0);
                added = Some((
                    m1 - nominal,
                    uniform(&mut rng, 3.2, 3.8),
                    uniform(&mut rng, 2.5, 3.5),
                ));
            }
            Situation::Rotation => {
                // Load ratio at mid-rotation U(0.92, 1.05) at the initial grip.
                let (t0, dur) = (uniform(&mut rng, 3.5, 4.5), uniform(&mut rng, 1.5, 2.5));
                let loss = uniform(&mut rng, 0.3, 0.45);
                let peak = uniform(&mut rng, 0.92, 1.05);
                let extra = (peak * (1.0 - loss) / rho0 - 1.0).max(0.0);
                rotation = Some((t0, dur, extra, loss));
            }
        }
        p.mass_kg = mass;
        Scenario {
            situation,
            p,
            nominal_mass_kg: nominal,
            initial_grip_n: grip,
            mass_kg: mass,
            added,
            rotation,
        }
    }

    /// Mass at `t` (kg).
    pub fn mass(&self, t: f64) -> f64 {
        match self.added {
            Some((dm, t0, dur)) if t >= t0 => {
                let x = if dur > 0.0 {
                    ((t - t0) / dur).min(1.0)
                } else {
                    1.0
                };
                self.mass_kg + dm * x
            }
            _ => self.mass_kg,
        }
    }

    /// Tangential load (N) at `t`: weight and lift acceleration (the force simulator's pulse and
    /// table take-over), an impact when weight drops in at once, the rotation's extra load.
    pub fn load(&self, t: f64) -> f64 {
        if t < self.p.t_lift {
            return 0.0;
        }
        let x = ((t - self.p.t_lift) / 0.3).clamp(0.0, 1.0);
        let take_over = x * x * (3.0 - 2.0 * x);
        let mut l = self.mass(t) * (G + self.p.accel(t)) * take_over;
        if let Some((dm, t0, 0.0)) = self.added
            && t >= t0
        {
            // The added weight lands: 10 % overshoot decaying in 30 ms.
            l += dm * G * 0.1 * (-(t - t0) / 0.03).exp();
        }
        if let Some((t0, dur, extra, _)) = self.rotation
            && (t0..t0 + dur).contains(&t)
        {
            let s = (std::f64::consts::PI * (t - t0) / dur).sin();
            l += extra * self.mass_kg * G * s;
        }
        l
    }

    /// Friction factor of the rotation (rolling contact, finger gaiting) at `t`.
    pub fn mu_factor(&self, t: f64) -> f64 {
        match self.rotation {
            Some((t0, dur, _, loss)) if (t0..t0 + dur).contains(&t) => {
                1.0 - loss * (std::f64::consts::PI * (t - t0) / dur).sin().powi(2)
            }
            _ => 1.0,
        }
    }

    /// One 1 kHz tick of the slip physics at `t` with the controller's grip `grip` (N);
    /// returns (normal force the pads read (N), tangential load carried (N)).
    pub fn tick(&self, contact: &mut Contact, t: f64, grip: f64) -> (f64, f64) {
        let lost = contact.t_loss.is_some();
        let load = self.load(t);
        let normal = contact.tick(&self.p, t, grip, load, self.mass(t), self.mu_factor(t));
        (normal, if lost { 0.0 } else { load })
    }
}

/// Where the controller's "unstable" information comes from.
#[derive(Clone, Copy, Debug)]
pub enum FlagSource<'a> {
    /// No prediction: the grip stays at its initial value.
    Off,
    /// The firmware with this model blob.
    Model(&'a [u8]),
    /// A perfect detector with the firmware's latency: "unstable" when the true load ratio at
    /// the last sample of the frame `delay_frames` before the one being sent was at or above
    /// the stick-slip onset (reference only; `delay_frames` > 0 shows what a detector that
    /// needs that many frames to see the slip could at best do).
    Oracle {
        /// Frames between the slip state and the frame that reports it.
        delay_frames: usize,
    },
    /// The hand-load rule ([`slipguard_core::decision::LoadRule`]) on the frames' model inputs
    /// behind the core's contact gate, from grasp start, flags sent like the firmware's (the
    /// same latency, though the rule costs a few hundred cycles where the model's frame costs
    /// the modelled inference).
    LoadRule {
        /// Fraction and window (frames at the source's rate).
        rule: slipguard_core::decision::LoadRule,
        /// The model's input scaling (mN → Q1.15).
        scale: slipguard_core::sample::InputScale,
        /// The contact gate on that scale.
        contact: slipguard_core::decision::ContactConfig,
    },
    /// The firmware with this model blob, its hand flag fused on the host with the hand-load
    /// rule ([`slipguard_core::decision::FusedHand`]: the rule at its fraction, OR the model's
    /// hand flag while the hand load is below the guard fraction of its peak).
    Fused {
        /// The model blob.
        blob: &'a [u8],
        /// Strict rule and guard.
        fused: slipguard_core::decision::FusedHand,
        /// The model's input scaling (mN → Q1.15).
        scale: slipguard_core::sample::InputScale,
        /// The contact gate on that scale.
        contact: slipguard_core::decision::ContactConfig,
    },
    /// Training-data teacher: the oracle's flags, each acted on with probability `act_prob`
    /// (slips caught late or not at all), so that recordings hold slips that recover as well
    /// as slips that end in a drop.
    Teacher {
        /// Probability that an unstable frame raises the grip.
        act_prob: f64,
        /// Rate (per second of grasp) of false-alarm bursts: 1–8 frames flagged unstable while
        /// nothing slips, so that recordings hold grip raises that follow no slip. A model
        /// trained without them takes the pad force rising under its own controller's raises
        /// for slip and keeps flagging, squeezing on to the hand's limit.
        false_alarm_hz: f64,
    },
}

/// Settings of the controller.
#[derive(Clone, Copy, Debug)]
pub struct ControllerConfig {
    /// Grip increase per unstable frame, as a fraction of the initial grip (the paper raised
    /// the joint currents by 5 and 10 mA from 25 and 50 mA: 20 %).
    pub step_fraction: f64,
    /// Frame rate (mHz): the model's.
    pub rate_mhz: Millihertz,
    /// Decision settings the controller sends with a set-threshold command right after grasp
    /// start (threshold Q0.15, raise after, clear after); `None` keeps the blob's.
    pub decision: Option<(u16, u8, u8)>,
    /// Flags are ignored for this long after grasp start (s): the model's state starts from
    /// zero at grasp start and its first frames are not predictions (0 = act on every flag).
    pub settle_s: f64,
    /// After a raise, further unstable frames are ignored for this long (s), so that the
    /// controller waits for its last step to reach the fingers (the actuator's time constant is
    /// [`ACTUATOR_TAU_S`]) before it steps again (0 = a step on every unstable frame).
    pub hold_off_s: f64,
    /// When the flags of a frame arrive.
    pub latency: Latency,
}

/// One sample of the trace (every 10 ms).
#[derive(Clone, Copy, Debug, Default)]
pub struct TracePoint {
    /// Time (s).
    pub t: f64,
    /// Grip force (N).
    pub grip: f64,
    /// Tangential load (N).
    pub load: f64,
    /// Sum of the pad readings (N).
    pub pads: f64,
    /// Load ratio.
    pub rho: f64,
}

/// One frame as the model sees it, recorded from grasp start on (training data).
#[derive(Clone, Copy, Debug)]
pub struct FrameRecord {
    /// Time of the frame's last sample (s).
    pub t: f64,
    /// Per-channel model input (mN, [`Profile::to_model_units`] of the front end's output).
    pub model_units: [i32; MAX_CHANNELS],
    /// True load ratio at the frame's last sample.
    pub rho: f64,
    /// Gross slip at the frame's last sample.
    pub gross: bool,
    /// The object is lost.
    pub lost: bool,
}

impl FrameRecord {
    /// Ground truth of the frame: incipient slip (ρ at or above the stick-slip onset), gross
    /// slip or loss. The oracle flags the first of these (ρ ≥ onset, object not yet lost).
    pub fn unstable(&self) -> bool {
        self.lost || self.gross || self.rho >= RHO_STICK_SLIP
    }
}

/// Outcome of one closed-loop trial.
#[derive(Clone, Debug, Default)]
pub struct Outcome {
    /// Object lost.
    pub dropped: bool,
    /// Time of the loss (s).
    pub t_drop: Option<f64>,
    /// Grip increases commanded.
    pub increases: u32,
    /// Commanded grip at the end (or at the drop), N.
    pub final_grip_n: f64,
    /// Initial grip, N.
    pub initial_grip_n: f64,
    /// Flag frames received with the hand flag up (armed).
    pub unstable_frames: u32,
    /// Flag frames received.
    pub flag_frames: u32,
    /// Fault frames received.
    pub fault_frames: u32,
    /// Times at which the grip was raised (s).
    pub raise_times: Vec<f64>,
    /// Trace every 10 ms.
    pub trace: Vec<TracePoint>,
    /// Every frame from grasp start on.
    pub frames: Vec<FrameRecord>,
}

/// Force a pad reads (mN) → ADC code of the hand profile with the force simulator's noise
/// (10 mN + 1 %) and ±1 LSB.
fn code(profile: &Profile, mn: f64, rng: &mut ChaCha8Rng) -> AdcCode {
    let noisy = if mn > 1.0 {
        mn + normal(rng) * (10.0 + 0.01 * mn)
    } else {
        0.0
    };
    let c = profile.to_counts(noisy.max(0.0).round() as i32).0 as i64 + rng.random_range(-1..=1);
    profile.clamp_code(c)
}

/// A flag frame of a detector that has only the hand flag (oracle, teacher, load rule): armed,
/// the hand flag (and channel 0's bit) as given.
fn flags_frame(seq: u16, unstable: bool) -> Frame {
    Frame {
        seq,
        msg: Message::Flags(protocol::Flags {
            timestamp_us: 0,
            status: if unstable {
                status::ARMED | status::HAND_UNSTABLE
            } else {
                status::ARMED
            },
            channels: 16,
            unstable: if unstable { 1 } else { 0 },
            fault: 0,
            overruns: 0,
            skipped: 0,
            p: [slipguard_core::protocol::PUnstable::from_q15(slipguard_core::decision::Q15(0));
                16],
        }),
    }
}

/// Runs one trial: `grip_override` replaces the controller by a constant commanded grip (used
/// to find the minimum grip needed).
pub fn run_trial(
    sc: &Scenario,
    source: FlagSource<'_>,
    ctl: &ControllerConfig,
    grip_override: Option<f64>,
    seed: u64,
) -> Outcome {
    let profile = Profile::HAND;
    let dt = 1.0 / INTERNAL_HZ;
    let ticks = (DURATION_S * INTERNAL_HZ).round() as usize;
    let period_s = 1000.0 / ctl.rate_mhz.0 as f64;
    let scan_dt = period_s / RATIO as f64;
    let mut rng = trial_rng(seed, 0xC0FF_EE00);
    // The teacher's coin has its own stream so that the sensor noise does not depend on it.
    let mut coin = trial_rng(seed, 0xC0FF_EE01);
    let (act_prob, oracle_delay, false_alarm_hz) = match source {
        FlagSource::Teacher {
            act_prob,
            false_alarm_hz,
        } => (act_prob, 0, false_alarm_hz),
        FlagSource::Oracle { delay_frames } => (1.0, delay_frames, 0.0),
        _ => (1.0, 0, 0.0),
    };
    // The teacher's false alarms: their own stream, so that a rate of 0 leaves the rest as is.
    let mut alarms = trial_rng(seed, 0xC0FF_EE02);
    let mut alarm_frames = 0u32;
    let mut app = match source {
        FlagSource::Model(blob) | FlagSource::Fused { blob, .. } => Some(App::new(profile, blob)),
        _ => None,
    };
    let mut rule_state = slipguard_core::decision::LoadRuleState::new();
    let mut rule_contact = [slipguard_core::decision::ContactState::new(); MAX_CHANNELS];
    let mut frontend = Frontend::new(profile);
    let mut device_rx = Deframer::new();
    let mut ctl_rx = Deframer::new();
    let mut buf = [0u8; MAX_WIRE];
    // Frames in flight: (delivery time, wire bytes).
    let mut in_flight: std::collections::VecDeque<(f64, Vec<u8>)> = Default::default();
    let mut out = Outcome {
        initial_grip_n: sc.initial_grip_n,
        ..Default::default()
    };
    let mut contact = Contact::default();
    let mut cmd = grip_override.unwrap_or(sc.initial_grip_n);
    let mut grip = 0.0f64;
    let mut lag = [0.0f64; MAX_CHANNELS];
    let alpha = dt / (0.02 + dt);
    let mut next_scan = 0.0f64;
    let mut grasp_sent = false;
    let mut settings_sent = false;
    let step = ctl.step_fraction * sc.initial_grip_n;
    for i in 0..ticks {
        let t = i as f64 * dt;
        // Controller: frames that have arrived.
        while in_flight.front().is_some_and(|(due, _)| *due <= t) {
            let (_, bytes) = in_flight.pop_front().expect("front");
            for b in bytes {
                if let Some(Ok(f)) = ctl_rx.push_decode(b) {
                    match f.msg {
                        Message::Flags(fl) => {
                            out.flag_frames += 1;
                            // The controller acts on the hand flag (the firmware's decision
                            // over the channels in contact), in its armed window: from its lift
                            // command on (T_LIFT_S), as docs/labels.md defines it.
                            if fl.hand_unstable() && fl.status & status::ARMED != 0 {
                                out.unstable_frames += 1;
                                if grip_override.is_none()
                                    && t >= T_LIFT_S.max(T_CONTACT_S + ctl.settle_s)
                                    && out
                                        .raise_times
                                        .last()
                                        .is_none_or(|&r| t >= r + ctl.hold_off_s)
                                    && (act_prob >= 1.0 || coin.random_bool(act_prob.max(0.0)))
                                    && contact.t_loss.is_none()
                                    && cmd < MAX_GRIP_N
                                {
                                    cmd = (cmd + step).min(MAX_GRIP_N);
                                    out.increases += 1;
                                    out.raise_times.push(t);
                                }
                            }
                        }
                        Message::Fault(_) => out.fault_frames += 1,
                        _ => {}
                    }
                }
            }
        }
        // Grip actuator.
        if t >= T_CONTACT_S {
            grip += (dt / (ACTUATOR_TAU_S + dt)) * (cmd - grip);
        }
        let (normal_n, load) = sc.tick(&mut contact, t, grip);
        // Pads (the force simulator's sensor: shares, gains, shear cross-talk, 20 ms lag).
        let shear = load * sc.p.shear_coupling;
        for (k, &ch) in sc.p.contacts.iter().enumerate() {
            let f = sc.p.shares[k] * (normal_n + shear) * 1000.0 * sc.p.gains[ch];
            lag[ch] += alpha * (f - lag[ch]);
        }
        if i % 10 == 0 {
            out.trace.push(TracePoint {
                t,
                grip,
                load,
                pads: lag.iter().sum::<f64>() / 1000.0,
                rho: if contact.t_loss.is_some() {
                    0.0
                } else {
                    contact.rho
                },
            });
        }
        // ADC scans due by now; a frame every RATIO scans.
        while next_scan <= t {
            next_scan += scan_dt;
            let mut scan = [AdcCode(0); MAX_CHANNELS];
            for (c, s) in scan.iter_mut().enumerate().take(profile.channels) {
                *s = code(&profile, lag[c], &mut rng);
            }
            let Some(input) = frontend.push_scan(&scan) else {
                continue;
            };
            if t >= T_CONTACT_S {
                out.frames.push(FrameRecord {
                    t,
                    model_units: core::array::from_fn(|c| {
                        profile.to_model_units(input.value_q4[c], 0)
                    }),
                    rho: contact.rho,
                    gross: contact.gross,
                    lost: contact.t_loss.is_some(),
                });
            }
            let deliver = t + ctl.latency.delay_s(period_s);
            match source {
                FlagSource::Off => {}
                FlagSource::LoadRule {
                    rule,
                    scale,
                    contact: gate,
                } => {
                    // The firmware resets at grasp start, sent when the fingers touch.
                    if t < T_CONTACT_S {
                        continue;
                    }
                    let load = slipguard_core::decision::LoadRule::hand_load(
                        rule_contact
                            .iter_mut()
                            .take(profile.channels)
                            .enumerate()
                            .map(|(c, st)| {
                                let x = scale.to_q15(profile.to_model_units(input.value_q4[c], 0));
                                gate.update(st, x).in_contact().then_some(x)
                            }),
                    );
                    let unstable = rule.update(&mut rule_state, load);
                    let f = flags_frame(input.index as u16, unstable);
                    let n = protocol::encode(&f, &mut buf);
                    in_flight.push_back((deliver, buf[..n].to_vec()));
                }
                FlagSource::Oracle { .. } | FlagSource::Teacher { .. } => {
                    // The frame just recorded is the newest; a late oracle looks `delay` back.
                    let n = out.frames.len();
                    if false_alarm_hz > 0.0
                        && t >= T_CONTACT_S
                        && alarm_frames == 0
                        && alarms.random_bool((false_alarm_hz * period_s).min(1.0))
                    {
                        alarm_frames = alarms.random_range(1..=8);
                    }
                    let false_alarm = alarm_frames > 0;
                    alarm_frames = alarm_frames.saturating_sub(1);
                    let unstable = contact.t_loss.is_none()
                        && (false_alarm
                            || n > oracle_delay
                                && out.frames[n - 1 - oracle_delay].rho >= RHO_STICK_SLIP);
                    let f = flags_frame(input.index as u16, unstable);
                    let n = protocol::encode(&f, &mut buf);
                    in_flight.push_back((deliver, buf[..n].to_vec()));
                }
                FlagSource::Model(_) | FlagSource::Fused { .. } => {
                    let app = app.as_mut().expect("app");
                    let mut bytes = Vec::new();
                    let mut commands: Vec<Command> = Vec::new();
                    if !settings_sent {
                        // The controller sets its decision settings once, at start-up.
                        settings_sent = true;
                        if let Some((threshold_q15, raise_after, clear_after)) = ctl.decision {
                            commands.push(Command::SetThreshold {
                                threshold_q15,
                                raise_after,
                                clear_after,
                            });
                        }
                    }
                    if !grasp_sent && t >= T_CONTACT_S {
                        // The controller sends grasp start when its fingers touch.
                        grasp_sent = true;
                        commands.push(Command::GraspStart);
                    }
                    for (k, cmd) in commands.into_iter().enumerate() {
                        let n = protocol::encode(
                            &Frame {
                                seq: 1 + k as u16,
                                msg: Message::Command(cmd),
                            },
                            &mut buf,
                        );
                        let cmd_bytes = buf[..n].to_vec();
                        slipguard_app::replay::receive(app, &mut device_rx, &cmd_bytes, |f| {
                            let n = protocol::encode(f, &mut buf);
                            bytes.extend_from_slice(&buf[..n]);
                        });
                    }
                    if let Some(mut f) = app.frame(&input, false) {
                        if let (
                            FlagSource::Fused {
                                fused,
                                scale,
                                contact: gate,
                                ..
                            },
                            Message::Flags(fl),
                        ) = (source, &mut f.msg)
                            && grasp_sent
                        {
                            let load = slipguard_core::decision::LoadRule::hand_load(
                                rule_contact
                                    .iter_mut()
                                    .take(profile.channels)
                                    .enumerate()
                                    .map(|(c, st)| {
                                        let x = scale
                                            .to_q15(profile.to_model_units(input.value_q4[c], 0));
                                        gate.update(st, x).in_contact().then_some(x)
                                    }),
                            );
                            let up = fused.update(&mut rule_state, fl.hand_unstable(), load);
                            fl.status = if up {
                                fl.status | status::HAND_UNSTABLE
                            } else {
                                fl.status & !status::HAND_UNSTABLE
                            };
                        }
                        let n = protocol::encode(&f, &mut buf);
                        bytes.extend_from_slice(&buf[..n]);
                    }
                    in_flight.push_back((deliver, bytes));
                }
            }
        }
        if contact.t_loss.is_some() && out.t_drop.is_none() {
            out.t_drop = contact.t_loss;
            out.dropped = true;
        }
    }
    out.final_grip_n = cmd;
    out
}

/// Smallest constant grip (N, within 1 %) with which the object is not dropped in this
/// scenario (no controller), by bisection; [`MAX_GRIP_N`] if even that drops.
pub fn min_grip_needed(sc: &Scenario, ctl: &ControllerConfig) -> f64 {
    let holds = |g: f64| {
        let mut c = Contact::default();
        let dt = 1.0 / INTERNAL_HZ;
        let mut grip = 0.0;
        for i in 0..(DURATION_S * INTERNAL_HZ).round() as usize {
            let t = i as f64 * dt;
            if t >= T_CONTACT_S {
                grip += (dt / (ACTUATOR_TAU_S + dt)) * (g - grip);
            }
            sc.tick(&mut c, t, grip);
            if c.t_loss.is_some() {
                return false;
            }
        }
        true
    };
    let _ = ctl;
    let (mut lo, mut hi) = (0.0, MAX_GRIP_N);
    if !holds(hi) {
        return MAX_GRIP_N;
    }
    while hi - lo > 0.01 * hi {
        let mid = 0.5 * (lo + hi);
        if holds(mid) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    hi
}

/// Aggregates of one (situation, source) cell.
#[derive(Clone, Debug, Default)]
pub struct Cell {
    /// Trials.
    pub n: usize,
    /// Drops.
    pub drops: usize,
    /// Mean grip increases per trial.
    pub mean_increases: f64,
    /// Mean grip increases per trial before the lift (no load yet: start-up alarms).
    pub mean_increases_before_lift: f64,
    /// Median final commanded grip (N).
    pub median_final_n: f64,
    /// Median of final grip / minimum grip needed.
    pub median_final_over_min: f64,
    /// Drops among the trials that dropped without prediction, prevented here.
    pub prevented: usize,
    /// Trials that dropped without prediction.
    pub drops_off: usize,
}

fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// Summarises outcomes against the prediction-off outcomes of the same scenarios.
pub fn summarise(on: &[Outcome], off: &[Outcome], min_grip: &[f64]) -> Cell {
    let n = on.len();
    let drops_off = off.iter().filter(|o| o.dropped).count();
    let prevented = on
        .iter()
        .zip(off)
        .filter(|(a, b)| b.dropped && !a.dropped)
        .count();
    Cell {
        n,
        drops: on.iter().filter(|o| o.dropped).count(),
        mean_increases: on.iter().map(|o| o.increases as f64).sum::<f64>() / n.max(1) as f64,
        mean_increases_before_lift: on
            .iter()
            .map(|o| o.raise_times.iter().filter(|&&t| t < T_LIFT_S).count() as f64)
            .sum::<f64>()
            / n.max(1) as f64,
        median_final_n: median(on.iter().map(|o| o.final_grip_n).collect()),
        median_final_over_min: median(
            on.iter()
                .zip(min_grip)
                .map(|(o, &m)| o.final_grip_n / m)
                .collect(),
        ),
        prevented,
        drops_off,
    }
}

/// Stream of the training trials' own draws (grip margin, teacher, controller step).
const TRAINING_STREAM: u64 = 0x7EAC_0000;

/// Settings of the simulated closed-loop training trials.
#[derive(Clone, Debug)]
pub struct TrainingConfig {
    /// Frame rate of the model to train (mHz).
    pub rate_mhz: Millihertz,
    /// A frame is labelled unstable when the object is in incipient slip, gross slip or lost
    /// at any frame up to this far ahead (s): the controller needs the flag before the slip,
    /// since a slip reaches gross slip and the drop within a few frames.
    pub lead_s: f64,
    /// Frames kept after the object is lost (the drop itself is easy to see and does not help
    /// the controller).
    pub after_loss: usize,
    /// Highest rate of the teacher's false-alarm bursts (per s); each trial draws its rate
    /// uniformly from 0 to this ([`FlagSource::Teacher`]).
    pub false_alarm_hz: f64,
    /// A trained model put in the loop instead of the teacher for [`Self::policy_share`] of the
    /// trials (its threshold drawn from 0.07–0.2), so that the data holds the states its own
    /// flags lead to: raises after a slip has stopped, and the pad force they make (the
    /// "dataset aggregation" remedy for a policy trained on a teacher's states only).
    pub policy: Option<slipguard_core::blob::AlignedBlob>,
    /// Share of the trials run with [`Self::policy`].
    pub policy_share: f64,
}

impl Default for TrainingConfig {
    fn default() -> Self {
        TrainingConfig {
            rate_mhz: PAPER_RATE_MHZ,
            lead_s: 0.3,
            after_loss: 3,
            false_alarm_hz: 0.0,
            policy: None,
            policy_share: 0.5,
        }
    }
}

/// Labelled sequences from `count` simulated closed-loop trials of `seed` (the four situations
/// in turn), for training a model to flag slip ahead in the situations the controller faces.
/// Each trial runs with the [`FlagSource::Teacher`]: the oracle's flags acted on with a drawn
/// probability (0 in a fifth of the trials) and a drawn grip step (10–30 % of the initial
/// grip); a quarter of the trials start with a grip 1.2–2× the light one, so most of those
/// hold. With [`TrainingConfig::false_alarm_hz`] the teacher also raises the grip on false
/// alarms; with [`TrainingConfig::policy`] a trained model replaces the teacher in some trials.
/// Labels come from the physics ([`FrameRecord::unstable`] within [`TrainingConfig::lead_s`]),
/// not from a lead before a drop step. Sequences start at grasp
/// start, one per contact channel plus one channel without contact (all stable), as the
/// firmware runs every channel. Use seeds other than the closed-loop report's.
pub fn training_sequences(seed: u64, count: usize, cfg: &TrainingConfig) -> Vec<Sequence> {
    use slipguard_data::labels::ChannelSequence;
    use slipguard_data::trial::{Outcome as TrialOutcome, Stability};
    let period_s = 1000.0 / cfg.rate_mhz.0 as f64;
    let lead = (cfg.lead_s / period_s).round() as usize;
    let mut out = Vec::new();
    for i in 0..count as u64 {
        let situation = Situation::ALL[(i % 4) as usize];
        let mut sc = Scenario::draw(seed, i, situation);
        let mut rng = trial_rng(seed, TRAINING_STREAM + i);
        if rng.random_bool(0.25) {
            sc.initial_grip_n *= uniform(&mut rng, 1.2, 2.0);
        }
        let act_prob = if rng.random_bool(0.2) {
            0.0
        } else {
            uniform(&mut rng, 0.3, 1.0)
        };
        let mut ctl = ControllerConfig {
            step_fraction: uniform(&mut rng, 0.1, 0.3),
            rate_mhz: cfg.rate_mhz,
            decision: None,
            settle_s: 0.0,
            hold_off_s: 0.0,
            // The latency the published training chains were recorded with.
            latency: Latency::Deadline,
        };
        // Drawn only when asked for, so that data without false alarms or a policy stays as it
        // was.
        let false_alarm_hz = if cfg.false_alarm_hz > 0.0 {
            uniform(&mut rng, 0.0, cfg.false_alarm_hz)
        } else {
            0.0
        };
        let policy = match &cfg.policy {
            Some(blob) if rng.random_bool(cfg.policy_share.clamp(0.0, 1.0)) => {
                let threshold = uniform(&mut rng, 0.07, 0.2);
                ctl.decision = Some((Q15::from_f64(threshold).header_threshold(), 1, 1));
                Some(blob.as_bytes())
            }
            _ => None,
        };
        let source = match policy {
            Some(blob) => FlagSource::Model(blob),
            None => FlagSource::Teacher {
                act_prob,
                false_alarm_hz,
            },
        };
        let o = run_trial(
            &sc,
            source,
            &ctl,
            None,
            seed.wrapping_mul(1_000_003).wrapping_add(i),
        );
        let len = o
            .frames
            .iter()
            .position(|f| f.lost)
            .map_or(o.frames.len(), |k| (k + cfg.after_loss).min(o.frames.len()));
        let frames = &o.frames[..len];
        let truth: Vec<bool> = (0..len)
            .map(|k| {
                frames[k..(k + lead + 1).min(len)]
                    .iter()
                    .any(FrameRecord::unstable)
            })
            .collect();
        let lift = frames.iter().position(|f| f.t >= T_LIFT_S);
        let free: Vec<usize> = (0..Profile::HAND.channels)
            .filter(|c| !sc.p.contacts.contains(c))
            .collect();
        let mut channels = sc.p.contacts.clone();
        if !free.is_empty() {
            channels.push(free[rng.random_range(0..free.len())]);
        }
        for c in channels {
            let contact = sc.p.contacts.contains(&c);
            out.push(Sequence {
                cs: ChannelSequence {
                    trial_id: format!("closed-loop-{}-{seed}-{i}", situation.name()),
                    channel: c,
                    samples: frames.iter().map(|f| f.model_units[c] as f32).collect(),
                    labels: truth
                        .iter()
                        .map(|&u| {
                            if contact && u {
                                Stability::Unstable
                            } else {
                                Stability::Stable
                            }
                        })
                        .collect(),
                    // The labels come from the physics, not from a lead before a drop step.
                    drop_index: None,
                    outcome: if o.dropped {
                        TrialOutcome::Failure
                    } else {
                        TrialOutcome::Success
                    },
                },
                lift,
                rate_hz: cfg.rate_mhz.hz_f32(),
            });
        }
    }
    out
}
