//! The field loop on the host: trials replayed through the firmware with the samples stream on
//! and recorded by the monitor's recorder make a folder of recordings that `label`, `train`,
//! `eval` and `replay` take (one test per command, folder and single file); and the whole loop
//! (record → label → train → export → upload into the simulated flash → flags from the new
//! model) in `field_loop_*`.
use std::path::{Path, PathBuf};
use std::process::Command as Process;

use slipguard::monitor::{Monitor, Recorder};
use slipguard::replay::{self, Scheduled};
use slipguard_app::profile::Profile;
use slipguard_core::protocol::{Command, Deframer, Frame, Message, StreamMode};
use slipguard_data::labels::LabelConfig;
use slipguard_data::{Outcome, load_path};

/// Two dropped and two held grasps of the repository's eagle-shoal copy.
const TRIALS: [&str; 4] = [
    "Cheez_100_814_top_3",
    "Scrub_100_461_right_5",
    "Cheez_100_432_right_5",
    "Cola_50_26_back_9",
];

fn slipguard() -> Process {
    Process::new(env!("CARGO_BIN_EXE_slipguard"))
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sg-field-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn run_ok(p: &mut Process) -> String {
    let out = p.output().unwrap();
    let (o, e) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{p:?}\nstdout:\n{o}\nstderr:\n{e}");
    format!("{o}{e}")
}

/// Records each trial as the monitor would on the controller's side: replayed through the
/// firmware (golden blob) with info and stream mode flags+samples at boot and the phase
/// commands at the trial's marks (release at its `l2`), the bytes through the monitor's
/// recorder. The recordings have no outcome (the monitor cannot know it).
fn record_folder(dir: &Path) -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../data/eagle-shoal/trials");
    let blob = replay::load_blob(&replay::golden_model_path()).unwrap();
    TRIALS
        .iter()
        .map(|id| {
            let src = load_path(&root.join(id), &LabelConfig::default(), |_, _| {})
                .unwrap()
                .remove(0);
            let m = src.marks;
            let at = |s: Option<usize>| s.unwrap() as u32;
            let script = replay::encode_script(&[
                Scheduled {
                    before_frame: 0,
                    command: Command::Info,
                },
                Scheduled {
                    before_frame: 0,
                    command: Command::StreamMode(StreamMode::FlagsAndSamples),
                },
                Scheduled {
                    before_frame: at(m.grasp_start),
                    command: Command::GraspStart,
                },
                Scheduled {
                    before_frame: at(m.lift_start),
                    command: Command::Lift,
                },
                Scheduled {
                    before_frame: at(m.open_start),
                    command: Command::Release,
                },
            ]);
            let out = replay::replay(Profile::HAND, blob.as_bytes(), &src, &script, &[]);
            let path = dir.join(format!("{id}.csv"));
            let mut mon = Monitor::new();
            mon.recorder = Some(Recorder::new(&path));
            for c in out.wire.chunks(64) {
                mon.push(c, |_| {});
            }
            let (stats, info) = (mon.stats.clone(), mon.info);
            let rows = mon
                .recorder
                .as_mut()
                .unwrap()
                .finish(&stats, info.as_ref())
                .unwrap();
            assert_eq!(rows, src.n_steps());
            path
        })
        .collect()
}

/// `label --outcome-from-drop --out`: the folder labelled (outcomes from the force).
fn label_folder(rec: &Path, out: &Path) -> String {
    run_ok(
        slipguard()
            .arg("label")
            .arg(rec)
            .args(["--stats", "--outcome-from-drop", "--out"])
            .arg(out),
    )
}

#[test]
fn label_takes_a_folder_of_recordings_and_a_single_one() {
    let dir = tmp("label");
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    let files = record_folder(&rec);
    let text = label_folder(&rec, &dir.join("labelled"));
    assert!(
        text.contains("Cheez_100_814_top_3: outcome failure"),
        "{text}"
    );
    assert!(
        text.contains("Cola_50_26_back_9: outcome success"),
        "{text}"
    );
    assert!(text.contains("trials 4 (labelled 4, skipped 0)"), "{text}");
    let labelled = load_path(&dir.join("labelled"), &LabelConfig::default(), |_, _| {}).unwrap();
    assert_eq!(labelled.len(), 4);
    let outcomes: Vec<Outcome> = labelled.iter().map(|t| t.outcome).collect();
    assert_eq!(
        outcomes.iter().filter(|&&o| o == Outcome::Failure).count(),
        2
    );
    assert!(
        labelled
            .iter()
            .all(|t| t.step_labels.is_some() && t.marks.release.is_some())
    );
    // One recording; without --outcome-from-drop its unknown outcome is reported as skipped.
    let text = run_ok(slipguard().arg("label").arg(&files[0]).arg("--stats"));
    assert!(text.contains("trials 1 (labelled 0, skipped 1)"), "{text}");
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn replay_takes_a_folder_of_recordings_and_a_single_one() {
    let dir = tmp("replay");
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    let files = record_folder(&rec);
    let out = dir.join("frames");
    let text = run_ok(slipguard().arg("replay").arg(&rec).arg("--out").arg(&out));
    // One line per recording run ("replay: ID (… steps …) with MODEL: N frames …"), and, as the
    // shipped blob carries a hand rule (format v2), one line per run with the fused flag's counts.
    let runs = text
        .lines()
        .filter(|l| l.starts_with("replay: ") && l.contains(" frames ("))
        .count();
    assert_eq!(runs, 4, "{text}");
    let fused = text
        .lines()
        .filter(|l| l.starts_with("replay: hand flag fused with the blob's hand rule"))
        .count();
    assert_eq!(fused, 4, "{text}");
    for id in TRIALS {
        let b = std::fs::read(out.join(format!("{id}.bin"))).unwrap();
        let frames = replay::decode_stream(&b);
        let flags = frames
            .iter()
            .filter(|f| matches!(f.msg, Message::Flags(_)))
            .count();
        assert_eq!(flags, 400, "{id}");
    }
    let one = dir.join("one.bin");
    run_ok(
        slipguard()
            .arg("replay")
            .arg(&files[1])
            .arg("--out")
            .arg(&one),
    );
    assert_eq!(
        std::fs::read(&one).unwrap(),
        std::fs::read(out.join(format!("{}.bin", TRIALS[1]))).unwrap()
    );
    // A recording with more channels than the profile takes is refused, naming it.
    let mut t = load_path(&files[0], &LabelConfig::default(), |_, _| {})
        .unwrap()
        .remove(0);
    t.samples.push(t.samples[0].clone());
    t.channel_names.push("c16".into());
    t.contact.push(false);
    let wide = dir.join("wide.csv");
    slipguard_data::recording::write_recording(&t, &wide).unwrap();
    let bad = slipguard().arg("replay").arg(&wide).output().unwrap();
    assert!(!bad.status.success());
    let err = String::from_utf8_lossy(&bad.stderr);
    assert!(
        err.contains("wide.csv: no sensor profile takes 17 channels at 16.7 Hz in mN (profiles: hand 16 channels"),
        "{err}"
    );
    std::fs::remove_dir_all(&dir).ok();
}

/// `train` on a labelled folder (hidden 8, one epoch): the checkpoint and its blob.
fn train_small(data: &Path, out: &Path) -> (PathBuf, PathBuf) {
    run_ok(
        slipguard()
            .arg("train")
            .arg(data)
            .arg("--out")
            .arg(out)
            .args(["--variant", "lstm", "--hidden", "8", "--epochs", "1"])
            .args(["--val-share", "0.25", "--name", "field"]),
    );
    (out.join("field.safetensors"), out.join("field.bin"))
}

#[test]
fn train_and_eval_take_a_folder_of_recordings_and_a_single_one() {
    let dir = tmp("train");
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    record_folder(&rec);
    let labelled = dir.join("labelled");
    label_folder(&rec, &labelled);
    let (ck, bin) = train_small(&labelled, &dir.join("model"));
    assert!(ck.is_file() && bin.is_file());
    let text = run_ok(
        slipguard()
            .arg("eval")
            .arg(&ck)
            .arg("--data")
            .arg(&labelled)
            .args(["--sim-force", "0", "--sim-suction", "0"]),
    );
    assert!(text.contains("field"), "{text}");
    // A single recording.
    let one = labelled.join(format!("{}.csv", TRIALS[0]));
    run_ok(
        slipguard()
            .arg("eval")
            .arg(&ck)
            .arg("--data")
            .arg(&one)
            .args(["--sim-force", "0", "--sim-suction", "0"]),
    );
    let single = dir.join("single");
    std::fs::create_dir_all(&single).unwrap();
    std::fs::copy(&one, single.join("one.csv")).unwrap();
    let (ck1, _) = train_small(&one, &dir.join("model1"));
    assert!(ck1.is_file());
    std::fs::remove_dir_all(&dir).ok();
}

fn decode(bytes: &[u8]) -> Vec<Frame> {
    let mut d = Deframer::new();
    bytes
        .iter()
        .filter_map(|&b| d.push_decode(b))
        .map(|r| r.unwrap())
        .collect()
}

#[test]
fn field_loop_record_label_train_export_upload_flags_from_the_new_model() {
    use slipguard_app::replay::{self as fw, field_script};
    use slipguard_app::upload::{FACTORY_SLOT, SimFlash};
    use slipguard_core::blob::AlignedBlob;
    use slipguard_export::pipeline::{self, ExportOptions, ModelSource};

    let dir = tmp("loop");
    // Record and label.
    let rec = dir.join("rec");
    std::fs::create_dir_all(&rec).unwrap();
    record_folder(&rec);
    let labelled = dir.join("labelled");
    label_folder(&rec, &labelled);
    // Train a small model, export it (calibrated on the recordings).
    let (ck, _) = train_small(&labelled, &dir.join("model"));
    let exported = pipeline::export(&ExportOptions {
        source: ModelSource {
            path: ck,
            ..Default::default()
        },
        data: Some(labelled.clone()),
        validation: None,
        max_trials: None,
        fit_norm: false,
        cell_bits: None,
        quiet: true,
        no_holdout: true,
    })
    .unwrap();
    let new = AlignedBlob::new(&exported.blob);
    let old = replay::load_blob(&replay::golden_model_path()).unwrap();
    assert_ne!(new.as_bytes(), old.as_bytes());

    // Upload it into the simulated flash during a replay with the samples stream on.
    let trial = load_path(
        &labelled.join(format!("{}.csv", TRIALS[0])),
        &LabelConfig::default(),
        |_, _| {},
    )
    .unwrap()
    .remove(0);
    // The trial twice over, so that the hand is in contact again after the script's second
    // grasp start (frame 390): channels out of contact do not run the model (`P_NONE`).
    let bytes = replay::trial_bytes(&trial, &Profile::HAND).repeat(2);
    let steps = 2 * trial.n_steps();
    let fw_trial = fw::Trial::new(&bytes, 16);
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
            Profile::HAND,
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
    // The recorder takes the same stream: samples frames throughout, the upload in between.
    let samples = field
        .iter()
        .filter(|f| matches!(f.msg, Message::Samples(_)))
        .count();
    assert_eq!(samples, steps);
    // After the grasp start on the new model the flags are the new blob's (an app that ran it
    // from boot, after the same grasp start) and not the old one's.
    let p_after = |v: &[Frame]| -> Vec<[slipguard_core::protocol::PUnstable; 16]> {
        v.iter()
            .filter_map(|f| match f.msg {
                Message::Flags(x) => Some(x.p),
                _ => None,
            })
            .skip(field_script::GRASP_AGAIN_AT as usize)
            .collect()
    };
    let new_ref = run(&new, &new).0;
    let old_ref = run(&old, &old).0;
    assert_eq!(
        p_after(&field).len(),
        steps - field_script::GRASP_AGAIN_AT as usize
    );
    assert_eq!(p_after(&field), p_after(&new_ref));
    assert_ne!(p_after(&field), p_after(&old_ref));
    // And directly through the core: the new blob's model stepped per channel from a reset state
    // at that grasp start (as the app's inference does) on the samples frames' values, the
    // model's input as the firmware fed it, gives the flag frames' p(unstable).
    use slipguard_core::model::{ChannelState, Model};
    let model = Model::new(new.parse().unwrap()).unwrap();
    let values: Vec<_> = field
        .iter()
        .filter_map(|f| match f.msg {
            Message::Samples(s) => Some(s),
            _ => None,
        })
        .skip(field_script::GRASP_AGAIN_AT as usize)
        .collect();
    let contact = slipguard_core::decision::ContactConfig::of(model.config());
    let mut states: Vec<ChannelState> = (0..16).map(|_| ChannelState::default()).collect();
    let (mut compared, mut in_contact) = (0, 0);
    for (s, p) in values.iter().zip(p_after(&field)) {
        assert_eq!(s.fault, 0);
        for c in 0..16 {
            let out = model.step_in_contact(&mut states[c], &contact, s.value[c]);
            let want = out.step.map_or(slipguard_core::protocol::P_NONE, |o| {
                o.p_unstable_q15.max(0) as u16
            });
            assert_eq!(want, p[c].to_bits(), "channel {c}");
            compared += 1;
            in_contact += usize::from(out.step.is_some());
        }
    }
    assert_eq!(
        compared,
        16 * (steps - field_script::GRASP_AGAIN_AT as usize)
    );
    // The comparison covers steps on which the new model ran.
    assert!(in_contact > 100, "{in_contact} channel steps in contact");
    std::fs::remove_dir_all(&dir).ok();
}
