//! The `slipguard` binary: exit codes and error messages.
use std::process::Command;

fn slipguard() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard"))
}

#[test]
fn malformed_file_gives_location_and_nonzero_exit() {
    let dir = std::env::temp_dir().join(format!("slipguard-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("bad.csv");
    std::fs::write(
        &p,
        "# slipguard-recording v1\n# rate_hz: 10\n# unit: mN\ntime_s,c0\n0,1\n0.1,zz\n",
    )
    .unwrap();
    let out = slipguard()
        .args(["dataset", "info"])
        .arg(&p)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.csv:6:2 (column `c0`)"), "{err}");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn simulate_writes_readable_recordings() {
    let dir = std::env::temp_dir().join(format!("slipguard-sim-{}", std::process::id()));
    let out = slipguard()
        .args(["simulate", "--count", "2", "--seed", "5", "--out"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let info = slipguard()
        .args(["dataset", "info"])
        .arg(&dir)
        .output()
        .unwrap();
    assert!(info.status.success());
    let text = String::from_utf8_lossy(&info.stdout);
    assert!(
        text.contains("sim-force-5-0000") && text.contains("2 trials"),
        "{text}"
    );
    let bad = slipguard()
        .args(["simulate", "--rate", "-1"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn train_refuses_a_closed_loop_policy_it_cannot_use() {
    // The golden blob runs at 16.7 Hz: refused for a 40 Hz model, before any training.
    let golden = slipguard::replay::golden_model_path();
    let out = slipguard()
        .args([
            "train",
            "--rate-hz",
            "40",
            "--closed-loop-mix",
            "4",
            "--epochs",
            "1",
        ])
        .arg("--closed-loop-policy")
        .arg(&golden)
        .args(["--out", "/nonexistent/never-written"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("runs at 16.7 Hz, not the --rate-hz 40 Hz"),
        "{err}"
    );
    // A corrupt blob: the parse error, naming the option.
    let dir = std::env::temp_dir().join(format!("slipguard-policy-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let bad = dir.join("bad.bin");
    let mut b = std::fs::read(&golden).unwrap();
    b.truncate(100);
    std::fs::write(&bad, b).unwrap();
    let out = slipguard()
        .args(["train", "--closed-loop-mix", "4", "--epochs", "1"])
        .arg("--closed-loop-policy")
        .arg(&bad)
        .args(["--out", "/nonexistent/never-written"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--closed-loop-policy") && err.contains("bad.bin"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn train_picks_the_decision_on_an_inner_cross_validation() {
    // Without --cv the inner 2-fold CV runs over all 23 real trials with contact: two inner
    // models, each run over the trials it did not see, and the decision picked on those runs.
    let dir = tmp_dir("inner-cv");
    let out = slipguard()
        .args([
            "train",
            "--variant",
            "lstm",
            "--hidden",
            "4",
            "--epochs",
            "1",
            "--tune-decision",
            "--tune-decision-cv",
            "2",
            "--name",
            "tiny",
        ])
        .arg("--out")
        .arg(&dir)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    for needle in [
        "train inner 0:",
        "train inner 1:",
        "decision tuned on 59 2-fold inner CV held-out trials",
    ] {
        assert!(err.contains(needle), "expected `{needle}` in: {err}");
    }
    assert!(dir.join("tiny.bin").is_file());
    std::fs::remove_dir_all(&dir).unwrap();
    // One inner fold, or the option without the decision sweep it feeds: refused up front.
    refused(
        &[
            "train",
            "--tune-decision",
            "--tune-decision-cv",
            "1",
            "--out",
            "/nonexistent/x",
        ],
        &["--tune-decision-cv 1", "2 to 20"],
    );
    refused(
        &[
            "train",
            "--tune-decision-cv",
            "3",
            "--out",
            "/nonexistent/x",
        ],
        &["--tune-decision"],
    );
}

/// Runs `slipguard ARGS`; expects a failure whose stderr names every `needle`, on few lines.
fn refused(args: &[&str], needles: &[&str]) -> String {
    let out = slipguard().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(!out.status.success(), "{args:?} succeeded: {err}");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    for n in needles {
        assert!(err.contains(n), "{args:?}: expected `{n}` in: {err}");
    }
    err
}

fn tmp_dir(test: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("slipguard-cli-{}-{test}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn real_trial() -> std::path::PathBuf {
    slipguard_data::eagle::default_data_dir().join("trials/Cheez_100_814_top_3")
}

#[test]
fn integer_arguments_out_of_range_are_refused_before_work() {
    // Once a panic in the float model (hidden 0) and an index out of bounds (trials 0).
    refused(
        &[
            "train",
            "--variant",
            "lstm",
            "--hidden",
            "0",
            "--epochs",
            "1",
            "--out",
            "/nonexistent/x",
        ],
        &["--hidden", "'0'", "1..=128"],
    );
    refused(
        &["train", "--hidden", "129", "--out", "/nonexistent/x"],
        &["--hidden", "129", "1..=128"],
    );
    refused(
        &["train", "--epochs", "0", "--out", "/nonexistent/x"],
        &["--epochs 0", "--init", "at least 1 epoch"],
    );
    refused(
        &["closed-loop", "--trials", "0"],
        &["--trials", "'0'", "1.."],
    );
    refused(&["baselines", "--k", "0"], &["--k", "'0'"]);
    refused(
        &["monitor", "--capture", "x", "--frames", "0"],
        &["--frames", "'0'"],
    );
}

#[test]
fn thresholds_and_shares_out_of_range_are_refused() {
    for t in ["0", "1", "1.5", "-0.2", "nan"] {
        refused(
            &[
                "train",
                &format!("--threshold={t}"),
                "--out",
                "/nonexistent/x",
            ],
            &["--threshold", "0 < x < 1"],
        );
    }
    refused(
        &["closed-loop", "--threshold", "1"],
        &["--threshold", "0 < x < 1"],
    );
    refused(
        &["eval", "x.safetensors", "--threshold", "0"],
        &["--threshold", "0 < x < 1"],
    );
    refused(
        &["train", "--val-share", "1", "--out", "/nonexistent/x"],
        &["--val-share", "0 ≤ x < 1"],
    );
    refused(
        &["train", "--lr", "0", "--out", "/nonexistent/x"],
        &["--lr", "x > 0"],
    );
    refused(
        &["label", "--drop-fraction", "2"],
        &["--drop-fraction", "0 < x < 1"],
    );
}

#[test]
fn names_rates_and_folds_the_firmware_cannot_use_are_refused() {
    refused(
        &[
            "train",
            "--blob-name",
            "thirteen-char",
            "--out",
            "/nonexistent/x",
        ],
        &["--blob-name", "thirteen-char", "12"],
    );
    refused(
        &[
            "train",
            "--rate-hz",
            "25",
            "--epochs",
            "1",
            "--out",
            "/nonexistent/x",
        ],
        &["--rate-hz 25", "16.7 or 40"],
    );
    refused(
        &["train", "--cv", "1", "--out", "/nonexistent/x"],
        &["--cv 1", "2 to"],
    );
    let t = real_trial();
    refused(
        &["replay", t.to_str().unwrap(), "--plot-channel", "16"],
        &["--plot-channel 16", "0 to 15"],
    );
    refused(
        &["replay", t.to_str().unwrap(), "--open-wire", "20:0:5"],
        &["--open-wire 20:0:5", "0 to 15"],
    );
}

#[test]
fn a_bad_model_blob_is_refused_or_with_allow_bad_model_run_with_a_warning() {
    let d = tmp_dir("bad-blob");
    let bad = d.join("notes.bin");
    std::fs::write(&bad, "this is a text file, not a blob\n").unwrap();
    let t = real_trial();
    let err = refused(
        &[
            "replay",
            t.to_str().unwrap(),
            "--model",
            bad.to_str().unwrap(),
        ],
        &["notes.bin", "not a valid model blob", "--allow-bad-model"],
    );
    assert_eq!(err.trim().lines().count(), 1, "{err}");
    let out = slipguard()
        .args([
            "replay",
            t.to_str().unwrap(),
            "--allow-bad-model",
            "--model",
        ])
        .arg(&bad)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(
        err.contains("warning") && err.contains("fault frames"),
        "{err}"
    );
    refused(
        &[
            "closed-loop",
            "--trials",
            "1",
            "--model",
            bad.to_str().unwrap(),
        ],
        &["notes.bin", "not a valid model blob"],
    );
    // A valid blob of the other profile: rate and unit named.
    let suction =
        slipguard::replay::default_models(&slipguard_app::profile::Profile::SUCTION).remove(0);
    refused(
        &[
            "replay",
            t.to_str().unwrap(),
            "--model",
            suction.to_str().unwrap(),
        ],
        &["suction.bin", "Hz", "hand profile"],
    );
    // eval: a blob alone says why not and what to run instead.
    refused(
        &["eval", bad.to_str().unwrap()],
        &["notes.bin", "slipguard replay --model"],
    );
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn a_trial_with_the_wrong_channel_count_is_refused() {
    let d = tmp_dir("channels");
    let p = d.join("three.csv");
    std::fs::write(
        &p,
        "# slipguard-recording v1\n# rate_hz: 16.7\n# unit: mN\ntime_s,c0,c1,c2\n0,1,2,3\n0.0598802,1,2,3\n",
    )
    .unwrap();
    refused(
        &["replay", p.to_str().unwrap(), "--profile", "hand"],
        &["three.csv", "3 channels", "16"],
    );
    let q = d.join("tactile.csv");
    std::fs::write(&q, "c0,c1\n1,2\n3\n").unwrap();
    refused(&["replay", q.to_str().unwrap()], &["tactile.csv:3"]);
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn replaying_a_training_trial_says_it_is_in_sample() {
    let out = slipguard()
        .arg("replay")
        .arg(real_trial())
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{err}");
    assert!(err.contains("in-sample"), "{err}");
}

/// Every subcommand's `--help` shows an example and a description for every option.
#[test]
fn every_subcommand_help_has_an_example_and_documents_every_option() {
    let subs: &[&[&str]] = &[
        &["dataset", "info"],
        &["label"],
        &["simulate"],
        &["baselines"],
        &["monitor"],
        &["replay"],
        &["closed-loop"],
        &["train"],
        &["eval"],
        &["demo"],
        &["bench-host"],
    ];
    for sub in subs {
        let out = slipguard().args(*sub).arg("--help").output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).to_string();
        assert!(out.status.success(), "{sub:?}: {text}");
        assert!(
            text.contains("Example"),
            "{sub:?} --help has no example:\n{text}"
        );
        assert!(
            text.contains("slipguard "),
            "{sub:?}: example command missing:\n{text}"
        );
        let bad = undocumented_options(&text);
        assert!(
            bad.is_empty(),
            "{sub:?} --help: options without a description: {bad:?}\n{text}"
        );
    }
}

/// Option lines of a clap `--help` with no description (on the line or the lines below).
pub fn undocumented_options(help: &str) -> Vec<String> {
    let lines: Vec<&str> = help.lines().collect();
    let mut bad = Vec::new();
    for (i, l) in lines.iter().enumerate() {
        let t = l.trim_start();
        let short = t.len() > 2 && t.as_bytes()[0] == b'-' && t.as_bytes()[1].is_ascii_alphabetic();
        let is_opt = l.starts_with("  ") && (t.starts_with("--") || short);
        if !is_opt || t.starts_with("-h, --help") || t.starts_with("-V, --version") {
            continue;
        }
        // Short help: the description follows the flag after two or more spaces.
        if t.split_once("  ")
            .is_some_and(|(_, d)| !d.trim().is_empty())
        {
            continue;
        }
        // Long help: on the following, deeper indented line.
        let indent = l.len() - t.len();
        let next = lines.get(i + 1).copied().unwrap_or("");
        let next_indent = next.len() - next.trim_start().len();
        if next.trim().is_empty() || next_indent <= indent {
            bad.push(t.to_string());
        }
    }
    bad
}

#[test]
fn train_out_writes_an_epoch_log_and_metrics_beside_the_checkpoint() {
    let d = tmp_dir("train-log");
    let out = slipguard()
        .args([
            "train",
            "--variant",
            "lstm",
            "--hidden",
            "4",
            "--epochs",
            "2",
            "--batch",
            "64",
        ])
        .arg("--out")
        .arg(&d)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let log = std::fs::read_to_string(d.join("lstm.epochs.csv")).unwrap();
    let rows: Vec<&str> = log.lines().collect();
    assert_eq!(rows[0], "epoch,train_loss,val_loss,seconds");
    assert_eq!(rows.len(), 3, "{log}");
    assert!(rows[2].starts_with("2,"), "{log}");
    let m: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("lstm.metrics.json")).unwrap())
            .unwrap();
    assert_eq!(m["epochs_run"], 2);
    assert!(m["best_val_loss"].as_f64().is_some_and(|v| v > 0.0), "{m}");
    std::fs::remove_dir_all(&d).unwrap();
}

#[test]
fn the_help_check_finds_an_undocumented_option() {
    let help = "Options:\n      --lr <LR>\n      --seed <SEED>  Seed of the batch order\n  -h, --help  Print help\n";
    assert_eq!(undocumented_options(help), vec!["--lr <LR>".to_string()]);
}

#[test]
fn errors_name_the_path_and_the_cause_once_without_debug_output() {
    let t = real_trial();
    for (args, path) in [
        (
            vec!["dataset", "info", "/nonexistent/data"],
            "/nonexistent/data",
        ),
        (
            vec![
                "replay",
                t.to_str().unwrap(),
                "--png",
                "/nonexistent/fig.png",
            ],
            "/nonexistent/fig.png",
        ),
        (
            vec!["replay", "/nonexistent/trial.csv"],
            "/nonexistent/trial.csv",
        ),
    ] {
        let all = refused(&args, &[path]);
        let errors: Vec<&str> = all.lines().filter(|l| l.starts_with("error")).collect();
        assert_eq!(errors.len(), 1, "{args:?}: {all}");
        let err = errors[0];
        assert_eq!(err.matches(path).count(), 1, "{args:?}: {err}");
        for debug in ["Os {", "IoError", "Some(", "kind:"] {
            assert!(!err.contains(debug), "{args:?}: debug output in: {err}");
        }
    }
}

#[test]
fn monitor_views_lines_and_none_do_what_the_help_says() {
    let d = tmp_dir("monitor-view");
    let cap = d.join("frames.bin");
    let out = slipguard()
        .arg("replay")
        .arg(real_trial())
        .args(["--script", "cheez", "--out"])
        .arg(&cap)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let view = |v: &str| {
        let o = slipguard()
            .args(["monitor", "--view", v, "--capture"])
            .arg(&cap)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stdout).to_string()
    };
    let none = view("none");
    assert_eq!(none.lines().count(), 1, "{none}");
    assert!(
        none.starts_with("summary: ") && none.contains("flags="),
        "{none}"
    );
    let lines = view("lines");
    assert!(
        lines.contains("flags t=") && lines.contains("reply to seq"),
        "{lines}"
    );
    assert!(lines.contains("info firmware"), "{lines}");
    for debug in ["{", "}", "Some(", "Info("] {
        assert!(
            !lines.contains(debug),
            "debug output `{debug}` in:\n{lines}"
        );
    }
    std::fs::remove_dir_all(&d).unwrap();
}
