//! The whole pipeline over a parsed blob: per channel, sample → features → LSTM(s) →
//! decision; for the hand-level variant, per frame, the contact channels' inputs → hand
//! features ([`crate::features::hand`]) → LSTM → p(unstable).

use crate::MAX_INPUT;
use crate::blob::{BlobError, ModelBlob, ModelConfig};
use crate::decision::{
    ContactConfig, ContactEdge, ContactState, DecisionConfig, DecisionState, p_unstable,
};
use crate::features::hand::{HAND_FEATURES, HandFeatureConfig, HandFeatureState, hand_features};
use crate::features::stft::StftPlan;
use crate::features::{FeatureLayout, FeatureState, normalise, raw_features};
use crate::lstm::{self, LstmState};
use crate::sample::InputScale;

/// A model ready to run: the parsed blob plus the shared STFT plan.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    blob: ModelBlob<'a>,
    plan: Option<StftPlan>,
    layout: FeatureLayout,
    scale: InputScale,
    decision: DecisionConfig,
    /// The hand features' windows (hand-level variant only).
    hand: Option<HandFeatureConfig>,
}

/// The hand features' windows of a hand-level model's header (`None` for a per-channel
/// variant): derived from its rate, its default contact threshold (the ratios' floor) and its
/// STFT setting, so the blob needs no record of its own. The one home of that derivation
/// (the model, the trainer's features and the tests use it).
pub fn hand_feature_config(config: &ModelConfig) -> Option<HandFeatureConfig> {
    config.variant.is_hand().then(|| {
        HandFeatureConfig::for_rate_mhz(
            config.sample_rate_mhz,
            ContactConfig::of(config).on_q15 as i32,
            config.stft.window_len,
            config.stft.first_bin,
            config.stft.n_bins,
        )
    })
}

/// Everything a hand-level model remembers between frames (about 0.8 KiB); reset at grasp
/// start. The channels' contact gates stay in their [`ChannelState`]s.
#[derive(Clone, Debug, Default)]
pub struct HandState {
    /// The hand features' history.
    pub features: HandFeatureState,
    /// The LSTM state.
    pub lstm: LstmState,
}

impl HandState {
    /// A state as after grasp start.
    pub const fn new() -> Self {
        Self {
            features: HandFeatureState::new(),
            lstm: LstmState::new(),
        }
    }
}

/// Everything one sensor channel remembers between steps (about 1.1 KiB with two LSTMs).
#[derive(Clone, Debug, Default)]
pub struct ChannelState {
    /// STFT window and previous sample.
    pub features: FeatureState,
    /// LSTM states (the second is used by the dual variant only).
    pub lstm: [LstmState; 2],
    /// Flag hysteresis.
    pub decision: DecisionState,
    /// Contact detection (used by [`Model::step_in_contact`]; kept across a contact restart).
    pub contact: ContactState,
}

impl ChannelState {
    /// A state as after reset.
    pub const fn new() -> Self {
        Self {
            features: FeatureState::new(),
            lstm: [LstmState::new(), LstmState::new()],
            decision: DecisionState {
                unstable: false,
                run_above: 0,
                run_below: 0,
            },
            contact: ContactState::new(),
        }
    }
    /// Forgets everything (grasp start).
    pub fn reset(&mut self) {
        *self = Self::new();
    }
    /// Restarts the model's state (STFT window, previous sample, LSTM, hysteresis) from zero
    /// and keeps the contact state: what happens at a contact onset.
    pub fn restart(&mut self) {
        let contact = self.contact;
        *self = Self::new();
        self.contact = contact;
    }
}

/// What one step produces for one channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepOutput {
    /// p(unstable), Q0.15.
    pub p_unstable_q15: i16,
    /// The flag after threshold and hysteresis.
    pub unstable: bool,
}

/// What one contact-gated step produces for one channel.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GatedOutput {
    /// The contact detector's view of this step.
    pub contact: ContactEdge,
    /// The model's output, `None` while the channel is not in contact (the model is not run).
    pub step: Option<StepOutput>,
}

impl<'a> Model<'a> {
    /// Parses and validates `bytes` (4-byte aligned) and prepares the STFT plan.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Self, BlobError> {
        Self::new(ModelBlob::parse(bytes)?)
    }

    /// Prepares a parsed blob.
    pub fn new(blob: ModelBlob<'a>) -> Result<Self, BlobError> {
        let config = blob.config;
        let plan = if config.variant.uses_bands() {
            Some(StftPlan::new(config.stft).map_err(BlobError::Stft)?)
        } else {
            None
        };
        let scale = InputScale::of(&config);
        let hand = hand_feature_config(&config);
        Ok(Self {
            blob,
            plan,
            layout: config.feature_layout(),
            scale,
            decision: DecisionConfig::of(&config),
            hand,
        })
    }

    /// The hand features' windows of a hand-level model (`None` for a per-channel model).
    pub fn hand_features(&self) -> Option<&HandFeatureConfig> {
        self.hand.as_ref()
    }

    /// Whether one network runs per hand ([`Self::hand_p`]) rather than per channel.
    pub fn is_hand(&self) -> bool {
        self.hand.is_some()
    }

    /// Contact detection alone on one raw sample of a channel (what a hand-level model gates
    /// its channels with): the edge and the channel's Q1.15 input.
    pub fn gate(
        &self,
        state: &mut ChannelState,
        contact: &ContactConfig,
        raw: i32,
    ) -> (ContactEdge, i16) {
        let x = self.scale.to_q15(raw);
        (contact.update(&mut state.contact, x), x)
    }

    /// One frame's raw hand features (Q3.12, [`crate::features::hand`]) from the channels'
    /// Q1.15 inputs (`None` out of contact) and whether the lift command has come; all zero
    /// for a per-channel model.
    pub fn hand_feature_row(
        &self,
        state: &mut HandState,
        x: &[Option<i16>],
        lifted: bool,
    ) -> [i16; HAND_FEATURES] {
        let mut v = [0i16; HAND_FEATURES];
        if let (Some(cfg), Some(plan)) = (&self.hand, &self.plan) {
            hand_features(cfg, plan, &mut state.features, x, lifted, &mut v);
        }
        v
    }

    /// One frame of a hand-level model: hand features, normalisation, LSTM and dense layer →
    /// the hand's p(unstable), Q0.15 (0 for a per-channel model).
    pub fn hand_p(&self, state: &mut HandState, x: &[Option<i16>], lifted: bool) -> i16 {
        let [only] = self.blob.lstms() else {
            return 0;
        };
        if self.hand.is_none() {
            return 0;
        }
        let mut v = self.hand_feature_row(state, x, lifted);
        normalise(self.blob.norm, &mut v);
        let n = only.inputs.min(HAND_FEATURES);
        lstm::step(only, &mut state.lstm, &v[..n]);
        p_unstable(&self.blob.dense, &[&state.lstm.h[..only.hidden]])
    }

    /// Header fields.
    pub fn config(&self) -> &ModelConfig {
        &self.blob.config
    }

    /// The parsed blob.
    pub fn blob(&self) -> &ModelBlob<'a> {
        &self.blob
    }

    /// The decision settings in force.
    pub fn decision(&self) -> DecisionConfig {
        self.decision
    }

    /// Replaces the decision settings (e.g. a threshold sent by the hand controller).
    pub fn set_decision(&mut self, decision: DecisionConfig) {
        self.decision = decision;
    }

    /// Runs one raw sample (sensor units) through the channel's pipeline.
    pub fn step(&self, state: &mut ChannelState, raw: i32) -> StepOutput {
        let p = self.p_unstable(state, self.scale.to_q15(raw));
        let unstable = self.decision.update(&mut state.decision, p);
        StepOutput {
            p_unstable_q15: p,
            unstable,
        }
    }

    /// Runs one raw sample through contact detection and, while the channel is in contact, the
    /// model: at a contact onset the model's state restarts from zero (so the start-up
    /// transient of a fresh LSTM falls on the onset, where the training sequences start too);
    /// without contact the model is not run, and the channel's flag is down.
    pub fn step_in_contact(
        &self,
        state: &mut ChannelState,
        contact: &ContactConfig,
        raw: i32,
    ) -> GatedOutput {
        let x = self.scale.to_q15(raw);
        let edge = contact.update(&mut state.contact, x);
        if edge == ContactEdge::Began {
            state.restart();
        }
        if !edge.in_contact() {
            return GatedOutput {
                contact: edge,
                step: None,
            };
        }
        let p = self.p_unstable(state, x);
        let unstable = self.decision.update(&mut state.decision, p);
        GatedOutput {
            contact: edge,
            step: Some(StepOutput {
                p_unstable_q15: p,
                unstable,
            }),
        }
    }

    /// The input scaling in force.
    pub fn scale(&self) -> &InputScale {
        &self.scale
    }

    /// Features, LSTM(s) and dense layer for one Q1.15 sample; returns p(unstable) in Q0.15
    /// (0 for a hand-level model, which has no per-channel network: [`Self::hand_p`]).
    pub fn p_unstable(&self, state: &mut ChannelState, x_q15: i16) -> i16 {
        if self.hand.is_some() {
            return 0;
        }
        let mut v = [0i16; MAX_INPUT];
        raw_features(
            self.layout,
            self.plan.as_ref(),
            &mut state.features,
            x_q15,
            &mut v,
        );
        let n = self.layout.len().min(MAX_INPUT);
        normalise(self.blob.norm, &mut v[..n]);
        let lstms = self.blob.lstms();
        match lstms {
            [only] => {
                lstm::step(only, &mut state.lstm[0], &v[..n]);
                p_unstable(&self.blob.dense, &[&state.lstm[0].h[..only.hidden]])
            }
            [a, b] => {
                let split = a.inputs.min(n);
                let [sa, sb] = &mut state.lstm;
                lstm::step(a, sa, &v[..split]);
                lstm::step(b, sb, &v[split..n]);
                p_unstable(&self.blob.dense, &[&sa.h[..a.hidden], &sb.h[..b.hidden]])
            }
            _ => 0,
        }
    }
}
