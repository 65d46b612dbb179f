//! The loader on the shared real trials (`$SLIPGUARD_DATA` or `<repo>/data/eagle-shoal`).
use std::path::PathBuf;

use slipguard_data::eagle::{
    EAGLE_RATE_HZ, default_data_dir, load_eagle_dataset, load_eagle_trial,
};
use slipguard_data::labels::{LabelConfig, detect_drop, label_annotated};
use slipguard_data::{Outcome, Unit};

fn data() -> PathBuf {
    let d = default_data_dir();
    assert!(
        d.join("trials").is_dir(),
        "real data not found at {} (set SLIPGUARD_DATA)",
        d.display()
    );
    d
}

/// Drop steps read off the force curves (README table, lasting-collapse column).
const FAILURES: [(&str, [usize; 3], usize); 7] = [
    ("Cheez_100_814_top_3", [52, 87, 137], 121),
    ("Scrub_100_461_right_5", [65, 100, 150], 128),
    ("Water_100_1045_back_8", [53, 87, 137], 120),
    ("Water_50_558_right_7", [64, 99, 149], 130),
    ("Yellow_100_332_back_4", [53, 88, 137], 126),
    ("Yellow_100_618_right_0", [70, 104, 154], 138),
    ("Yellow_100_618_right_5", [66, 100, 150], 134),
];

#[test]
fn all_trials_load_with_sizes_and_labels() {
    let cfg = LabelConfig::default();
    let trials = load_eagle_dataset(&data(), &cfg, |_, _| {}).expect("load");
    // 25 trials with the dataset's label.txt and 36 with marks estimated from the force
    // (data/eagle-shoal/README.md); the estimated ones were copied up to the grasp's end.
    assert_eq!(trials.len(), 61);
    let estimated = trials.iter().filter(|t| t.label_estimated()).count();
    assert_eq!(estimated, 36);
    for t in &trials {
        let rows = if t.label_estimated() { 280 } else { 400 };
        assert_eq!(t.n_steps(), rows, "{}", t.id);
        assert_eq!(t.n_channels(), 16, "{}", t.id);
        assert_eq!(t.rate_hz, EAGLE_RATE_HZ);
        assert_eq!(t.unit, Unit::MilliNewton);
        assert_eq!(t.channel_names[15], "c15");
        let (g, l, o) = (
            t.marks.grasp_start.unwrap(),
            t.marks.lift_start.unwrap(),
            t.marks.open_start.unwrap(),
        );
        assert!(g < l && l < o, "{}: marks {g} {l} {o}", t.id);
        // Successes never get a drop; failures always do, between lift and l2.
        match t.outcome {
            Outcome::Success => assert_eq!(t.drop_step, None, "{}", t.id),
            Outcome::Failure => {
                let d = t.drop_step.expect("failure has a drop");
                assert!(d > l && d < o, "{}: drop {d}", t.id);
            }
            Outcome::Unknown => panic!("{}: outcome unknown", t.id),
        }
    }
    let fails = trials
        .iter()
        .filter(|t| t.outcome == Outcome::Failure)
        .count();
    assert_eq!(fails, 33);
    let labelled_fails = trials
        .iter()
        .filter(|t| t.outcome == Outcome::Failure && !t.label_estimated())
        .count();
    assert_eq!(labelled_fails, 7);
    // The grasp setting is object, grip force and weight: 24 settings, the repeats of one
    // setting share it.
    let mut settings: Vec<String> = trials.iter().map(|t| t.grasp_setting()).collect();
    settings.sort();
    settings.dedup();
    assert_eq!(settings.len(), 24);
    let cheez = trials
        .iter()
        .find(|t| t.id == "Cheez_100_814_top_8")
        .unwrap();
    assert_eq!(cheez.grasp_setting(), "Cheez_100_814");
    assert!(cheez.label_estimated());
    // A success with no real contact keeps all 16 channels, all marked as no contact.
    let none = trials.iter().find(|t| t.id == "Cheez_50_50_top_0").unwrap();
    assert!(none.contact_channels().is_empty());
    let l = label_annotated(none, &cfg);
    assert!(l.channel(0).is_none());
}

#[test]
fn known_drops_of_the_failures() {
    let cfg = LabelConfig::default();
    for (id, marks, drop) in FAILURES {
        let t = load_eagle_trial(&data().join("trials").join(id), &cfg).expect(id);
        assert_eq!(
            [t.marks.grasp_start, t.marks.lift_start, t.marks.open_start],
            marks.map(Some),
            "{id}"
        );
        assert_eq!(t.outcome, Outcome::Failure);
        assert_eq!(t.drop_step, Some(drop), "{id}");
        let l = label_annotated(&t, &cfg);
        assert_eq!(l.unstable_from, Some(drop - 20));
        assert_eq!(l.n_unstable(), marks[0] + 160 - (drop - 20));
    }
}

#[test]
fn cheez_dip_at_100_is_not_the_drop() {
    let t = load_eagle_trial(
        &data().join("trials/Cheez_100_814_top_3"),
        &LabelConfig::default(),
    )
    .unwrap();
    // Raw values: row 100 is c2 = 181 only; row 121 has c12 = 107, c15 = 99.
    assert_eq!(t.samples[2][100], 181.0);
    assert_eq!(t.row(121).iter().sum::<f32>(), 206.0);
    assert_eq!(t.samples[0][118], 6151.0);
    let d = detect_drop(&t, &LabelConfig::default());
    assert_eq!(d.first_dip, Some(100));
    assert_eq!(d.step, Some(121));
    assert_eq!(d.channels, vec![0, 4, 8]);
    assert_eq!(d.peak, 15705.0);
    // Fingers pressing on each other after the drop (c9 > 20 N at 143) are not contact.
    assert!(t.samples[9][143] > 20_000.0);
    assert!(!t.contact[9]);
}

/// The release rule (docs/labels.md) on the real successes. With the dataset's label.txt: every
/// success with a contact channel gets a release well after the lift window, where the force
/// curves show the hand opening (90–150 steps after the lift start); the two without contact
/// get none. With estimated marks (recordings copied up to the grasp's end, 280 steps): a
/// release in 9 of the 10, 80–140 steps after the lift; Scrub_50_461_right_5 loses its only
/// contact before its estimated lift and has none (its armed window runs to the end).
#[test]
fn release_is_found_on_every_success_with_contact() {
    use slipguard_data::labels::detect_release;
    let cfg = LabelConfig::default();
    let trials = load_eagle_dataset(&data(), &cfg, |_, _| {}).expect("load");
    let (mut found, mut found_estimated) = (0, 0);
    for t in trials.iter().filter(|t| t.outcome == Outcome::Success) {
        let lift = t.marks.lift_start.unwrap();
        let r = detect_release(t, &cfg);
        eprintln!("{} lift {lift} release {r:?}", t.id);
        if !t.contact.iter().any(|&c| c) {
            assert_eq!(r, None, "{}", t.id);
            continue;
        }
        if t.label_estimated() {
            if t.id == "Scrub_50_461_right_5" {
                assert_eq!(r, None);
                continue;
            }
            let after = r.unwrap_or_else(|| panic!("{}: no release found", t.id)) - lift;
            assert!(
                (80..=140).contains(&after),
                "{}: release {after} steps after lift",
                t.id
            );
            found_estimated += 1;
            continue;
        }
        let r = r.unwrap_or_else(|| panic!("{}: no release found", t.id));
        let after = r - lift;
        assert!(
            (90..=150).contains(&after),
            "{}: release {after} steps after lift",
            t.id
        );
        found += 1;
    }
    assert_eq!((found, found_estimated), (16, 9));
}
