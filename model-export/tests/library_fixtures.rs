//! Each importer against its library's own outputs (fixtures made by the committed scripts in
//! `tests/fixtures/` with torch, torch.onnx.export + ONNX's reference runtime, and Keras 3):
//! import → our float reference (features, logits, p) vs the library, then the quantized blob
//! vs the float model and vs the library. Max errors are printed (`cargo test -- --nocapture`).

use std::path::{Path, PathBuf};

use serde_json::Value;
use slipguard_core::blob::AlignedBlob;
use slipguard_core::float::p_from_logits;
use slipguard_core::model::{ChannelState, Model};
use slipguard_export::pipeline::{ModelSource, load_float, quantize_calibrated};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

struct Errors {
    features: f64,
    logits: f64,
    p_library_features: f64,
    p_end_to_end: f64,
    quant_vs_float: f64,
    quant_vs_library: f64,
    flag_mismatch: usize,
}

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn check(model_file: &str, settings: Option<&str>, expected: &str) -> Errors {
    let src = ModelSource {
        path: fixture(model_file),
        settings_file: settings.map(fixture),
        ..Default::default()
    };
    check_src(&src, expected)
}

fn check_src(src: &ModelSource, expected: &str) -> Errors {
    let model_file = src
        .path
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_default();
    let loaded = load_float(src).unwrap_or_else(|e| panic!("{model_file}: {e}"));
    assert!(
        loaded.norm_given,
        "{model_file}: normalisation should come with the settings"
    );
    let model = loaded.model;
    let exp: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture(expected)).expect("read"))
            .expect("json");
    let seqs = exp["sequences"].as_array().expect("sequences");
    let nf = model.config.feature_count();
    let mut e = Errors {
        features: 0.0,
        logits: 0.0,
        p_library_features: 0.0,
        p_end_to_end: 0.0,
        quant_vs_float: 0.0,
        quant_vs_library: 0.0,
        flag_mismatch: 0,
    };

    let raws: Vec<Vec<f32>> = seqs
        .iter()
        .map(|s| floats(&s["raw"]).into_iter().map(|x| x as f32).collect())
        .collect();
    let raw_refs: Vec<&[f32]> = raws.iter().map(|r| r.as_slice()).collect();
    let (blob, _q, cal) = quantize_calibrated(&model, &raw_refs, None, true).expect("quantize");
    let aligned = AlignedBlob::new(&blob);
    let qmodel = Model::from_bytes(aligned.as_bytes()).expect("blob parses");
    assert_eq!(qmodel.config().hidden, model.config.hidden);
    assert_eq!(cal.cell_frac_bits.len(), model.lstms.len());

    for (s, raw) in seqs.iter().zip(&raws) {
        let feats = floats(&s["features"]);
        let p_lib = floats(&s["p"]);
        let logits_lib = s.get("logits").map(floats);
        assert_eq!(feats.len(), raw.len() * nf);
        // (1) our features from the raw samples vs the script's (float64) features.
        let mut st = model.new_channel();
        for (t, &r) in raw.iter().enumerate() {
            let v = model.features(&mut st, r);
            for j in 0..nf {
                e.features = e.features.max((v[j] as f64 - feats[t * nf + j]).abs());
            }
        }
        // (2) the library's features through our LSTM(s) and dense layer: the importer alone.
        let mut st = model.new_channel();
        for t in 0..raw.len() {
            let v: Vec<f32> = feats[t * nf..(t + 1) * nf]
                .iter()
                .map(|&x| x as f32)
                .collect();
            let l = model.logits(&mut st, &v);
            if let Some(ll) = &logits_lib {
                e.logits = e
                    .logits
                    .max((l[0] as f64 - ll[2 * t]).abs())
                    .max((l[1] as f64 - ll[2 * t + 1]).abs());
            }
            e.p_library_features = e
                .p_library_features
                .max((p_from_logits(l) as f64 - p_lib[t]).abs());
        }
        // (3) end to end, raw samples → p; (4) the quantized blob vs the float model and the library.
        let mut fs = model.new_channel();
        let mut qs = ChannelState::new();
        for (t, &r) in raw.iter().enumerate() {
            let f = model.step(&mut fs, r);
            let q = qmodel.step(&mut qs, r.round() as i32);
            let pq = q.p_unstable_q15 as f64 / 32768.0;
            e.p_end_to_end = e.p_end_to_end.max((f.p_unstable as f64 - p_lib[t]).abs());
            e.quant_vs_float = e.quant_vs_float.max((pq - f.p_unstable as f64).abs());
            e.quant_vs_library = e.quant_vs_library.max((pq - p_lib[t]).abs());
            let th = model.config.threshold_q15 as f64 / 32768.0;
            if (p_lib[t] - th).abs() > 0.02 && q.unstable != f.unstable {
                e.flag_mismatch += 1;
            }
        }
    }
    println!(
        "{model_file:<28} ({} {}): max |Δfeature| {:.2e}, |Δlogit| {:.2e}, |Δp| (library features) {:.2e}, |Δp| end-to-end {:.2e}; blob: |p_q − p_float| {:.4}, |p_q − p_library| {:.4}, cell bits {:?}",
        exp["library"].as_str().unwrap_or("?"),
        exp["library_version"].as_str().unwrap_or("?"),
        e.features,
        e.logits,
        e.p_library_features,
        e.p_end_to_end,
        e.quant_vs_float,
        e.quant_vs_library,
        cal.cell_frac_bits
    );
    e
}

fn assert_close(e: &Errors, what: &str) {
    assert!(
        e.features < 1e-5,
        "{what}: features differ by {}",
        e.features
    );
    assert!(e.logits < 1e-4, "{what}: logits differ by {}", e.logits);
    assert!(
        e.p_library_features < 2e-5,
        "{what}: p differs by {}",
        e.p_library_features
    );
    assert!(
        e.p_end_to_end < 1e-4,
        "{what}: end-to-end p differs by {}",
        e.p_end_to_end
    );
    assert!(
        e.quant_vs_float < 0.02,
        "{what}: quantized p differs from float by {}",
        e.quant_vs_float
    );
    assert!(
        e.quant_vs_library < 0.02,
        "{what}: quantized p differs from the library by {}",
        e.quant_vs_library
    );
    assert_eq!(
        e.flag_mismatch, 0,
        "{what}: flags differ away from the threshold"
    );
}

#[test]
fn safetensors_variant_c_with_force_difference() {
    assert_close(
        &check("torch_c.safetensors", None, "torch_c.expected.json"),
        "torch_c",
    );
}

#[test]
fn safetensors_dual_variant_d() {
    assert_close(
        &check("torch_d.safetensors", None, "torch_d.expected.json"),
        "torch_d",
    );
}

#[test]
fn safetensors_plain_state_dict_with_prefix_variant_a() {
    assert_close(
        &check(
            "torch_a_prefixed.safetensors",
            None,
            "torch_a_prefixed.expected.json",
        ),
        "torch_a",
    );
}

#[test]
fn onnx_dynamo_export_with_external_data() {
    assert_close(
        &check(
            "onnx_c.onnx",
            Some("onnx_c.settings.json"),
            "onnx_c.expected.json",
        ),
        "onnx_c",
    );
}

#[test]
fn onnx_legacy_export_dual_concatenated_bands_first() {
    assert_close(
        &check(
            "onnx_d_legacy.onnx",
            Some("onnx_d_legacy.settings.json"),
            "onnx_d_legacy.expected.json",
        ),
        "onnx_d",
    );
}

#[test]
fn keras_archive_variant_c_softmax_head() {
    assert_close(
        &check(
            "keras_c.keras",
            Some("keras_c.settings.json"),
            "keras_c.expected.json",
        ),
        "keras_c",
    );
}

#[test]
fn keras_weights_h5_only() {
    assert_close(
        &check(
            "keras_c.weights.h5",
            Some("keras_c.settings.json"),
            "keras_c.expected.json",
        ),
        "keras_c.weights.h5",
    );
}

#[test]
fn keras_dual_concatenated_bands_first() {
    assert_close(
        &check(
            "keras_d.keras",
            Some("keras_d.settings.json"),
            "keras_d.expected.json",
        ),
        "keras_d",
    );
}

/// torch's default exporter (dynamo, opset 18+) at hidden 64: R (and for some variants W)
/// arrives as a constant subgraph (Slice/Concat/… of initializers), folded by the importer.
#[test]
fn onnx_default_dynamo_export_at_hidden_64_all_four_variants() {
    for v in ["a", "b", "c", "d"] {
        let name = format!("dynamo64_{v}");
        let e = check(
            &format!("{name}.onnx"),
            Some(&format!("{name}.settings.json")),
            &format!("{name}.expected.json"),
        );
        // Float import as tight as the other routes; blob vs library measured ≤ 0.0014.
        assert!(e.features < 1e-5 && e.logits < 1e-4, "{name}: {}", e.logits);
        assert!(e.p_end_to_end < 1e-4, "{name}: {}", e.p_end_to_end);
        assert!(e.quant_vs_library < 0.003, "{name}: {}", e.quant_vs_library);
    }
}

/// A dual state_dict whose names do not say in which order the hidden states were
/// concatenated: with `--dual-order bands,force` it matches torch; without it the import is
/// refused (tests/cli.rs); with the wrong order it is far off.
#[test]
fn safetensors_dual_with_explicit_dual_order() {
    let src = |order: &str| ModelSource {
        path: fixture("torch_d_bands_first.safetensors"),
        overrides: vec![("dual_order".into(), order.into())],
        ..Default::default()
    };
    assert_close(
        &check_src(&src("bands,force"), "torch_d_bands_first.expected.json"),
        "torch_d_bands_first",
    );
    let wrong = check_src(&src("force,bands"), "torch_d_bands_first.expected.json");
    println!("wrong --dual-order: max |Δlogit| {:.3}", wrong.logits);
    assert!(wrong.logits > 0.05, "{}", wrong.logits);
}

/// Keras LSTM and Dense with use_bias=False: no bias datasets in the file, zero biases.
#[test]
fn keras_without_biases() {
    assert_close(
        &check(
            "keras_c_nobias.keras",
            Some("keras_c_nobias.settings.json"),
            "keras_c_nobias.expected.json",
        ),
        "keras_c_nobias",
    );
}

/// The comparison has teeth: a model with ONNX's gate order left in (i, o, f, c read as
/// i, f, g, o) or with the dual model's dense columns swapped is far from the library.
#[test]
fn wrong_gate_order_or_column_order_is_detected() {
    let exp: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("onnx_c.expected.json")).unwrap())
            .unwrap();
    let s = &exp["sequences"][0];
    let (feats, logits_lib) = (floats(&s["features"]), floats(&s["logits"]));
    let max_logit_error = |m: &slipguard_core::float::FloatModel| {
        let nf = m.config.feature_count();
        let mut st = m.new_channel();
        let mut err = 0f64;
        for t in 0..feats.len() / nf {
            let v: Vec<f32> = feats[t * nf..(t + 1) * nf]
                .iter()
                .map(|&x| x as f32)
                .collect();
            let l = m.logits(&mut st, &v);
            err = err
                .max((l[0] as f64 - logits_lib[2 * t]).abs())
                .max((l[1] as f64 - logits_lib[2 * t + 1]).abs());
        }
        err
    };
    let src = ModelSource {
        path: fixture("onnx_c.onnx"),
        settings_file: Some(fixture("onnx_c.settings.json")),
        ..Default::default()
    };
    let good = load_float(&src).unwrap().model;
    assert!(max_logit_error(&good) < 1e-4);
    let mut bad = good.clone();
    let l = &mut bad.lstms[0];
    // Back to ONNX's block order: PyTorch blocks [i, f, g, o] → [i, o, f, g].
    let back = [0, 3, 1, 2];
    l.w_ih = slipguard_export::import::reorder_gates(&l.w_ih, l.hidden, l.input, back);
    l.w_hh = slipguard_export::import::reorder_gates(&l.w_hh, l.hidden, l.hidden, back);
    let e = max_logit_error(&bad);
    println!("gate order left as ONNX's: max |Δlogit| {e:.3}");
    assert!(e > 0.05, "a gate-order mix-up must be visible, got {e}");

    let src = ModelSource {
        path: fixture("keras_d.keras"),
        settings_file: Some(fixture("keras_d.settings.json")),
        ..Default::default()
    };
    let mut dual = load_float(&src).unwrap().model;
    let (h0, h1) = (dual.lstms[0].hidden, dual.lstms[1].hidden);
    let k = h0 + h1;
    for r in 0..2 {
        let row = dual.dense.w[r * k..(r + 1) * k].to_vec();
        let swapped: Vec<f32> = row[h0..]
            .iter()
            .chain(&row[..h0])
            .copied()
            .take(k)
            .collect();
        if h0 == h1 {
            dual.dense.w[r * k..(r + 1) * k].copy_from_slice(&swapped);
        } else {
            dual.dense.w[r * k..(r + 1) * k].reverse();
        }
    }
    let exp: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("keras_d.expected.json")).unwrap())
            .unwrap();
    let s = &exp["sequences"][0];
    let (feats, l_lib) = (floats(&s["features"]), floats(&s["logits"]));
    let mut st = dual.new_channel();
    let mut err = 0f64;
    for t in 0..feats.len() / 11 {
        let v: Vec<f32> = feats[t * 11..(t + 1) * 11]
            .iter()
            .map(|&x| x as f32)
            .collect();
        let l = dual.logits(&mut st, &v);
        err = err.max((l[1] as f64 - l_lib[2 * t + 1]).abs());
    }
    println!("dual dense columns permuted: max |Δlogit| {err:.3}");
    assert!(err > 0.05);
}
