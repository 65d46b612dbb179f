//! The binary: every kind of malformed or unsupported input gets its own error and exit code,
//! failed exports leave no file behind, and the outputs (blob, report, snippet) are right.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use safetensors::tensor::{Dtype, SafeTensors, TensorView};

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures")
        .join(name)
}

fn tmp(test: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("slipguard-export-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).expect("temp dir");
    d
}

fn data_dir() -> PathBuf {
    slipguard_data::eagle::default_data_dir()
}

fn run(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_slipguard-export"))
        .args(args)
        .output()
        .expect("run binary")
}

/// Runs, expects exit `code` and `needle` in stderr; returns stderr.
fn expect_fail(args: &[&str], code: i32, needle: &str) -> String {
    let out = run(args);
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(code), "args {args:?}: stderr {err}");
    assert!(
        err.contains(needle),
        "args {args:?}: expected `{needle}` in: {err}"
    );
    println!("exit {code}: {}", err.lines().next().unwrap_or(""));
    err
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// (name, dtype, shape, bytes) of one tensor.
type Tensor = (String, Dtype, Vec<usize>, Vec<u8>);

/// Tensors of a safetensors file as (name, dtype, shape, bytes), and its metadata.
fn read_st(path: &Path) -> (Vec<Tensor>, HashMap<String, String>) {
    let bytes = std::fs::read(path).expect("read");
    let st = SafeTensors::deserialize(&bytes).expect("parse");
    let (_, meta) = SafeTensors::read_metadata(&bytes).expect("meta");
    let mut v: Vec<_> = st
        .tensors()
        .into_iter()
        .map(|(n, t)| (n, t.dtype(), t.shape().to_vec(), t.data().to_vec()))
        .collect();
    v.sort_by(|a, b| a.0.cmp(&b.0));
    (v, meta.metadata().clone().unwrap_or_default())
}

fn write_st(path: &Path, tensors: &[Tensor], meta: &HashMap<String, String>) {
    let views: Vec<(String, TensorView<'_>)> = tensors
        .iter()
        .map(|(n, d, s, b)| (n.clone(), TensorView::new(*d, s.clone(), b).expect("view")))
        .collect();
    let bytes = safetensors::serialize(views, Some(meta.clone())).expect("serialize");
    std::fs::write(path, bytes).expect("write");
}

fn f32_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn truncated(src: &str, dir: &Path, frac: f64) -> PathBuf {
    let b = std::fs::read(fixture(src)).expect("read");
    let p = dir.join(src);
    std::fs::write(&p, &b[..(b.len() as f64 * frac) as usize]).expect("write");
    p
}

#[test]
fn truncated_files_exit_4() {
    let d = tmp("trunc");
    let out = d.join("m.bin");
    for (src, frac, needle) in [
        ("torch_c.safetensors", 0.5, "not a valid safetensors"),
        ("onnx_d_legacy.onnx", 0.5, "not a valid ONNX"),
        ("keras_c.keras", 0.6, "not a readable .keras"),
        ("keras_c.weights.h5", 0.5, ""),
    ] {
        let p = truncated(src, &d, frac);
        expect_fail(
            &[
                "export",
                s(&p),
                "--settings",
                s(&fixture("keras_c.settings.json")),
                "-o",
                s(&out),
                "-q",
            ],
            4,
            needle,
        );
        assert!(!out.exists(), "a failed export must not leave a blob");
    }
    // ONNX external data cut short.
    std::fs::copy(fixture("onnx_c.onnx"), d.join("onnx_c.onnx")).unwrap();
    let data = std::fs::read(fixture("onnx_c.onnx.data")).unwrap();
    std::fs::write(d.join("onnx_c.onnx.data"), &data[..data.len() / 2]).unwrap();
    expect_fail(
        &[
            "export",
            s(&d.join("onnx_c.onnx")),
            "--settings",
            s(&fixture("onnx_c.settings.json")),
            "-o",
            s(&out),
            "-q",
        ],
        4,
        "past the end",
    );
}

#[test]
fn missing_or_misnamed_tensors_exit_5() {
    let d = tmp("names");
    let (t, meta) = read_st(&fixture("torch_c.safetensors"));
    let renamed: Vec<_> = t
        .iter()
        .map(|(n, dt, sh, b)| {
            (
                n.replace("weight_ih_l0", "w_ih"),
                *dt,
                sh.clone(),
                b.clone(),
            )
        })
        .collect();
    let p = d.join("renamed.safetensors");
    write_st(&p, &renamed, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        5,
        "lstm.weight_ih_l0",
    );
    let no_hh: Vec<_> = t
        .iter()
        .filter(|x| x.0 != "lstm.weight_hh_l0")
        .cloned()
        .collect();
    write_st(&p, &no_hh, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        5,
        "`lstm.weight_hh_l0`",
    );
    let no_dense: Vec<_> = t
        .iter()
        .filter(|x| !x.0.starts_with("dense"))
        .cloned()
        .collect();
    write_st(&p, &no_dense, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        5,
        "dense.weight",
    );
    // A dual checkpoint declared as such but holding one LSTM.
    expect_fail(
        &[
            "export",
            s(&fixture("torch_c.safetensors")),
            "--variant",
            "d",
            "-o",
            s(&d.join("m.bin")),
        ],
        5,
        "needs 2 LSTMs",
    );
}

#[test]
fn wrong_shapes_exit_6() {
    let d = tmp("shapes");
    let out = d.join("m.bin");
    // Variant (a) has 2 inputs (force, d(t)); the checkpoint's LSTM takes 12.
    expect_fail(
        &[
            "export",
            s(&fixture("torch_c.safetensors")),
            "--variant",
            "a",
            "-o",
            s(&out),
        ],
        6,
        "`lstm.weight_ih_l0` has shape [64, 12], expected [64, 2]",
    );
    // Keras model exported for 11 features but declared with d(t).
    expect_fail(
        &[
            "export",
            s(&fixture("keras_c.keras")),
            "--settings",
            s(&fixture("keras_c.settings.json")),
            "--force-diff",
            "true",
            "-o",
            s(&out),
        ],
        6,
        "layers/lstm/cell/vars/0 (kernel)",
    );
    let (mut t, meta) = read_st(&fixture("torch_c.safetensors"));
    for x in t.iter_mut() {
        if x.0 == "dense.weight" {
            x.2 = vec![3, 16];
            x.3 = f32_bytes(&[0.1; 48]);
        }
        if x.0 == "dense.bias" {
            x.2 = vec![3];
            x.3 = f32_bytes(&[0.0; 3]);
        }
    }
    let p = d.join("dense3.safetensors");
    write_st(&p, &t, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&out)],
        6,
        "`dense.weight` has shape [3, 16], expected [2, 16]",
    );
    let (mut t, meta) = read_st(&fixture("torch_c.safetensors"));
    for x in t.iter_mut() {
        if x.0 == "lstm.bias_hh_l0" {
            x.2 = vec![60];
            x.3.truncate(240);
        }
    }
    write_st(&p, &t, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&out)],
        6,
        "`lstm.bias_hh_l0` has shape [60], expected [64]",
    );
    assert!(!out.exists());
}

#[test]
fn nan_and_inf_weights_exit_7() {
    let d = tmp("nan");
    let (t, meta) = read_st(&fixture("torch_c.safetensors"));
    for (name, idx, val) in [
        ("lstm.weight_hh_l0", 37usize, f32::NAN),
        ("dense.bias", 1, f32::INFINITY),
    ] {
        let mut t2 = t.clone();
        for x in t2.iter_mut() {
            if x.0 == name {
                x.3[idx * 4..idx * 4 + 4].copy_from_slice(&val.to_le_bytes());
            }
        }
        let p = d.join("nan.safetensors");
        write_st(&p, &t2, &meta);
        expect_fail(
            &["export", s(&p), "-o", s(&d.join("m.bin"))],
            7,
            &format!("`{name}` has a NaN or infinite value at flat index {idx}"),
        );
    }
}

#[test]
fn constructs_the_firmware_cannot_run_exit_8() {
    let d = tmp("unsupported");
    let out = d.join("m.bin");
    let ks = fixture("keras_c.settings.json");
    let os = fixture("onnx_c.settings.json");
    let cases: Vec<(PathBuf, Option<&PathBuf>, &str)> = vec![
        (
            fixture("bad_bidirectional.safetensors"),
            None,
            "bidirectional",
        ),
        (fixture("bad_proj.safetensors"), None, "projection"),
        (fixture("bad_two_layers.safetensors"), None, "stacked LSTM"),
        (
            fixture("bad_bidirectional.onnx"),
            Some(&os),
            "direction=bidirectional",
        ),
        (fixture("bad_two_layers.onnx"), Some(&os), "stacked LSTMs"),
        (fixture("bad_peephole.onnx"), Some(&os), "peephole"),
        (fixture("bad_clip.onnx"), Some(&os), "attribute clip"),
        (fixture("bad_hard_sigmoid.onnx"), Some(&os), "HardSigmoid"),
        (
            fixture("bad_hard_sigmoid.keras"),
            Some(&ks),
            "recurrent_activation=hard_sigmoid",
        ),
        (
            fixture("bad_bidirectional.keras"),
            Some(&ks),
            "Bidirectional",
        ),
    ];
    for (model, settings, needle) in cases {
        let mut args = vec!["export", s(&model), "-o", s(&out)];
        if let Some(st) = settings {
            args.extend(["--settings", s(st)]);
        }
        expect_fail(&args, 8, needle);
    }
    // The dual checkpoint declared as a single-LSTM variant.
    expect_fail(
        &[
            "export",
            s(&fixture("torch_d.safetensors")),
            "--variant",
            "c",
            "-o",
            s(&out),
        ],
        8,
        "has 2 LSTMs but variant data-stft-lstm has 1",
    );
    assert!(!out.exists());
}

#[test]
fn hidden_over_128_exit_9() {
    let d = tmp("hidden");
    let (_, meta) = read_st(&fixture("torch_c.safetensors"));
    let h = 129;
    let t = vec![
        (
            "lstm.weight_ih_l0".to_string(),
            Dtype::F32,
            vec![4 * h, 12],
            f32_bytes(&vec![0.01; 4 * h * 12]),
        ),
        (
            "lstm.weight_hh_l0".to_string(),
            Dtype::F32,
            vec![4 * h, h],
            f32_bytes(&vec![0.01; 4 * h * h]),
        ),
        (
            "lstm.bias_ih_l0".to_string(),
            Dtype::F32,
            vec![4 * h],
            f32_bytes(&vec![0.0; 4 * h]),
        ),
        (
            "lstm.bias_hh_l0".to_string(),
            Dtype::F32,
            vec![4 * h],
            f32_bytes(&vec![0.0; 4 * h]),
        ),
        (
            "dense.weight".to_string(),
            Dtype::F32,
            vec![2, h],
            f32_bytes(&vec![0.01; 2 * h]),
        ),
        (
            "dense.bias".to_string(),
            Dtype::F32,
            vec![2],
            f32_bytes(&[0.0; 2]),
        ),
    ];
    let p = d.join("h129.safetensors");
    write_st(&p, &t, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        9,
        "hidden size 129 is outside the firmware's static bound 1..=128",
    );
}

#[test]
fn bad_settings_exit_10_and_usage_2() {
    let d = tmp("settings");
    let out = d.join("m.bin");
    let m = fixture("torch_c.safetensors");
    expect_fail(
        &["export", s(&m), "--threshold", "1.5", "-o", s(&out)],
        10,
        "setting `threshold`",
    );
    expect_fail(
        &["export", s(&m), "--variant", "e", "-o", s(&out)],
        10,
        "setting `variant`",
    );
    expect_fail(
        &["export", s(&m), "--stft-bins", "40", "-o", s(&out)],
        10,
        "stft",
    );
    expect_fail(
        &[
            "export",
            s(&m),
            "--name",
            "a-name-longer-than-12",
            "-o",
            s(&out),
        ],
        10,
        "setting `name`",
    );
    // ONNX carries no settings: without a normalisation it is refused, naming the key.
    expect_fail(
        &["export", s(&fixture("onnx_c.onnx")), "-o", s(&out)],
        10,
        "setting `norm_mean`",
    );
    expect_fail(
        &[
            "export",
            s(&m),
            "--norm-mean",
            "[0.5]",
            "--norm-std",
            "[1]",
            "-o",
            s(&out),
        ],
        10,
        "has 1 entries",
    );
    expect_fail(
        &["export", s(&m), "--cell-bits", "16", "-o", s(&out)],
        2,
        "--cell-bits",
    );
    expect_fail(&["export", s(&m), "--no-such-option"], 2, "");
    expect_fail(
        &["export", s(&d.join("missing.safetensors")), "-o", s(&out)],
        3,
        "missing.safetensors",
    );
    assert!(!out.exists());
}

#[test]
fn data_errors_exit_11() {
    let d = tmp("data");
    expect_fail(
        &[
            "export",
            s(&fixture("torch_c.safetensors")),
            "--data",
            s(&d.join("no-such-dir")),
            "-o",
            s(&d.join("m.bin")),
            "-q",
        ],
        11,
        "no-such-dir",
    );
    assert!(!d.join("m.bin").exists());
}

#[test]
fn export_inspect_verify_end_to_end() {
    let d = tmp("e2e");
    let out = d.join("model.bin");
    let snippet = d.join("model_blob.rs");
    let data = data_dir();
    let o = run(&[
        "export",
        s(&fixture("torch_c.safetensors")),
        "--data",
        s(&data),
        "--max-trials",
        "6",
        "-o",
        s(&out),
        "--rust-snippet",
        s(&snippet),
        "-q",
    ]);
    let stdout = String::from_utf8_lossy(&o.stdout);
    println!("{stdout}");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(stdout.contains("flag agreement"));
    let blob = std::fs::read(&out).unwrap();
    let aligned = slipguard_core::blob::AlignedBlob::new(&blob);
    let parsed = aligned.parse().expect("the written blob parses");
    assert_eq!(parsed.config.name_str(), "torch-c");
    assert_eq!(
        parsed.config.threshold_q15,
        (0.55f64 * 32768.0).round() as u16
    );
    assert_eq!(parsed.config.raise_after, 2);
    assert!(parsed.config.force_diff);
    // Reports.
    let md = std::fs::read_to_string(d.join("model.bin.report.md")).unwrap();
    assert!(
        md.contains("## Quantization error per tensor")
            && md.contains("lstm0.weight_hh_l0")
            && md.contains("success rate")
    );
    let js: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("model.bin.report.json")).unwrap())
            .unwrap();
    assert!(js["agreement"]["flag_agreement"].as_f64().unwrap() > 0.98);
    // Measured over whole recordings, with the worst step named: on the held-out trial(s), or
    // on all of --data with the written blob where it strays more (the notes give both).
    let on = js["agreement_data"].as_str().unwrap();
    assert!(
        on.contains("whole recordings")
            && (on.contains("held out: every 5th trial (1 trials") || on.contains("all of --data")),
        "{on}"
    );
    let notes = js["notes"].to_string();
    assert!(
        notes.contains("quantization loss measured twice"),
        "{notes}"
    );
    assert!(js["agreement"]["worst"]["trial"].is_string());
    assert!(js["weight_loss"]["tensors"].as_array().unwrap().len() == 4);
    assert!(js["agreement"]["float_metrics"]["success_rate"].is_number());
    assert_eq!(js["blob"]["crc"].as_u64().unwrap() as u32, parsed.crc);
    // Snippet.
    let rs = std::fs::read_to_string(&snippet).unwrap();
    assert!(
        rs.contains("#[unsafe(link_section = \".model\")]")
            && rs.contains(&format!("pub const MODEL_LEN: usize = {};", blob.len()))
    );
    assert!(rs.contains(&format!("{:#010x}", parsed.crc)));
    // No temporary files left.
    let left: Vec<_> = std::fs::read_dir(&d)
        .unwrap()
        .filter_map(|e| e.ok())
        .map(|e| e.file_name().to_string_lossy().to_string())
        .filter(|n| n.contains(".tmp-"))
        .collect();
    assert!(left.is_empty(), "{left:?}");

    // inspect
    let o = run(&["inspect", s(&out)]);
    let text = String::from_utf8_lossy(&o.stdout);
    println!("{text}");
    assert!(o.status.success());
    for needle in [
        "variant            data-stft-lstm",
        "MACs per step:     1824 (LSTM + dense) + 400 (STFT)",
        &format!("CRC-32:            {:#010x}", parsed.crc),
        "flash:             ",
        "RAM per channel:",
    ] {
        assert!(text.contains(needle), "inspect output lacks `{needle}`");
    }
    let o = run(&["inspect", s(&out), "--json"]);
    let js: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(js["total_bytes"].as_u64().unwrap() as usize, blob.len());

    // verify passes, and fails (13) with an impossible bound.
    let o = run(&[
        "verify",
        s(&out),
        "--float",
        s(&fixture("torch_c.safetensors")),
        "--data",
        s(&data),
        "--max-trials",
        "6",
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(String::from_utf8_lossy(&o.stdout).contains("verify: OK"));
    expect_fail(
        &[
            "verify",
            s(&out),
            "--float",
            s(&fixture("torch_c.safetensors")),
            "--data",
            s(&data),
            "--max-trials",
            "6",
            "--max-dp",
            "0",
            "-q",
        ],
        13,
        "verification failed",
    );
    // verify against the wrong checkpoint.
    expect_fail(
        &[
            "verify",
            s(&out),
            "--float",
            s(&fixture("torch_d.safetensors")),
            "--data",
            s(&data),
            "--max-trials",
            "2",
            "-q",
        ],
        13,
        "the checkpoint is lstm-stft-lstm with hidden [8, 12], the blob data-stft-lstm with hidden [16]",
    );

    // A failed export over an existing blob leaves it untouched.
    let before = std::fs::read(&out).unwrap();
    expect_fail(
        &["export", s(&fixture("bad_proj.safetensors")), "-o", s(&out)],
        8,
        "projection",
    );
    assert_eq!(std::fs::read(&out).unwrap(), before);

    // Damaged blobs.
    let mut bad = before.clone();
    bad[100] ^= 0x40;
    let p = d.join("corrupt.bin");
    std::fs::write(&p, &bad).unwrap();
    expect_fail(&["inspect", s(&p)], 12, "CRC mismatch");
    std::fs::write(&p, &before[..before.len() - 10]).unwrap();
    expect_fail(&["inspect", s(&p)], 12, "truncated");
}

#[test]
fn every_format_exports_from_the_cli() {
    let d = tmp("formats");
    for (m, settings) in [
        ("torch_d.safetensors", None),
        ("torch_a_prefixed.safetensors", None),
        ("onnx_c.onnx", Some("onnx_c.settings.json")),
        ("onnx_d_legacy.onnx", Some("onnx_d_legacy.settings.json")),
        ("keras_c.keras", Some("keras_c.settings.json")),
        ("keras_c.weights.h5", Some("keras_c.settings.json")),
        ("keras_d.keras", Some("keras_d.settings.json")),
    ] {
        let out = d.join(format!("{m}.bin"));
        let mut args = vec![
            "export".to_string(),
            s(&fixture(m)).to_string(),
            "-o".into(),
            s(&out).to_string(),
            "--no-report".into(),
            "-q".into(),
        ];
        if let Some(st) = settings {
            args.extend(["--settings".into(), s(&fixture(st)).to_string()]);
        }
        let refs: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = run(&refs);
        assert!(
            o.status.success(),
            "{m}: {}",
            String::from_utf8_lossy(&o.stderr)
        );
        let b = std::fs::read(&out).unwrap();
        assert!(
            slipguard_core::blob::AlignedBlob::new(&b).parse().is_ok(),
            "{m}"
        );
    }
    // The .weights.h5 and the .keras archive of the same model give the same blob.
    assert_eq!(
        std::fs::read(d.join("keras_c.keras.bin")).unwrap(),
        std::fs::read(d.join("keras_c.weights.h5.bin")).unwrap()
    );
    // Options override the file's settings; norm fitted on data for a model without one.
    let out = d.join("fit.bin");
    let o = run(&[
        "export",
        s(&fixture("onnx_c.onnx")),
        "--fit-norm",
        "--data",
        s(&data_dir()),
        "--max-trials",
        "3",
        "--threshold",
        "0.7",
        "--name",
        "fitted",
        "-o",
        s(&out),
        "-q",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let b = std::fs::read(&out).unwrap();
    let a = slipguard_core::blob::AlignedBlob::new(&b);
    let p = a.parse().unwrap();
    assert_eq!(p.config.name_str(), "fitted");
    assert_eq!(p.config.threshold_q15, 22938);
}

#[test]
fn help_has_an_example_per_input_format() {
    for args in [&["--help"][..], &["export", "--help"][..]] {
        let o = run(args);
        assert!(o.status.success());
        let h = String::from_utf8_lossy(&o.stdout);
        for needle in [
            ".safetensors",
            ".onnx",
            ".keras ",
            ".weights.h5",
            "inspect model.bin",
            "verify model.bin",
            "Exit codes",
        ] {
            assert!(h.contains(needle), "{args:?} help lacks `{needle}`");
        }
    }
}

/// Inputs that used to convert silently wrong with exit 0, each refused naming the cause.
#[test]
fn ambiguous_or_unconvertible_inputs_are_refused() {
    let d = tmp("strict");
    let out = d.join("m.bin");
    let os = fixture("onnx_c.settings.json");
    let ds = fixture("dynamo64_c.settings.json");
    let cases: Vec<(PathBuf, Option<&PathBuf>, i32, &str)> = vec![
        // Linear → ReLU → Linear: not one affine layer (the last Linear used to be taken).
        (
            fixture("bad_relu_head.safetensors"),
            None,
            8,
            "the head is not a single affine layer to 2 logits",
        ),
        (
            fixture("bad_relu_head.safetensors"),
            None,
            8,
            "after the LSTM `lstm` the file has the layers `head.0` [32, 32], `head.2` [2, 32]",
        ),
        // A dual state_dict whose names do not give the concatenation order.
        (
            fixture("torch_d_bands_first.safetensors"),
            None,
            10,
            "pass --dual-order force,bands or --dual-order bands,force",
        ),
        (fixture("bad_layout1.onnx"), Some(&ds), 8, "layout=1"),
        (
            fixture("bad_seqlens_short.onnx"),
            Some(&os),
            8,
            "sequence_lens [15.0] differs from the sequence length 20",
        ),
        (
            fixture("bad_seqlens_dynamic.onnx"),
            Some(&os),
            8,
            "declares no fixed sequence length",
        ),
        // Messages that name the cause.
        (fixture("bad_gru.safetensors"), None, 8, "is a GRU (nn.GRU"),
        (
            fixture("bad_torch_save.pt"),
            None,
            4,
            "a PyTorch pickle (torch.save), which the exporter does not read",
        ),
        (
            fixture("bad_torch_save.pt"),
            None,
            4,
            "save_file(model.state_dict(), \"model.safetensors\")",
        ),
        (
            fixture("bad_two_layers_dynamic.onnx"),
            Some(&os),
            8,
            "stacked LSTMs (2 layers)",
        ),
    ];
    for (model, settings, code, needle) in cases {
        let mut args = vec!["export", s(&model), "-o", s(&out)];
        if let Some(st) = settings {
            args.extend(["--settings", s(st)]);
        }
        expect_fail(&args, code, needle);
    }
    // A constant sequence_lens equal to the declared sequence length runs every step: accepted.
    let o = run(&[
        "export",
        s(&fixture("onnx_static_seqlens_ok.onnx")),
        "--settings",
        s(&os),
        "-o",
        s(&out),
        "--no-report",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // --dual-order given, or contradicting what the graph says.
    let o = run(&[
        "export",
        s(&fixture("torch_d_bands_first.safetensors")),
        "--dual-order",
        "bands,force",
        "-o",
        s(&out),
        "--no-report",
    ]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    expect_fail(
        &[
            "export",
            s(&fixture("onnx_d_legacy.onnx")),
            "--settings",
            s(&fixture("onnx_d_legacy.settings.json")),
            "--dual-order",
            "force,bands",
            "-o",
            s(&out),
        ],
        10,
        "--dual-order says otherwise",
    );
    expect_fail(
        &[
            "export",
            s(&fixture("torch_d.safetensors")),
            "--dual-order",
            "sideways",
            "-o",
            s(&out),
        ],
        10,
        "`sideways` is not force,bands or bands,force",
    );
    // A bare .weights.h5 of a dual model: no config, so no concatenation order.
    let keras_d = std::fs::read(fixture("keras_d.keras")).unwrap();
    let mut z = zip::ZipArchive::new(std::io::Cursor::new(keras_d)).unwrap();
    let mut h5 = Vec::new();
    std::io::Read::read_to_end(&mut z.by_name("model.weights.h5").unwrap(), &mut h5).unwrap();
    let p = d.join("dual.weights.h5");
    std::fs::write(&p, h5).unwrap();
    expect_fail(
        &[
            "export",
            s(&p),
            "--settings",
            s(&fixture("keras_d.settings.json")),
            "-o",
            s(&out),
        ],
        10,
        "--dual-order",
    );
}

/// The NaN/Inf index is given in the file's own layout (the element's index in its shape).
#[test]
fn nan_index_is_given_in_the_files_layout() {
    let d = tmp("nan-layout");
    let (mut t, meta) = read_st(&fixture("torch_c.safetensors"));
    for x in t.iter_mut().filter(|x| x.0 == "lstm.weight_hh_l0") {
        // [64, 16]: flat 37 = row 2, column 5.
        x.3[37 * 4..38 * 4].copy_from_slice(&f32::NAN.to_le_bytes());
    }
    let p = d.join("nan.safetensors");
    write_st(&p, &t, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        7,
        "flat index 37 = NaN, element [2, 5] of its shape [64, 16] as stored in the file",
    );
}

/// Export warns in the terminal when there is no calibration data, and when the blob is over
/// the fidelity bounds; verify fails (13) at the same bounds.
#[test]
fn export_warns_and_verify_fails_at_the_fidelity_bounds() {
    let d = tmp("warn");
    let out = d.join("m.bin");
    let o = run(&[
        "export",
        s(&fixture("torch_c.safetensors")),
        "-o",
        s(&out),
        "--no-report",
    ]);
    assert!(o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains("warning: no --data: the cell state uses the default format Q4.11 (±16)"),
        "{err}"
    );
    // A cell format of ±16 384 with 1 fractional bit: far off the float model.
    let o = run(&[
        "export",
        s(&fixture("torch_c.safetensors")),
        "--data",
        s(&data_dir()),
        "--max-trials",
        "5",
        "--cell-bits",
        "1",
        "-o",
        s(&out),
        "--no-report",
        "-q",
    ]);
    assert!(o.status.success());
    let (stdout, err) = (
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr),
    );
    println!("{stdout}{err}");
    assert!(
        err.contains("warning: the blob does not follow the float model closely enough: max |Δp|"),
        "{err}"
    );
    assert!(stdout.contains("worst step: trial "), "{stdout}");
    // The loss attribution points at the cause: the cell format, not the weights.
    assert!(
        err.contains("hint: the weights rounded alone give")
            && err.contains("--cell-bits, now [1]"),
        "{err}"
    );
    expect_fail(
        &[
            "verify",
            s(&out),
            "--float",
            s(&fixture("torch_c.safetensors")),
            "--data",
            s(&data_dir()),
            "--max-trials",
            "5",
            "-q",
        ],
        13,
        "over every step of",
    );
}

/// `run` prints the blob's p per step for a raw trace: it follows torch's p on the fixture's
/// trace (the quantized bound of tests/library_fixtures.rs), and `--check-features` accepts
/// torch's own features and refuses them with the bands in the wrong unit (|X_k| instead of
/// |X_k|/N before normalisation, i.e. ×N after it, roughly).
#[test]
fn run_dumps_p_per_step_and_checks_features() {
    let d = tmp("run");
    let blob = d.join("m.bin");
    let o = run(&[
        "export",
        s(&fixture("torch_c.safetensors")),
        "--cell-bits",
        "10",
        "-o",
        s(&blob),
        "--no-report",
    ]);
    assert!(o.status.success());
    let exp: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(fixture("torch_c.expected.json")).unwrap())
            .unwrap();
    let seq = &exp["sequences"][0];
    let nums = |v: &serde_json::Value| -> Vec<f64> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap())
            .collect()
    };
    let (raw, p_torch, feats) = (nums(&seq["raw"]), nums(&seq["p"]), nums(&seq["features"]));
    let trace = d.join("trace.csv");
    let mut text = String::from("force_mN\n");
    for r in &raw {
        text.push_str(&format!("{r}\n"));
    }
    std::fs::write(&trace, text).unwrap();
    let o = run(&["run", s(&blob), s(&trace)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let stdout = String::from_utf8_lossy(&o.stdout);
    let mut lines = stdout.lines();
    assert_eq!(lines.next(), Some("step,p_force_mN,flag_force_mN"));
    let mut worst = 0f64;
    let mut n = 0;
    for (line, pt) in lines.zip(&p_torch) {
        let p: f64 = line.split(',').nth(1).unwrap().parse().unwrap();
        worst = worst.max((p - pt).abs());
        n += 1;
    }
    println!("run: {n} steps, max |p_blob − p_torch| {worst:.4}");
    assert_eq!(n, raw.len());
    assert!(worst < 0.01, "{worst}");

    let nf = feats.len() / raw.len();
    let write_feats = |name: &str, scale_bands: f64| {
        let p = d.join(name);
        let mut t = String::new();
        for row in feats.chunks(nf) {
            let v: Vec<String> = row
                .iter()
                .enumerate()
                .map(|(j, x)| format!("{}", if j >= 2 { x * scale_bands } else { *x }))
                .collect();
            t.push_str(&v.join(","));
            t.push('\n');
        }
        std::fs::write(&p, t).unwrap();
        p
    };
    let good = write_feats("good.csv", 1.0);
    let o = run(&["run", s(&blob), s(&trace), "--check-features", s(&good)]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let bad = write_feats("bad.csv", 20.0);
    expect_fail(
        &["run", s(&blob), s(&trace), "--check-features", s(&bad)],
        13,
        "differs from the blob's front end",
    );
    // From the features: the same p as from the raw trace, within the Q3.12 rounding.
    let o = run(&["run", s(&blob), s(&good), "--features"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let from_feats: Vec<f64> = String::from_utf8_lossy(&o.stdout)
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(1).unwrap().parse().unwrap())
        .collect();
    let worst = from_feats
        .iter()
        .zip(&p_torch)
        .map(|(a, b)| (a - b).abs())
        .fold(0f64, f64::max);
    println!("run --features: max |p_blob − p_torch| {worst:.4}");
    assert!(worst < 0.01, "{worst}");
}

/// Shapes in a safetensors header are bounded too: a [0, 2^62] tensor holds no bytes (so the
/// container is valid) but must not reach `3 * H` or `4 * H`.
#[test]
fn huge_safetensors_dimensions_exit_9() {
    let d = tmp("st-dims");
    let (mut t, meta) = read_st(&fixture("torch_c.safetensors"));
    for x in t.iter_mut() {
        if x.0 == "lstm.weight_ih_l0" || x.0 == "lstm.weight_hh_l0" {
            x.2 = vec![0, 1 << 62];
            x.3.clear();
        }
    }
    let p = d.join("huge.safetensors");
    write_st(&p, &t, &meta);
    expect_fail(
        &["export", s(&p), "-o", s(&d.join("m.bin"))],
        9,
        "has a dimension of 4611686018427387904",
    );
}

#[test]
fn arguments_out_of_range_are_refused_before_work() {
    let blob = "../firmware/core/tests/fixtures/bench/model.bin";
    let ck = fixture("torch_d.safetensors");
    let ck = s(&ck);
    for (args, needle) in [
        (
            vec![
                "verify",
                blob,
                "--float",
                ck,
                "--data",
                "x",
                "--max-trials",
                "0",
            ],
            "--max-trials",
        ),
        (
            vec![
                "verify",
                blob,
                "--float",
                ck,
                "--data",
                "x",
                "--min-flag-agreement",
                "2",
            ],
            "0 ≤ x ≤ 1",
        ),
        (
            vec![
                "verify", blob, "--float", ck, "--data", "x", "--max-dp", "2",
            ],
            "0 ≤ x ≤ 1",
        ),
        (vec!["export", ck, "--max-trials", "0"], "--max-trials"),
        (vec!["upload", blob, "--port", "x", "--baud", "0"], "--baud"),
    ] {
        let out = run(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {err}");
        assert!(
            err.contains(needle) && !err.contains("panicked"),
            "{args:?}: {err}"
        );
    }
}

#[test]
fn every_subcommand_help_has_an_example() {
    for sub in ["export", "inspect", "verify", "upload", "run"] {
        let out = run(&[sub, "--help"]);
        let text = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success(), "{sub}: {text}");
        assert!(
            text.contains("Example") && text.contains("slipguard-export "),
            "{sub} --help has no example:\n{text}"
        );
    }
}

#[test]
fn verify_on_the_training_trials_says_in_sample() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let blob = root.join("models/hand-force/hand-force.bin");
    let ck = root.join("models/hand-force/hand-force.safetensors");
    let data = data_dir();
    let out = run(&[
        "verify",
        s(&blob),
        "--float",
        s(&ck),
        "--data",
        s(&data),
        "-q",
    ]);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("in-sample"), "{err}");
    // A fixture checkpoint without trainer metadata: no note.
    let out = run(&[
        "verify",
        "../firmware/core/tests/fixtures/bench/model.bin",
        "--float",
        s(&fixture("torch_c.safetensors")),
        "--data",
        s(&data),
        "--max-trials",
        "2",
        "-q",
    ]);
    assert!(!String::from_utf8_lossy(&out.stderr).contains("in-sample"));
}

/// `--hand-rule` puts a hand rule into the blob (format v2) and `inspect` prints it; without it
/// the blob stays v1; a value out of range is refused with one line naming its key (exit 10).
#[test]
fn hand_rule_option_writes_a_v2_blob_and_inspect_prints_it() {
    let d = tmp("hand_rule");
    let (v1, v2) = (d.join("v1.bin"), d.join("v2.bin"));
    let model = fixture("torch_c.safetensors");
    let export = |out: &Path, extra: &[&str]| {
        let mut args = vec![
            "export",
            s(&model),
            "--cell-bits",
            "10",
            "-o",
            s(out),
            "--no-report",
        ];
        args.extend_from_slice(extra);
        let o = run(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    };
    export(&v1, &[]);
    export(&v2, &["--hand-rule", "0.4,0.8,0.6"]);
    let (b1, b2) = (std::fs::read(&v1).unwrap(), std::fs::read(&v2).unwrap());
    assert_eq!(&b1[4..6], &[1, 0], "no rule: format v1");
    assert_eq!(&b2[4..6], &[2, 0], "with a rule: format v2");
    // v2 = v1 + one 16-byte directory entry + the 12-byte record (the CRC differs).
    assert_eq!(b2.len(), b1.len() + 16 + 12);
    // The record, last before the CRC: 0.4 and 0.8 in Q0.15, 0.6 s at 16.7 Hz = 10 frames.
    let n = b2.len();
    let rec: Vec<i32> = (0..3)
        .map(|k| i32::from_le_bytes(b2[n - 16 + 4 * k..n - 12 + 4 * k].try_into().unwrap()))
        .collect();
    assert_eq!(rec, [13_107, 26_214, 10]);
    let o = run(&["inspect", s(&v2)]);
    assert!(o.status.success());
    let out = String::from_utf8_lossy(&o.stdout);
    let field = |out: &str, k: &str| {
        out.lines()
            .find_map(|l| l.trim().strip_prefix(k).map(|v| v.trim().to_string()))
    };
    assert_eq!(field(&out, "format_version").as_deref(), Some("2"), "{out}");
    assert!(out.contains("format v2"), "{out}");
    assert!(
        out.contains("rule < 0.40·peak OR (model flag AND load < 0.80·peak), peak over 10 frames"),
        "{out}"
    );
    assert_eq!(
        field(&out, "hand_rule_window_s").as_deref(),
        Some("0.5988"),
        "{out}"
    );
    let o = run(&["inspect", s(&v1)]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(field(&out, "format_version").as_deref(), Some("1"), "{out}");
    assert!(!out.contains("hand_rule"), "{out}");
    for (bad, key) in [
        ("1.5,0.8,0.6", "hand_rule_fraction"),
        ("0.4,0.8,9", "hand_rule_window_s"),
        ("0.4,0.8", "hand_rule"),
    ] {
        let err = expect_fail(
            &[
                "export",
                s(&fixture("torch_c.safetensors")),
                "--cell-bits",
                "10",
                "-o",
                s(&d.join("bad.bin")),
                "--no-report",
                "--hand-rule",
                bad,
            ],
            10,
            key,
        );
        assert_eq!(err.trim_end().lines().count(), 1, "one line: {err}");
    }
}
