//! What `dc-record bench` measures: the recorder's own end-of-run counts, and the steps a
//! recording misses against what the simulator published.

use crate::read::RecordingReader;
use crate::Result;
use serde::{Deserialize, Serialize};
use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// The recorder's counts at the end of a run (`dc-record --stats-json FILE`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RecorderStats {
    /// Frames the subscribers took off the bus.
    pub received: u64,
    /// Frames the bus delivered but that did not decode.
    pub undecodable: u64,
    /// Frames the MCAP writer refused (dropped).
    pub write_failed: u64,
    /// Encoded (CBOR) bytes handed to the writer.
    pub payload_bytes: u64,
    /// Seconds from the first to the last frame received.
    pub active_s: f64,
    /// Seconds from the start of recording to the end of the file.
    pub wall_s: f64,
    /// CPU time of the recorder process, user + system, seconds.
    pub cpu_s: f64,
}

/// CPU time (user + system) of this process so far, seconds.
pub fn process_cpu_seconds() -> f64 {
    // SAFETY: getrusage only writes the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return f64::NAN;
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    secs(usage.ru_utime) + secs(usage.ru_stime)
}

/// Per step topic, how many (run, simulation, step) frames the recording lacks when
/// `simulations` simulations each published `steps` steps (0..steps) on each of `topics`. A topic
/// missing from the file entirely misses all of them.
pub fn missing_steps(path: &Path, topics: &[&str], simulations: u64, steps: u32) -> Result<BTreeMap<String, u64>> {
    let mut seen: BTreeMap<String, BTreeSet<(u64, u32, u32)>> =
        topics.iter().map(|t| (t.to_string(), BTreeSet::new())).collect();
    let mut reader = RecordingReader::open(path)?;
    while let Some(message) = reader.next_message() {
        let message = message?;
        let Some(kind) = message.channel.kind else { continue };
        let Ok(step) = kind.step_of(&message.data) else { continue };
        if let Some(keys) = seen.get_mut(&message.channel.topic) {
            if step.step < steps {
                keys.insert((step.run_id, step.simulation, step.step));
            }
        }
    }
    let expected = simulations * u64::from(steps);
    Ok(seen.into_iter().map(|(topic, keys)| (topic, expected.saturating_sub(keys.len() as u64))).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{FrameKind, RecordingWriter};
    use msgs::{Body, Contact, Frame, StepHeader};

    #[test]
    fn missing_steps_counts_the_gaps_per_topic() {
        let dir = std::env::temp_dir().join(format!("dc-missing-steps-{}", std::process::id()));
        let path = dir.join("gaps.mcap");
        let mut w = RecordingWriter::create(&path).unwrap();
        w.add_channel("bodies", FrameKind::Bodies).unwrap();
        w.add_channel("contacts", FrameKind::Contacts).unwrap();
        for step in 0..5u32 {
            let key = StepHeader { run_id: 1, simulation: 0, step };
            let bodies = msgs::encode(&Frame::<StepHeader, Body>::new(key, vec![Body::default()])).unwrap();
            w.write("bodies", FrameKind::Bodies, 0, 0, &bodies).unwrap();
            if step != 3 {
                let contacts = msgs::encode(&Frame::<StepHeader, Contact>::new(key, vec![])).unwrap();
                w.write("contacts", FrameKind::Contacts, 0, 0, &contacts).unwrap();
            }
        }
        w.finish().unwrap();
        let missing = missing_steps(&path, &["bodies", "contacts", "stats/solve"], 1, 5).unwrap();
        assert_eq!(missing, BTreeMap::from([("bodies".into(), 0), ("contacts".into(), 1), ("stats/solve".into(), 5)]));
        std::fs::remove_dir_all(&dir).ok();
    }
}
