//! The float reference against PyTorch: `nn.LSTM` + `nn.Linear` outputs recorded by
//! `fixtures/make_torch_fixture.py` (torch, float64 forward pass on f32-exact weights).
use serde_json::Value;
use slipguard_core::float::{FloatDense, FloatLstm, p_from_logits};

fn floats(v: &Value) -> Vec<f64> {
    v.as_array()
        .expect("array")
        .iter()
        .map(|x| x.as_f64().expect("number"))
        .collect()
}

fn lstm(v: &Value) -> FloatLstm {
    let f32s = |k: &str| {
        floats(&v[k])
            .into_iter()
            .map(|x| x as f32)
            .collect::<Vec<_>>()
    };
    FloatLstm {
        input: v["input_size"].as_u64().unwrap() as usize,
        hidden: v["hidden_size"].as_u64().unwrap() as usize,
        w_ih: f32s("weight_ih_l0"),
        w_hh: f32s("weight_hh_l0"),
        b_ih: f32s("bias_ih_l0"),
        b_hh: f32s("bias_hh_l0"),
    }
}

#[test]
fn float_reference_matches_pytorch() {
    let text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/fixtures/torch_lstm.json"
    ))
    .expect("fixture");
    let doc: Value = serde_json::from_str(&text).expect("json");
    let cases = doc["cases"].as_object().expect("cases");
    assert_eq!(cases.len(), 4);
    for (name, case) in cases {
        let t = case["seq_len"].as_u64().unwrap() as usize;
        let ni = case["input_size"].as_u64().unwrap() as usize;
        let input = floats(&case["input"]);
        let (lstms, specs): (Vec<FloatLstm>, Vec<&Value>) = if case["kind"] == "dual" {
            let (a, b) = (&case["lstm_a"], &case["lstm_b"]);
            (vec![lstm(a), lstm(b)], vec![a, b])
        } else {
            (vec![lstm(&case["lstm"])], vec![&case["lstm"]])
        };
        let dense = FloatDense {
            inputs: case["dense"]["in_features"].as_u64().unwrap() as usize,
            w: floats(&case["dense"]["weight"])
                .into_iter()
                .map(|x| x as f32)
                .collect(),
            b: floats(&case["dense"]["bias"])
                .into_iter()
                .map(|x| x as f32)
                .collect(),
        };
        dense.validate().unwrap();
        let mut states: Vec<_> = lstms
            .iter()
            .map(|l| {
                l.validate().unwrap();
                l.zero_state()
            })
            .collect();
        let want_logits = floats(&case["logits"]);
        let want_p = floats(&case["p1"]);
        let (mut err_h, mut err_c, mut err_l, mut err_p) = (0f64, 0f64, 0f64, 0f64);
        for step in 0..t {
            let x: Vec<f32> = input[step * ni..(step + 1) * ni]
                .iter()
                .map(|&v| v as f32)
                .collect();
            let mut off = 0;
            let mut hcat = Vec::new();
            for ((l, s), spec) in lstms.iter().zip(states.iter_mut()).zip(&specs) {
                l.step(s, &x[off..off + l.input]);
                off += l.input;
                let (wh, wc) = (floats(&spec["h"]), floats(&spec["c"]));
                for j in 0..l.hidden {
                    err_h = err_h.max((s.h[j] as f64 - wh[step * l.hidden + j]).abs());
                    err_c = err_c.max((s.c[j] as f64 - wc[step * l.hidden + j]).abs());
                }
                hcat.extend_from_slice(&s.h);
            }
            let logits = dense.logits(&hcat);
            for k in 0..2 {
                err_l = err_l.max((logits[k] as f64 - want_logits[step * 2 + k]).abs());
            }
            err_p = err_p.max((p_from_logits(logits) as f64 - want_p[step]).abs());
        }
        println!(
            "{name:>10}: max |Δh| {err_h:.2e}, |Δc| {err_c:.2e}, |Δlogit| {err_l:.2e}, |Δp| {err_p:.2e}"
        );
        // f32 arithmetic against PyTorch's float64 over 64 steps. Bounds about twice the
        // largest measured over the four cases (|Δh| 1.13e-7, |Δc| 1.94e-7, |Δlogit| 4.3e-8,
        // |Δp| 6.7e-8).
        assert!(err_h < 2.5e-7, "{name}: |Δh| {err_h:.2e}");
        assert!(err_c < 4e-7, "{name}: |Δc| {err_c:.2e}");
        assert!(err_l < 1e-7, "{name}: |Δlogit| {err_l:.2e}");
        assert!(err_p < 1.5e-7, "{name}: |Δp| {err_p:.2e}");
    }
}
