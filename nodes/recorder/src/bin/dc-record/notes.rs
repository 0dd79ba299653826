//! What both recorders (the graph's and `dc record -a`) note beside the frames they write.

use msgs::ControlKind;
use recorder::RecordingWriter;
use std::collections::BTreeMap;

/// What a recorder notes about a control frame it wrote: a run start's parameters as a
/// `run_start` metadata record (JSON text, readable by any MCAP tool). Returns the frame's kind.
pub fn note_control(
    writer: &mut RecordingWriter,
    data: &[u8],
    step: msgs::StepHeader,
) -> anyhow::Result<Option<ControlKind>> {
    let c: msgs::Control = msgs::decode_header(data)?;
    if c.kind() == Some(ControlKind::RunStart) {
        let msg = msgs::decode::<msgs::Control, u8>(data)?;
        let details = match msg.details() {
            Ok(msgs::ControlDetails::RunStart(p)) => serde_json::to_string(&p)?,
            other => {
                tracing::warn!("control: a run start whose details do not decode: {other:?}");
                String::new()
            }
        };
        let meta = BTreeMap::from([("run_id".to_string(), step.run_id.to_string()), ("details".to_string(), details)]);
        writer.write_metadata("run_start", meta)?;
    }
    Ok(c.kind())
}
