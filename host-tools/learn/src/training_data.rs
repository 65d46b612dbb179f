//! Training data: the sequences a model is trained on, from recorded trials and from the
//! simulators, cut to where the firmware's model state starts; each fold's training and
//! validation split; the calibration inputs of the quantizer; the whole recordings the
//! quantization-aware fine-tuning checks its blob against. `slipguard train` draws on these
//! (the closed-loop simulator's own training sequences come from
//! `slipguard_learn::closed_loop::training_sequences`).

use slipguard_data::Trial;
use slipguard_data::labels::{ChannelSequence, LabelConfig};

use crate::evaluation::{Sequence, sequences_of, sim_force_sequences, sim_suction_sequences};
use crate::product::{OnsetRule, cut_to_contact};
use crate::train::split_by_trial;

/// Sequences of calibration inputs the quantizer sees (the first of the training set).
pub const CALIBRATION_SEQUENCES: usize = 64;

/// The labelled sequences of recorded trials at `rate_hz`: the paper's label durations
/// ([`LabelConfig::default`]) scaled to the data's rate.
pub fn recorded_sequences(trials: &[Trial], rate_hz: f32) -> Vec<Sequence> {
    sequences_of(trials, &LabelConfig::default().scaled_to(rate_hz))
}

/// How many simulated trials to draw, and how.
#[derive(Clone, Copy, Debug)]
pub struct SimRecipe {
    /// Seed of the pre-training trials; the mixed trials use `seed + 1`.
    pub seed: u64,
    /// Trials for the pre-training.
    pub pretrain: usize,
    /// Trials mixed into the (fine-)tuning set.
    pub mix: usize,
    /// Share of trials drawn as drops (0…1).
    pub failure_share: f64,
    /// Frame rate, Hz (force; the suction simulator runs at its own 71 Hz).
    pub rate_hz: f32,
}

impl SimRecipe {
    /// Simulated force sequences: (pre-training, mixed), from seeds `seed` and `seed + 1`.
    pub fn force(&self) -> (Vec<Sequence>, Vec<Sequence>) {
        let pre = sim_force_sequences(self.seed, self.pretrain, self.failure_share, self.rate_hz);
        let mix = sim_force_sequences(self.seed + 1, self.mix, self.failure_share, self.rate_hz);
        (pre, mix)
    }

    /// Simulated suction sequences to mix in, from seed `seed + 1` (suction has no
    /// pre-training: the simulated trials are the whole training set when no recordings are
    /// given).
    pub fn suction_mix(&self) -> Vec<Sequence> {
        sim_suction_sequences(self.seed + 1, self.mix, self.failure_share)
    }
}

/// Everything one training run draws on.
#[derive(Clone, Debug, Default)]
pub struct TrainingSets {
    /// Recorded trials' sequences ([`recorded_sequences`]).
    pub real: Vec<Sequence>,
    /// Simulated sequences for the pre-training (simulated and closed-loop trials).
    pub sim_pre: Vec<Sequence>,
    /// Simulated sequences mixed into the (fine-)tuning set.
    pub sim_mix: Vec<Sequence>,
    /// Simulated closed-loop sequences mixed into the (fine-)tuning set.
    pub cl_mix: Vec<Sequence>,
}

impl TrainingSets {
    /// Sequences in all four sets.
    pub fn len(&self) -> usize {
        self.real.len() + self.sim_pre.len() + self.sim_mix.len() + self.cl_mix.len()
    }

    /// No sequence in any set.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Any simulated sequence (pre-training, mixed or closed-loop).
    pub fn has_simulated(&self) -> bool {
        !self.sim_pre.is_empty() || !self.sim_mix.is_empty() || !self.cl_mix.is_empty()
    }

    /// Every sequence cut to start where the firmware's model state starts, at its channel's
    /// contact onset by `rule` ([`cut_to_contact`]; channels without contact are dropped).
    pub fn cut_to_contact(self, rule: &OnsetRule) -> Self {
        Self {
            real: cut_to_contact(self.real, rule),
            sim_pre: cut_to_contact(self.sim_pre, rule),
            sim_mix: cut_to_contact(self.sim_mix, rule),
            cl_mix: cut_to_contact(self.cl_mix, rule),
        }
    }
}

/// The channel sequences of `v`.
pub fn channel_refs(v: &[Sequence]) -> Vec<&ChannelSequence> {
    v.iter().map(|s| &s.cs).collect()
}

/// One fold's (training, validation) sets: `train_real` split by trial with `split_seed`
/// (`val_share` of it for validation); the simulated mix all to training when there are
/// recorded sequences, else split too (with `mix_seed`); the closed-loop mix split by trial
/// with `mix_seed`. Training holds real, simulated, closed-loop in that order, validation
/// the same.
pub fn fold_split<'d>(
    train_real: &[&'d Sequence],
    sets: &'d TrainingSets,
    val_share: f64,
    split_seed: u64,
    mix_seed: u64,
) -> (Vec<&'d ChannelSequence>, Vec<&'d ChannelSequence>) {
    let tr_refs: Vec<&ChannelSequence> = train_real.iter().map(|s| &s.cs).collect();
    let (mut tr, val) = split_by_trial(&tr_refs, val_share, split_seed);
    let (mut tr_mix, val_mix) = if sets.real.is_empty() {
        split_by_trial(&channel_refs(&sets.sim_mix), val_share, mix_seed)
    } else {
        (channel_refs(&sets.sim_mix), Vec::new())
    };
    tr.append(&mut tr_mix);
    let (mut tr_cl, val_cl) = split_by_trial(&channel_refs(&sets.cl_mix), val_share, mix_seed);
    tr.append(&mut tr_cl);
    let val = val.into_iter().chain(val_mix).chain(val_cl).collect();
    (tr, val)
}

/// The quantizer's calibration inputs: the samples of the first
/// [`CALIBRATION_SEQUENCES`] training sequences.
pub fn calibration_inputs<'s>(tr: &[&'s ChannelSequence]) -> Vec<&'s [f32]> {
    tr.iter()
        .take(CALIBRATION_SEQUENCES)
        .map(|s| s.samples.as_slice())
        .collect()
}

/// The whole contact channels of `trials` except those in `excluded` (held-out trials): the
/// recordings on which the quantization-aware fine-tuning measures its blob against the float
/// model, unlabelled.
pub fn agreement_channels(trials: &[Trial], excluded: &[String]) -> Vec<Vec<f32>> {
    trials
        .iter()
        .filter(|t| !excluded.contains(&t.id))
        .flat_map(|t| {
            t.samples
                .iter()
                .enumerate()
                .filter(|(c, s)| t.contact.get(*c) == Some(&true) && !s.is_empty())
                .map(|(_, s)| s.clone())
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn agreement_channels_keep_contact_channels_outside_the_excluded_trials() {
        let mut a = Trial::new(
            "a",
            slipguard_data::Unit::MilliNewton,
            16.7,
            vec![vec![1.0, 2.0], vec![3.0], vec![]],
        );
        a.contact = vec![true, false, true];
        let mut b = a.clone();
        b.id = "b".into();
        let got = agreement_channels(&[a, b], &["b".to_string()]);
        assert_eq!(got, vec![vec![1.0, 2.0]]);
    }
}
