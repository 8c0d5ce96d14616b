//! `safety-config monitor`: the live view of the bus, or plain lines and a summary.

use crate::{bus, load, open_bus};
use safety_config::ToolError;
use std::io::IsTerminal;
use std::time::Duration;

/// What `monitor` is given on the command line.
pub(crate) struct MonitorArgs<'a> {
    /// `--bus`, when given.
    pub(crate) bus: Option<&'a str>,
    /// The network file or DCF to judge the SRDOs against.
    pub(crate) file: Option<&'a str>,
    /// The candump log or pcap to record into.
    pub(crate) record: Option<&'a str>,
    /// The candump log to replay instead of the bus.
    pub(crate) replay: Option<&'a str>,
    /// Replay as fast as the log can be read.
    pub(crate) fast: bool,
    /// End after this many seconds.
    pub(crate) stop_after: Option<f64>,
    /// Plain lines instead of the live view.
    pub(crate) plain: bool,
}

/// `safety-config monitor`: the live view, or plain lines and a summary. It prints no JSON.
pub(crate) fn monitor(given: &MonitorArgs, as_json: bool) -> Result<bool, ToolError> {
    use safety_config::monitor::{self, Options, Source, model::Monitor};
    if as_json {
        return Err(ToolError::Usage(
            "monitor prints no JSON: record the bus with --record LOG (candump format) \
             for scripts"
                .into(),
        ));
    }
    let model = match given.file {
        Some(file) => Monitor::for_network(&load(file)?),
        None => Monitor::default(),
    };
    let stop_after = given
        .stop_after
        .map(|seconds| {
            Duration::try_from_secs_f64(seconds).map_err(|_| {
                ToolError::Usage(format!("--stop-after {seconds} is not a number of seconds"))
            })
        })
        .transpose()?;
    let (source, title) = match given.replay {
        Some(log) => (
            Source::replay(std::path::Path::new(log), given.fast)?,
            format!("safety-config monitor: replay of {log}"),
        ),
        None => {
            let bus = bus(given.bus)?;
            (
                Source::Bus(open_bus(&bus)?),
                format!("safety-config monitor: {bus}"),
            )
        }
    };
    let live = !given.plain && std::io::stdout().is_terminal();
    let options = Options {
        title,
        record: given.record.map(Into::into),
        stop_after,
        live,
        interrupt: Some(monitor::interrupt_on_ctrl_c()?),
    };
    let model = monitor::run(source, model, options)?;
    if !live {
        println!("## Summary");
        for line in monitor::view::summary(&model) {
            println!("{line}");
        }
    }
    Ok(true)
}
