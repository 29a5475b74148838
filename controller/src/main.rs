//! `bdft-controller`: the control core's command-line tool (design analysis and offline
//! simulation). Thin: parsing and printing here, everything else in the library.

mod cli;

fn main() -> std::process::ExitCode {
    cli::run()
}
