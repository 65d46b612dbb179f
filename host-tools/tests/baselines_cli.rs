//! `slipguard baselines` on three real trials: folds, row count, the JSON and table output.
use std::process::Command;

#[test]
fn cli_runs_on_three_real_trials() {
    let data = slipguard_data::eagle::default_data_dir();
    assert!(
        data.join("trials").is_dir(),
        "real data not found at {} (set SLIPGUARD_DATA)",
        data.display()
    );
    let ids = [
        "Cheez_100_814_top_3",
        "Cola_100_26_top_3",
        "Water_100_1045_back_8",
    ];
    let run = |extra: &[&str]| {
        let mut c = Command::new(env!("CARGO_BIN_EXE_slipguard"));
        c.arg("baselines").arg(&data);
        for id in ids {
            c.args(["--trial", id]);
        }
        let out = c
            .args(["--svm-max-train", "200"])
            .args(extra)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        String::from_utf8(out.stdout).unwrap()
    };
    let json: serde_json::Value = serde_json::from_str(&run(&["--json"])).unwrap();
    let rows = json["rows"].as_array().unwrap();
    // 2 feature sets × (all stable, NB, KNN, SVM).
    assert_eq!(rows.len(), 8);
    assert_eq!(json["fold_plan"], "leave-one-trial-out");
    assert_eq!(
        json["folds"],
        serde_json::json!([[ids[0]], [ids[2]], [ids[1]]])
    );
    for r in rows {
        let m = &r["metrics"];
        let sr = m["success_rate"].as_f64().unwrap();
        assert!((0.0..=1.0).contains(&sr), "{r}");
        let multi = r["features"] == "multi-channel";
        // 3 trials × 160 steps, or 3 contact channels each (see `label --stats`) × 160.
        assert_eq!(m["evaluated_steps"], if multi { 480 } else { 1440 });
        assert_eq!(m["failure_sequences"], if multi { 2 } else { 6 });
        let paper = r["model"] != "all stable" && multi;
        assert_eq!(r["paper"].is_object(), paper, "{r}");
    }
    // All stable on 16 channels: 256 of 480 steps are stable (the success trial's 160 and
    // 49 + 47 of the failures').
    assert_eq!(rows[0]["model"], "all stable");
    assert_eq!(rows[0]["metrics"]["tn"], 256);

    let table = run(&["--features", "multi", "--models", "nb,knn"]);
    assert!(
        table.contains("68.81%") && table.contains("81.76%"),
        "{table}"
    );
    assert!(table.contains("fold  1: Cheez_100_814_top_3"), "{table}");
}
