//! Cross-validation folds by grasp setting against what they must be: every trial once, every
//! setting in one fold, the failures spread as evenly as whole settings allow; by trial as
//! before.
use slipguard_learn::evaluation::{CvGrouping, cv_folds_by_setting, cv_folds_of};

fn trials() -> Vec<(String, bool)> {
    // Settings with 5, 4, 2, 1 failures and three success-only settings.
    let mut v = Vec::new();
    let mut add = |setting: &str, n: usize, failure: bool| {
        for i in 0..n {
            v.push((format!("{setting}_top_{i}"), failure));
        }
    };
    add("Cheez_100_814", 5, true);
    add("Water_100_1045", 4, true);
    add("Yellow_50_332", 2, true);
    add("Scrub_50_461", 1, true);
    add("Cola_100_26", 3, false);
    add("Tomato_100_164", 4, false);
    add("Cheez_100_50", 2, false);
    v
}

#[test]
fn setting_folds_keep_a_setting_together_and_spread_the_failures() {
    let t = trials();
    let folds = cv_folds_by_setting(&t, 3);
    assert_eq!(folds.len(), 3);
    let mut all: Vec<&String> = folds.iter().flatten().collect();
    all.sort();
    let mut want: Vec<&String> = t.iter().map(|(id, _)| id).collect();
    want.sort();
    assert_eq!(all, want, "every trial exactly once");
    let setting = |id: &str| id.rsplitn(3, '_').nth(2).unwrap().to_string();
    for (i, f) in folds.iter().enumerate() {
        for id in f {
            for (j, g) in folds.iter().enumerate() {
                if j != i {
                    assert!(g.iter().all(|o| setting(o) != setting(id)), "{id} split");
                }
            }
        }
    }
    let fails: Vec<usize> = folds
        .iter()
        .map(|f| {
            f.iter()
                .filter(|id| t.iter().any(|(x, fl)| x == *id && *fl))
                .count()
        })
        .collect();
    // 12 failures in settings of 5, 4, 2, 1: the best split is 5 / 4 / 3.
    let mut sorted = fails.clone();
    sorted.sort();
    assert_eq!(sorted, vec![3, 4, 5]);
    // Deterministic.
    assert_eq!(folds, cv_folds_by_setting(&t, 3));
    assert_eq!(CvGrouping::Setting.folds(&t, 3), folds);
}

#[test]
fn trial_folds_deal_failures_round_robin() {
    let t = trials();
    let folds = cv_folds_of(&t, 4);
    let fails: Vec<usize> = folds
        .iter()
        .map(|f| {
            f.iter()
                .filter(|id| t.iter().any(|(x, fl)| x == *id && *fl))
                .count()
        })
        .collect();
    assert_eq!(fails, vec![3, 3, 3, 3]);
    assert_eq!(CvGrouping::Trial.folds(&t, 4), folds);
    assert_eq!("setting".parse::<CvGrouping>(), Ok(CvGrouping::Setting));
    assert!("object".parse::<CvGrouping>().is_err());
}
