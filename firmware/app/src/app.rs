//! The application: model check at boot, per-frame inference over every channel, flags,
//! commands and their replies, system faults. Board layers own one [`App`] and call
//! [`App::frame`] for every [`FrameInput`] and [`App::handle`] for every received frame.
//!
//! - At boot [`App::new`] validates the blob (CRC, version, sizes), the model rate against the
//!   profile and the input unit. Any failure puts the app in a system fault: no flag frames,
//!   a [`Fault`] frame once per second instead, replies with status `NoModel`.
//! - Flagging is on after boot ("armed"); grasp start resets every channel's state, tares
//!   (suction profile) and arms; release disarms (p(unstable) still reported, unstable mask and
//!   hand flag 0).
//! - Every channel goes through contact detection ([`ContactConfig`], from the model by
//!   default): only a channel in contact runs the model, and its model state restarts from zero
//!   at each contact onset. A channel without contact is not predicted: p = [`PUnstable::NONE`] with its
//!   fault bit clear, flag 0.
//! - Faulted channels (see [`crate::fault`]) are not stepped and count as not in contact:
//!   p = [`PUnstable::NONE`], flag 0, and their model and contact state is reset when they recover.
//! - The hand decision ([`HandConfig`]) runs once per frame over the p of the channels in
//!   contact: the hand flag (status bit [`status::HAND_UNSTABLE`], the board's UNSTABLE line),
//!   0 while disarmed as the per-channel mask is. Its hysteresis restarts at grasp start and
//!   on a reload, as the channels' states do; a channel's fault only takes that channel out of
//!   the decision (not in contact), the other channels' evidence stands.
//! - A blob with a hand rule (format v2, [`slipguard_core::blob::ModelConfig::hand_rule`])
//!   fuses it with that decision ([`FusedHand::update`] over the model's hand flag and the hand
//!   load of the channels in contact, [`LoadRule::hand_load`]): the hand flag is the fused one,
//!   and status bit [`status::HAND_BY_RULE`] says the rule raised it while the model's hand
//!   flag is down. The rule's state restarts where the hand decision's does.
//! - Stream mode (flags, flags + samples, samples): [`App::emit_samples`] frames the model input
//!   of every channel, with the phase marks (grasp start, lift, release) of the commands handled
//!   since the previous frame. Samples and marks go out with or without a model, so a hand
//!   can be recorded before any model for it exists.
//! - Model uploads are answered by [`crate::upload::Uploader`]; after one, the board layer
//!   moves the app onto the new blob with [`App::reload`].

use crate::MAX_CHANNELS;
use crate::frontend::FrameInput;
use crate::profile::Profile;
use crate::schedule::frame_timestamp_us;
use slipguard_core::blob::{BlobError, IMAGE_MAGIC, InputUnit};
use slipguard_core::decision::{
    ContactConfig, DecisionConfig, DecisionState, FusedHand, HandConfig, HandOutput, LoadRule,
    LoadRuleState, Q15,
};
use slipguard_core::model::{ChannelState, HandState, Model};
use slipguard_core::protocol::{
    Command, DecodeError, Error, Fault, Flags, Frame, Info, Message, PUnstable, Reply, ReplyBody,
    ReplyStatus, Samples, StreamMode, fault_code, mark, status, upload_code,
};
use slipguard_core::units::Millihertz;

/// Firmware version reported by info (major, minor, patch).
pub const FIRMWARE_VERSION: [u8; 3] = [0, 1, 0];

/// Why the app is not predicting.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SystemFault {
    /// The blob failed validation.
    BadModel(BlobError),
    /// The model's sample rate (mHz) is not one the profile runs.
    RateMismatch(u32),
    /// The model expects another input unit than the profile delivers.
    UnitMismatch,
}

impl SystemFault {
    /// (code, detail, value) of the fault frame.
    pub fn wire(&self) -> (u8, u8, u32) {
        match *self {
            Self::BadModel(e) => {
                let (detail, value) = e.wire_detail();
                (fault_code::BAD_MODEL, detail, value)
            }
            Self::RateMismatch(r) => (fault_code::RATE_MISMATCH, 0, r),
            Self::UnitMismatch => (fault_code::UNIT_MISMATCH, 0, 0),
        }
    }
}

/// What [`App::frame`] computed for one frame, before it is stamped and counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FrameResult {
    /// The input's frame index.
    pub index: u32,
    /// Unstable mask (already 0 when disarmed).
    pub unstable: u16,
    /// Fault mask.
    pub fault: u16,
    /// Contact mask: bit c set while channel c is in contact (and so predicted on); a faulted
    /// channel is not in contact.
    pub contact: u16,
    /// The hand flag (already false when disarmed): what the UNSTABLE line and status bit
    /// [`status::HAND_UNSTABLE`] carry; with a hand rule in the blob, the fused flag.
    pub hand_unstable: bool,
    /// The hand flag is up and the model's own hand flag is down: the blob's hand rule raised
    /// it (status bit [`status::HAND_BY_RULE`]; always false without a rule or when disarmed).
    pub hand_by_rule: bool,
    /// The hand's p(unstable), Q0.15 (0 with no channel in contact or without a model).
    pub hand_p_q15: i16,
    /// p(unstable) per channel, or [`PUnstable::NONE`] for a channel not predicted on (faulted,
    /// not in contact, or no model).
    pub p: [PUnstable; MAX_CHANNELS],
    /// Model input per channel (the profile's unit, after tare): what `Model::step` received,
    /// or would have for a faulted channel or without a model.
    pub value: [i32; MAX_CHANNELS],
}

/// The per-channel part of one frame, borrowed from the [`App`] apart from its model.
struct Channels<'a> {
    states: &'a mut [ChannelState],
    stale: &'a mut u16,
    fault: u16,
    contact: &'a ContactConfig,
}

impl Channels<'_> {
    /// A channel's fault bookkeeping before its step: `false` for a faulted channel (not
    /// stepped, reset before its next step), else its state reset if it comes back from a
    /// fault (out of contact, so the model restarts at its next onset).
    fn ready(&mut self, c: usize) -> bool {
        let bit = 1u16 << c;
        if self.fault & bit != 0 {
            *self.stale |= bit;
            return false;
        }
        if *self.stale & bit != 0 {
            self.states[c].reset();
            *self.stale &= !bit;
        }
        true
    }

    /// A per-channel model over the frame: each channel in contact through its network, then
    /// the hand decision over the channels' p. Returns the hand's p and the model's hand flag.
    fn channel_frame(
        &mut self,
        model: &Model<'_>,
        hand: &HandConfig,
        hand_state: &mut DecisionState,
        r: &mut FrameResult,
    ) -> (i16, bool) {
        for c in 0..self.states.len() {
            if !self.ready(c) {
                continue;
            }
            let st = &mut self.states[c];
            let Some(out) = model.step_in_contact(st, self.contact, r.value[c]).step else {
                continue;
            };
            let bit = 1u16 << c;
            r.contact |= bit;
            r.p[c] = PUnstable::from_q15(Q15(out.p_unstable_q15));
            if out.unstable {
                r.unstable |= bit;
            }
        }
        let n = self.states.len();
        let HandOutput {
            p_unstable_q15,
            unstable,
        } = hand.update(
            hand_state,
            // Each channel's p, `None` when not in contact (so not predicted on).
            r.p[..n].iter().map(|p| p.q15().map(|p| p.0)),
        );
        (p_unstable_q15, unstable)
    }

    /// A hand-level model over the frame: each channel through its contact gate, then one
    /// network over the channels in contact (and whether the lift came). Every channel in
    /// contact carries the hand's p and the model's hand flag on the wire (there is no
    /// per-channel p). Returns the hand's p and the model's hand flag.
    fn hand_frame(
        &mut self,
        model: &Model<'_>,
        hand_model: &mut HandState,
        lifted: bool,
        hand: &HandConfig,
        hand_state: &mut DecisionState,
        r: &mut FrameResult,
    ) -> (i16, bool) {
        let n = self.states.len();
        let mut x = [None; MAX_CHANNELS];
        for (c, xc) in x.iter_mut().enumerate().take(n) {
            if !self.ready(c) {
                continue;
            }
            let (edge, v) = model.gate(&mut self.states[c], self.contact, r.value[c]);
            if edge.in_contact() {
                *xc = Some(v);
                r.contact |= 1 << c;
            }
        }
        let p = model.hand_p(hand_model, &x[..n], lifted);
        let unstable = hand.decision.update(hand_state, p);
        for (c, pc) in r.p.iter_mut().enumerate().take(n) {
            if r.contact & (1 << c) != 0 {
                *pc = PUnstable::from_q15(Q15(p));
                if unstable {
                    r.unstable |= 1 << c;
                }
            }
        }
        (p, unstable)
    }
}

/// The firmware application over a model borrowed from flash (or a host buffer).
pub struct App<'m> {
    profile: Profile,
    model: Result<Model<'m>, SystemFault>,
    states: [ChannelState; MAX_CHANNELS],
    /// When a channel is in contact (the model's default rule unless changed).
    contact: ContactConfig,
    /// The hand decision (its threshold and hysteresis are the model's, as the channels').
    hand: HandConfig,
    /// The hand flag's hysteresis state.
    hand_state: DecisionState,
    /// The blob's hand rule, fused with the hand decision (`None`: the hand decision alone).
    rule: Option<FusedHand>,
    /// The hand rule's recent loads (reset with `hand_state`).
    rule_state: LoadRuleState,
    /// A hand-level model's features and LSTM (reset at grasp start; unused by a per-channel
    /// model).
    hand_model: HandState,
    /// The lift command has come since the grasp start (a hand-level model's input).
    lifted: bool,
    /// Channels whose state must be reset before their next step (after a fault).
    stale: u16,
    armed: bool,
    tared: bool,
    tare_q4: [i32; MAX_CHANNELS],
    last_q4: [i32; MAX_CHANNELS],
    seq: u16,
    overruns: u16,
    skipped: u16,
    fault_frames: u32,
    stream: StreamMode,
    /// [`mark`] bits of the phase commands handled since the last frame.
    marks: u8,
}

/// Checks a blob as the app does at boot: it parses (CRC, version, sizes), its rate is one the
/// profile runs and its input unit is the profile's.
pub fn check_model<'m>(profile: &Profile, blob: &'m [u8]) -> Result<Model<'m>, SystemFault> {
    let m = Model::from_bytes(blob).map_err(SystemFault::BadModel)?;
    let c = m.config();
    if !profile.check_rate(c.sample_rate_mhz) {
        Err(SystemFault::RateMismatch(c.sample_rate_mhz.0))
    } else if c.input_unit != profile.unit {
        Err(SystemFault::UnitMismatch)
    } else {
        Ok(m)
    }
}

/// The one check of a blob stored in a model slot: the commit of an upload and the slot choice
/// at boot both make it ([`crate::upload::slot_state`]), so a commit accepts exactly what the
/// boot path runs. The blob must be a blob (`SGMB`: a RAM image, `SGMI`, exists only in RAM and
/// is not loaded again) and pass [`check_model`]; the boot path then runs its RAM copy, which
/// [`slipguard_core::model_ram::ModelRam::load`] guarantees parses as the same model, or, when
/// the copy does not fit, the blob where it lies ([`crate::upload::load`]).
pub fn check_stored<'m>(profile: &Profile, blob: &'m [u8]) -> Result<Model<'m>, SystemFault> {
    if blob.get(..4) == Some(&IMAGE_MAGIC[..]) {
        return Err(SystemFault::BadModel(BlobError::BadMagic));
    }
    check_model(profile, blob)
}

impl<'m> App<'m> {
    /// Validates `blob` against `profile` and starts armed (or in a system fault).
    pub fn new(profile: Profile, blob: &'m [u8]) -> Self {
        let model = check_model(&profile, blob);
        let (contact, hand) = match &model {
            Ok(m) => (ContactConfig::of(m.config()), HandConfig::of(m.config())),
            // Never used without a model: no channel is stepped.
            Err(_) => (
                ContactConfig {
                    on_q15: i16::MAX,
                    on_after: u8::MAX,
                    off_after: 1,
                },
                HandConfig {
                    k: 1,
                    decision: DecisionConfig {
                        threshold_q15: i16::MAX,
                        raise_after: u8::MAX,
                        clear_after: 1,
                    },
                },
            ),
        };
        let rule = model.as_ref().ok().and_then(|m| m.config().hand_rule);
        Self {
            profile,
            model,
            states: [const { ChannelState::new() }; MAX_CHANNELS],
            contact,
            hand,
            hand_state: DecisionState::default(),
            rule,
            rule_state: LoadRuleState::new(),
            hand_model: HandState::new(),
            lifted: false,
            stale: 0,
            armed: true,
            tared: false,
            tare_q4: [0; MAX_CHANNELS],
            last_q4: [0; MAX_CHANNELS],
            seq: 0,
            overruns: 0,
            skipped: 0,
            fault_frames: 0,
            stream: StreamMode::Flags,
            marks: 0,
        }
    }

    /// The same app over another blob (after an upload): checked as at boot, every channel's
    /// state and the tare reset, the decision from the new blob; the sequence numbers, counters,
    /// stream mode, armed state and pending marks carry over.
    pub fn reload<'n>(self, blob: &'n [u8]) -> App<'n> {
        let mut a = App::new(self.profile, blob);
        a.armed = self.armed;
        a.last_q4 = self.last_q4;
        a.seq = self.seq;
        a.overruns = self.overruns;
        a.skipped = self.skipped;
        a.stream = self.stream;
        a.marks = self.marks;
        a.lifted = self.lifted;
        a
    }

    /// [`Self::reload`] in place, for a board layer that holds the app by reference (the blob
    /// must live as long as the old one, e.g. flash).
    pub fn reload_in_place(&mut self, blob: &'m [u8]) {
        let old = core::mem::replace(self, App::new(self.profile, &[]));
        *self = old.reload(blob);
    }

    /// The stream mode in force.
    pub fn stream_mode(&self) -> StreamMode {
        self.stream
    }

    /// The profile.
    pub fn profile(&self) -> &Profile {
        &self.profile
    }

    /// The model, or why there is none.
    pub fn model(&self) -> Result<&Model<'m>, SystemFault> {
        self.model.as_ref().map_err(|e| *e)
    }

    /// The frame rate to run the ADC at: the model's, or the profile's default without one.
    pub fn rate_mhz(&self) -> Millihertz {
        match &self.model {
            Ok(m) => m.config().sample_rate_mhz,
            Err(_) => self.profile.default_rate_mhz(),
        }
    }

    /// The contact rule in force.
    pub fn contact_config(&self) -> ContactConfig {
        self.contact
    }

    /// Replaces the contact rule (from the next frame; channels keep their contact state).
    pub fn set_contact_config(&mut self, contact: ContactConfig) {
        self.contact = contact;
    }

    /// The hand decision in force.
    pub fn hand_config(&self) -> HandConfig {
        self.hand
    }

    /// The blob's hand rule fused with the hand decision, if it carries one.
    pub fn hand_rule(&self) -> Option<FusedHand> {
        self.rule
    }

    /// Whether flagging is on.
    pub fn armed(&self) -> bool {
        self.armed
    }

    /// Frames late so far.
    pub fn overruns(&self) -> u16 {
        self.overruns
    }

    /// Frames skipped so far.
    pub fn skipped(&self) -> u16 {
        self.skipped
    }

    /// Counts a frame that was acquired but will never be processed or sent.
    pub fn note_skipped(&mut self) {
        self.skipped = self.skipped.saturating_add(1);
    }

    fn next_seq(&mut self) -> u16 {
        let s = self.seq;
        self.seq = self.seq.wrapping_add(1);
        s
    }

    /// Runs every channel of one frame through the model. Call [`Self::emit`] with its result
    /// once the deadline check is known.
    pub fn infer(&mut self, input: &FrameInput) -> FrameResult {
        let n = self.profile.channels.min(MAX_CHANNELS);
        self.last_q4 = input.value_q4;
        let mut r = FrameResult {
            index: input.index,
            unstable: 0,
            fault: input.fault,
            contact: 0,
            hand_unstable: false,
            hand_by_rule: false,
            hand_p_q15: 0,
            p: [PUnstable::NONE; MAX_CHANNELS],
            value: [0; MAX_CHANNELS],
        };
        for c in 0..n {
            r.value[c] = self
                .profile
                .to_model_units(input.value_q4[c], self.tare_q4[c]);
        }
        let App {
            model,
            states,
            stale,
            contact,
            hand,
            hand_state,
            hand_model,
            lifted,
            armed,
            ..
        } = self;
        let Ok(model) = &*model else {
            return r;
        };
        let mut ctx = Channels {
            states: &mut states[..n],
            stale,
            fault: input.fault,
            contact,
        };
        let (p_unstable_q15, unstable) = if model.is_hand() {
            ctx.hand_frame(model, hand_model, *lifted, hand, hand_state, &mut r)
        } else {
            ctx.channel_frame(model, hand, hand_state, &mut r)
        };
        if !*armed {
            r.unstable = 0;
        }
        r.hand_p_q15 = p_unstable_q15;
        let hand = match &self.rule {
            Some(rule) => {
                // The hand load: Σ |x| (Q1.15, the model's input scale) of the channels in
                // contact, exactly what the model stepped on.
                let scale = model.scale();
                let load = LoadRule::hand_load(
                    (0..n).map(|c| (r.contact & (1 << c) != 0).then(|| scale.to_q15(r.value[c]))),
                );
                rule.update(&mut self.rule_state, unstable, load)
            }
            None => unstable,
        };
        r.hand_unstable = hand && self.armed;
        r.hand_by_rule = r.hand_unstable && !unstable;
        r
    }

    fn status_bits(&self, late: bool, r: &FrameResult) -> u8 {
        let mut st = 0;
        if r.hand_unstable {
            st |= status::HAND_UNSTABLE;
        }
        if r.hand_by_rule {
            st |= status::HAND_BY_RULE;
        }
        if self.armed {
            st |= status::ARMED;
        }
        if late {
            st |= status::LATE;
        }
        if self.tared {
            st |= status::TARED;
        }
        st
    }

    /// The samples frame of a result when the stream mode includes samples (with or without a
    /// model), carrying the phase marks since the previous frame. Call it before [`Self::emit`]
    /// for the same result (samples go out first; `emit` clears the marks).
    pub fn emit_samples(&mut self, r: &FrameResult, late: bool) -> Option<Frame> {
        if !self.stream.samples() {
            return None;
        }
        Some(Frame {
            seq: self.next_seq(),
            msg: Message::Samples(Samples {
                timestamp_us: frame_timestamp_us(r.index, self.rate_mhz()),
                status: self.status_bits(late, r),
                marks: self.marks,
                channels: self.profile.channels.min(MAX_CHANNELS) as u8,
                unit: self.profile.unit as u8,
                fault: r.fault,
                value: r.value,
            }),
        })
    }

    /// Stamps, counts and frames a result: a flag frame (unless the stream mode is samples
    /// only), or, in a system fault, a fault frame once per second (`None` in between), in
    /// every stream mode. Clears the phase marks.
    pub fn emit(&mut self, r: &FrameResult, late: bool) -> Option<Frame> {
        self.marks = 0;
        if late {
            self.overruns = self.overruns.saturating_add(1);
        }
        let rate = self.rate_mhz();
        let timestamp_us = frame_timestamp_us(r.index, rate);
        if let Err(fault) = self.model {
            let per_second = (rate.0 / 1000).max(1);
            let due = self.fault_frames.is_multiple_of(per_second);
            self.fault_frames = self.fault_frames.wrapping_add(1);
            if !due {
                return None;
            }
            let (code, detail, value) = fault.wire();
            return Some(Frame {
                seq: self.next_seq(),
                msg: Message::Fault(Fault {
                    timestamp_us,
                    code,
                    detail,
                    value,
                }),
            });
        }
        if !self.stream.flags() {
            return None;
        }
        let st = self.status_bits(late, r);
        Some(Frame {
            seq: self.next_seq(),
            msg: Message::Flags(Flags {
                timestamp_us,
                status: st,
                channels: self.profile.channels.min(MAX_CHANNELS) as u8,
                unstable: r.unstable,
                fault: r.fault,
                overruns: self.overruns,
                skipped: self.skipped,
                p: r.p,
            }),
        })
    }

    /// A fault frame saying the sensors stopped delivering frames (`periods` model periods
    /// without one); the board layer sends it while it waits.
    pub fn stall_frame(&mut self, periods: u32) -> Frame {
        Frame {
            seq: self.next_seq(),
            msg: Message::Fault(Fault {
                timestamp_us: 0,
                code: fault_code::SENSOR_STALL,
                detail: 0,
                value: periods,
            }),
        }
    }

    /// [`Self::infer`] then [`Self::emit`] (the flag or fault frame only).
    pub fn frame(&mut self, input: &FrameInput, late: bool) -> Option<Frame> {
        let r = self.infer(input);
        self.emit(&r, late)
    }

    /// [`Self::infer`], [`Self::emit_samples`] and [`Self::emit`]: every frame of one model
    /// period to `sink`, in wire order.
    pub fn frames(&mut self, input: &FrameInput, late: bool, mut sink: impl FnMut(&Frame)) {
        let r = self.infer(input);
        if let Some(f) = self.emit_samples(&r, late) {
            sink(&f);
        }
        if let Some(f) = self.emit(&r, late) {
            sink(&f);
        }
    }

    /// A reply frame to the command with `request_seq`, numbered in the device's sequence (for
    /// commands answered outside the app, e.g. uploads).
    pub fn reply(&mut self, request_seq: u16, status: ReplyStatus, body: ReplyBody) -> Frame {
        Frame {
            seq: self.next_seq(),
            msg: Message::Reply(Reply {
                request_seq,
                status,
                body,
            }),
        }
    }

    /// Answers one received frame (a command, or a decode error with its [`Error`] reply).
    /// Frames that are not commands (e.g. a flag frame echoed back) get an `UnknownType` error.
    pub fn handle(&mut self, received: Result<Frame, (DecodeError, Error)>) -> Frame {
        let (request_seq, cmd) = match received {
            Ok(Frame {
                seq,
                msg: Message::Command(c),
            }) => (seq, c),
            Ok(f) => {
                let e = Error {
                    error: DecodeError::UnknownType(f.msg.msg_type()).code(),
                    msg_type: f.msg.msg_type(),
                    request_seq: f.seq,
                };
                return Frame {
                    seq: self.next_seq(),
                    msg: Message::Error(e),
                };
            }
            Err((_, e)) => {
                return Frame {
                    seq: self.next_seq(),
                    msg: Message::Error(e),
                };
            }
        };
        let (status, body) = self.command(cmd);
        self.reply(request_seq, status, body)
    }

    fn decision(&self) -> DecisionConfig {
        match &self.model {
            Ok(m) => m.decision(),
            Err(_) => DecisionConfig {
                threshold_q15: 0,
                raise_after: 0,
                clear_after: 0,
            },
        }
    }

    /// The part of grasp start that the sample stream sees, with or without a model: the
    /// phase mark and the tare (suction profile).
    fn mark_grasp_start(&mut self) {
        self.marks |= mark::GRASP_START;
        if self.profile.tare {
            self.tare_q4 = self.last_q4;
            // The profile's live zero is subtracted as well: keep it out of the tare.
            let z = self.profile.zero_counts << crate::decimate::OUT_FRAC_BITS;
            for t in &mut self.tare_q4 {
                *t -= z;
            }
            self.tared = true;
        }
    }

    fn command(&mut self, cmd: Command) -> (ReplyStatus, ReplyBody) {
        let have_model = self.model.is_ok();
        match cmd {
            Command::Ping { token } => (ReplyStatus::Ok, ReplyBody::Pong { token }),
            Command::Info => (ReplyStatus::Ok, ReplyBody::Info(self.info())),
            Command::Lift => {
                self.marks |= mark::LIFT;
                self.lifted = true;
                (ReplyStatus::Ok, ReplyBody::Lifted)
            }
            Command::StreamMode(m) => {
                self.stream = m;
                (ReplyStatus::Ok, ReplyBody::StreamMode(m))
            }
            Command::UploadBegin { .. } | Command::UploadChunk(_) | Command::UploadCommit => (
                ReplyStatus::BadArgument,
                ReplyBody::Upload {
                    command: cmd.msg_type(),
                    code: upload_code::UNSUPPORTED,
                    detail: 0,
                    slot: 0,
                    value: 0,
                },
            ),
            Command::GraspStart if have_model => {
                self.mark_grasp_start();
                for s in &mut self.states {
                    s.reset();
                }
                self.hand_state = DecisionState::default();
                self.rule_state = LoadRuleState::new();
                self.hand_model = HandState::new();
                self.lifted = false;
                self.stale = 0;
                self.armed = true;
                (ReplyStatus::Ok, ReplyBody::GraspStarted)
            }
            Command::Release if have_model => {
                self.marks |= mark::RELEASE;
                self.armed = false;
                (ReplyStatus::Ok, ReplyBody::Released)
            }
            Command::SetThreshold {
                threshold_q15,
                raise_after,
                clear_after,
            } if have_model => {
                let ok = (1..=i16::MAX as u16).contains(&threshold_q15)
                    && raise_after >= 1
                    && clear_after >= 1;
                if ok && let Ok(m) = &mut self.model {
                    let d = DecisionConfig {
                        threshold_q15: threshold_q15 as i16,
                        raise_after,
                        clear_after,
                    };
                    // One decision for the channels and the hand.
                    m.set_decision(d);
                    self.hand.decision = d;
                }
                let d = self.decision();
                (
                    if ok {
                        ReplyStatus::Ok
                    } else {
                        ReplyStatus::BadArgument
                    },
                    ReplyBody::ThresholdSet {
                        threshold_q15: d.threshold_q15 as u16,
                        raise_after: d.raise_after,
                        clear_after: d.clear_after,
                    },
                )
            }
            // Without a model the phase is still marked in the sample stream (recording).
            Command::GraspStart => {
                self.mark_grasp_start();
                (ReplyStatus::NoModel, ReplyBody::GraspStarted)
            }
            Command::Release => {
                self.marks |= mark::RELEASE;
                (ReplyStatus::NoModel, ReplyBody::Released)
            }
            Command::SetThreshold { .. } => (
                ReplyStatus::NoModel,
                ReplyBody::ThresholdSet {
                    threshold_q15: 0,
                    raise_after: 0,
                    clear_after: 0,
                },
            ),
        }
    }

    /// The info reply's fields.
    pub fn info(&self) -> Info {
        let d = self.decision();
        let mut i = Info {
            firmware: FIRMWARE_VERSION,
            profile: self.profile.id as u8,
            channels: self.profile.channels as u8,
            oversample: crate::decimate::RATIO as u8,
            model_ok: 0,
            variant: 0xFF,
            model_id: 0,
            model_crc: 0,
            sample_rate_mhz: self.rate_mhz(),
            hidden: 0,
            threshold_q15: d.threshold_q15 as u16,
            raise_after: d.raise_after,
            clear_after: d.clear_after,
            name: [0; 12],
        };
        if let Ok(m) = &self.model {
            let c = m.config();
            i.model_ok = 1;
            i.variant = c.variant as u8;
            i.model_id = c.model_id;
            i.model_crc = m.blob().crc;
            i.hidden = c.hidden[0];
            i.name = c.name;
        }
        i
    }

    /// The unit the profile feeds the model (for logs).
    pub fn unit(&self) -> InputUnit {
        self.profile.unit
    }
}
