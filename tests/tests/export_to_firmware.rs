//! Export → blob → firmware path, across the crates: the exporter, fed the shipped float
//! checkpoint, the real trials and the card's hand rule, must reproduce the shipped blob (format
//! v2) byte for byte (the trainer and the exporter share one quantizer and one model id), and
//! that blob must give the same
//! flags on the host core as the float model within the quantizer's documented agreement.
use slipguard_core::blob::AlignedBlob;
use slipguard_core::model::{ChannelState, Model};
use slipguard_data::eagle::{default_data_dir, read_tactile_csv};
use slipguard_export::pipeline::{ExportOptions, ModelSource, export};

#[test]
fn exporter_reproduces_the_shipped_hand_force_blob() {
    let root = slipguard_tests::repo_root();
    let ckpt = root.join("models/hand-force/hand-force.safetensors");
    let shipped =
        std::fs::read(root.join("models/hand-force/hand-force.bin")).expect("shipped blob");
    let opts = ExportOptions {
        source: ModelSource {
            path: ckpt,
            format: None,
            keras_config: None,
            settings_file: None,
            // The shipped hand rule (format v2), as the card's export command sets it.
            overrides: vec![(
                slipguard_export::settings::HAND_RULE.to_string(),
                "0.4,0.8,0.6".to_string(),
            )],
        },
        data: Some(default_data_dir()),
        validation: None,
        max_trials: None,
        fit_norm: false,
        cell_bits: None,
        quiet: true,
        no_holdout: false,
    };
    let out = export(&opts).expect("export of the shipped checkpoint");
    assert_eq!(out.blob.len(), shipped.len());
    let first = out.blob.iter().zip(&shipped).position(|(a, b)| a != b);
    assert_eq!(
        first, None,
        "exported blob differs from models/hand-force/hand-force.bin at byte {first:?}"
    );

    // The shipped blob parses, and on a real failure trial (force channel c4 of
    // Cheez_100_814_top_3, the object lost near step 121) its flags agree with the float model
    // on every step where the float p is at least 0.05 from the threshold.
    let blob = AlignedBlob::new(&shipped);
    let model = Model::from_bytes(blob.as_bytes()).expect("shipped blob parses");
    // Its hand rule: 0.40 and 0.80 in Q0.15 (0.4 · 32768 = 13107.2, 0.8 · 32768 = 26214.4),
    // 0.6 s at 16.7 Hz = 10 frames.
    let rule = model
        .config()
        .hand_rule
        .expect("the shipped blob carries a hand rule");
    assert_eq!(
        (rule.strict.fraction_q15, rule.guard_q15, rule.strict.window),
        (13_107, 26_214, 10)
    );
    let th = model.config().threshold_q15 as f32 / 32768.0;
    let (_, channels) =
        read_tactile_csv(&default_data_dir().join("trials/Cheez_100_814_top_3/tactile.csv"))
            .expect("trial Cheez_100_814_top_3");
    let c4 = &channels[4];
    let mut qs = ChannelState::new();
    let mut fs = out.model.new_channel();
    let (mut decisive, mut disagree) = (0, 0);
    let scale = slipguard_core::sample::InputScale::of(model.config());
    // 160 steps from the trial's grasp start (label l0 = 52).
    for &raw in &c4[52..52 + 160] {
        let q = model.p_unstable(&mut qs, scale.to_q15(raw as i32));
        let f = out.model.step(&mut fs, raw);
        if (f.p_unstable - th).abs() >= 0.05 {
            decisive += 1;
            if (q as f32 / 32768.0 >= th) != (f.p_unstable >= th) {
                disagree += 1;
            }
        }
    }
    println!("Cheez_100_814_top_3 c4: {disagree} of {decisive} decisive steps disagree");
    assert!(decisive > 100);
    assert_eq!(disagree, 0);
}
