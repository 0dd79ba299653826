//! The frame types a recording holds, found from a topic name (recording) or from a channel's
//! `type` metadata (replay, reading), and what can be done with a payload without knowing its type
//! statically.

use msgs::{topics, CodecError, StepHeader};

/// The frame type of a topic: header and item types.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum FrameKind {
    /// `Frame<StepHeader, Body>`.
    Bodies,
    /// `Frame<StepHeader, Contact>`.
    Contacts,
    /// `Frame<GridHeader, f32>`.
    Grid,
    /// `Frame<SolveStatsHeader, f32>`.
    SolveStats,
    /// `Frame<Control, u8>`.
    Control,
}

impl FrameKind {
    pub const ALL: [FrameKind; 5] =
        [FrameKind::Bodies, FrameKind::Contacts, FrameKind::Grid, FrameKind::SolveStats, FrameKind::Control];

    /// The frame type of a known topic.
    pub fn of_topic(topic: &str) -> Option<FrameKind> {
        let is = |names: &[&str]| names.contains(&topic);
        if is(&[topics::BODIES.name, topics::BENCH_BODIES.name, topics::BENCH_ECHO.name]) {
            Some(FrameKind::Bodies)
        } else if is(&[topics::CONTACTS.name]) {
            Some(FrameKind::Contacts)
        } else if is(&[
            topics::GRID_BODIES.name,
            topics::GRID_CONTACTS.name,
            topics::GRID_UNET.name,
            topics::BENCH_GRID.name,
            topics::BENCH_GRID_ECHO.name,
        ]) {
            Some(FrameKind::Grid)
        } else if is(&[topics::SOLVE_STATS.name, topics::METRICS_STEP.name]) {
            Some(FrameKind::SolveStats)
        } else if is(&[topics::CONTROL.name]) {
            Some(FrameKind::Control)
        } else {
            None
        }
    }

    /// The name written in channel metadata (`type`).
    pub fn type_name(self) -> &'static str {
        match self {
            FrameKind::Bodies => "dc::Bodies",
            FrameKind::Contacts => "dc::Contacts",
            FrameKind::Grid => "dc::Grid",
            FrameKind::SolveStats => "dc::SolveStats",
            FrameKind::Control => "dc::ControlMsg",
        }
    }

    pub fn from_type_name(name: &str) -> Option<FrameKind> {
        FrameKind::ALL.into_iter().find(|k| k.type_name() == name)
    }

    /// Header and item type names, for channel metadata and `dc-record info`.
    pub fn parts(self) -> (&'static str, &'static str) {
        match self {
            FrameKind::Bodies => ("dc::StepHeader", "dc::Body"),
            FrameKind::Contacts => ("dc::StepHeader", "dc::Contact"),
            FrameKind::Grid => ("dc::GridHeader", "f32"),
            FrameKind::SolveStats => ("dc::SolveStatsHeader", "f32"),
            FrameKind::Control => ("dc::Control", "u8"),
        }
    }

    /// The (run, simulation, step) a payload belongs to, decoding its header only.
    pub fn step_of(self, payload: &[u8]) -> Result<StepHeader, CodecError> {
        Ok(match self {
            FrameKind::Bodies | FrameKind::Contacts => msgs::decode_header::<StepHeader>(payload)?,
            FrameKind::Grid => msgs::decode_header::<msgs::GridHeader>(payload)?.step,
            FrameKind::SolveStats => msgs::decode_header::<msgs::SolveStatsHeader>(payload)?.step,
            FrameKind::Control => msgs::decode_header::<msgs::Control>(payload)?.step,
        })
    }

    /// Decodes a payload fully (version, header, item length) and drops it: is it a valid frame?
    pub fn validate(self, payload: &[u8]) -> Result<(), CodecError> {
        match self {
            FrameKind::Bodies => msgs::decode::<StepHeader, msgs::Body>(payload).map(drop),
            FrameKind::Contacts => msgs::decode::<StepHeader, msgs::Contact>(payload).map(drop),
            FrameKind::Grid => msgs::decode::<msgs::GridHeader, f32>(payload).map(drop),
            FrameKind::SolveStats => msgs::decode::<msgs::SolveStatsHeader, f32>(payload).map(drop),
            FrameKind::Control => msgs::decode::<msgs::Control, u8>(payload).map(drop),
        }
    }
}

/// A header that carries the (run, simulation, step) of its frame.
pub trait HasStep {
    fn step_header(&self) -> StepHeader;
}

impl HasStep for StepHeader {
    fn step_header(&self) -> StepHeader {
        *self
    }
}
impl HasStep for msgs::GridHeader {
    fn step_header(&self) -> StepHeader {
        self.step
    }
}
impl HasStep for msgs::SolveStatsHeader {
    fn step_header(&self) -> StepHeader {
        self.step
    }
}
impl HasStep for msgs::Control {
    fn step_header(&self) -> StepHeader {
        self.step
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_known_topic_has_a_frame_kind() {
        for t in topics::ALL {
            assert!(FrameKind::of_topic(t).is_some(), "{t}");
        }
        assert_eq!(FrameKind::of_topic("nope"), None);
    }

    #[test]
    fn type_names_round_trip() {
        for k in FrameKind::ALL {
            assert_eq!(FrameKind::from_type_name(k.type_name()), Some(k));
        }
    }

    #[test]
    fn step_is_read_from_every_header_kind() {
        let s = StepHeader { run_id: 9, simulation: 2, step: 5 };
        let grid = msgs::Grid::zeros(s, [0.0; 2], 1.0, 2, 2, &["a"]);
        assert_eq!(FrameKind::Grid.step_of(&msgs::encode(&grid).unwrap()).unwrap(), s);
        let c = msgs::ControlMsg::control(s, msgs::ControlKind::SimulationEnd, 0, "");
        assert_eq!(FrameKind::Control.step_of(&msgs::encode(&c).unwrap()).unwrap(), s);
        assert!(FrameKind::Bodies.validate(&msgs::encode(&c).unwrap()).is_err());
    }
}
