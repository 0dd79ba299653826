//! Typed details of control messages and the simulator's run summary.
//!
//! A control frame's header says what happened ([`ControlKind`]); its items carry the details as
//! CBOR of the type that kind implies ([`RunParams`] for a run start, [`SceneInfo`] for a
//! simulation start, [`NodeNotice`] for node down / up, nothing otherwise). Recordings written
//! before the details were typed carry JSON text there; [`ControlMsg::details`] reads both.

use crate::{Control, ControlKind, ControlMsg, Frame, StepHeader};
use serde::{de::DeserializeOwned, Deserialize, Serialize};

/// What a run start announces: the simulator's parameters, the same for every simulation.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct RunParams {
    pub scene: String,
    /// Dynamic bodies asked for.
    pub n: u64,
    pub seeds: Vec<u64>,
    pub steps: u32,
    /// The warm-start model of the run.
    pub model: String,
    /// The model standing in when the model's warm start is late or missing.
    pub fallback: String,
    pub tolerance: f32,
    pub max_sweeps: u32,
    pub sampler: String,
    /// Time step, seconds.
    pub dt: f32,
    /// Relative compliance of the contact rows (0: rigid; absent in older recordings).
    #[serde(default)]
    pub compliance: f32,
    /// Over-relaxation factor of the solver (1: projected Gauss-Seidel; absent in older
    /// recordings, read as 1; a zero, as `Default` makes it, reads as 1 through
    /// [`crate::recorded_relaxation`]).
    #[serde(default = "plain_gauss_seidel")]
    pub relaxation: f32,
    /// The solver setting as `dc-sim --solver` spells it (`sor:1.4/down`; empty in older
    /// recordings: the solver `relaxation` says).
    #[serde(default)]
    pub solver: String,
    /// The stopping rule, `change` or `natural` (empty in older recordings: `change`).
    #[serde(default)]
    pub stop: String,
}

fn plain_gauss_seidel() -> f32 {
    crate::recorded_relaxation(0.0)
}

/// What a simulation start announces about its scene.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SceneInfo {
    pub seed: u64,
    /// Box side, metres.
    pub side: f32,
    /// Bodies, walls included.
    pub bodies: u64,
    pub dynamic: u64,
    /// Drum angular speed (0 for fixed walls), rad/s.
    pub omega: f32,
}

/// The launcher's notice that a node went down or came back.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct NodeNotice {
    pub node: String,
    pub host: String,
    /// The topics the node publishes (a reader of one of them knows its producer is gone).
    pub publishes: Vec<String>,
    /// Its exit status ("exit status 1", "signal 9"), "running", "host gone", "host back".
    pub status: String,
}

/// The details of a control message, by kind.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub enum ControlDetails {
    RunStart(RunParams),
    SimulationStart(SceneInfo),
    NodeDown(NodeNotice),
    NodeUp(NodeNotice),
    /// Kinds without details (run end, simulation end, shutdown).
    None,
}

/// Why a control message's details could not be read.
#[derive(Debug, thiserror::Error)]
pub enum DetailsError {
    #[error("unknown control kind {0}")]
    UnknownKind(u32),
    #[error("{kind:?} details are neither CBOR nor legacy JSON of the expected shape: {why}")]
    Malformed { kind: ControlKind, why: String },
}

fn cbor<T: Serialize>(value: &T) -> Vec<u8> {
    let mut out = Vec::new();
    ciborium::into_writer(value, &mut out).expect("control details serialise to a Vec");
    out
}

/// CBOR first; legacy recordings carry JSON text (which CBOR reads as something else or fails on).
fn parse<T: DeserializeOwned>(kind: ControlKind, bytes: &[u8]) -> Result<T, DetailsError> {
    match ciborium::from_reader::<T, _>(bytes) {
        Ok(v) => Ok(v),
        Err(cbor_err) => serde_json::from_slice(bytes)
            .map_err(|json_err| DetailsError::Malformed { kind, why: format!("CBOR: {cbor_err}; JSON: {json_err}") }),
    }
}

impl ControlMsg {
    /// A control message without details.
    pub fn simple(step: StepHeader, kind: ControlKind, count: u32) -> ControlMsg {
        Frame::new(Control { step, kind: kind as u32, count }, Vec::new())
    }

    /// A run start for `params.seeds.len()` simulations.
    pub fn run_start(step: StepHeader, params: &RunParams) -> ControlMsg {
        let count = params.seeds.len() as u32;
        Frame::new(Control { step, kind: ControlKind::RunStart as u32, count }, cbor(params))
    }

    /// A simulation start announcing `steps` steps.
    pub fn simulation_start(step: StepHeader, steps: u32, scene: &SceneInfo) -> ControlMsg {
        Frame::new(Control { step, kind: ControlKind::SimulationStart as u32, count: steps }, cbor(scene))
    }

    /// A node down (`up == false`) or node up notice; they belong to no run.
    pub fn node_notice(up: bool, notice: &NodeNotice) -> ControlMsg {
        let kind = if up { ControlKind::NodeUp } else { ControlKind::NodeDown };
        Frame::new(Control { step: StepHeader::default(), kind: kind as u32, count: 0 }, cbor(notice))
    }

    /// The typed details (CBOR, or legacy JSON text of recordings made before they were typed).
    pub fn details(&self) -> Result<ControlDetails, DetailsError> {
        details_of(&self.header, &self.items)
    }
}

/// The typed details of a control header and its item bytes.
pub fn details_of(header: &Control, items: &[u8]) -> Result<ControlDetails, DetailsError> {
    let kind = header.kind().ok_or(DetailsError::UnknownKind(header.kind))?;
    Ok(match kind {
        ControlKind::RunStart => ControlDetails::RunStart(parse(kind, items)?),
        ControlKind::SimulationStart => ControlDetails::SimulationStart(parse(kind, items)?),
        ControlKind::NodeDown => ControlDetails::NodeDown(parse(kind, items)?),
        ControlKind::NodeUp => ControlDetails::NodeUp(parse(kind, items)?),
        ControlKind::RunEnd | ControlKind::SimulationEnd | ControlKind::Shutdown => ControlDetails::None,
    })
}

/// A simulator run's totals, printed by `dc-sim` at the end of each run (one JSON line after
/// [`RunSummary::PREFIX`]) and read by benchmarks and tests.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RunSummary {
    #[serde(with = "crate::id_text")]
    pub run_id: u64,
    pub model: String,
    pub steps: u64,
    /// Wall time of the step loops (all stages), seconds.
    pub loop_secs: f64,
    pub total_sweeps: u64,
    pub fallbacks: u64,
}

impl RunSummary {
    /// What starts the summary line.
    pub const PREFIX: &'static str = "dc-sim run ";

    /// The stdout line.
    pub fn line(&self) -> String {
        format!("{}{}", Self::PREFIX, serde_json::to_string(self).expect("summary serialises"))
    }

    /// The summaries among stdout lines (as printed, or forwarded by the launcher behind a
    /// `[node]` prefix).
    pub fn find_in<'a, I: IntoIterator<Item = &'a str>>(lines: I) -> Result<Vec<RunSummary>, serde_json::Error> {
        lines
            .into_iter()
            .filter_map(|l| l.split_once(Self::PREFIX).map(|(_, json)| json))
            .map(serde_json::from_str)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn params() -> RunParams {
        RunParams {
            scene: "ball-box".into(),
            n: 100,
            seeds: vec![0, 1],
            steps: 250,
            model: "builtin".into(),
            fallback: "builtin".into(),
            tolerance: 1e-4,
            max_sweeps: 1000,
            sampler: "native".into(),
            dt: 0.01,
            compliance: 0.0,
            relaxation: 1.0,
            ..Default::default()
        }
    }

    #[test]
    fn details_round_trip_through_the_wire() {
        let s = StepHeader { run_id: 3, simulation: 0, step: 0 };
        let m = ControlMsg::run_start(s, &params());
        let back: ControlMsg = crate::decode(&crate::encode(&m).unwrap()).unwrap();
        assert_eq!(back.header.count, 2);
        assert_eq!(back.details().unwrap(), ControlDetails::RunStart(params()));
        let named = RunParams { solver: "sor:1.4/down".into(), stop: "natural".into(), ..params() };
        let m = ControlMsg::run_start(s, &named);
        let back: ControlMsg = crate::decode(&crate::encode(&m).unwrap()).unwrap();
        assert_eq!(back.details().unwrap(), ControlDetails::RunStart(named));
        let n = NodeNotice {
            node: "sph".into(),
            host: "a".into(),
            publishes: vec!["grid/contacts".into()],
            status: "signal 9".into(),
        };
        assert_eq!(ControlMsg::node_notice(false, &n).details().unwrap(), ControlDetails::NodeDown(n.clone()));
        assert_eq!(ControlMsg::node_notice(true, &n).details().unwrap(), ControlDetails::NodeUp(n));
        assert_eq!(ControlMsg::simple(s, ControlKind::RunEnd, 2).details().unwrap(), ControlDetails::None);
    }

    #[test]
    fn legacy_json_details_are_read() {
        // As recordings made before typed details hold them.
        let json = r#"{"scene":"ball-box","n":100,"seeds":[0,1],"steps":250,"model":"builtin","fallback":"builtin","tolerance":0.0001,"max_sweeps":1000,"sampler":"native","dt":0.01}"#;
        let c = Control { step: StepHeader::default(), kind: ControlKind::RunStart as u32, count: 2 };
        assert_eq!(details_of(&c, json.as_bytes()).unwrap(), ControlDetails::RunStart(params()));
        let json = r#"{"node":"sph","host":"local","publishes":["grid/contacts"],"status":"exit status 1"}"#;
        let c = Control { kind: ControlKind::NodeDown as u32, ..c };
        assert!(matches!(details_of(&c, json.as_bytes()).unwrap(), ControlDetails::NodeDown(n) if n.node == "sph"));
    }

    #[test]
    fn malformed_details_are_an_error_naming_the_kind() {
        let c = Control { step: StepHeader::default(), kind: ControlKind::NodeUp as u32, count: 0 };
        let err = details_of(&c, b"\xff\x00junk").unwrap_err();
        assert!(err.to_string().starts_with("NodeUp details"), "{err}");
        let c = Control { kind: 99, ..c };
        assert!(matches!(details_of(&c, b""), Err(DetailsError::UnknownKind(99))));
    }

    #[test]
    fn run_summary_line_round_trips_with_a_text_id() {
        let s = RunSummary {
            run_id: 1796139974837132098,
            model: "unet".into(),
            steps: 10,
            loop_secs: 1.5,
            total_sweeps: 99,
            fallbacks: 0,
        };
        let line = s.line();
        assert!(line.contains(r#""run_id":"1796139974837132098""#), "{line}");
        let forwarded = format!("[sim   ] {line}");
        let found = RunSummary::find_in(["[sim] noise", line.as_str(), forwarded.as_str()]).unwrap();
        assert_eq!(found, vec![s.clone(), s]);
    }
}
