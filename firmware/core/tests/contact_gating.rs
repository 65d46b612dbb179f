//! Contact gating: a channel stepped with `Model::step_in_contact` must give, from each contact
//! onset on, exactly what a freshly reset model gives on the samples from that onset — the
//! property training relies on (its sequences start at the onset with a zero state).
mod common;

use slipguard_core::blob::{AlignedBlob, Variant};
use slipguard_core::decision::{ContactConfig, ContactEdge};
use slipguard_core::model::{ChannelState, Model};
use slipguard_core::quantize::quantize;

/// A force trace with two contacts: idle, load, a one-step dip, unload, idle, load again.
fn two_contacts() -> Vec<i32> {
    let load = common::smooth_force(9, 120);
    let mut x = vec![0i32; 15];
    x.extend(load[..60].iter().map(|v| 2000 + v.round() as i32));
    x.push(100); // one-step dip: contact holds
    x.extend(load[60..].iter().map(|v| 2000 + v.round() as i32));
    x.extend(std::iter::repeat_n(50, 25));
    x.extend(load[..40].iter().map(|v| 3000 + v.round() as i32));
    x
}

#[test]
fn gated_steps_restart_at_each_onset_like_a_fresh_model() {
    for (variant, diff) in [
        (Variant::DataStftLstm, true),
        (Variant::Lstm, false),
        (Variant::LstmStftLstm, true),
    ] {
        let float = common::random_model(variant, 16, diff, 5);
        let calib = [common::smooth_force(3, 300)];
        let refs: Vec<&[f32]> = calib.iter().map(|c| c.as_slice()).collect();
        let (blob, _) = quantize(&float, &refs, None).unwrap();
        let blob = AlignedBlob::new(&blob);
        let model = Model::from_bytes(blob.as_bytes()).unwrap();
        let contact = ContactConfig::of(model.config());
        let x = two_contacts();

        let mut st = ChannelState::new();
        let gated: Vec<_> = x
            .iter()
            .map(|&r| model.step_in_contact(&mut st, &contact, r))
            .collect();
        let onsets: Vec<usize> = (0..x.len())
            .filter(|&i| gated[i].contact == ContactEdge::Began)
            .collect();
        assert_eq!(
            onsets.len(),
            2,
            "{variant:?}: two contacts, the dip is not a third"
        );
        for (i, g) in gated.iter().enumerate() {
            assert_eq!(g.step.is_some(), g.contact.in_contact(), "step {i}");
        }
        // Reference: a fresh model from each onset over the steps in contact.
        for &on in &onsets {
            let mut fresh = ChannelState::new();
            for i in on..x.len() {
                let Some(got) = gated[i].step else { break };
                let want = model.step(&mut fresh, x[i]);
                assert_eq!(got, want, "{variant:?}: onset {on}, step {i}");
            }
        }
    }
}
