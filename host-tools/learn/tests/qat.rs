//! Quantization-aware fine-tuning: the forward pass it trains with is the blob's arithmetic.
use slipguard_core::blob::{AlignedBlob, Variant};
use slipguard_core::quantize::quantize;
use slipguard_core::units::Millihertz;
use slipguard_data::labels::ChannelSequence;
use slipguard_learn::evaluation::{force_config, sim_force_sequences};
use slipguard_learn::qat::{QatConfig, blob_agreement, qat_finetune, snap_to_blob_grid};
use slipguard_learn::train::{TrainConfig, init_model, train};

/// A float model trained briefly on simulated force trials (weights of a realistic scale, a
/// cell state well away from zero), then fine-tuned with QAT. After QAT the bit-exact core's p
/// follows the QAT forward pass (the blob's arithmetic in f32) 40× more closely than the plain
/// float model's, and the checkpoint QAT returns (snapped to the blob's grid) differs from its
/// blob by the fixed-point arithmetic alone.
#[test]
fn blob_follows_the_qat_forward_pass() {
    let seqs = sim_force_sequences(5, 6, 0.5, 16.7);
    let data: Vec<&ChannelSequence> = seqs.iter().map(|s| &s.cs).take(12).collect();
    let config = force_config(Variant::DataStftLstm, true, 16, "qat", Millihertz(16_700));
    let init = init_model(config, 2, &data);
    let cfg = TrainConfig {
        epochs: 6,
        batch: 4,
        lr: 2e-2,
        patience: 100,
        ..TrainConfig::default()
    };
    let float = train(&init, &data, &[], &cfg, |_| {}).unwrap().model;
    let calib: Vec<&[f32]> = data.iter().map(|s| s.samples.as_slice()).collect();
    let bits = quantize(&float, &calib, None).unwrap().1.cell_frac_bits;
    let before = blob_agreement(&float, &calib, &calib).unwrap();
    let qc = QatConfig {
        epochs: 3,
        lr: 1e-3,
        cell_frac_bits: bits.clone(),
        agreement: Vec::new(),
        max_dp: 0.05,
        cell_max: 0.0,
    };
    let mut epochs = 0;
    let out = qat_finetune(&float, &data, &[], &cfg, &qc, |p| {
        if let slipguard_learn::train::Progress::Epoch(_) = p {
            epochs += 1;
        }
    })
    .unwrap()
    .trained;
    assert_eq!(epochs, 3);
    assert_ne!(
        out.model.lstms[0].w_hh,
        snap_to_blob_grid(&float).lstms[0].w_hh,
        "QAT changed nothing"
    );
    let after = blob_agreement(&out.model, &calib, &calib).unwrap();
    println!(
        "cell bits {bits:?}; max |dp| of the blob: before QAT vs float {:.5}, vs the QAT forward {:.5}; after QAT vs the (snapped) float checkpoint {:.5}, vs the QAT forward {:.5}",
        before.float, before.fake_quant, after.float, after.fake_quant
    );
    // Measured (cell bits [8]): before 0.00331 / 0.00008; after 0.00175 (the rest is the
    // fixed-point arithmetic: the weights now agree) / 0.00008.
    assert!(after.fake_quant <= 2e-4, "{after:?}");
    assert!(
        before.float >= 10.0 * after.fake_quant,
        "{before:?} {after:?}"
    );
    assert!(after.float <= 0.0035, "{after:?}");
}

/// Snapping puts every weight on its row's int8 grid: the quantizer then stores the same int8
/// weights and Q3.12 biases, and the float model with the snapped weights is the model that the
/// blob's weights describe.
#[test]
fn snapped_weights_quantize_to_the_same_blob_weights() {
    let seqs = sim_force_sequences(5, 2, 0.5, 16.7);
    let data: Vec<&ChannelSequence> = seqs.iter().map(|s| &s.cs).collect();
    for v in [Variant::DataStftLstm, Variant::LstmStftLstm] {
        let m = init_model(
            force_config(v, true, 16, "snap", Millihertz(16_700)),
            4,
            &data,
        );
        let s = snap_to_blob_grid(&m);
        assert_ne!(s.lstms[0].w_hh, m.lstms[0].w_hh);
        let (a, _) = quantize(&m, &[], Some([11, 11])).unwrap();
        let (b, _) = quantize(&s, &[], Some([11, 11])).unwrap();
        let (a, b) = (AlignedBlob::new(&a), AlignedBlob::new(&b));
        let (a, b) = (a.parse().unwrap(), b.parse().unwrap());
        for (la, lb) in a.lstms().iter().zip(b.lstms()) {
            assert_eq!(la.weights, lb.weights);
            for (ra, rb) in la.rows.iter().zip(lb.rows) {
                assert_eq!(ra.bias_q12, rb.bias_q12);
                assert_eq!(ra.shift, rb.shift);
                assert!((ra.mx - rb.mx).abs() <= 1 << 8, "{ra:?} {rb:?}");
                assert!((ra.mh - rb.mh).abs() <= 1 << 8, "{ra:?} {rb:?}");
            }
        }
        assert_eq!(a.dense.weights, b.dense.weights);
    }
}

/// The epoch kept with agreement recordings: with a bound no epoch meets, the one whose blob
/// follows its float checkpoint most closely on them; every epoch's figure is reported, and the
/// kept model's own agreement is that figure.
#[test]
fn qat_keeps_the_epoch_closest_to_its_blob_when_none_is_within_the_bound() {
    let seqs = sim_force_sequences(7, 4, 0.5, 16.7);
    let data: Vec<&ChannelSequence> = seqs.iter().map(|s| &s.cs).take(8).collect();
    let config = force_config(Variant::DataStftLstm, true, 8, "qat", Millihertz(16_700));
    let init = init_model(config, 3, &data);
    let cfg = TrainConfig {
        epochs: 3,
        batch: 4,
        lr: 2e-2,
        patience: 100,
        ..TrainConfig::default()
    };
    let float = train(&init, &data, &[], &cfg, |_| {}).unwrap().model;
    let agreement: Vec<Vec<f32>> = data.iter().map(|s| s.samples.clone()).collect();
    let bits = vec![9u8];
    let qc = QatConfig {
        epochs: 3,
        lr: 5e-3,
        cell_frac_bits: bits.clone(),
        agreement: agreement.clone(),
        max_dp: 0.0,
        cell_max: 0.0,
    };
    let out = qat_finetune(&float, &data, &[], &cfg, &qc, |_| {}).unwrap();
    assert_eq!(out.agreement.len(), 4, "{:?}", out.agreement);
    let (kept, min) = out
        .agreement
        .iter()
        .enumerate()
        .min_by(|a, b| a.1.total_cmp(b.1))
        .unwrap();
    println!(
        "per epoch {:?}, kept {}",
        out.agreement, out.trained.best_epoch
    );
    assert_eq!(out.trained.best_epoch, kept);
    let own =
        slipguard_learn::qat::max_dp_blob_vs_float(&out.trained.model, &bits, &agreement).unwrap();
    assert!((own - min).abs() < 1e-6, "{own} vs {min}");
}
