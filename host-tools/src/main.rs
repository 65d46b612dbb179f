//! `slipguard`: the host command line. Subcommands live in `cli/`, one module each.
mod cli;

fn main() -> std::process::ExitCode {
    cli::main()
}
