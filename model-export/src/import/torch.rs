//! safetensors with PyTorch names: our trainer's checkpoints and any `nn.LSTM` + `nn.Linear`
//! state_dict saved with `safetensors.torch.save_file`.
//!
//! Matching rule (docs/export.md): every tensor named `<p>weight_ih_l0` starts an LSTM with
//! prefix `<p>` (any prefix, e.g. `lstm.`, `lstm_force.`, `model.rnn.`), which needs
//! `<p>weight_hh_l0` and optionally both `<p>bias_ih_l0` and `<p>bias_hh_l0` (`bias=False` →
//! zeros). `*_l1`…, `*_reverse` and `*weight_hr_l0` mean stacked, bidirectional and projected
//! LSTMs and are refused. The dense layer is `dense.weight` / `dense.bias` when present, otherwise
//! the only other 2-D `<q>weight` with a `<q>bias` whose shape is [2, K] or [1, K].

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use safetensors::{Dtype, SafeTensors};
use slipguard_core::float::FloatLstm;

use super::{Format, Imported, NamedDense, NamedLstm, dims, element_count};
use crate::error::{ExportError, Result, check_finite_in};

/// A tensor converted to f32.
struct T {
    shape: Vec<usize>,
    data: Vec<f32>,
}

fn to_f32(name: &str, dtype: Dtype, raw: &[u8]) -> Result<Vec<f32>> {
    Ok(match dtype {
        Dtype::F32 => raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        Dtype::F64 => raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32)
            .collect(),
        Dtype::BF16 => raw
            .chunks_exact(2)
            .map(|c| f32::from_bits((u16::from_le_bytes([c[0], c[1]]) as u32) << 16))
            .collect(),
        Dtype::F16 => raw
            .chunks_exact(2)
            .map(|c| f16_to_f32(u16::from_le_bytes([c[0], c[1]])))
            .collect(),
        other => {
            return Err(ExportError::shape(
                name,
                "element type F32, F64, F16 or BF16",
                format!("element type {other:?}"),
            ));
        }
    })
}

/// IEEE binary16 → f32 (exact).
pub fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0 } else { 1.0 };
    let exp = ((h >> 10) & 0x1f) as i32;
    let man = (h & 0x3ff) as f32;
    sign * match exp {
        0 => man * 2f32.powi(-24),
        31 if man == 0.0 => f32::INFINITY,
        31 => f32::NAN,
        e => (1.0 + man / 1024.0) * 2f32.powi(e - 15),
    }
}

/// Reads a safetensors file.
pub fn import(path: &Path, bytes: &[u8]) -> Result<Imported> {
    let st = SafeTensors::deserialize(bytes)
        .map_err(|e| ExportError::format(path, format!("not a valid safetensors file: {e}")))?;
    let (_, meta) = SafeTensors::read_metadata(bytes)
        .map_err(|e| ExportError::format(path, format!("not a valid safetensors file: {e}")))?;
    let metadata: BTreeMap<String, String> = meta
        .metadata()
        .clone()
        .unwrap_or_default()
        .into_iter()
        .collect();

    let mut tensors: BTreeMap<String, T> = BTreeMap::new();
    for (name, view) in st.tensors() {
        // Shapes come from the file's header: every dimension bounded before `4 * H` and co.
        let shape64: Vec<u64> = view.shape().iter().map(|&d| d as u64).collect();
        element_count(&name, &shape64)?;
        let data = to_f32(&name, view.dtype(), view.data())?;
        check_finite_in(&name, view.shape(), &data)?;
        tensors.insert(
            name,
            T {
                shape: view.shape().to_vec(),
                data,
            },
        );
    }
    let names: Vec<String> = tensors.keys().cloned().collect();
    let (lstms, used) = find_lstms(&names, &tensors)?;
    let found = find_dense(&tensors, &used, lstms.iter().map(|l| l.lstm.hidden).sum());
    // Parameters of layers that are neither the LSTMs nor the dense layer (a Linear → ReLU →
    // Linear head, a LayerNorm, …): the network is not LSTM → one affine layer, refuse.
    let dense_names: Vec<String> = match &found {
        Ok((_, u)) => u.iter().cloned().collect(),
        Err(_) => Vec::new(),
    };
    let extra: Vec<&String> = names
        .iter()
        .filter(|n| !used.contains(*n) && !dense_names.contains(n))
        .filter(|n| n.ends_with("weight") || n.ends_with("bias"))
        .collect();
    if !extra.is_empty() {
        // Name the layers (tensor prefixes) found, with their weight shapes.
        let mut layers: Vec<String> = Vec::new();
        let mut prefixes: Vec<String> = Vec::new();
        let mut describe = |n: &str| {
            let prefix = n
                .strip_suffix("weight")
                .or_else(|| n.strip_suffix("bias"))
                .unwrap_or(n)
                .trim_end_matches('.');
            let w = format!("{prefix}.weight");
            let shape = tensors
                .get(&w)
                .map_or("no weight".into(), |t| dims(&t.shape));
            let l = format!("`{prefix}` {shape}");
            if !layers.contains(&l) {
                layers.push(l);
                prefixes.push(prefix.to_string());
            }
        };
        for n in &extra {
            describe(n);
        }
        if let Ok((d, _)) = &found {
            describe(&d.weight);
        }
        let lstm_names: Vec<String> = lstms.iter().map(|l| format!("`{}`", l.name)).collect();
        return Err(ExportError::unsupported(
            prefixes.join(", "),
            format!(
                "the head is not a single affine layer to 2 logits: after the LSTM {} the file has the layers {}; the firmware runs LSTM → one Linear(K, 2) (a second layer or an activation between them cannot be converted: retrain with one nn.Linear head)",
                lstm_names.join(" and "),
                layers.join(", ")
            ),
        ));
    }
    let (dense, dense_used) = found?;
    let mut notes = Vec::new();
    if !tensors.contains_key(&dense.bias) {
        notes.push(format!(
            "`{}` has no bias tensor `{}` (nn.Linear(bias=False)): zero biases",
            dense.weight, dense.bias
        ));
    }
    let ignored: Vec<&String> = names
        .iter()
        .filter(|n| !used.contains(*n) && !dense_used.contains(*n))
        .collect();
    if !ignored.is_empty() {
        notes.push(format!(
            "ignored tensors: {}",
            ignored
                .iter()
                .map(|s| s.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    // A state_dict does not record the order of a concatenation; our trainer's names
    // (`lstm_force.*`, `lstm_bands.*`, `dense.*`) declare [h_force, h_bands].
    let mut lstms = lstms;
    let names: Vec<&str> = lstms.iter().map(|l| l.name.as_str()).collect();
    let trainer_dual = dense.weight == "dense.weight"
        && (names == ["lstm_force", "lstm_bands"] || names == ["lstm_bands", "lstm_force"]);
    if trainer_dual && lstms[0].name == "lstm_bands" {
        lstms.swap(0, 1);
    }
    Ok(Imported {
        format: Format::Safetensors,
        lstms,
        concat_order_known: trainer_dual,
        dense,
        metadata,
        notes,
    })
}

/// Finds the LSTMs of a PyTorch state_dict (shared with other name-based importers).
fn find_lstms(
    names: &[String],
    t: &BTreeMap<String, T>,
) -> Result<(Vec<NamedLstm>, BTreeSet<String>)> {
    for n in names {
        if n.contains("_reverse") && (n.contains("weight_") || n.contains("bias_")) {
            return Err(ExportError::unsupported(
                n,
                "bidirectional LSTM (`*_reverse` weights): the firmware runs causal, forward-only LSTMs; train with bidirectional=False",
            ));
        }
        if n.contains("weight_hr_l") {
            return Err(ExportError::unsupported(
                n,
                "LSTM with projection (proj_size > 0): the firmware's cell has no projection; train with proj_size=0",
            ));
        }
        for kind in ["weight_ih_l", "weight_hh_l", "bias_ih_l", "bias_hh_l"] {
            if let Some(pos) = n.rfind(kind) {
                let layer = &n[pos + kind.len()..];
                if layer != "0" && layer.parse::<u32>().is_ok() {
                    return Err(ExportError::unsupported(
                        n,
                        format!(
                            "stacked LSTM (layer {layer}): the firmware runs one LSTM layer per path; train with num_layers=1"
                        ),
                    ));
                }
            }
        }
    }
    let mut lstms = Vec::new();
    let mut used = BTreeSet::new();
    for n in names {
        let Some(prefix) = n.strip_suffix("weight_ih_l0") else {
            continue;
        };
        let tn = |s: &str| format!("{prefix}{s}");
        let wih = &t[n];
        let whh_name = tn("weight_hh_l0");
        let whh = t.get(&whh_name).ok_or_else(|| {
            ExportError::missing(
                &whh_name,
                format!("`{n}` is present but its recurrent weights are not"),
            )
        })?;
        // nn.GRU (3 gate blocks) and nn.RNN (1) share the names; say so rather than "shape".
        if let ([g, _], [gh, h]) = (wih.shape.as_slice(), whh.shape.as_slice())
            && g == gh
            && *h > 0
            && (*g == 3 * h || g == h)
        {
            let what = if g == h {
                "a plain RNN (nn.RNN: one gate block"
            } else {
                "a GRU (nn.GRU: 3 gate blocks r, z, n"
            };
            return Err(ExportError::unsupported(
                prefix.trim_end_matches('.'),
                format!(
                    "`{n}` {} with `{whh_name}` {} is {what}, not the 4 of an LSTM); the firmware runs LSTM cells only: train with nn.LSTM",
                    dims(&wih.shape),
                    dims(&whh.shape)
                ),
            ));
        }
        if wih.shape.len() != 2 || wih.shape[0] == 0 || !wih.shape[0].is_multiple_of(4) {
            return Err(ExportError::shape(n, "[4H, I]", dims(&wih.shape)));
        }
        let h = wih.shape[0] / 4;
        let i = wih.shape[1];
        if whh.shape != [4 * h, h] {
            return Err(ExportError::shape(
                &whh_name,
                format!("[{}, {h}]", 4 * h),
                dims(&whh.shape),
            ));
        }
        let (bih_name, bhh_name) = (tn("bias_ih_l0"), tn("bias_hh_l0"));
        let (b_ih, b_hh) = match (t.get(&bih_name), t.get(&bhh_name)) {
            (Some(a), Some(b)) => {
                for (name, v) in [(&bih_name, a), (&bhh_name, b)] {
                    if v.shape != [4 * h] {
                        return Err(ExportError::shape(
                            name,
                            format!("[{}]", 4 * h),
                            dims(&v.shape),
                        ));
                    }
                }
                used.insert(bih_name.clone());
                used.insert(bhh_name.clone());
                (a.data.clone(), b.data.clone())
            }
            (None, None) => (vec![0.0; 4 * h], vec![0.0; 4 * h]),
            (Some(_), None) => {
                return Err(ExportError::missing(
                    &bhh_name,
                    format!("`{bih_name}` is present but not `{bhh_name}`"),
                ));
            }
            (None, Some(_)) => {
                return Err(ExportError::missing(
                    &bih_name,
                    format!("`{bhh_name}` is present but not `{bih_name}`"),
                ));
            }
        };
        used.insert(n.clone());
        used.insert(whh_name.clone());
        lstms.push(NamedLstm {
            name: prefix.trim_end_matches('.').to_string(),
            tensors: [n.clone(), whh_name, bih_name, bhh_name],
            lstm: FloatLstm {
                input: i,
                hidden: h,
                w_ih: wih.data.clone(),
                w_hh: whh.data.clone(),
                b_ih,
                b_hh,
            },
        });
    }
    if lstms.is_empty() {
        return Err(ExportError::missing(
            "lstm.weight_ih_l0",
            format!(
                "no tensor named `<prefix>weight_ih_l0` (PyTorch nn.LSTM); the file has: {}",
                preview(names)
            ),
        ));
    }
    Ok((lstms, used))
}

fn preview(names: &[String]) -> String {
    let mut s = names
        .iter()
        .take(12)
        .cloned()
        .collect::<Vec<_>>()
        .join(", ");
    if names.len() > 12 {
        s.push_str(&format!(", … ({} tensors)", names.len()));
    }
    if s.is_empty() {
        s = "no tensors".into();
    }
    s
}

fn find_dense(
    t: &BTreeMap<String, T>,
    used: &BTreeSet<String>,
    k: usize,
) -> Result<(NamedDense, BTreeSet<String>)> {
    // A head without its bias tensor is `nn.Linear(K, 2, bias=False)`: an exact zero bias
    // (the caller notes it).
    let pick = |w: &str, b: &str| -> Result<(NamedDense, BTreeSet<String>)> {
        let wt = &t[w];
        if wt.shape.len() != 2 {
            return Err(ExportError::shape(w, format!("[2, {k}]"), dims(&wt.shape)));
        }
        let (o, i) = (wt.shape[0], wt.shape[1]);
        let bias = match t.get(b) {
            Some(bt) if bt.shape != [o] => {
                return Err(ExportError::shape(b, format!("[{o}]"), dims(&bt.shape)));
            }
            Some(bt) => bt.data.clone(),
            None => vec![0.0; o],
        };
        Ok((
            NamedDense {
                weight: w.into(),
                bias: b.into(),
                outputs: o,
                inputs: i,
                w: wt.data.clone(),
                b: bias,
            },
            [w.to_string(), b.to_string()].into_iter().collect(),
        ))
    };
    if t.contains_key("dense.weight") {
        return pick("dense.weight", "dense.bias");
    }
    let candidates: Vec<&String> = t
        .keys()
        .filter(|n| !used.contains(*n) && n.ends_with("weight"))
        .filter(|n| {
            let s = &t[*n].shape;
            s.len() == 2 && (s[0] == 1 || s[0] == 2) && s[1] == k
        })
        .collect();
    match candidates.as_slice() {
        [one] => pick(one, &bias_of(one)),
        [] => Err(ExportError::missing(
            "dense.weight",
            format!(
                "no `dense.weight` and no other [2, {k}] `<prefix>weight` (nn.Linear to the 2 logits); the file has: {}",
                preview(&t.keys().cloned().collect::<Vec<_>>())
            ),
        )),
        many => Err(ExportError::missing(
            "dense.weight",
            format!(
                "several tensors could be the output layer ({}); name it `dense`",
                many.iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )),
    }
}

fn bias_of(weight: &str) -> String {
    format!("{}bias", weight.strip_suffix("weight").unwrap_or(weight))
}

#[cfg(test)]
mod tests {
    /// A state_dict of `nn.LSTM(3, 4)` named `lstm` and `nn.Linear(4, 2, bias=False)` named
    /// `head` (tensor names and shapes as PyTorch saves them; values are arbitrary).
    fn bias_free_head() -> Vec<u8> {
        use safetensors::tensor::TensorView;
        let (i, h) = (3usize, 4usize);
        let shapes: [(&str, Vec<usize>); 5] = [
            ("lstm.weight_ih_l0", vec![4 * h, i]),
            ("lstm.weight_hh_l0", vec![4 * h, h]),
            ("lstm.bias_ih_l0", vec![4 * h]),
            ("lstm.bias_hh_l0", vec![4 * h]),
            ("head.weight", vec![2, h]),
        ];
        let data: Vec<Vec<u8>> = shapes
            .iter()
            .map(|(_, s)| {
                (0..s.iter().product::<usize>())
                    .flat_map(|k| (0.01 * k as f32 - 0.1).to_le_bytes())
                    .collect()
            })
            .collect();
        let views: Vec<(&str, TensorView<'_>)> = shapes
            .iter()
            .zip(&data)
            .map(|((n, s), d)| {
                (
                    *n,
                    TensorView::new(safetensors::Dtype::F32, s.clone(), d).unwrap(),
                )
            })
            .collect();
        safetensors::serialize(views, None).unwrap()
    }

    #[test]
    fn a_linear_head_without_bias_imports_with_zero_bias() {
        let im = super::import(std::path::Path::new("head.safetensors"), &bias_free_head())
            .expect("nn.Linear(H, 2, bias=False) is a single affine head");
        assert_eq!(im.dense.weight, "head.weight");
        assert_eq!(im.dense.b, vec![0.0, 0.0]);
        assert_eq!((im.dense.outputs, im.dense.inputs), (2, 4));
        assert!(
            im.notes.iter().any(|n| n.contains("bias=False")),
            "{:?}",
            im.notes
        );
    }

    #[test]
    fn half_precision_converts_exactly() {
        use super::f16_to_f32;
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x3555), 0.333_251_95);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert!(f16_to_f32(0x7c00).is_infinite() && f16_to_f32(0x7e00).is_nan());
    }
}
