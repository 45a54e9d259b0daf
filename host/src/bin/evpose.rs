//! The `evpose` command-line tool; everything lives in [`evpose_host::cli`].

use clap::Parser;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> anyhow::Result<()> {
    evpose_host::cli::quiet_broken_pipe();
    evpose_host::cli::run(evpose_host::cli::Cli::parse())
}
