//! `objloc train`: placeholder until its issue lands.

#[derive(Debug, clap::Args)]
pub struct Args {}

pub fn run(_args: Args) -> anyhow::Result<()> {
    anyhow::bail!("objloc train is not implemented yet")
}
