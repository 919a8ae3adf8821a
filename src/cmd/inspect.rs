//! `objloc inspect SESSION [--json]`: summary of a session or any ROS 2 MCAP.

use std::path::PathBuf;

use anyhow::Context;

use super::TopicArgs;

#[derive(Debug, clap::Args)]
pub struct Args {
    /// The MCAP file to summarise.
    session: PathBuf,
    /// Print the summary as JSON instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    topics: TopicArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let summary = objloc_core::io::inspect::summarize(&args.session, args.topics.topics()?)
        .context("inspect")?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&summary)?);
    } else {
        print!("{}", summary.to_text());
    }
    for w in &summary.warnings {
        if args.json {
            eprintln!("warning: {w}");
        }
    }
    Ok(())
}
