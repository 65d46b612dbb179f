//! The field loop at every profile rate and sensor (issue 25): recordings written by `simulate`
//! at 40 Hz (hand) and 71 Hz (suction), labelled by `label`, train a model whose blob header
//! has the recordings' rate and unit; a folder that mixes rates, options that contradict the
//! data and unlabelled data are refused before any output; and the CLI defects of issue 27
//! that touch these commands (each test fails without its fix).
use slipguard_core::units::Millihertz;
use std::path::{Path, PathBuf};
use std::process::{Command as Process, Output};

use slipguard_core::blob::{AlignedBlob, InputUnit};
use slipguard_core::model::Model;

fn slipguard() -> Process {
    Process::new(env!("CARGO_BIN_EXE_slipguard"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sg-rates-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn text(out: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    )
}

fn run_ok(p: &mut Process) -> String {
    let out = p.output().unwrap();
    assert!(out.status.success(), "{p:?}\n{}", text(&out));
    text(&out)
}

/// Runs `p`, which must fail with exactly one line on stderr; returns that line.
fn run_err(p: &mut Process) -> String {
    let out = p.output().unwrap();
    assert!(!out.status.success(), "{p:?} succeeded:\n{}", text(&out));
    let err = String::from_utf8_lossy(&out.stderr).trim().to_string();
    assert_eq!(err.lines().count(), 1, "{p:?}: not one line:\n{err}");
    err
}

/// `simulate` recordings into `dir` (suction: the 71 Hz ones; the 17.75 Hz copies go into a
/// subfolder).
fn simulate(dir: &Path, args: &[&str]) {
    run_ok(
        slipguard()
            .arg("simulate")
            .args(args)
            .args(["--failure-share", "0.5", "--out"])
            .arg(dir),
    );
}

/// The recordings' `# outcome:` lines removed, as the monitor writes them.
fn strip_outcomes(dir: &Path) -> Vec<(String, String)> {
    let mut truth = Vec::new();
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.extension().is_none_or(|e| e != "csv") {
            continue;
        }
        let s = std::fs::read_to_string(&p).unwrap();
        let mut kept = String::new();
        for l in s.lines() {
            if let Some(o) = l.strip_prefix("# outcome: ") {
                let id = p.file_stem().unwrap().to_string_lossy().into_owned();
                truth.push((id, o.trim().to_string()));
            } else if !l.starts_with("# drop_step:") && !l.starts_with("# slip_onset_step:") {
                kept.push_str(l);
                kept.push('\n');
            }
        }
        std::fs::write(&p, kept).unwrap();
    }
    truth.sort();
    truth
}

fn blob_header(p: &Path) -> (u32, InputUnit, String) {
    let b = AlignedBlob::new(&std::fs::read(p).unwrap());
    let m = Model::from_bytes(b.as_bytes()).unwrap();
    let c = m.config();
    let name = String::from_utf8_lossy(&c.name)
        .trim_end_matches('\0')
        .to_string();
    (c.sample_rate_mhz.0, c.input_unit, name)
}

fn train_small(data: &Path, out: &Path, extra: &[&str]) -> Process {
    let mut p = slipguard();
    p.arg("train")
        .arg(data)
        .arg("--out")
        .arg(out)
        .args([
            "--variant",
            "lstm",
            "--hidden",
            "4",
            "--epochs",
            "1",
            "--batch",
            "64",
        ])
        .args(extra);
    p
}

#[test]
fn forty_hz_force_recordings_train_a_40_hz_blob_named_as_asked() {
    let dir = tmp("f40");
    let rec = dir.join("rec");
    simulate(&rec, &["--rate", "40", "--count", "6", "--seed", "5"]);
    let truth = strip_outcomes(&rec);
    let lab = dir.join("labelled");
    let t = run_ok(
        slipguard()
            .arg("label")
            .arg(&rec)
            .args(["--outcome-from-drop", "--stats", "--out"])
            .arg(&lab),
    );
    // The durations in seconds at 40 Hz: 1.2 s lead = 48 steps, 0.6 s hold = 24 steps.
    assert!(t.contains("config at 40 Hz: lead 48 steps"), "{t}");
    assert!(t.contains("for 24 steps (0.60 s)"), "{t}");
    // The outcome from the force agrees with the simulator's on every trial.
    for (id, o) in &truth {
        assert!(t.contains(&format!("{id}: outcome {o}")), "{id} {o}\n{t}");
    }
    // A failure whose recording shows no lasting drop gets no labels: train names it.
    let held = truth
        .iter()
        .find(|(_, o)| o == "success")
        .unwrap()
        .0
        .clone();
    let odd = dir.join("odd");
    std::fs::create_dir_all(&odd).unwrap();
    for e in std::fs::read_dir(&lab).unwrap() {
        let f = e.unwrap().path();
        let mut text = std::fs::read_to_string(&f).unwrap();
        if f.file_stem().unwrap().to_string_lossy() == held {
            text = text.replace("# outcome: success", "# outcome: failure");
        }
        std::fs::write(odd.join(f.file_name().unwrap()), text).unwrap();
    }
    let t = run_ok(&mut train_small(&odd, &dir.join("odd-model"), &[]));
    assert!(
        t.contains("failure without a lasting drop") && t.contains(&held),
        "{t}"
    );
    let out = dir.join("model");
    let t = run_ok(&mut train_small(&lab, &out, &["--name", "mine"]));
    assert!(t.contains("at 40 Hz"), "{t}");
    let (rate, unit, name) = blob_header(&out.join("mine.bin"));
    assert_eq!(
        (rate, unit, name.as_str()),
        (40_000, InputUnit::MilliNewton, "mine")
    );
    // A model at another rate than the data is refused by eval, naming both rates.
    let e = run_err(
        slipguard()
            .arg("eval")
            .arg(out.join("mine.safetensors"))
            .arg("--data")
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/eagle-shoal"))
            .args(["--sim-force", "0", "--sim-suction", "0"]),
    );
    assert!(e.contains("40 Hz") && e.contains("16.7 Hz"), "{e}");
    // And by export: calibrating on recordings at another rate is refused; on its own it
    // exports.
    use slipguard_export::pipeline::{self, ExportOptions, ModelSource};
    let opts = |data: PathBuf| ExportOptions {
        source: ModelSource {
            path: out.join("mine.safetensors"),
            ..Default::default()
        },
        data: Some(data),
        validation: None,
        max_trials: None,
        fit_norm: false,
        cell_bits: None,
        quiet: true,
        no_holdout: true,
    };
    let e = pipeline::export(&opts(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/eagle-shoal"),
    ))
    .err()
    .unwrap()
    .to_string();
    assert!(e.contains("16.7 Hz") && e.contains("40 Hz"), "{e}");
    let blob = pipeline::export(&opts(lab)).unwrap().blob;
    let m = Model::from_bytes(AlignedBlob::new(&blob).as_bytes())
        .unwrap()
        .config()
        .sample_rate_mhz;
    assert_eq!(m, Millihertz(40_000));
}

#[test]
fn suction_recordings_train_a_71_hz_counts_blob_and_their_drops_are_found() {
    let dir = tmp("s71");
    let sim = dir.join("sim");
    simulate(
        &sim,
        &["--sensor", "suction", "--count", "4", "--seed", "2"],
    );
    // The 17.75 Hz copies are in their own folder, so `sim` is one rate.
    assert!(sim.join("17.75hz").is_dir());
    // Recorded as from the board: through the firmware (tare at grasp start) with the samples
    // stream on, the bytes through the monitor's recorder; release at the simulated opening.
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    let mut truth = Vec::new();
    for e in std::fs::read_dir(&sim).unwrap() {
        let f = e.unwrap().path();
        if f.extension().is_none_or(|e| e != "csv") {
            continue;
        }
        let id = f.file_stem().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&f).unwrap();
        let meta = |k: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(&format!("# {k}: ")))
                .unwrap()
                .trim()
                .to_string()
        };
        truth.push((id.clone(), meta("outcome")));
        let bin = dir.join(format!("{id}.bin"));
        run_ok(
            slipguard()
                .arg("replay")
                .arg(&f)
                .args(["--samples", "--script", "marks", "--release-at"])
                .arg(meta("open_start"))
                .arg("--out")
                .arg(&bin),
        );
        run_ok(
            slipguard()
                .arg("monitor")
                .arg("--capture")
                .arg(&bin)
                .arg("--record")
                .arg(rec.join(format!("{id}.csv"))),
        );
    }
    truth.sort();
    assert!(truth.iter().any(|(_, o)| o == "failure"), "{truth:?}");
    assert!(truth.iter().any(|(_, o)| o == "success"), "{truth:?}");
    let lab = dir.join("labelled");
    let t = run_ok(
        slipguard()
            .arg("label")
            .arg(&rec)
            .args(["--outcome-from-drop", "--stats", "--out"])
            .arg(&lab),
    );
    assert!(t.contains("contact >= 1500 counts"), "{t}");
    for (id, o) in &truth {
        assert!(t.contains(&format!("{id}: outcome {o}")), "{id} {o}\n{t}");
    }
    let out = dir.join("model");
    run_ok(&mut train_small(&lab, &out, &[]));
    let (rate, unit, _) = blob_header(&out.join("lstm.bin"));
    assert_eq!((rate, unit), (71_000, InputUnit::Counts));
    // Suction recordings given to a force model: refused, naming both.
    let e = run_err(&mut train_small(
        &lab,
        &dir.join("x"),
        &["--sensor", "force"],
    ));
    assert!(
        e.contains("--sensor force") && e.contains("suction (counts)"),
        "{e}"
    );
    assert!(!dir.join("x").exists());
}

#[test]
fn mixed_rates_contradicting_options_and_unlabelled_data_are_refused_before_output() {
    let dir = tmp("mixed");
    let (a, b) = (dir.join("a"), dir.join("b"));
    simulate(&a, &["--rate", "40", "--count", "1", "--seed", "1"]);
    simulate(&b, &["--count", "1", "--seed", "1"]);
    let mixed = dir.join("mixed");
    std::fs::create_dir_all(&mixed).unwrap();
    for (src, name) in [(&a, "a.csv"), (&b, "b.csv")] {
        let f = std::fs::read_dir(src)
            .unwrap()
            .next()
            .unwrap()
            .unwrap()
            .path();
        std::fs::copy(f, mixed.join(name)).unwrap();
    }
    for cmd in ["label", "train"] {
        let mut p = slipguard();
        p.arg(cmd).arg(&mixed).arg("--out").arg(dir.join("out"));
        let e = run_err(&mut p);
        assert!(
            e.contains("b.csv")
                && e.contains("16.7 Hz")
                && e.contains("a.csv")
                && e.contains("40 Hz"),
            "{cmd}: {e}"
        );
        assert!(!dir.join("out").exists(), "{cmd} created its output");
    }
    // --rate-hz against the data's.
    let e = run_err(&mut train_small(
        &a,
        &dir.join("out"),
        &["--rate-hz", "16.7"],
    ));
    assert!(e.contains("--rate-hz 16.7") && e.contains("40 Hz"), "{e}");
    // Unlabelled recordings: `label --out` needs --outcome-from-drop, `train` needs `label`.
    strip_outcomes(&a);
    let e = run_err(
        slipguard()
            .arg("label")
            .arg(&a)
            .arg("--out")
            .arg(dir.join("out")),
    );
    assert!(e.contains("--outcome-from-drop"), "{e}");
    let e = run_err(&mut train_small(&a, &dir.join("out"), &[]));
    assert!(
        e.contains("slipguard label") && e.contains("--outcome-from-drop"),
        "{e}"
    );
    assert!(!dir.join("out").exists());
}

#[test]
fn negative_numbers_reach_the_range_check() {
    for (cmd, args) in [
        ("train", &["--epochs", "-1"][..]),
        ("train", &["--hidden", "-3"][..]),
        ("label", &["--lead-s", "-1"][..]),
        ("replay", &["x.csv", "--rate", "-5"][..]),
    ] {
        let out = slipguard()
            .arg(cmd)
            .args(args)
            .args(["--out", "/nonexistent/x"])
            .output()
            .unwrap();
        let e = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert!(!e.contains("unexpected argument"), "{cmd} {args:?}: {e}");
        assert!(e.contains(args[args.len() - 1]), "{cmd} {args:?}: {e}");
    }
}

#[test]
fn label_plot_to_a_png_file_draws_that_file() {
    let dir = tmp("plot");
    let png = dir.join("out/label.png");
    run_ok(
        slipguard()
            .arg("label")
            .arg(Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/eagle-shoal"))
            .args(["--trial", "Cheez_100_814_top_3", "--plot"])
            .arg(&png),
    );
    assert!(png.is_file());
    assert_eq!(&std::fs::read(&png).unwrap()[1..4], b"PNG");
}

#[test]
fn replay_of_a_40_hz_recording_picks_the_40_hz_shipped_model() {
    let dir = tmp("replay40");
    simulate(&dir, &["--rate", "40", "--count", "1", "--seed", "3"]);
    let f = std::fs::read_dir(&dir)
        .unwrap()
        .next()
        .unwrap()
        .unwrap()
        .path();
    let t = run_ok(
        slipguard()
            .arg("replay")
            .arg(&f)
            .arg("--out")
            .arg(dir.join("f.bin")),
    );
    assert!(t.contains("hand-force-40hz"), "{t}");
}

#[test]
fn calibrate_picks_from_held_grasps_within_the_budget_and_eval_agrees() {
    let dir = tmp("calib");
    // Ten eagle-shoal trials (held and dropped) in their own dataset folder.
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/eagle-shoal/trials");
    let data = dir.join("trials");
    std::fs::create_dir_all(&data).unwrap();
    let mut ids: Vec<_> = std::fs::read_dir(&src)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    ids.sort();
    for id in ids.iter().take(10) {
        let to = data.join(id);
        std::fs::create_dir_all(&to).unwrap();
        for f in std::fs::read_dir(src.join(id)).unwrap() {
            let f = f.unwrap().path();
            std::fs::copy(&f, to.join(f.file_name().unwrap())).unwrap();
        }
    }
    let pick = dir.join("pick.txt");
    let t = run_ok(
        slipguard()
            .arg("calibrate")
            .arg(&data)
            .args(["--false-alarm-budget", "0.2", "--out"])
            .arg(&pick),
    );
    let line = std::fs::read_to_string(&pick).unwrap();
    let v: Vec<&str> = line.split_whitespace().collect();
    assert_eq!(v[0], "threshold", "{line}");
    let (fa, held) = t
        .lines()
        .find_map(|l| l.strip_prefix("pick: "))
        .and_then(|l| l.split("(the model's): ").nth(1))
        .and_then(|l| l.split(' ').next())
        .and_then(|s| s.split_once('/'))
        .map(|(a, b)| (a.parse::<usize>().unwrap(), b.parse::<usize>().unwrap()))
        .unwrap();
    assert!(held >= 3 && fa as f64 <= 0.2 * held as f64, "{t}");
    // The same decision scored by `eval` (its own armed-window path) gives the same count.
    let json = dir.join("e.json");
    run_ok(
        slipguard()
            .arg("eval")
            .arg(
                Path::new(env!("CARGO_MANIFEST_DIR"))
                    .join("../models/hand-force/hand-force.safetensors"),
            )
            .arg("--data")
            .arg(&data)
            .args(["--threshold", v[1], "--raise-after", v[2]])
            .args(["--sim-force", "0", "--sim-suction", "0", "--json"])
            .arg(&json),
    );
    let j = std::fs::read_to_string(&json).unwrap();
    assert!(
        j.contains(&format!("\"armed.false_alarm_grasps\": {fa},"))
            || j.contains(&format!("\"armed.false_alarm_grasps\":{fa},")),
        "{t}\n{j}"
    );
    // A negative budget reaches the range check.
    let out = slipguard()
        .arg("calibrate")
        .arg(&data)
        .args(["--false-alarm-budget", "-0.1"])
        .output()
        .unwrap();
    let e = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && e.contains("-0.1 is not in the allowed range"),
        "{e}"
    );
}

fn decode(bytes: &[u8]) -> Vec<slipguard_core::protocol::Frame> {
    let mut d = slipguard_core::protocol::Deframer::new();
    bytes
        .iter()
        .filter_map(|&b| d.push_decode(b))
        .map(|r| r.unwrap())
        .collect()
}

/// The field loop at a profile's rate on the host, through the same portable app the QEMU
/// build runs: simulated grasps recorded from the firmware's samples stream by the monitor,
/// labelled (outcomes from the drop), trained, exported on the recordings, uploaded into the
/// simulated flash of a board running the shipped model for that rate, and then the flags are
/// the new model's: equal to an app that ran it from boot and to the core stepped on the
/// samples frames' values, and not the old model's.
fn field_loop_at(sim_args: &[&str], profile: slipguard_app::profile::Profile, name: &str) {
    use slipguard::replay;
    use slipguard_app::replay::{self as fw, field_script};
    use slipguard_app::upload::{FACTORY_SLOT, SimFlash};
    use slipguard_core::model::ChannelState;
    use slipguard_core::protocol::Message;
    use slipguard_export::pipeline::{self, ExportOptions, ModelSource};

    let dir = tmp(name);
    let sim = dir.join("sim");
    simulate(&sim, sim_args);
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    for e in std::fs::read_dir(&sim).unwrap() {
        let f = e.unwrap().path();
        if f.extension().is_none_or(|e| e != "csv") {
            continue;
        }
        let id = f.file_stem().unwrap().to_string_lossy().into_owned();
        let text = std::fs::read_to_string(&f).unwrap();
        let open = text
            .lines()
            .find_map(|l| l.strip_prefix("# open_start: "))
            .unwrap()
            .trim()
            .to_string();
        let bin = dir.join(format!("{id}.bin"));
        run_ok(
            slipguard()
                .arg("replay")
                .arg(&f)
                .args(["--samples", "--script", "marks", "--release-at", &open])
                .arg("--out")
                .arg(&bin),
        );
        run_ok(
            slipguard()
                .arg("monitor")
                .arg("--capture")
                .arg(&bin)
                .arg("--record")
                .arg(rec.join(format!("{id}.csv"))),
        );
    }
    let lab = dir.join("labelled");
    run_ok(
        slipguard()
            .arg("label")
            .arg(&rec)
            .args(["--outcome-from-drop", "--out"])
            .arg(&lab),
    );
    let out = dir.join("model");
    run_ok(&mut train_small(&lab, &out, &["--name", "field"]));
    let exported = pipeline::export(&ExportOptions {
        source: ModelSource {
            path: out.join("field.safetensors"),
            ..Default::default()
        },
        data: Some(lab.clone()),
        validation: None,
        max_trials: None,
        fit_norm: false,
        cell_bits: None,
        quiet: true,
        no_holdout: true,
    })
    .unwrap();
    let new = AlignedBlob::new(&exported.blob);
    let first = std::fs::read_dir(&lab)
        .unwrap()
        .map(|e| e.unwrap().path())
        .min()
        .unwrap();
    // The sensor's signal is the simulated grasp's (absolute pressure for suction: the
    // recording holds the firmware's tared values), the same grasp the first recording holds.
    let trial = slipguard_data::load_path(
        &sim.join(first.file_name().unwrap()),
        &slipguard_data::labels::LabelConfig::default(),
        |_, _| {},
    )
    .unwrap()
    .remove(0);
    let rate_mhz = trial.rate_mhz();
    assert_eq!(new.parse().unwrap().config.sample_rate_mhz, rate_mhz);
    // The board runs the shipped model for this rate and sensor.
    let old = replay::load_blob(&replay::default_model_for(&profile, rate_mhz)).unwrap();
    assert_eq!(
        Model::from_bytes(old.as_bytes())
            .unwrap()
            .config()
            .sample_rate_mhz,
        rate_mhz
    );
    assert_ne!(new.as_bytes(), old.as_bytes());
    let bytes = replay::trial_bytes(&trial, &profile).repeat(2);
    let steps = 2 * trial.n_steps();
    let fw_trial = fw::Trial::new(&bytes, profile.channels);
    let run = |model: &AlignedBlob, second: &AlignedBlob| {
        let mut slots = [
            vec![u32::MAX; 128 * 1024 / 4],
            vec![u32::MAX; 128 * 1024 / 4],
        ];
        for (w, b) in slots[FACTORY_SLOT as usize]
            .iter_mut()
            .zip(model.as_bytes().chunks_exact(4))
        {
            *w = u32::from_ne_bytes([b[0], b[1], b[2], b[3]]);
        }
        let [s0, s1] = &mut slots;
        let mut flash = SimFlash::new(s0, s1);
        let mut out = Vec::new();
        let (n, reloaded) = fw::run_field(
            profile,
            model.as_bytes(),
            second.as_bytes(),
            &mut flash,
            &fw_trial,
            |b| out.extend_from_slice(b),
        );
        let frames = decode(&out);
        assert_eq!(frames.len(), n);
        (frames, reloaded)
    };
    let (field, reloaded) = run(&old, &new);
    assert_eq!(
        reloaded,
        Some(field_script::commit_at(new.as_bytes().len()))
    );
    let p_after =
        |v: &[slipguard_core::protocol::Frame]| -> Vec<[slipguard_core::protocol::PUnstable; 16]> {
            v.iter()
                .filter_map(|f| match f.msg {
                    Message::Flags(x) => Some(x.p),
                    _ => None,
                })
                .skip(field_script::GRASP_AGAIN_AT as usize)
                .collect()
        };
    assert_eq!(
        p_after(&field).len(),
        steps - field_script::GRASP_AGAIN_AT as usize
    );
    assert_eq!(p_after(&field), p_after(&run(&new, &new).0));
    assert_ne!(p_after(&field), p_after(&run(&old, &old).0));
    // The core stepped per channel from the grasp start on the samples frames' values.
    let model = Model::new(new.parse().unwrap()).unwrap();
    let contact = slipguard_core::decision::ContactConfig::of(model.config());
    let values: Vec<_> = field
        .iter()
        .filter_map(|f| match f.msg {
            Message::Samples(s) => Some(s),
            _ => None,
        })
        .skip(field_script::GRASP_AGAIN_AT as usize)
        .collect();
    let n = profile.channels;
    let mut states: Vec<ChannelState> = (0..n).map(|_| ChannelState::default()).collect();
    let mut in_contact = 0;
    for (s, p) in values.iter().zip(p_after(&field)) {
        assert_eq!(s.fault, 0);
        for c in 0..n {
            let o = model.step_in_contact(&mut states[c], &contact, s.value[c]);
            let want = o.step.map_or(slipguard_core::protocol::P_NONE, |o| {
                o.p_unstable_q15.max(0) as u16
            });
            assert_eq!(want, p[c].to_bits(), "channel {c}");
            in_contact += usize::from(o.step.is_some());
        }
    }
    assert!(in_contact > 100, "{in_contact} channel steps in contact");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn field_loop_at_40_hz_on_the_hand_profile() {
    field_loop_at(
        &["--rate", "40", "--count", "4", "--seed", "7"],
        slipguard_app::profile::Profile::HAND,
        "loop40",
    );
}

#[test]
fn field_loop_on_the_suction_profile() {
    field_loop_at(
        &["--sensor", "suction", "--count", "3", "--seed", "2"],
        slipguard_app::profile::Profile::SUCTION,
        "loop71",
    );
}
