//! ONNX: one or two `LSTM` nodes (forward, one layer) whose hidden states go, possibly through a
//! `Concat`, into a `Gemm` or a `MatMul` + `Add`: what `torch.onnx.export` emits for
//! `nn.LSTM` + `nn.Linear` (both the dynamo and the TorchScript exporter).
//!
//! ONNX's LSTM weights: W [1, 4H, I], R [1, 4H, H], B [1, 8H] = [Wb, Rb], gate blocks in the
//! order **i, o, f, c**; reordered here to PyTorch's i, f, g(=c), o. Refused, each naming the node
//! or tensor: `direction` reverse/bidirectional, a non-zero peephole input P, `clip`,
//! `input_forget`, `activations` other than Sigmoid/Tanh/Tanh (HardSigmoid included), a non-zero
//! or computed initial state, stacked LSTMs, and any operator on the data path that is not part
//! of LSTM → dense (e.g. an activation between them).

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use prost::Message;
use slipguard_core::float::FloatLstm;

use super::onnx_proto::{ModelProto, NodeProto, TensorProto, data_type};
use super::{
    Format, Imported, NamedDense, NamedLstm, dims, element_count, reorder_gates, transpose,
};
use crate::error::{ExportError, Result, check_finite_in};

/// A constant: dims and values as f32.
#[derive(Clone, Debug)]
pub(super) struct Const {
    pub(super) dims: Vec<usize>,
    pub(super) data: Vec<f32>,
}

/// Reads the bytes of a tensor stored outside the .onnx (`data_location = EXTERNAL`, as
/// `torch.onnx.export` writes by default): `location` relative to the model's folder (no
/// absolute paths, no `..`), `offset`, `length`.
fn external_bytes(path: &Path, t: &TensorProto) -> Result<Vec<u8>> {
    let get = |k: &str| {
        t.external_data
            .iter()
            .find(|e| e.key == k)
            .map(|e| e.value.clone())
    };
    let loc = get("location").ok_or_else(|| {
        ExportError::format(
            path,
            format!("tensor `{}`: external data without a location", t.name),
        )
    })?;
    let rel = Path::new(&loc);
    if rel.is_absolute()
        || rel
            .components()
            .any(|c| matches!(c, std::path::Component::ParentDir))
    {
        return Err(ExportError::format(
            path,
            format!(
                "tensor `{}`: external data location `{loc}` leaves the model's folder",
                t.name
            ),
        ));
    }
    let file = path.parent().unwrap_or(Path::new(".")).join(rel);
    let data = std::fs::read(&file).map_err(|e| ExportError::io(&file, e))?;
    let parse = |k: &str| {
        get(k)
            .map(|v| {
                v.parse::<usize>().map_err(|_| {
                    ExportError::format(
                        path,
                        format!("tensor `{}`: bad external {k} `{v}`", t.name),
                    )
                })
            })
            .transpose()
    };
    let offset = parse("offset")?.unwrap_or(0);
    let length = parse("length")?.unwrap_or(data.len().saturating_sub(offset));
    // Both come from the file: the end is computed with checked arithmetic.
    let past_end = |end: String| {
        ExportError::format(
            &file,
            format!(
                "tensor `{}`: external data bytes {offset}..{end} are past the end of the file ({} bytes; truncated?)",
                t.name,
                data.len()
            ),
        )
    };
    let end = offset
        .checked_add(length)
        .ok_or_else(|| past_end(format!("{offset} + {length} (overflows)")))?;
    data.get(offset..end)
        .map(<[u8]>::to_vec)
        .ok_or_else(|| past_end(end.to_string()))
}

fn tensor_values(path: &Path, t: &TensorProto) -> Result<Const> {
    let external;
    let raw: &Vec<u8> = if t.data_location == 1 || !t.external_data.is_empty() {
        external = external_bytes(path, t)?;
        &external
    } else {
        &t.raw_data
    };
    if let Some(&d) = t.dims.iter().find(|&&d| d < 0) {
        return Err(ExportError::format(
            path,
            format!("tensor `{}` has a negative dimension {d}", t.name),
        ));
    }
    let dims64: Vec<u64> = t.dims.iter().map(|&d| d as u64).collect();
    // Bounded (checked product, at most MAX_TENSOR_ELEMENTS) before anything is decoded.
    let n = element_count(&t.name, &dims64)?;
    let dims: Vec<usize> = dims64.iter().map(|&d| d as usize).collect();
    let data: Vec<f32> = match t.data_type {
        data_type::FLOAT if !raw.is_empty() => raw
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect(),
        data_type::FLOAT => t.float_data.clone(),
        data_type::DOUBLE if !raw.is_empty() => raw
            .chunks_exact(8)
            .map(|c| f64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32)
            .collect(),
        data_type::DOUBLE => t.double_data.iter().map(|&x| x as f32).collect(),
        data_type::FLOAT16 | data_type::BFLOAT16 => {
            let bits: Vec<u16> = if !raw.is_empty() {
                raw.chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect()
            } else {
                t.int32_data.iter().map(|&x| x as u16).collect()
            };
            bits.into_iter()
                .map(|b| {
                    if t.data_type == data_type::FLOAT16 {
                        super::torch::f16_to_f32(b)
                    } else {
                        f32::from_bits((b as u32) << 16)
                    }
                })
                .collect()
        }
        data_type::INT64 if !raw.is_empty() => raw
            .chunks_exact(8)
            .map(|c| i64::from_le_bytes(c.try_into().unwrap_or([0; 8])) as f32)
            .collect(),
        data_type::INT64 => t.int64_data.iter().map(|&x| x as f32).collect(),
        data_type::INT32 if !raw.is_empty() => raw
            .chunks_exact(4)
            .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f32)
            .collect(),
        data_type::INT32 => t.int32_data.iter().map(|&x| x as f32).collect(),
        other => {
            return Err(ExportError::shape(
                &t.name,
                "a float tensor",
                format!("ONNX data type {other}"),
            ));
        }
    };
    if data.len() != n {
        return Err(ExportError::format(
            path,
            format!(
                "tensor `{}` declares {} elements but holds {}",
                t.name,
                n,
                data.len()
            ),
        ));
    }
    Ok(Const { dims, data })
}

pub(super) fn attr<'a>(
    n: &'a NodeProto,
    name: &str,
) -> Option<&'a super::onnx_proto::AttributeProto> {
    n.attribute.iter().find(|a| a.name == name)
}

pub(super) fn node_label(n: &NodeProto) -> String {
    if n.name.is_empty() {
        format!(
            "{} node → {}",
            n.op_type,
            n.output.first().cloned().unwrap_or_default()
        )
    } else {
        format!("{} node `{}`", n.op_type, n.name)
    }
}

/// Operators allowed on the data path between the graph input and the logits.
const DATA_OPS: &[&str] = &[
    "LSTM",
    "Gemm",
    "MatMul",
    "Add",
    "Concat",
    "Squeeze",
    "Unsqueeze",
    "Transpose",
    "Reshape",
    "Slice",
    "Gather",
    "Identity",
    "Softmax",
    "Split",
    "Flatten",
    "Cast",
];

/// Reads an ONNX model.
pub fn import(path: &Path, bytes: &[u8]) -> Result<Imported> {
    let model = ModelProto::decode(bytes)
        .map_err(|e| ExportError::format(path, format!("not a valid ONNX protobuf: {e}")))?;
    let graph = model
        .graph
        .as_ref()
        .ok_or_else(|| ExportError::format(path, "ONNX model without a graph"))?;
    if graph.node.is_empty() {
        return Err(ExportError::format(
            path,
            "ONNX graph has no nodes (truncated?)",
        ));
    }
    // Constants: initializers and Constant nodes.
    let mut consts: BTreeMap<String, Const> = BTreeMap::new();
    for t in &graph.initializer {
        consts.insert(t.name.clone(), tensor_values(path, t)?);
    }
    for n in graph.node.iter().filter(|n| n.op_type == "Constant") {
        if let (Some(out), Some(t)) = (
            n.output.first(),
            attr(n, "value").and_then(|a| a.t.as_ref()),
        ) {
            consts.insert(out.clone(), tensor_values(path, t)?);
        }
    }
    // W, R, B computed from initializers by Slice/Concat/Reshape/… (torch's dynamo exporter
    // for larger models): evaluated here, so that the LSTM reads constants.
    let folded = super::onnx_fold::fold(graph, &mut consts)?;
    let producer: BTreeMap<&str, usize> = graph
        .node
        .iter()
        .enumerate()
        .flat_map(|(i, n)| n.output.iter().map(move |o| (o.as_str(), i)))
        .collect();

    // Data path: forward from the graph inputs that are not initializers, not through Shape.
    let mut data_vals: BTreeSet<String> = graph
        .input
        .iter()
        .filter(|v| !consts.contains_key(&v.name))
        .map(|v| v.name.clone())
        .collect();
    let mut data_nodes = BTreeSet::new();
    loop {
        let before = data_vals.len();
        for (i, n) in graph.node.iter().enumerate() {
            if n.op_type == "Shape" || data_nodes.contains(&i) {
                continue;
            }
            if n.input.iter().any(|x| data_vals.contains(x)) {
                data_nodes.insert(i);
                data_vals.extend(n.output.iter().cloned());
            }
        }
        if data_vals.len() == before {
            break;
        }
    }
    for &i in &data_nodes {
        let n = &graph.node[i];
        if !DATA_OPS.contains(&n.op_type.as_str()) {
            return Err(ExportError::unsupported(
                node_label(n),
                format!(
                    "operator {} lies between the input and the logits; the firmware runs LSTM → dense (→ softmax) only",
                    n.op_type
                ),
            ));
        }
    }

    // Ancestor LSTMs of a value.
    let ancestors = |start: &str| -> BTreeSet<usize> {
        let mut out = BTreeSet::new();
        let mut stack = vec![start.to_string()];
        let mut seen = BTreeSet::new();
        while let Some(v) = stack.pop() {
            if !seen.insert(v.clone()) {
                continue;
            }
            if let Some(&p) = producer.get(v.as_str()) {
                let n = &graph.node[p];
                if n.op_type == "LSTM" {
                    out.insert(p);
                } else {
                    stack.extend(n.input.iter().filter(|x| !x.is_empty()).cloned());
                }
            }
        }
        out
    };

    let lstm_nodes: Vec<usize> = (0..graph.node.len())
        .filter(|&i| graph.node[i].op_type == "LSTM")
        .collect();
    if lstm_nodes.is_empty() {
        return Err(ExportError::missing(
            "LSTM",
            "the ONNX graph has no LSTM node",
        ));
    }
    // Stacking first, over every LSTM: a 2-layer model is refused as such, whatever else its
    // layers carry (e.g. initial states sliced from one [2, B, H] tensor).
    for &li in &lstm_nodes {
        let n = &graph.node[li];
        if let Some(x) = n.input.first()
            && let Some(&below) = ancestors(x).iter().next()
        {
            return Err(ExportError::unsupported(
                node_label(n),
                format!(
                    "stacked LSTMs (2 layers): its input comes from {}; the firmware runs one LSTM layer per path (train with num_layers=1)",
                    node_label(&graph.node[below])
                ),
            ));
        }
    }
    let mut lstms = Vec::new();
    for &li in &lstm_nodes {
        let n = &graph.node[li];
        let label = node_label(n);
        lstms.push(read_lstm(n, &label, &consts, &producer, graph)?);
    }

    // Dense: exactly one Gemm or MatMul with a constant weight.
    let dense_nodes: Vec<usize> = (0..graph.node.len())
        .filter(|&i| {
            let n = &graph.node[i];
            (n.op_type == "Gemm" || n.op_type == "MatMul")
                && n.input.get(1).is_some_and(|w| consts.contains_key(w))
        })
        .collect();
    let di = match dense_nodes.as_slice() {
        [one] => *one,
        [] => {
            return Err(ExportError::missing(
                "Gemm/MatMul",
                "no Gemm or MatMul with a constant weight after the LSTM (nn.Linear to 2 logits)",
            ));
        }
        many => {
            return Err(ExportError::unsupported(
                many.iter()
                    .map(|&i| node_label(&graph.node[i]))
                    .collect::<Vec<_>>()
                    .join(", "),
                "more than one dense layer; the firmware has one dense layer to the 2 logits",
            ));
        }
    };
    let dn = &graph.node[di];
    let wname = dn.input[1].clone();
    let wc = &consts[&wname];
    check_finite_in(&wname, &wc.dims, &wc.data)?;
    if wc.dims.len() != 2 {
        return Err(ExportError::shape(
            &wname,
            "[K, 2] (MatMul) or [2, K] (Gemm, transB=1)",
            dims(&wc.dims),
        ));
    }
    let (mut w, outputs, inputs);
    let mut b: Vec<f32>;
    let bname;
    if dn.op_type == "Gemm" {
        let alpha = attr(dn, "alpha").map_or(1.0, |a| a.f);
        let beta = attr(dn, "beta").map_or(1.0, |a| a.f);
        if attr(dn, "transA").is_some_and(|a| a.i != 0) {
            return Err(ExportError::unsupported(
                node_label(dn),
                "Gemm with transA=1",
            ));
        }
        if attr(dn, "transB").is_some_and(|a| a.i != 0) {
            (outputs, inputs) = (wc.dims[0], wc.dims[1]);
            w = wc.data.clone();
        } else {
            (inputs, outputs) = (wc.dims[0], wc.dims[1]);
            w = transpose(&wc.data, inputs, outputs);
        }
        w.iter_mut().for_each(|x| *x *= alpha);
        bname = dn.input.get(2).cloned().unwrap_or_default();
        b = match consts.get(&bname) {
            Some(c) => c.data.iter().map(|x| x * beta).collect(),
            None => vec![0.0; outputs],
        };
    } else {
        (inputs, outputs) = (wc.dims[0], wc.dims[1]);
        w = transpose(&wc.data, inputs, outputs);
        // The Add that takes the MatMul's output and a constant.
        let Some(out) = dn.output.first() else {
            return Err(ExportError::missing(
                node_label(dn),
                "the MatMul has no output, so its bias Add cannot be found",
            ));
        };
        let add = graph
            .node
            .iter()
            .find(|n| n.op_type == "Add" && n.input.iter().any(|x| x == out));
        match add.and_then(|a| a.input.iter().find(|x| consts.contains_key(*x))) {
            Some(name) => {
                bname = name.clone();
                b = consts[name].data.clone();
            }
            None => {
                bname = "(none)".into();
                b = vec![0.0; outputs];
            }
        }
    }
    if b.len() == 1 && outputs > 1 {
        b = vec![b[0]; outputs];
    }
    if b.len() != outputs {
        return Err(ExportError::shape(
            &bname,
            format!("[{outputs}]"),
            format!("[{}]", b.len()),
        ));
    }

    // Concatenation order of the hidden states.
    let mut notes = Vec::new();
    let mut concat_order_known = lstms.len() == 1;
    if lstms.len() == 2 {
        let src = &dn.input[0];
        let mut v = src.clone();
        let mut order = None;
        for _ in 0..64 {
            let Some(&p) = producer.get(v.as_str()) else {
                break;
            };
            let n = &graph.node[p];
            if n.op_type == "Concat" {
                let mut o = Vec::new();
                for x in &n.input {
                    let a = ancestors(x);
                    if a.len() == 1 {
                        let li = *a.iter().next().unwrap_or(&0);
                        if let Some(k) = lstm_nodes.iter().position(|&q| q == li) {
                            o.push(k);
                        }
                    }
                }
                if o.len() == 2 && o[0] != o[1] {
                    order = Some(o);
                }
                break;
            }
            match n.input.first() {
                Some(x) => v = x.clone(),
                None => break,
            }
        }
        match order {
            Some(o) => {
                lstms = o.iter().map(|&k| lstms[k].clone()).collect();
                concat_order_known = true;
            }
            None => notes.push(
                "no Concat of the two LSTM outputs found; dense columns taken as [force, bands]"
                    .into(),
            ),
        }
    }
    if !folded.is_empty() {
        notes.push(format!(
            "constant subgraphs folded: {}",
            folded
                .iter()
                .map(|(op, k)| format!("{k} × {op}"))
                .collect::<Vec<_>>()
                .join(", ")
        ));
    }
    notes.push(format!(
        "producer {} {}, opset {}",
        model.producer_name,
        model.producer_version,
        model
            .opset_import
            .iter()
            .find(|o| o.domain.is_empty())
            .map_or(0, |o| o.version)
    ));
    Ok(Imported {
        format: Format::Onnx,
        lstms,
        concat_order_known,
        dense: NamedDense {
            weight: wname,
            bias: bname,
            outputs,
            inputs,
            w,
            b,
        },
        metadata: BTreeMap::new(),
        notes,
    })
}

fn is_zero_state(
    name: &str,
    consts: &BTreeMap<String, Const>,
    producer: &BTreeMap<&str, usize>,
    graph: &super::onnx_proto::GraphProto,
) -> bool {
    if let Some(c) = consts.get(name) {
        return c.data.iter().all(|&x| x == 0.0);
    }
    let Some(&p) = producer.get(name) else {
        return false;
    };
    let n = &graph.node[p];
    match n.op_type.as_str() {
        "ConstantOfShape" => attr(n, "value").and_then(|a| a.t.as_ref()).is_none_or(|t| {
            t.raw_data.iter().all(|&b| b == 0) && t.float_data.iter().all(|&x| x == 0.0)
        }),
        "Expand" | "Tile" | "Reshape" | "Unsqueeze" | "Squeeze" | "Identity" | "Cast" | "Slice"
        | "Gather" | "Transpose" => n
            .input
            .first()
            .is_some_and(|x| is_zero_state(x, consts, producer, graph)),
        _ => false,
    }
}

/// Static dims of a graph input or value, when the file declares them (`None` per symbolic dim).
fn declared_dims(name: &str, graph: &super::onnx_proto::GraphProto) -> Option<Vec<Option<i64>>> {
    let vi = graph
        .input
        .iter()
        .chain(&graph.value_info)
        .find(|v| v.name == name)?;
    let shape = vi.r#type.as_ref()?.tensor_type.as_ref()?.shape.as_ref()?;
    Some(
        shape
            .dim
            .iter()
            .map(|d| d.dim_value.filter(|&v| v > 0))
            .collect(),
    )
}

/// The LSTM's `sequence_lens` input masks steps past each sequence's length; the firmware runs
/// an unbounded stream, so it is accepted only as a constant equal to the sequence length the
/// graph declares (every step runs), and refused otherwise.
fn check_sequence_lens(
    sl: &str,
    n: &NodeProto,
    label: &str,
    consts: &BTreeMap<String, Const>,
    producer: &BTreeMap<&str, usize>,
    graph: &super::onnx_proto::GraphProto,
) -> Result<()> {
    let refuse = |why: String| {
        Err(ExportError::unsupported(
            format!("{label} input sequence_lens `{sl}`"),
            format!(
                "{why}; the firmware runs every step of an unbounded stream (export without sequence_lens / packed sequences)"
            ),
        ))
    };
    let Some(c) = consts.get(sl) else {
        return refuse("sequence_lens is computed by the graph, not a constant".into());
    };
    // X [T, B, I] (layout 0): T from X's declared shape, or from the graph input it is a
    // Transpose of.
    let x = n.input.first().map(String::as_str).unwrap_or("");
    let mut t = declared_dims(x, graph).and_then(|d| d.first().copied().flatten());
    if t.is_none()
        && let Some(&p) = producer.get(x)
    {
        let pn = &graph.node[p];
        if pn.op_type == "Transpose"
            && let Some(src) = pn.input.first()
            && let Some(d) = declared_dims(src, graph)
        {
            let perm: Vec<usize> = attr(pn, "perm")
                .map(|a| a.ints.iter().map(|&i| i.max(0) as usize).collect())
                .unwrap_or_else(|| (0..d.len()).rev().collect());
            t = perm.first().and_then(|&a| d.get(a).copied().flatten());
        }
    }
    match t {
        Some(t) if c.data.iter().all(|&v| v == t as f32) => Ok(()),
        Some(t) => refuse(format!(
            "sequence_lens {:?} differs from the sequence length {t} the graph declares",
            c.data
        )),
        None => refuse(format!(
            "sequence_lens {:?} is given but the graph declares no fixed sequence length to compare it with",
            c.data
        )),
    }
}

fn read_lstm(
    n: &NodeProto,
    label: &str,
    consts: &BTreeMap<String, Const>,
    producer: &BTreeMap<&str, usize>,
    graph: &super::onnx_proto::GraphProto,
) -> Result<NamedLstm> {
    let dir = attr(n, "direction")
        .map(|a| String::from_utf8_lossy(&a.s).to_string())
        .unwrap_or_else(|| "forward".into());
    if dir != "forward" {
        return Err(ExportError::unsupported(
            label,
            format!(
                "direction={dir}: the firmware runs causal, forward-only LSTMs (bidirectional/reverse cannot run on a live stream)"
            ),
        ));
    }
    if let Some(a) = attr(n, "clip") {
        return Err(ExportError::unsupported(
            format!("{label} attribute clip"),
            format!(
                "cell clipping (clip={}) is not implemented by the firmware's cell; train without it",
                a.f
            ),
        ));
    }
    if attr(n, "input_forget").is_some_and(|a| a.i != 0) {
        return Err(ExportError::unsupported(
            format!("{label} attribute input_forget"),
            "coupled input-forget gate (input_forget=1) is not supported",
        ));
    }
    if let Some(a) = attr(n, "activations") {
        let acts: Vec<String> = a
            .strings
            .iter()
            .map(|s| String::from_utf8_lossy(s).to_ascii_lowercase())
            .collect();
        if acts != ["sigmoid", "tanh", "tanh"] {
            let hint = if acts.iter().any(|s| s == "hardsigmoid") {
                " (HardSigmoid is not the logistic σ the firmware's gate table implements; retrain with sigmoid — converting would change the model's outputs)"
            } else {
                ""
            };
            return Err(ExportError::unsupported(
                format!("{label} attribute activations"),
                format!("activations {acts:?}; the firmware needs [Sigmoid, Tanh, Tanh]{hint}"),
            ));
        }
    }
    if let Some(a) = n.attribute.iter().find(|a| a.name == "layout" && a.i != 0) {
        return Err(ExportError::unsupported(
            format!("{label} attribute layout"),
            format!(
                "layout={} (batch-major X [B, T, I]): the importer does not trace the Transposes around a batch-major LSTM, so it cannot tell whether time is on the axis the LSTM recurs over; export with layout=0 (what torch.onnx.export emits, also for batch_first=True)",
                a.i
            ),
        ));
    }
    let input = |k: usize| n.input.get(k).filter(|s| !s.is_empty());
    if let Some(sl) = input(4) {
        check_sequence_lens(sl, n, label, consts, producer, graph)?;
    }
    let get = |k: usize, what: &str| -> Result<(&String, &Const)> {
        let name = input(k).ok_or_else(|| {
            ExportError::missing(
                format!("{label} input {what}"),
                "required LSTM input is absent",
            )
        })?;
        let c = consts.get(name).ok_or_else(|| {
            ExportError::unsupported(
                name,
                format!("LSTM {what} is computed by the graph, not a constant initializer"),
            )
        })?;
        Ok((name, c))
    };
    let (wn, w) = get(1, "W")?;
    let (rn, r) = get(2, "R")?;
    check_finite_in(wn, &w.dims, &w.data)?;
    check_finite_in(rn, &r.dims, &r.data)?;
    if w.dims.len() != 3 || !w.dims[1].is_multiple_of(4) || w.dims[1] == 0 {
        return Err(ExportError::shape(wn, "[1, 4H, I]", dims(&w.dims)));
    }
    if w.dims[0] != 1 {
        return Err(ExportError::unsupported(
            wn,
            format!(
                "{} directions (bidirectional); the firmware runs forward-only LSTMs",
                w.dims[0]
            ),
        ));
    }
    let h = w.dims[1] / 4;
    let i = w.dims[2];
    if let Some(hs) = attr(n, "hidden_size")
        && hs.i != h as i64
    {
        return Err(ExportError::shape(
            wn,
            format!("[1, {}, I] (hidden_size={})", hs.i.saturating_mul(4), hs.i),
            dims(&w.dims),
        ));
    }
    if r.dims != [1, 4 * h, h] {
        return Err(ExportError::shape(
            rn,
            format!("[1, {}, {h}]", 4 * h),
            dims(&r.dims),
        ));
    }
    let (bn, bias) = match input(3) {
        Some(_) => {
            let (bn, b) = get(3, "B")?;
            if b.dims != [1, 8 * h] {
                return Err(ExportError::shape(
                    bn,
                    format!("[1, {}]", 8 * h),
                    dims(&b.dims),
                ));
            }
            check_finite_in(bn, &b.dims, &b.data)?;
            (bn.clone(), b.data.clone())
        }
        None => ("(none)".to_string(), vec![0.0; 8 * h]),
    };
    if let Some(pn) = input(7) {
        let nonzero = consts
            .get(pn)
            .is_none_or(|c| c.data.iter().any(|&x| x != 0.0));
        if nonzero {
            return Err(ExportError::unsupported(
                pn,
                "peephole weights (LSTM input P): the firmware's cell has no peephole connections",
            ));
        }
    }
    for (k, what) in [(5, "initial_h"), (6, "initial_c")] {
        if let Some(s) = input(k)
            && !is_zero_state(s, consts, producer, graph)
        {
            return Err(ExportError::unsupported(
                s,
                format!(
                    "{what} is not a zero constant; the firmware starts every grasp from a zero state"
                ),
            ));
        }
    }
    // ONNX blocks i, o, f, c → PyTorch i, f, g, o.
    let order = [0, 2, 3, 1];
    let w_ih = reorder_gates(&w.data, h, i, order);
    let w_hh = reorder_gates(&r.data, h, h, order);
    let b_ih = reorder_gates(&bias[..4 * h], h, 1, order);
    let b_hh = reorder_gates(&bias[4 * h..], h, 1, order);
    Ok(NamedLstm {
        name: if n.name.is_empty() {
            wn.clone()
        } else {
            n.name.clone()
        },
        tensors: [
            wn.clone(),
            rn.clone(),
            format!("{bn}[0..4H]"),
            format!("{bn}[4H..8H]"),
        ],
        lstm: FloatLstm {
            input: i,
            hidden: h,
            w_ih,
            w_hh,
            b_ih,
            b_hh,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::super::onnx_proto::{
        AttributeProto, GraphProto, StringStringEntryProto, ValueInfoProto,
    };
    use super::*;

    pub(super) fn tensor(name: &str, dims: &[i64], data: Vec<f32>) -> TensorProto {
        TensorProto {
            name: name.into(),
            dims: dims.to_vec(),
            data_type: data_type::FLOAT,
            float_data: data,
            ..Default::default()
        }
    }

    pub(super) fn node(op: &str, inputs: &[&str], outputs: &[&str]) -> NodeProto {
        NodeProto {
            op_type: op.into(),
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: outputs.iter().map(|s| s.to_string()).collect(),
            ..Default::default()
        }
    }

    pub(super) fn int_attr(name: &str, i: i64) -> AttributeProto {
        AttributeProto {
            name: name.into(),
            i,
            r#type: 2,
            ..Default::default()
        }
    }

    /// x [T, 1, I] → LSTM(H) → Squeeze → MatMul [H, 2] → Add [2]: the smallest graph the
    /// importer accepts, with W, R, B given by the caller.
    pub(super) fn graph(w: TensorProto, r: TensorProto, b: TensorProto, h: usize) -> ModelProto {
        let lstm = node("LSTM", &["x", &w.name, &r.name, &b.name], &["y", "", ""]);
        let wd = tensor("wd", &[h as i64, 2], vec![0.5; 2 * h]);
        let bd = tensor("bd", &[2], vec![0.0, 0.1]);
        ModelProto {
            graph: Some(GraphProto {
                node: vec![
                    lstm,
                    node("Squeeze", &["y"], &["ys"]),
                    node("MatMul", &["ys", "wd"], &["m"]),
                    node("Add", &["m", "bd"], &["logits"]),
                ],
                initializer: vec![w, r, b, wd, bd],
                input: vec![ValueInfoProto {
                    name: "x".into(),
                    ..Default::default()
                }],
                ..Default::default()
            }),
            ..Default::default()
        }
    }

    pub(super) fn plain(i: usize, h: usize) -> ModelProto {
        graph(
            tensor("W", &[1, 4 * h as i64, i as i64], vec![0.1; 4 * h * i]),
            tensor("R", &[1, 4 * h as i64, h as i64], vec![0.1; 4 * h * h]),
            tensor("B", &[1, 8 * h as i64], vec![0.0; 8 * h]),
            h,
        )
    }

    fn import_model(m: &ModelProto) -> Result<Imported> {
        import(Path::new("crafted.onnx"), &m.encode_to_vec())
    }

    #[test]
    fn the_crafted_graph_imports() {
        let imp = import_model(&plain(3, 2)).expect("import");
        assert_eq!((imp.lstms[0].lstm.input, imp.lstms[0].lstm.hidden), (3, 2));
        assert_eq!(imp.dense.inputs, 2);
    }

    #[test]
    fn a_matmul_without_an_output_is_an_error_not_a_panic() {
        // Found by the import_onnx fuzz target: the bias lookup read the MatMul's first output.
        let mut m = plain(3, 2);
        let g = m.graph.as_mut().expect("graph");
        let mm = g
            .node
            .iter_mut()
            .find(|n| n.op_type == "MatMul")
            .expect("MatMul");
        mm.output.clear();
        let e = import_model(&m).expect_err("refused");
        assert!(e.to_string().contains("the MatMul has no output"), "{e}");
    }

    #[test]
    fn hidden_size_attribute_near_i64_max_is_a_shape_error() {
        for (hs, needle) in [
            (
                1i64 << 62,
                "[1, 9223372036854775807, I] (hidden_size=4611686018427387904)",
            ),
            (-1, "(hidden_size=-1)"),
        ] {
            let mut m = plain(3, 2);
            let g = m.graph.as_mut().expect("graph");
            g.node[0].attribute.push(int_attr("hidden_size", hs));
            let e = import_model(&m).expect_err("refused");
            assert_eq!(e.exit_code(), 6, "{e}");
            assert!(e.to_string().contains(needle), "{e}");
        }
    }

    #[test]
    fn huge_and_overflowing_dims_are_refused_before_decoding() {
        for (dims, needle) in [
            (
                vec![1, 1 << 62, 3],
                "has a dimension of 4611686018427387904",
            ),
            (vec![1 << 24, 1 << 24, 1 << 24], "overflows 64 bits"),
            (vec![4096, 4096, 4096], "has 68719476736 elements"),
            (vec![0, 1 << 40, 3], "has a dimension of"),
        ] {
            let mut m = plain(3, 2);
            m.graph.as_mut().expect("graph").initializer[0].dims = dims.clone();
            let e = import_model(&m).expect_err("refused");
            assert_eq!(e.exit_code(), 9, "{dims:?}: {e}");
            assert!(e.to_string().contains(needle), "{dims:?}: {e}");
        }
        let mut m = plain(3, 2);
        m.graph.as_mut().expect("graph").initializer[1].dims = vec![1, -8, 2];
        let e = import_model(&m).expect_err("refused");
        assert_eq!(e.exit_code(), 4, "{e}");
    }

    #[test]
    fn external_data_offset_plus_length_overflow_is_a_format_error() {
        let dir = std::env::temp_dir().join(format!("slipguard-onnx-ext-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        std::fs::write(dir.join("w.data"), [0u8; 64]).expect("data");
        for (offset, length, needle) in [
            (u64::MAX - 3, 16, "overflows"),
            (32, 48, "bytes 32..80 are past the end"),
        ] {
            let mut m = plain(1, 2);
            let w = &mut m.graph.as_mut().expect("graph").initializer[0];
            w.float_data.clear();
            w.data_location = 1;
            w.external_data = [
                ("location", "w.data".to_string()),
                ("offset", offset.to_string()),
                ("length", length.to_string()),
            ]
            .into_iter()
            .map(|(k, v)| StringStringEntryProto {
                key: k.into(),
                value: v,
            })
            .collect();
            let path = dir.join("m.onnx");
            let e = import(&path, &m.encode_to_vec()).expect_err("refused");
            assert_eq!(e.exit_code(), 4, "{e}");
            assert!(e.to_string().contains(needle), "{e}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
