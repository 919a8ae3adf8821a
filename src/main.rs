//! The `objloc` binary: parses arguments, dispatches to one subcommand, prints any error on
//! one line with its context chain and exits 1. All logic lives in the library.

mod cmd;

use clap::Parser;

fn main() -> std::process::ExitCode {
    cmd::main(cmd::Cli::parse())
}
