//! Keras 3: a `.keras` archive (zip of `config.json` + `model.weights.h5`) or a bare
//! `.weights.h5` (optionally with the model's `config.json` via `--keras-config`).
//!
//! Keras' LSTM stores `kernel` [I, 4H], `recurrent_kernel` [H, 4H] and one `bias` [4H] with gate
//! order i, f, c, o (= PyTorch's i, f, g, o): the importer transposes and takes b_ih = bias,
//! b_hh = 0. In the weights file Keras 3 names groups by class, not by layer name:
//! `layers/lstm/cell/vars/{0,1,2}`, `layers/lstm_1/…`, `layers/dense/vars/{0,1}`, numbered in the
//! order of the model's layer list. The config is checked: `activation` must be tanh and
//! `recurrent_activation` sigmoid (hard_sigmoid is refused: the firmware's gate table is the
//! logistic σ, and converting would change the outputs), no Bidirectional, no go_backwards, no
//! stacked LSTMs, Dense(2) with softmax/linear or Dense(1) with sigmoid, and no other layer with
//! weights or arithmetic on the path.

use std::collections::BTreeMap;
use std::io::Read;
use std::path::Path;

use serde_json::Value;
use slipguard_core::float::FloatLstm;

use super::{Format, Imported, NamedDense, NamedLstm, dims, element_count, transpose};
use crate::error::{ExportError, Result, check_finite_in};

/// What the config says about one layer.
#[derive(Clone, Debug)]
struct LayerInfo {
    class: String,
    name: String,
    config: Value,
    inbound: Vec<String>,
}

fn act_name(v: Option<&Value>) -> String {
    match v {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Object(o)) => o
            .get("config")
            .and_then(|c| c.get("name"))
            .or_else(|| o.get("class_name"))
            .and_then(Value::as_str)
            .unwrap_or("?")
            .to_string(),
        None => "linear".into(),
        Some(other) => other.to_string(),
    }
}

/// Names of the layers a Keras 3 `inbound_nodes` entry refers to (via `keras_history`).
fn inbound_names(v: &Value, out: &mut Vec<String>) {
    match v {
        Value::Object(o) => {
            if let Some(Value::Array(h)) = o.get("keras_history")
                && let Some(Value::String(n)) = h.first()
            {
                out.push(n.clone());
                return;
            }
            for x in o.values() {
                inbound_names(x, out);
            }
        }
        Value::Array(a) => a.iter().for_each(|x| inbound_names(x, out)),
        _ => {}
    }
}

fn parse_config(path: &Path, text: &str) -> Result<(Vec<LayerInfo>, bool)> {
    let v: Value = serde_json::from_str(text)
        .map_err(|e| ExportError::format(path, format!("Keras config is not JSON: {e}")))?;
    let top = v.get("class_name").and_then(Value::as_str).unwrap_or("");
    let sequential = top == "Sequential";
    let layers = v
        .get("config")
        .and_then(|c| c.get("layers"))
        .and_then(Value::as_array)
        .ok_or_else(|| ExportError::format(path, "Keras config has no config.layers"))?;
    let mut out = Vec::new();
    for l in layers {
        let class = l
            .get("class_name")
            .and_then(Value::as_str)
            .unwrap_or("")
            .to_string();
        let config = l.get("config").cloned().unwrap_or(Value::Null);
        let name = l
            .get("name")
            .or_else(|| config.get("name"))
            .and_then(Value::as_str)
            .unwrap_or("")
            .to_string();
        let mut inbound = Vec::new();
        if let Some(ib) = l.get("inbound_nodes") {
            inbound_names(ib, &mut inbound);
        }
        out.push(LayerInfo {
            class,
            name,
            config,
            inbound,
        });
    }
    Ok((out, sequential))
}

/// Checks the config and returns (LSTM layer names in layer order, the Dense layer, the
/// concatenation order of LSTM names if any).
fn check_config(
    layers: &[LayerInfo],
    sequential: bool,
    notes: &mut Vec<String>,
) -> Result<(Vec<LayerInfo>, LayerInfo, Option<Vec<String>>)> {
    const PASSIVE: &[&str] = &[
        "InputLayer",
        "GetItem",
        "Concatenate",
        "Dropout",
        "SpatialDropout1D",
        "Activation",
    ];
    let mut lstms = Vec::new();
    let mut denses = Vec::new();
    for l in layers {
        let label = format!("{} layer `{}`", l.class, l.name);
        match l.class.as_str() {
            "LSTM" => {
                let c = &l.config;
                let act = act_name(c.get("activation"));
                let rec = act_name(c.get("recurrent_activation"));
                if act != "tanh" {
                    return Err(ExportError::unsupported(
                        format!("{label} activation"),
                        format!("activation={act}; the firmware's cell uses tanh"),
                    ));
                }
                if rec != "sigmoid" {
                    let hint = if rec == "hard_sigmoid" {
                        ": hard_sigmoid (relu6(x+3)/6 in Keras 3) is not the logistic σ the firmware's gate table implements; retrain with recurrent_activation=\"sigmoid\" (converting would change the model's outputs)"
                    } else {
                        ""
                    };
                    return Err(ExportError::unsupported(
                        format!("{label} recurrent_activation"),
                        format!("recurrent_activation={rec}; the firmware needs sigmoid{hint}"),
                    ));
                }
                if c.get("go_backwards").and_then(Value::as_bool) == Some(true) {
                    return Err(ExportError::unsupported(
                        label,
                        "go_backwards=True: the firmware runs causal, forward-only LSTMs",
                    ));
                }
                if c.get("stateful").and_then(Value::as_bool) == Some(true) {
                    notes.push(format!("{label} is stateful; the firmware keeps state per channel and resets it at grasp start"));
                }
                if l.inbound
                    .iter()
                    .any(|n| layers.iter().any(|o| o.name == *n && o.class == "LSTM"))
                    || (sequential && !lstms.is_empty())
                {
                    return Err(ExportError::unsupported(
                        label,
                        "stacked LSTMs: the firmware runs one LSTM layer per path",
                    ));
                }
                lstms.push(l.clone());
            }
            "Dense" => {
                let units = l.config.get("units").and_then(Value::as_u64).unwrap_or(0);
                let act = act_name(l.config.get("activation"));
                let ok = matches!(
                    (units, act.as_str()),
                    (2, "softmax" | "linear") | (1, "sigmoid" | "linear")
                );
                if !ok {
                    return Err(ExportError::unsupported(
                        format!("{label} activation"),
                        format!(
                            "Dense({units}, activation={act}); the firmware needs Dense(2) with softmax or linear logits, or Dense(1) with sigmoid"
                        ),
                    ));
                }
                denses.push(l.clone());
            }
            "Activation" => {
                let act = act_name(l.config.get("activation"));
                if !matches!(act.as_str(), "softmax" | "linear") || denses.is_empty() {
                    return Err(ExportError::unsupported(
                        label,
                        format!(
                            "activation {act} on the data path; only a final softmax is allowed"
                        ),
                    ));
                }
            }
            "Bidirectional" => {
                return Err(ExportError::unsupported(
                    label,
                    "Bidirectional LSTM: the firmware runs causal, forward-only LSTMs",
                ));
            }
            c if PASSIVE.contains(&c) => {}
            other => {
                return Err(ExportError::unsupported(
                    label,
                    format!(
                        "layer class {other} is not part of the firmware's network (LSTM → Dense)"
                    ),
                ));
            }
        }
    }
    let dense = match denses.as_slice() {
        [d] => d.clone(),
        [] => {
            return Err(ExportError::missing(
                "Dense",
                "the Keras model has no Dense output layer",
            ));
        }
        _ => {
            return Err(ExportError::unsupported(
                "Dense layers",
                "more than one Dense layer; the firmware has one",
            ));
        }
    };
    // Concatenation order: the inputs of a Concatenate, each traced back to an LSTM.
    let by_name: BTreeMap<&str, &LayerInfo> = layers.iter().map(|l| (l.name.as_str(), l)).collect();
    let trace = |start: &str| -> Option<String> {
        let mut n = start.to_string();
        for _ in 0..32 {
            let l = by_name.get(n.as_str())?;
            if l.class == "LSTM" {
                return Some(n);
            }
            n = l.inbound.first()?.clone();
        }
        None
    };
    let order = layers.iter().find(|l| l.class == "Concatenate").map(|c| {
        c.inbound
            .iter()
            .filter_map(|n| trace(n))
            .collect::<Vec<_>>()
    });
    Ok((lstms, dense, order))
}

/// One layer's variables: group path, shapes, values.
type H5Layer<const N: usize> = (String, [Vec<usize>; N], [Vec<f32>; N]);

/// Weights read from the `.weights.h5`.
struct H5Weights {
    lstms: Vec<H5Layer<3>>,
    dense: Option<H5Layer<2>>,
}

fn read_ds(
    path: &Path,
    f: &hdf5_reader::Hdf5File,
    file_len: usize,
    name: &str,
) -> Result<(Vec<usize>, Vec<f32>)> {
    let ds = f.dataset(name).map_err(|e| {
        ExportError::missing(name, format!("not readable in {}: {e}", path.display()))
    })?;
    // Sizes come from the file: bounded before anything is allocated.
    let n = element_count(name, ds.shape())?;
    let shape: Vec<usize> = ds.shape().iter().map(|&d| d as usize).collect();
    if let Some(chunk) = ds.chunks() {
        // The decoder allocates a chunk at a time: its shape is bounded like the dataset's.
        let c64: Vec<u64> = chunk.iter().map(|&c| c as u64).collect();
        element_count(&format!("{name} (chunk)"), &c64)?;
    } else {
        // Contiguous (uncompressed) storage, as Keras writes it, lies inside the file.
        let elem = ds.raw_element_size().unwrap_or(1).max(1);
        if n.saturating_mul(elem) > file_len {
            return Err(ExportError::format(
                path,
                format!(
                    "dataset `{name}` of shape {} needs {} bytes, more than the whole file ({file_len} bytes; truncated or malformed)",
                    dims(&shape),
                    n.saturating_mul(elem)
                ),
            ));
        }
    }
    let mut v = vec![0f32; n];
    if ds.read_into(&mut v).is_err() {
        let mut d = vec![0f64; n];
        ds.read_into(&mut d)
            .map_err(|e| ExportError::format(path, format!("dataset `{name}`: {e}")))?;
        v = d.into_iter().map(|x| x as f32).collect();
    }
    check_finite_in(name, &shape, &v)?;
    Ok((shape, v))
}

/// Whether `group` has a member `name` (a missing group reads as no member).
fn has_member(f: &hdf5_reader::Hdf5File, group: &str, name: &str) -> bool {
    f.group(group)
        .and_then(|g| g.member_names())
        .is_ok_and(|(groups, datasets)| groups.iter().chain(&datasets).any(|m| m == name))
}

fn suffix_num(name: &str, base: &str) -> Option<u32> {
    if name == base {
        Some(0)
    } else {
        name.strip_prefix(base)?.strip_prefix('_')?.parse().ok()
    }
}

fn read_h5(path: &Path, bytes: Vec<u8>) -> Result<H5Weights> {
    let file_len = bytes.len();
    let f = hdf5_reader::Hdf5File::from_vec(bytes)
        .map_err(|e| ExportError::format(path, format!("not a readable HDF5 file: {e}")))?;
    // The superblock records where the file ends: a shorter file lost its tail (an interrupted
    // copy or download), where datasets would read as zeros or vanish. libhdf5 (h5py) refuses
    // such a file too.
    let sb = f.superblock();
    let end = sb.base_address.saturating_add(sb.eof_address);
    if end > file_len as u64 {
        return Err(ExportError::format(
            path,
            format!(
                "truncated: the HDF5 superblock says the file ends at byte {end}, the file has {file_len} bytes ({} missing); copy the whole file again",
                end - file_len as u64
            ),
        ));
    }
    let layers = f.group("layers").map_err(|e| {
        ExportError::missing(
            "layers",
            format!("no `layers` group (not a Keras 3 weights file): {e}"),
        )
    })?;
    let (groups, _) = layers
        .member_names()
        .map_err(|e| ExportError::format(path, e.to_string()))?;
    if let Some(b) = groups.iter().find(|g| g.starts_with("bidirectional")) {
        return Err(ExportError::unsupported(
            format!("layers/{b}"),
            "Bidirectional LSTM: the firmware runs causal, forward-only LSTMs",
        ));
    }
    for other in ["gru", "simple_rnn", "conv_lstm"] {
        if let Some(g) = groups.iter().find(|g| suffix_num(g, other).is_some()) {
            return Err(ExportError::unsupported(
                format!("layers/{g}"),
                "only LSTM cells are supported",
            ));
        }
    }
    let mut lstm_groups: Vec<(u32, String)> = groups
        .iter()
        .filter_map(|g| suffix_num(g, "lstm").map(|n| (n, g.clone())))
        .collect();
    lstm_groups.sort();
    let mut lstms = Vec::new();
    for (_, g) in lstm_groups {
        let mut shapes: [Vec<usize>; 3] = Default::default();
        let mut vals: [Vec<f32>; 3] = Default::default();
        let vars = format!("layers/{g}/cell/vars");
        for k in 0..3 {
            // vars/2 (bias) is absent for LSTM(use_bias=False): zero biases.
            if k == 2 && !has_member(&f, &vars, "2") {
                continue;
            }
            let (s, v) = read_ds(path, &f, file_len, &format!("{vars}/{k}"))?;
            shapes[k] = s;
            vals[k] = v;
        }
        lstms.push((format!("layers/{g}/cell/vars"), shapes, vals));
    }
    let mut dense_groups: Vec<(u32, String)> = groups
        .iter()
        .filter_map(|g| suffix_num(g, "dense").map(|n| (n, g.clone())))
        .collect();
    dense_groups.sort();
    if dense_groups.len() > 1 {
        return Err(ExportError::unsupported(
            "layers/dense_1",
            "more than one Dense layer; the firmware has one",
        ));
    }
    let dense = match dense_groups.first() {
        Some((_, g)) => {
            let (s0, v0) = read_ds(path, &f, file_len, &format!("layers/{g}/vars/0"))?;
            // vars/1 (bias) is absent for Dense(use_bias=False): zero biases.
            let (s1, v1) = if has_member(&f, &format!("layers/{g}/vars"), "1") {
                read_ds(path, &f, file_len, &format!("layers/{g}/vars/1"))?
            } else {
                (Vec::new(), Vec::new())
            };
            Some((format!("layers/{g}/vars"), [s0, s1], [v0, v1]))
        }
        None => None,
    };
    Ok(H5Weights { lstms, dense })
}

fn to_imported(
    w: H5Weights,
    lstm_names: Option<Vec<String>>,
    concat: Option<Vec<String>>,
    mut notes: Vec<String>,
    format: Format,
) -> Result<Imported> {
    if w.lstms.is_empty() {
        return Err(ExportError::missing(
            "layers/lstm/cell/vars/0",
            "no LSTM weights in the Keras weights file",
        ));
    }
    let mut lstms = Vec::new();
    for (k, (base, shapes, vals)) in w.lstms.into_iter().enumerate() {
        let names = [
            format!("{base}/0 (kernel)"),
            format!("{base}/1 (recurrent_kernel)"),
            format!("{base}/2 (bias)"),
        ];
        let [ks, rs, bs] = &shapes;
        if rs.len() != 2 || rs[0] == 0 || rs[1] != 4 * rs[0] {
            return Err(ExportError::shape(&names[1], "[H, 4H]", dims(rs)));
        }
        let h = rs[0];
        if ks.len() != 2 || ks[1] != 4 * h {
            return Err(ExportError::shape(
                &names[0],
                format!("[I, {}]", 4 * h),
                dims(ks),
            ));
        }
        let i = ks[0];
        let b_ih = if bs.is_empty() && vals[2].is_empty() {
            notes.push(format!(
                "`{base}` has no bias (LSTM use_bias=False): zero biases"
            ));
            vec![0.0; 4 * h]
        } else if *bs == [4 * h] {
            vals[2].clone()
        } else {
            return Err(ExportError::shape(
                &names[2],
                format!("[{}]", 4 * h),
                dims(bs),
            ));
        };
        let name = lstm_names
            .as_ref()
            .and_then(|n| n.get(k).cloned())
            .unwrap_or_else(|| base.clone());
        lstms.push(NamedLstm {
            name,
            tensors: [
                names[0].clone(),
                names[1].clone(),
                names[2].clone(),
                format!("{base} (no b_hh in Keras)"),
            ],
            lstm: FloatLstm {
                input: i,
                hidden: h,
                w_ih: transpose(&vals[0], i, 4 * h),
                w_hh: transpose(&vals[1], h, 4 * h),
                b_ih,
                b_hh: vec![0.0; 4 * h],
            },
        });
    }
    let (base, [ws, bs], [wv, bv]) = w.dense.ok_or_else(|| {
        ExportError::missing(
            "layers/dense/vars/0",
            "no Dense weights in the Keras weights file",
        )
    })?;
    let (wn, bn) = (format!("{base}/0 (kernel)"), format!("{base}/1 (bias)"));
    if ws.len() != 2 {
        return Err(ExportError::shape(&wn, "[K, 2]", dims(&ws)));
    }
    let (k, o) = (ws[0], ws[1]);
    let bv = if bs.is_empty() && bv.is_empty() {
        notes.push(format!(
            "`{base}` has no bias (Dense use_bias=False): zero biases"
        ));
        vec![0.0; o]
    } else if bs == [o] {
        bv
    } else {
        return Err(ExportError::shape(&bn, format!("[{o}]"), dims(&bs)));
    };
    let mut concat_order_known = lstms.len() == 1;
    if let Some(order) = concat
        && lstms.len() == 2
        && order.len() == 2
    {
        let pos = |n: &str| lstms.iter().position(|l| l.name == n);
        if let (Some(a), Some(b)) = (pos(&order[0]), pos(&order[1]))
            && a != b
        {
            lstms = vec![lstms[a].clone(), lstms[b].clone()];
            concat_order_known = true;
        }
    }
    if !concat_order_known {
        notes.push(
            "concatenation order unknown (no config); dense columns taken as [force, bands]".into(),
        );
    }
    Ok(Imported {
        format,
        lstms,
        concat_order_known,
        dense: NamedDense {
            weight: wn,
            bias: bn,
            outputs: o,
            inputs: k,
            w: transpose(&wv, k, o),
            b: bv,
        },
        metadata: BTreeMap::new(),
        notes,
    })
}

fn with_config(
    path: &Path,
    config: &str,
    weights: Vec<u8>,
    format: Format,
    weights_path: &Path,
) -> Result<Imported> {
    let (layers, sequential) = parse_config(path, config)?;
    let mut notes = Vec::new();
    let (lstm_layers, dense, concat) = check_config(&layers, sequential, &mut notes)?;
    let w = read_h5(weights_path, weights)?;
    check_declared_biases(&dense, &w)?;
    if w.lstms.len() != lstm_layers.len() {
        return Err(ExportError::missing(
            "layers/lstm*/cell/vars",
            format!(
                "the config has {} LSTM layers, the weights file {}",
                lstm_layers.len(),
                w.lstms.len()
            ),
        ));
    }
    for (l, (base, shapes, _)) in lstm_layers.iter().zip(&w.lstms) {
        let units = l.config.get("units").and_then(Value::as_u64).unwrap_or(0);
        if shapes[1].first().map(|&d| d as u64) != Some(units) {
            return Err(ExportError::shape(
                format!("{base}/1 (recurrent_kernel of `{}`)", l.name),
                format!("[{units}, {}]", units.saturating_mul(4)),
                dims(&shapes[1]),
            ));
        }
        let use_bias = l.config.get("use_bias").and_then(Value::as_bool) != Some(false);
        if use_bias && shapes[2].is_empty() {
            return Err(ExportError::missing(
                format!("{base}/2 (bias of `{}`)", l.name),
                "the config says use_bias=True but the weights file has no bias",
            ));
        }
    }
    let names = lstm_layers.iter().map(|l| l.name.clone()).collect();
    to_imported(w, Some(names), concat, notes, format)
}

/// Every bias the config declares is in the weights file: the Dense layer's (`use_bias`
/// defaults to true in Keras), as the LSTMs' are checked in [`with_config`].
fn check_declared_biases(dense: &LayerInfo, w: &H5Weights) -> Result<()> {
    let use_bias = dense.config.get("use_bias").and_then(Value::as_bool) != Some(false);
    if let Some((base, shapes, _)) = &w.dense
        && use_bias
        && shapes[1].is_empty()
    {
        return Err(ExportError::missing(
            format!("{base}/1 (bias of `{}`)", dense.name),
            "the config says use_bias=True but the weights file has no bias",
        ));
    }
    Ok(())
}

/// Largest `config.json` or `model.weights.h5` read from a `.keras` archive: 256 MiB, the
/// f32 bytes of [`super::MAX_TENSOR_ELEMENTS`] values several times over.
pub const MAX_ARCHIVE_ENTRY: u64 = 256 << 20;

/// Reads a `.keras` archive.
pub fn import_keras(path: &Path, bytes: &[u8]) -> Result<Imported> {
    let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes)).map_err(|e| {
        ExportError::format(path, format!("not a readable .keras (zip) archive: {e}"))
    })?;
    let mut read = |name: &str| -> Result<Vec<u8>> {
        let mut f = zip.by_name(name).map_err(|e| {
            ExportError::format(
                path,
                format!("`{name}` missing from the .keras archive: {e}"),
            )
        })?;
        // The sizes in a zip are the file's claims: bounded, and the read capped at the bound
        // whatever the entry decompresses to.
        if f.size() > MAX_ARCHIVE_ENTRY {
            return Err(ExportError::format(
                path,
                format!(
                    "`{name}` in the archive declares {} bytes, over the importer's bound of {MAX_ARCHIVE_ENTRY} (a model the firmware can run is a few MB at most)",
                    f.size()
                ),
            ));
        }
        let mut v = Vec::new();
        (&mut f)
            .take(MAX_ARCHIVE_ENTRY + 1)
            .read_to_end(&mut v)
            .map_err(|e| {
                ExportError::format(path, format!("`{name}` in the archive is unreadable: {e}"))
            })?;
        if v.len() as u64 > MAX_ARCHIVE_ENTRY {
            return Err(ExportError::format(
                path,
                format!(
                    "`{name}` in the archive decompresses to more than {MAX_ARCHIVE_ENTRY} bytes"
                ),
            ));
        }
        Ok(v)
    };
    let config = String::from_utf8(read("config.json")?)
        .map_err(|_| ExportError::format(path, "config.json is not UTF-8"))?;
    let weights = read("model.weights.h5")?;
    with_config(path, &config, weights, Format::Keras, path)
}

/// Reads a `.weights.h5`, with the model's config when given.
pub fn import_h5(path: &Path, bytes: Vec<u8>, config: Option<&Path>) -> Result<Imported> {
    match config {
        Some(c) => {
            let text = std::fs::read_to_string(c).map_err(|e| ExportError::io(c, e))?;
            with_config(c, &text, bytes, Format::KerasH5, path)
        }
        None => {
            let w = read_h5(path, bytes)?;
            let notes = vec![
                "weights only: activations were not checked (pass --keras-config config.json to check them); tanh/sigmoid assumed".into(),
            ];
            to_imported(w, None, None, notes, Format::KerasH5)
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const H5: &[u8] = include_bytes!("../../tests/fixtures/keras_c.weights.h5");

    /// The fixture with every dataspace whose dims (and max dims) read `from` rewritten to `to`
    /// (u64 little-endian, as HDF5 stores dataspace dimensions).
    fn patched(from: [u64; 2], to: [u64; 2]) -> Vec<u8> {
        let enc = |d: [u64; 2]| -> Vec<u8> { d.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let (pat, rep) = (enc(from), enc(to));
        let mut b = H5.to_vec();
        let mut hits = 0;
        let mut i = 0;
        while i + pat.len() <= b.len() {
            if b[i..i + pat.len()] == pat[..] {
                b[i..i + pat.len()].copy_from_slice(&rep);
                hits += 1;
                i += pat.len();
            } else {
                i += 1;
            }
        }
        assert!(hits >= 1, "pattern {from:?} not in the fixture");
        b
    }

    fn err_of(bytes: Vec<u8>) -> ExportError {
        match import_h5(Path::new("crafted.weights.h5"), bytes, None) {
            Ok(_) => panic!("a crafted file was accepted"),
            Err(e) => e,
        }
    }

    #[test]
    fn the_unpatched_fixture_imports() {
        let imp = import_h5(Path::new("keras_c.weights.h5"), H5.to_vec(), None).expect("import");
        assert_eq!(imp.lstms[0].lstm.hidden, 16);
    }

    #[test]
    fn huge_dataset_dimensions_are_refused_before_allocating() {
        // recurrent_kernel [16, 64] → [2^33, 64]: 2^39 elements (2 TiB as f32).
        let e = err_of(patched([16, 64], [1 << 33, 64]));
        assert_eq!(e.exit_code(), 9, "{e}");
        assert!(e.to_string().contains("layers/lstm/cell/vars/1"), "{e}");
        // A product that overflows u64: [2^40, 2^40].
        let e = err_of(patched([16, 64], [1 << 40, 1 << 40]));
        assert_eq!(e.exit_code(), 9, "{e}");
        // A zero next to a huge dimension (product 0): still bounded per dimension.
        let e = err_of(patched([11, 64], [0, 1 << 62]));
        assert_eq!(e.exit_code(), 9, "{e}");
        // Under the element bound but larger than the whole file (contiguous storage).
        let e = err_of(patched([16, 64], [4096, 64]));
        assert_eq!(e.exit_code(), 4, "{e}");
        assert!(e.to_string().contains("more than the whole file"), "{e}");
    }

    /// A file that lost its tail (h5py refuses it) used to convert with exit 0 and a zero
    /// Dense bias: refused as truncated, whatever the number of bytes lost.
    #[test]
    fn a_truncated_weights_file_is_refused() {
        for cut in [1usize, 8, 48, 200] {
            let e = err_of(H5[..H5.len() - cut].to_vec());
            assert_eq!(e.exit_code(), 4, "cut {cut}: {e}");
            assert!(e.to_string().contains("truncated"), "cut {cut}: {e}");
        }
    }

    /// The config of the `.keras` fixture (Dense with `use_bias` true) against weights whose
    /// Dense bias dataset is gone: refused, not a silent zero bias.
    #[test]
    fn a_dense_bias_the_config_declares_must_be_present() {
        let keras = include_bytes!("../../tests/fixtures/keras_c.keras");
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(&keras[..])).unwrap();
        let mut config = String::new();
        zip.by_name("config.json")
            .unwrap()
            .read_to_string(&mut config)
            .unwrap();
        let (layers, sequential) = parse_config(Path::new("config.json"), &config).unwrap();
        let (_, dense, _) = check_config(&layers, sequential, &mut Vec::new()).unwrap();
        let mut w = read_h5(Path::new("keras_c.weights.h5"), H5.to_vec()).unwrap();
        check_declared_biases(&dense, &w).expect("the intact file has its bias");
        let d = w.dense.as_mut().unwrap();
        d.1[1].clear();
        d.2[1].clear();
        let e = check_declared_biases(&dense, &w).expect_err("missing bias accepted");
        assert_eq!(e.exit_code(), 5, "{e}");
        assert!(e.to_string().contains("use_bias=True"), "{e}");
    }
}
