//! Constant folding of the small subgraphs exporters emit to compute an LSTM's W, R and B from
//! initializers. torch's default (dynamo) exporter with onnxscript folds initializers only up to
//! a size limit, so for hidden ≥ 64 R arrives as e.g. `Concat(Slice(w), …)` or
//! `Reshape(Transpose(Slice(w)))` of a constant. Every node whose inputs are all constants and
//! whose operator only moves or converts values (Identity, Cast, Reshape, Transpose, Squeeze,
//! Unsqueeze, Slice, Concat, Gather, Split) is evaluated here, in graph order (ONNX nodes are
//! topologically sorted), so that the LSTM reads plain constants. Arithmetic is not folded: a
//! weight computed by arithmetic is still refused, naming it.
//!
//! Every output size is bounded with [`element_count`] before it is allocated.

use std::collections::BTreeMap;

use super::element_count;
use super::onnx::{Const, attr, node_label};
use super::onnx_proto::{GraphProto, NodeProto};
use crate::error::{ExportError, Result};

/// Operators folded when all their inputs are constants.
pub(super) const FOLDED_OPS: &[&str] = &[
    "Identity",
    "Cast",
    "Reshape",
    "Transpose",
    "Squeeze",
    "Unsqueeze",
    "Slice",
    "Concat",
    "Gather",
    "Split",
];

/// Folds every foldable node; returns how many nodes of each operator were folded.
pub(super) fn fold(
    graph: &GraphProto,
    consts: &mut BTreeMap<String, Const>,
) -> Result<BTreeMap<String, usize>> {
    let mut counts = BTreeMap::new();
    for n in &graph.node {
        if !FOLDED_OPS.contains(&n.op_type.as_str())
            || n.output.iter().all(|o| consts.contains_key(o))
        {
            continue;
        }
        // Optional inputs left empty ("") are allowed only at the end (e.g. Slice's steps).
        let given = n.input.iter().take_while(|x| !x.is_empty()).count();
        if n.input[given..].iter().any(|x| !x.is_empty()) {
            continue;
        }
        let Some(inputs) = n.input[..given]
            .iter()
            .map(|x| consts.get(x))
            .collect::<Option<Vec<&Const>>>()
        else {
            continue;
        };
        if inputs.is_empty() {
            continue;
        }
        let outs = eval(n, &inputs)?;
        for (name, c) in n.output.iter().zip(outs) {
            if !name.is_empty() {
                consts.insert(name.clone(), c);
            }
        }
        *counts.entry(n.op_type.clone()).or_insert(0) += 1;
    }
    Ok(counts)
}

fn bad(n: &NodeProto, msg: impl Into<String>) -> ExportError {
    ExportError::unsupported(
        node_label(n),
        format!("cannot fold this constant subgraph: {}", msg.into()),
    )
}

fn new_const(n: &NodeProto, dims: Vec<usize>, data: Vec<f32>) -> Result<Const> {
    let d64: Vec<u64> = dims.iter().map(|&d| d as u64).collect();
    let count = element_count(&node_label(n), &d64)?;
    if count != data.len() {
        return Err(bad(
            n,
            format!("{} values for {} elements", data.len(), count),
        ));
    }
    Ok(Const { dims, data })
}

fn strides(dims: &[usize]) -> Vec<usize> {
    let mut s = vec![1usize; dims.len()];
    for k in (0..dims.len().saturating_sub(1)).rev() {
        s[k] = s[k + 1] * dims[k + 1];
    }
    s
}

/// An axis attribute or input value in -rank..rank, normalised to 0..rank.
fn axis(n: &NodeProto, a: i64, rank: usize) -> Result<usize> {
    let r = rank as i64;
    if !(-r..r).contains(&a) {
        return Err(bad(n, format!("axis {a} outside a rank-{rank} tensor")));
    }
    Ok(if a < 0 { (a + r) as usize } else { a as usize })
}

fn ints(c: &Const) -> Vec<i64> {
    // Integer constants are held as f32; `as` saturates INT64_MAX-style "to the end" values.
    c.data.iter().map(|&v| v as i64).collect()
}

/// Axes from the second input (opset ≥ 13) or the `axes` attribute.
fn axes_of(n: &NodeProto, inputs: &[&Const]) -> Option<Vec<i64>> {
    inputs
        .get(1)
        .map(|c| ints(c))
        .or_else(|| attr(n, "axes").map(|a| a.ints.clone()))
}

/// Gathers `src` at the multi-indices given per axis (`idx[k]` lists the source indices kept on
/// axis k), the output having dims `idx[k].len()`.
fn select(src: &Const, idx: &[Vec<usize>]) -> Vec<f32> {
    let st = strides(&src.dims);
    let out_dims: Vec<usize> = idx.iter().map(Vec::len).collect();
    let total: usize = out_dims.iter().product();
    let mut out = Vec::with_capacity(total);
    let mut pos = vec![0usize; idx.len()];
    for _ in 0..total {
        let off: usize = pos
            .iter()
            .enumerate()
            .map(|(k, &p)| idx[k][p] * st[k])
            .sum();
        out.push(src.data[off]);
        for k in (0..pos.len()).rev() {
            pos[k] += 1;
            if pos[k] < out_dims[k] {
                break;
            }
            pos[k] = 0;
        }
    }
    out
}

fn eval(n: &NodeProto, inputs: &[&Const]) -> Result<Vec<Const>> {
    let x = inputs[0];
    let rank = x.dims.len();
    Ok(match n.op_type.as_str() {
        "Identity" => vec![x.clone()],
        "Cast" => {
            let to = attr(n, "to").map_or(1, |a| a.i);
            // Float types keep the value (f32 holds every f16/bf16 exactly; f64 is rounded as
            // the rest of the importer does); integer types truncate toward zero.
            let float = matches!(to, 1 | 10 | 11 | 16);
            let data = if float {
                x.data.clone()
            } else {
                x.data.iter().map(|v| v.trunc()).collect()
            };
            vec![Const {
                dims: x.dims.clone(),
                data,
            }]
        }
        "Reshape" => {
            let shape = ints(
                inputs
                    .get(1)
                    .ok_or_else(|| bad(n, "Reshape without shape"))?,
            );
            let allowzero = attr(n, "allowzero").is_some_and(|a| a.i != 0);
            let mut dims = Vec::with_capacity(shape.len());
            let mut infer = None;
            for (k, &s) in shape.iter().enumerate() {
                match s {
                    -1 if infer.is_none() => {
                        infer = Some(k);
                        dims.push(1);
                    }
                    0 if !allowzero => dims.push(
                        *x.dims
                            .get(k)
                            .ok_or_else(|| bad(n, "0 past the input rank"))?,
                    ),
                    s if s >= 0 => dims.push(s as usize),
                    s => return Err(bad(n, format!("shape entry {s}"))),
                }
            }
            if let Some(k) = infer {
                let known: usize = dims.iter().product();
                if known == 0 || !x.data.len().is_multiple_of(known) {
                    return Err(bad(n, "cannot infer the -1 dimension"));
                }
                dims[k] = x.data.len() / known;
            }
            vec![new_const(n, dims, x.data.clone())?]
        }
        "Transpose" => {
            let perm: Vec<usize> = match attr(n, "perm") {
                Some(a) => a
                    .ints
                    .iter()
                    .map(|&p| axis(n, p, rank))
                    .collect::<Result<_>>()?,
                None => (0..rank).rev().collect(),
            };
            let mut seen = vec![false; rank];
            if perm.len() != rank || perm.iter().any(|&p| std::mem::replace(&mut seen[p], true)) {
                return Err(bad(n, format!("perm {perm:?} for rank {rank}")));
            }
            // out[i0, i1, …] = x[… with axis perm[k] = i_k]: select along permuted strides.
            let st = strides(&x.dims);
            let out_dims: Vec<usize> = perm.iter().map(|&p| x.dims[p]).collect();
            let total: usize = out_dims.iter().product();
            let mut out = Vec::with_capacity(total);
            let mut pos = vec![0usize; rank];
            for _ in 0..total {
                let off: usize = (0..rank).map(|k| pos[k] * st[perm[k]]).sum();
                out.push(x.data[off]);
                for k in (0..rank).rev() {
                    pos[k] += 1;
                    if pos[k] < out_dims[k] {
                        break;
                    }
                    pos[k] = 0;
                }
            }
            vec![new_const(n, out_dims, out)?]
        }
        "Squeeze" => {
            let dims = match axes_of(n, inputs) {
                Some(axes) => {
                    let axes: Vec<usize> = axes
                        .iter()
                        .map(|&a| axis(n, a, rank))
                        .collect::<Result<_>>()?;
                    if axes.iter().any(|&a| x.dims[a] != 1) {
                        return Err(bad(n, "squeezing an axis that is not 1"));
                    }
                    (0..rank)
                        .filter(|k| !axes.contains(k))
                        .map(|k| x.dims[k])
                        .collect()
                }
                None => x.dims.iter().copied().filter(|&d| d != 1).collect(),
            };
            vec![new_const(n, dims, x.data.clone())?]
        }
        "Unsqueeze" => {
            let axes = axes_of(n, inputs).ok_or_else(|| bad(n, "Unsqueeze without axes"))?;
            let out_rank = rank + axes.len();
            let axes: Vec<usize> = axes
                .iter()
                .map(|&a| axis(n, a, out_rank))
                .collect::<Result<_>>()?;
            let mut rest = x.dims.iter();
            let dims: Vec<usize> = (0..out_rank)
                .map(|k| {
                    if axes.contains(&k) {
                        1
                    } else {
                        rest.next().copied().unwrap_or(1)
                    }
                })
                .collect();
            vec![new_const(n, dims, x.data.clone())?]
        }
        "Slice" => {
            // opset ≥ 10: starts, ends, axes, steps inputs; opset 1: attributes.
            let (starts, ends, axes, steps) = if inputs.len() >= 3 {
                (
                    ints(inputs[1]),
                    ints(inputs[2]),
                    inputs.get(3).map(|c| ints(c)),
                    inputs.get(4).map(|c| ints(c)),
                )
            } else {
                let get = |k: &str| attr(n, k).map(|a| a.ints.clone());
                (
                    get("starts").unwrap_or_default(),
                    get("ends").unwrap_or_default(),
                    get("axes"),
                    None,
                )
            };
            let axes = axes.unwrap_or_else(|| (0..starts.len() as i64).collect());
            let steps = steps.unwrap_or_else(|| vec![1; starts.len()]);
            if ends.len() != starts.len()
                || axes.len() != starts.len()
                || steps.len() != starts.len()
            {
                return Err(bad(n, "starts/ends/axes/steps of different lengths"));
            }
            let mut idx: Vec<Vec<usize>> = x.dims.iter().map(|&d| (0..d).collect()).collect();
            for k in 0..starts.len() {
                let a = axis(n, axes[k], rank)?;
                let d = x.dims[a] as i64;
                let step = steps[k];
                if step == 0 {
                    return Err(bad(n, "step 0"));
                }
                let clampi = |v: i64, lo: i64, hi: i64| {
                    let v = if v < 0 { v.saturating_add(d) } else { v };
                    v.clamp(lo, hi)
                };
                let mut sel = Vec::new();
                if step > 0 {
                    let (s, e) = (clampi(starts[k], 0, d), clampi(ends[k], 0, d));
                    let mut i = s;
                    while i < e {
                        sel.push(i as usize);
                        i += step;
                    }
                } else {
                    let (s, e) = (clampi(starts[k], -1, d - 1), clampi(ends[k], -1, d - 1));
                    let mut i = s;
                    while i > e {
                        sel.push(i as usize);
                        i += step;
                    }
                }
                idx[a] = sel;
            }
            let dims: Vec<usize> = idx.iter().map(Vec::len).collect();
            vec![new_const(n, dims, select(x, &idx))?]
        }
        "Concat" => {
            let a = axis(n, attr(n, "axis").map_or(0, |a| a.i), rank)?;
            for c in inputs {
                let same =
                    c.dims.len() == rank && (0..rank).all(|k| k == a || c.dims[k] == x.dims[k]);
                if !same {
                    return Err(bad(n, "inputs of different shapes"));
                }
            }
            let mut dims = x.dims.clone();
            dims[a] = inputs.iter().map(|c| c.dims[a]).sum();
            let outer: usize = x.dims[..a].iter().product();
            let mut out = Vec::new();
            for o in 0..outer {
                for c in inputs {
                    let blk: usize = c.dims[a..].iter().product();
                    out.extend_from_slice(&c.data[o * blk..(o + 1) * blk]);
                }
            }
            vec![new_const(n, dims, out)?]
        }
        "Gather" => {
            let ind = inputs
                .get(1)
                .ok_or_else(|| bad(n, "Gather without indices"))?;
            let a = axis(n, attr(n, "axis").map_or(0, |a| a.i), rank)?;
            let d = x.dims[a] as i64;
            let picks: Vec<usize> = ints(ind)
                .into_iter()
                .map(|i| {
                    let i = if i < 0 { i + d } else { i };
                    if (0..d).contains(&i) {
                        Ok(i as usize)
                    } else {
                        Err(bad(n, format!("index {i} outside 0..{d}")))
                    }
                })
                .collect::<Result<_>>()?;
            let mut dims = x.dims[..a].to_vec();
            dims.extend_from_slice(&ind.dims);
            dims.extend_from_slice(&x.dims[a + 1..]);
            // Many indices into a large axis multiply: bounded before the output is built.
            let d64: Vec<u64> = dims.iter().map(|&d| d as u64).collect();
            element_count(&node_label(n), &d64)?;
            let outer: usize = x.dims[..a].iter().product();
            let inner: usize = x.dims[a + 1..].iter().product();
            let mut out = Vec::new();
            for o in 0..outer {
                for &p in &picks {
                    let base = (o * x.dims[a] + p) * inner;
                    out.extend_from_slice(&x.data[base..base + inner]);
                }
            }
            vec![new_const(n, dims, out)?]
        }
        "Split" => {
            let a = axis(n, attr(n, "axis").map_or(0, |a| a.i), rank)?;
            let parts = n.output.len().max(1);
            let sizes: Vec<usize> = match inputs.get(1).map(|c| ints(c)).or_else(|| {
                attr(n, "split")
                    .map(|s| s.ints.clone())
                    .filter(|v| !v.is_empty())
            }) {
                Some(s) => s.into_iter().map(|v| v.max(0) as usize).collect(),
                None => {
                    let per = x.dims[a].div_ceil(parts);
                    (0..parts)
                        .map(|k| per.min(x.dims[a].saturating_sub(k * per)))
                        .collect()
                }
            };
            if sizes.iter().sum::<usize>() != x.dims[a] {
                return Err(bad(
                    n,
                    format!("split sizes {sizes:?} of an axis of {}", x.dims[a]),
                ));
            }
            let mut out = Vec::new();
            let mut start = 0;
            for s in sizes {
                let mut idx: Vec<Vec<usize>> = x.dims.iter().map(|&d| (0..d).collect()).collect();
                idx[a] = (start..start + s).collect();
                start += s;
                let mut dims = x.dims.clone();
                dims[a] = s;
                out.push(new_const(n, dims, select(x, &idx))?);
            }
            out
        }
        other => return Err(bad(n, format!("operator {other}"))),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn c(dims: &[usize], data: Vec<f32>) -> Const {
        Const {
            dims: dims.to_vec(),
            data,
        }
    }

    fn node(op: &str) -> NodeProto {
        NodeProto {
            op_type: op.into(),
            output: vec!["y".into()],
            ..Default::default()
        }
    }

    fn with_ints(mut n: NodeProto, name: &str, v: &[i64]) -> NodeProto {
        n.attribute.push(super::super::onnx_proto::AttributeProto {
            name: name.into(),
            ints: v.to_vec(),
            ..Default::default()
        });
        n
    }

    // The references below are written out by hand from numpy's definitions.
    #[test]
    fn transpose_slice_concat_match_numpy() {
        let x = c(&[2, 3], vec![0., 1., 2., 3., 4., 5.]);
        let t = eval(&with_ints(node("Transpose"), "perm", &[1, 0]), &[&x]).expect("t");
        assert_eq!(
            (t[0].dims.clone(), t[0].data.clone()),
            (vec![3, 2], vec![0., 3., 1., 4., 2., 5.])
        );
        // x[:, 1:] and x[::-1, ::2]
        let s = eval(
            &node("Slice"),
            &[
                &x,
                &c(&[1], vec![1.]),
                &c(&[1], vec![9.2e18]),
                &c(&[1], vec![1.]),
            ],
        )
        .expect("s");
        assert_eq!(
            (s[0].dims.clone(), s[0].data.clone()),
            (vec![2, 2], vec![1., 2., 4., 5.])
        );
        let s = eval(
            &node("Slice"),
            &[
                &x,
                &c(&[2], vec![-1., 0.]),
                &c(&[2], vec![-9.2e18, 9.2e18]),
                &c(&[2], vec![0., 1.]),
                &c(&[2], vec![-1., 2.]),
            ],
        )
        .expect("s");
        assert_eq!(
            (s[0].dims.clone(), s[0].data.clone()),
            (vec![2, 2], vec![3., 5., 0., 2.])
        );
        let mut cat = node("Concat");
        cat.attribute
            .push(super::super::onnx_proto::AttributeProto {
                name: "axis".into(),
                i: 1,
                ..Default::default()
            });
        let y = eval(&cat, &[&x, &c(&[2, 1], vec![9., 8.])]).expect("cat");
        assert_eq!(
            (y[0].dims.clone(), y[0].data.clone()),
            (vec![2, 4], vec![0., 1., 2., 9., 3., 4., 5., 8.])
        );
        let g = eval(&node("Gather"), &[&x, &c(&[], vec![1.])]).expect("g");
        assert_eq!(
            (g[0].dims.clone(), g[0].data.clone()),
            (vec![3], vec![3., 4., 5.])
        );
        let r = eval(&node("Reshape"), &[&x, &c(&[3], vec![1., -1., 2.])]).expect("r");
        assert_eq!(r[0].dims, vec![1, 3, 2]);
        let u = eval(&node("Unsqueeze"), &[&x, &c(&[1], vec![0.])]).expect("u");
        assert_eq!(u[0].dims, vec![1, 2, 3]);
        let q = eval(&node("Squeeze"), &[&u[0], &c(&[1], vec![0.])]).expect("q");
        assert_eq!(q[0].dims, vec![2, 3]);
    }

    #[test]
    fn a_gather_that_multiplies_sizes_is_refused_before_allocating() {
        // 4096 indices into each of 4096 rows of 4096 values: 2^36 outputs from 2^24 inputs.
        let x = c(&[4096, 4096], vec![0.; 4096 * 4096]);
        let idx = c(&[4096, 4096], vec![1.; 4096 * 4096]);
        let e = eval(&node("Gather"), &[&x, &idx]).expect_err("refused");
        assert_eq!(e.exit_code(), 9, "{e}");
    }

    #[test]
    fn a_reshape_to_a_huge_shape_is_refused_before_allocating() {
        let x = c(&[2], vec![1., 2.]);
        let e = eval(&node("Reshape"), &[&x, &c(&[3], vec![4096., 4096., 4096.])])
            .expect_err("refused");
        assert_eq!(e.exit_code(), 9, "{e}");
    }
}
