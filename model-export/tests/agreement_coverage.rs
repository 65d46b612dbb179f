//! The default export (no `--validation`, held-out split) measures the quantization loss on
//! every recording given, not only on the held-out fifth: the report's max |Δp| is at least the
//! written blob's over all of `--data`, measured here independently of the export.
use std::path::Path;

use slipguard_export::calib;
use slipguard_export::pipeline::{ExportOptions, ModelSource, export};

#[test]
fn the_default_report_sees_the_worst_recording_of_all_the_data() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let data = root.join("data/eagle-shoal");
    let opts = ExportOptions {
        source: ModelSource {
            path: root.join("models/hand-force/hand-force.safetensors"),
            ..Default::default()
        },
        data: Some(data.clone()),
        // Ten trials keep the debug test short: two held out, ten in all.
        max_trials: Some(10),
        quiet: true,
        ..Default::default()
    };
    let out = export(&opts).expect("export of the shipped checkpoint");
    let shown = out.report.agreement.as_ref().expect("agreement measured");
    let d = calib::load_data(&data, &out.model.config, Some(10), true).expect("data");
    let all = calib::agreement(&out.model, &out.blob, &d, true).expect("agreement on all");
    eprintln!(
        "report max |dp| {:.5} on {} sequences; written blob on all {} trials {:.5}",
        shown.max_abs_dp, shown.sequences, d.trials, all.max_abs_dp
    );
    assert!(
        shown.max_abs_dp >= all.max_abs_dp,
        "the report's max |Δp| {} misses the written blob's {} over all {} trials",
        shown.max_abs_dp,
        all.max_abs_dp,
        d.trials
    );
    assert!(
        out.report
            .notes
            .iter()
            .any(|n| n.contains(&format!("all {} trials of --data", d.trials))),
        "{:?}",
        out.report.notes
    );
}
