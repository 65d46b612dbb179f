//! The armed-window table of `slipguard eval` and `slipguard demo`: a model's figures on the
//! real trials as the product is used ([`Product`]), its rows ([`armed_row`]) with the
//! header and the notes that say what the columns mean, and the rows of one blob on recorded
//! trials ([`rows_for_blob`]).

use slipguard_data::Trial;
use slipguard_data::armed::ArmedReport;
use slipguard_data::labels::LabelConfig;
use slipguard_learn::load_rule::{self, RuleEval};
use slipguard_learn::product::{self, ArmedError, CurvePoint};

/// A model's figures on the real trials as the product is used: the quantized model, hand
/// level and per channel, in the armed window, with bootstrap intervals; the paper's two
/// metrics with theirs; and the operating curve.
pub struct Product {
    pub name: String,
    pub in_sample: bool,
    pub hand: ArmedReport,
    pub channel: ArmedReport,
    pub curve: Vec<CurvePoint>,
    pub shipped: Option<CurvePoint>,
    pub paper_success_ci: Option<slipguard_data::armed::Interval>,
    pub paper_ahead_ci: Option<slipguard_data::armed::Interval>,
    /// The hand-load rule on the same trials, its parameters picked on training trials only.
    pub rule: Option<RuleEval>,
    /// The blob's own hand rule (format v2): the hand row is then the fused hand flag, as the
    /// firmware computes it.
    pub hand_rule: Option<slipguard_core::decision::FusedHand>,
    /// Scored trials whose marks were estimated from the force ([`Trial::label_estimated`]).
    pub estimated: usize,
    /// The hand row and the rule's on the other trials only (marks recorded, e.g. the dataset's
    /// label.txt); `None` when no trial has estimated marks.
    pub label_txt: Option<(ArmedReport, Option<ArmedReport>)>,
}

/// [`Product::label_txt`]: `hand` and the rule's grasps without the trials of `estimated`.
pub fn label_txt_only(
    hand: &[slipguard_data::armed::ArmedGrasp],
    rule: Option<&RuleEval>,
    estimated: &[String],
) -> Option<(ArmedReport, Option<ArmedReport>)> {
    if estimated.is_empty() {
        return None;
    }
    let keep = |v: &[slipguard_data::armed::ArmedGrasp]| -> Vec<slipguard_data::armed::ArmedGrasp> {
        v.iter()
            .filter(|g| !estimated.contains(&g.trial))
            .cloned()
            .collect()
    };
    Some((
        ArmedReport::of(&keep(hand)),
        rule.map(|r| ArmedReport::of(&keep(&r.grasps))),
    ))
}

/// The level label of a product's hand row: "hand", or "hand (fused)" for a blob with a rule.
pub fn hand_level(p: &Product) -> &'static str {
    if p.hand_rule.is_some() {
        "hand (fused)"
    } else {
        "hand"
    }
}

/// What a fused hand row means.
pub fn fused_note(name: &str, f: &slipguard_core::decision::FusedHand) -> String {
    format!(
        "{name}: hand (fused) = the hand flag as the firmware computes it from this blob, its \
         hand decision fused with the blob's hand rule (format v2): {f}. The rule's parameters \
         are the blob's (set at export; eval picks nothing): chosen on these trials, they make \
         this row in-sample for them."
    )
}

/// Header of the armed-window table.
pub const ARMED_HEADER: &str = "| model | data | level | grasps (fail) | detected | lead median | false-alarm grasps | false alarms / armed min |\n|---|---|---|---|---|---|---|---|";

/// What the load-rule row means.
pub const RULE_NOTE: &str = " load rule = the baseline that learns nothing \
(`slipguard_core::decision::LoadRule`): the hand flag is up while the summed load of the channels \
in contact is below a fraction of its peak over the last frames; fraction (0.20–0.80) and window \
(0.3–1.2 s) picked on training trials only, by the models' decision criterion, and scored on the \
same held-out trials as the model beside it.";

/// What the armed-window columns mean.
pub const ARMED_NOTE: &str = "\nArmed window: from the lift start to the release start (successes, found from the force: \
docs/labels.md) or to the drop (failures); nothing before the lift or after the release counts. \
detected = failures with a flag up in their armed window (so before the drop), with the 95 % \
bootstrap interval over trials; lead = drop − first flag; false-alarm grasps = successes with any \
flag in their armed window; false alarms per minute of the successes' armed time. hand = the \
hand flag (the firmware's decision over the channels in contact), channel = each contact channel's \
own flag scored as a grasp.";

/// The rows of one product: hand and channel level, and the load rule beside it when
/// evaluated.
pub fn armed_row(p: &Product) -> String {
    let data = if p.in_sample {
        "real (all, in-sample)"
    } else {
        "real held-out"
    };
    let mut rows = format!(
        "{}\n{}",
        armed_line(&p.name, data, hand_level(p), &p.hand),
        armed_line(&p.name, data, "channel", &p.channel)
    );
    if let Some(r) = &p.rule {
        rows.push('\n');
        rows.push_str(&armed_line(
            &format!("load rule beside {}", p.name),
            "real held-out",
            "hand",
            &r.report,
        ));
    }
    rows
}

/// One row of the armed-window table.
pub fn armed_line(name: &str, data: &str, level: &str, r: &ArmedReport) -> String {
    let m = &r.metrics;
    let ci = |i: Option<slipguard_data::armed::Interval>| {
        i.map_or(String::new(), |i| {
            format!(" [{:.0}–{:.0} %]", 100.0 * i.lo, 100.0 * i.hi)
        })
    };
    format!(
        "| {name} | {data} | {level} | {} ({}) | {}/{}{} (≥ 300 ms ahead: {}) | {} | {}/{}{} | {:.2} |",
        m.grasps,
        m.failures,
        m.detected,
        m.failures,
        ci(r.detected_rate_ci),
        m.detected_early(),
        m.lead_median_ms()
            .map_or("-".into(), |l| format!("{l:.0} ms")),
        m.false_alarm_grasps,
        m.successes,
        ci(r.false_alarm_grasp_rate_ci),
        m.false_alarms_per_min().unwrap_or(0.0)
    )
}

/// Why [`rows_for_blob`] has no rows.
#[derive(Debug)]
#[non_exhaustive]
pub enum RowsError {
    /// The blob does not parse.
    Blob {
        /// The model's name in the table.
        name: String,
        source: slipguard_core::blob::BlobError,
    },
    /// A trial cannot be scored in its armed window.
    Armed(ArmedError),
}

impl std::fmt::Display for RowsError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RowsError::Blob { name, source } => {
                write!(f, "{name}: the model blob does not parse: {source}")
            }
            RowsError::Armed(e) => write!(f, "{e}"),
        }
    }
}

impl std::error::Error for RowsError {}

impl From<ArmedError> for RowsError {
    fn from(e: ArmedError) -> Self {
        RowsError::Armed(e)
    }
}

/// The armed-window rows (hand and channel level, and the load rule held out leave one trial
/// out beside them) of one blob on `trials`; `in_sample` when the blob was trained on them.
pub fn rows_for_blob(
    name: &str,
    bytes: &[u8],
    trials: &[Trial],
    in_sample: bool,
) -> Result<String, RowsError> {
    let cfg = LabelConfig::default();
    let aligned = slipguard_core::blob::AlignedBlob::new(bytes);
    let m = slipguard_core::model::Model::from_bytes(aligned.as_bytes()).map_err(|source| {
        RowsError::Blob {
            name: name.to_string(),
            source,
        }
    })?;
    let refs: Vec<&Trial> = trials.iter().collect();
    let (refs, _skipped) = product::scoreable(&refs, &cfg)?;
    let kept: Vec<Trial> = refs.iter().map(|&t| t.clone()).collect();
    let (mut hand, mut channel) = (Vec::new(), Vec::new());
    let hand_rule = m.config().hand_rule;
    for w in product::windowed_runs(&m, &refs, &cfg)? {
        if let Some(t) = trials.iter().find(|t| t.id == w.trial)
            && let Some(sc) = product::score(t, &w.run, &cfg)?
        {
            hand.push(sc.hand);
            channel.extend(sc.channels);
        }
    }
    let p = Product {
        name: name.to_string(),
        in_sample,
        hand: ArmedReport::of(&hand),
        channel: ArmedReport::of(&channel),
        curve: Vec::new(),
        shipped: None,
        paper_success_ci: None,
        paper_ahead_ci: None,
        rule: Some(load_rule::beside_model(&kept, m.config(), None)?),
        hand_rule,
        estimated: 0,
        label_txt: None,
    };
    Ok(armed_row(&p))
}
