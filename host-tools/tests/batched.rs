//! The batched, parallel host paths through the binary: `bench-host`'s report and refusals, and
//! the same output on 1 and 2 threads for the closed loop and a folder replay.
use std::process::Command;

fn slipguard() -> Command {
    Command::new(env!("CARGO_BIN_EXE_slipguard"))
}

#[test]
fn bench_host_reports_every_batch_and_thread_count_and_ends_with_the_summary() {
    let out = slipguard()
        .args(["bench-host", "--seconds", "0.01", "--batch", "1,16"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    for want in [
        "single-step path (Model::step), 1 thread(s)",
        "single-step path (Model::step), 2 thread(s)",
        "batch    1, 1 thread(s)",
        "batch   16, 2 thread(s)",
    ] {
        assert!(text.contains(want), "`{want}` missing:\n{text}");
    }
    let last = text.lines().last().unwrap();
    let words: Vec<&str> = last.split(' ').collect();
    assert_eq!(words[..3], ["host", "throughput:", "batched"], "{last}");
    assert_eq!(
        words[4..8],
        ["channel-steps/s", "(2", "threads),", "single"],
        "{last}"
    );
    assert_eq!(words[9], "ratio", "{last}");
    let n: f64 = words[3].parse().unwrap();
    let m: f64 = words[8].trim_end_matches(',').parse().unwrap();
    let r: f64 = words[10].parse().unwrap();
    assert!(
        n > 0.0 && m > 0.0 && (r - n / m).abs() <= 0.05 + 0.01 * r,
        "{last}"
    );
}

#[test]
fn bench_host_refuses_empty_batches_and_no_threads_on_one_line() {
    for (args, needle) in [
        (["--batch", "0"], "--batch 0"),
        (["--threads", "0"], "--threads 0"),
        (["--seconds", "0"], "--seconds 0"),
    ] {
        let out = slipguard().arg("bench-host").args(args).output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?}");
        assert_eq!(err.trim_end().lines().count(), 1, "{args:?}: {err}");
        assert!(err.contains(needle), "{args:?}: {err}");
    }
}

#[test]
fn closed_loop_report_is_the_same_on_one_and_two_threads() {
    let run = |threads: &str| {
        let out = slipguard()
            .args([
                "closed-loop",
                "--trials",
                "3",
                "--seed",
                "4",
                "--threads",
                threads,
            ])
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        out.stdout
    };
    let one = run("1");
    assert!(!one.is_empty());
    assert_eq!(
        String::from_utf8_lossy(&one),
        String::from_utf8_lossy(&run("2"))
    );
}

#[test]
fn folder_replay_is_the_same_on_one_and_two_threads() {
    let data = slipguard_data::eagle::default_data_dir();
    let run = |threads: &str| {
        let dir = std::env::temp_dir().join(format!(
            "slipguard-batched-{}-{threads}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&dir);
        let out = slipguard()
            .env("RAYON_NUM_THREADS", threads)
            .args(["replay", "--script", "marks", "--out"])
            .arg(&dir)
            .arg(&data)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let mut files: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().path())
            .collect();
        files.sort();
        let bytes: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
        std::fs::remove_dir_all(&dir).unwrap();
        (
            String::from_utf8_lossy(&out.stderr).to_string(),
            files.len(),
            bytes,
        )
    };
    let one = run("1");
    assert!(one.1 >= 20, "{} frame files", one.1);
    assert!(
        one.0.lines().count() >= one.1,
        "a line per trial at least: {}",
        one.0
    );
    assert_eq!(one, run("2"));
}
