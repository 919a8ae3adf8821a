//! `objloc demo`: placeholder until its issue lands.

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("objloc demo is not implemented yet")
}
