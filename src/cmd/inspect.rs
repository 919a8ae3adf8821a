//! `objloc inspect SESSION [--json] [--quick]`: summary of a session or any ROS 2 MCAP; the
//! full check decodes every message (in bounded memory), `--quick` reads only the summary
//! section and says so.

use super::say;

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
    /// Read only the file's summary section (channels, message counts, time range, chunk
    /// count): instant on any size, but nothing is decoded or checked. Without a summary
    /// section (or with a truncated file) the full check runs, and the output says so.
    #[arg(long)]
    quick: bool,
    /// No progress spinner (there is none anyway when stderr is not a terminal).
    #[arg(short, long)]
    quiet: bool,
    #[command(flatten)]
    topics: TopicArgs,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let topics = args.topics.topics()?;
    let spinner = super::progress::stage_spinner(args.quiet);
    spinner.set_message(format!("reading {}", args.session.display()));
    let (text, json, warnings) = if args.quick {
        let q =
            objloc_core::io::inspect::summarize_quick(&args.session, topics).context("inspect")?;
        (
            q.to_text(),
            serde_json::to_string_pretty(&q)?,
            q.warnings().to_vec(),
        )
    } else {
        let s = objloc_core::io::inspect::summarize(&args.session, topics).context("inspect")?;
        (
            s.to_text(),
            serde_json::to_string_pretty(&s)?,
            s.warnings.clone(),
        )
    };
    spinner.finish_and_clear();
    if args.json {
        say!("{json}");
        for w in &warnings {
            eprintln!("warning: {w}");
        }
    } else {
        super::say_part!("{text}");
    }
    Ok(())
}
