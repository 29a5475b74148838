//! `bdft-server`: thin entry point; everything is in the library.

fn main() -> std::process::ExitCode {
    bdft_server::cli::run()
}
