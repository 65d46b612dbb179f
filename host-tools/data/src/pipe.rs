//! The command lines' one answer to a closed standard output (`slipguard label --stats | head -1`,
//! `slipguard-export run … | true`): the reader has what it wanted, so the program ends quietly
//! with exit status 0 instead of `println!`'s panic (exit 101).
//!
//! Rust ignores `SIGPIPE`, so a write to a closed pipe fails with `EPIPE` and `println!` panics
//! with "failed printing to stdout: Broken pipe". [`exit_quietly_on_broken_pipe`] installs a
//! panic hook that turns exactly that panic into `exit(0)`; every other panic keeps the default
//! report.

use std::panic;

/// Whether a panic message is `print!`/`println!`'s failure on a closed pipe.
pub fn is_broken_pipe_panic(message: &str) -> bool {
    message.starts_with("failed printing to stdout") && message.contains("Broken pipe")
}

/// Installs the hook; call first thing in `main`.
pub fn exit_quietly_on_broken_pipe() {
    let default = panic::take_hook();
    panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let message = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if is_broken_pipe_panic(message) {
            std::process::exit(0);
        }
        default(info);
    }));
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recognises_only_the_stdout_broken_pipe() {
        assert!(is_broken_pipe_panic(
            "failed printing to stdout: Broken pipe (os error 32)"
        ));
        assert!(!is_broken_pipe_panic("index out of bounds"));
        assert!(!is_broken_pipe_panic(
            "failed printing to stdout: No space left on device (os error 28)"
        ));
    }
}
