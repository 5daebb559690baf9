//! `plumenet`: the command-line front end. Parses flags, runs the library, prints one clear
//! error line and exits non-zero on failure.

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    // A reader that closes the pipe early (`plumenet eval ... | head -1`) ends the program
    // quietly, as it ends other command-line tools, instead of making `println!` panic (Rust
    // ignores SIGPIPE). Sockets are unaffected: the standard library writes to them without
    // the signal.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of one signal before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args = cli::Cli::parse();
    match args.run() {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
