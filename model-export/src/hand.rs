//! The hand-level model (`hand-lstm`, blob format v3) in the exporter: its calibration and its
//! agreement run on whole grasps, every channel together, not on one channel's samples.
//!
//! A hand recording is a trial's channels from the grasp start (where the firmware resets) to
//! the end, with the lift command at the trial's lift mark. The float model sees the hand
//! feature rows the firmware computes ([`slipguard_core::float::hand_feature_rows`]); the blob
//! runs as the firmware does (contact gate per channel, [`Model::hand_p`]).

use slipguard_core::blob::AlignedBlob;
use slipguard_core::decision::{ContactConfig, DecisionConfig, DecisionState};
use slipguard_core::float::{FloatModel, hand_feature_rows};
use slipguard_core::model::{ChannelState, HandState, Model};

use crate::calib::{Agreement, Calibration, DECISIVE_MARGIN, WorstStep};
use crate::error::{ExportError, Result};

/// One trial's channels as a hand-level model runs over them.
#[derive(Clone, Debug, PartialEq)]
pub struct HandRecording {
    /// Trial id.
    pub trial_id: String,
    /// Samples, channel-major (every channel, in contact or not: the gate decides).
    pub samples: Vec<Vec<f32>>,
    /// Grasp start (the first step run).
    pub start: usize,
    /// Lift mark.
    pub lift: Option<usize>,
    /// End of the span the hand flag can matter in (exclusive): the drop of a failure, the
    /// release of a success (`slipguard_data::labels`), the recording's end when neither is
    /// known. After it the object is gone or the controller has released (the firmware is
    /// disarmed), and the state of a network never trained there drifts freely.
    pub end: usize,
}

impl HandRecording {
    /// The float model's rows of this recording.
    pub fn rows(&self, model: &FloatModel) -> Vec<Vec<f32>> {
        hand_feature_rows(&model.config, &self.samples, self.start, self.lift)
    }
}

/// Calibrates the cell format on every row of `recs` (or takes `fixed`) and quantizes: the
/// blob and what the float model did there.
pub fn quantize(
    model: &FloatModel,
    recs: &[HandRecording],
    fixed: Option<[u8; 2]>,
) -> Result<(Vec<u8>, slipguard_core::quantize::QuantReport, Calibration)> {
    let rows: Vec<Vec<Vec<f32>>> = recs.iter().map(|r| r.rows(model)).collect();
    let refs: Vec<&[Vec<f32>]> = rows.iter().map(Vec::as_slice).collect();
    let (blob, q) = slipguard_core::quantize::quantize_rows(model, &refs, fixed)
        .map_err(|e| ExportError::unsupported("model", e.to_string()))?;
    let steps = rows.iter().map(Vec::len).sum();
    let nf = model.config.feature_count();
    let (mut clipped, mut max_abs) = (vec![0usize; nf], vec![0f32; nf]);
    let mut max_h = vec![0f32; model.lstms.len()];
    for seq in &rows {
        let mut st = model.new_channel();
        for r in seq {
            let mut v = r.clone();
            for ((x, m), s) in v.iter_mut().zip(&model.norm_mean).zip(&model.norm_std) {
                *x = (*x - m) / s;
            }
            for (j, &x) in v.iter().enumerate().take(nf) {
                clipped[j] += (x.abs() >= 8.0) as usize;
                max_abs[j] = max_abs[j].max(x.abs());
            }
            model.step_row(&mut st, r);
            for (m, s) in max_h.iter_mut().zip(&st.lstm) {
                *m = s.h.iter().fold(*m, |a, h| a.max(h.abs()));
            }
        }
    }
    let cal = Calibration {
        sequences: rows.len(),
        steps,
        max_abs_cell: q.max_abs_cell.clone(),
        cell_frac_bits: q.cell_frac_bits.clone(),
        max_abs_hidden: max_h,
        input_saturated: 0.0,
        feature_clipped: clipped
            .iter()
            .map(|&c| c as f64 / steps.max(1) as f64)
            .collect(),
        feature_max_abs: max_abs,
    };
    Ok((blob, q, cal))
}

/// Runs the blob as the firmware does and the float model on the same rows over every
/// recording from the grasp start to its [`HandRecording::end`], and compares p, the flag (the
/// model's decision) and h. `channel` in the worst step is 0: a hand model has one output per
/// frame. [`agreement_whole`] compares to each recording's last step.
pub fn agreement(float: &FloatModel, blob: &[u8], recs: &[HandRecording]) -> Result<Agreement> {
    agreement_over(float, blob, recs, false)
}

/// [`agreement`] over every step of every recording, past the armed span too.
pub fn agreement_whole(
    float: &FloatModel,
    blob: &[u8],
    recs: &[HandRecording],
) -> Result<Agreement> {
    agreement_over(float, blob, recs, true)
}

fn agreement_over(
    float: &FloatModel,
    blob: &[u8],
    recs: &[HandRecording],
    whole: bool,
) -> Result<Agreement> {
    let aligned = AlignedBlob::new(blob);
    let model = Model::from_bytes(aligned.as_bytes()).map_err(|e| ExportError::Blob {
        path: "(exported blob)".into(),
        source: e,
    })?;
    let contact = ContactConfig::of(model.config());
    let dq = model.decision();
    let df = DecisionConfig::of(&float.config);
    let th = df.threshold_q15 as f32 / 32768.0;
    let window = df.raise_after.max(df.clear_after).max(1) as usize;
    let mut a = Agreement {
        sequences: recs.len(),
        steps: 0,
        flag_agreement: 1.0,
        flag_disagreements: 0,
        decisive_steps: 0,
        decisive_flag_agreement: 1.0,
        max_abs_dp: 0.0,
        worst: None,
        mean_abs_dp: 0.0,
        max_abs_dh: 0.0,
        float_metrics: None,
        quant_metrics: None,
    };
    let (mut sum_dp, mut decisive_disagree) = (0f64, 0usize);
    for r in recs {
        let rows = r.rows(float);
        let mut gates = vec![ChannelState::new(); r.samples.len()];
        let mut hs = HandState::new();
        let mut fs = float.new_channel();
        let (mut sq, mut sf) = (DecisionState::default(), DecisionState::default());
        let mut recent: Vec<f32> = Vec::new();
        let span = if whole {
            rows.len()
        } else {
            r.end.saturating_sub(r.start).min(rows.len())
        };
        for (i, row) in rows.iter().enumerate().take(span) {
            let t = r.start + i;
            let x: Vec<Option<i16>> = gates
                .iter_mut()
                .zip(&r.samples)
                .map(|(g, ch)| {
                    let (edge, v) = model.gate(g, &contact, ch[t].round() as i32);
                    edge.in_contact().then_some(v)
                })
                .collect();
            let lifted = r.lift.is_some_and(|l| t >= l);
            let pq = model.hand_p(&mut hs, &x, lifted);
            let step = float.step_row(&mut fs, row);
            let pf = step.p_unstable;
            let fq = dq.update(&mut sq, pq);
            let ff = df.update(&mut sf, (pf * 32768.0).round().min(32767.0) as i16);
            let dp = (pq as f32 / 32768.0 - pf).abs();
            sum_dp += dp as f64;
            if dp > a.max_abs_dp {
                a.max_abs_dp = dp;
                a.worst = Some(WorstStep {
                    trial: r.trial_id.clone(),
                    channel: 0,
                    step: t,
                    p_float: pf,
                    p_quantized: pq as f32 / 32768.0,
                });
            }
            for (hq, hf) in hs.lstm.h.iter().zip(&fs.lstm[0].h) {
                a.max_abs_dh = a.max_abs_dh.max((*hq as f32 / 32768.0 - hf).abs());
            }
            recent.push(pf);
            if recent.len() > window {
                recent.remove(0);
            }
            let decisive = recent.iter().all(|p| (p - th).abs() >= DECISIVE_MARGIN);
            a.steps += 1;
            if fq != ff {
                a.flag_disagreements += 1;
                decisive_disagree += decisive as usize;
            }
            a.decisive_steps += decisive as usize;
        }
    }
    if a.steps > 0 {
        a.mean_abs_dp = (sum_dp / a.steps as f64) as f32;
        a.flag_agreement = 1.0 - a.flag_disagreements as f64 / a.steps as f64;
    }
    if a.decisive_steps > 0 {
        a.decisive_flag_agreement = 1.0 - decisive_disagree as f64 / a.decisive_steps as f64;
    }
    Ok(a)
}
