//! The contact-graph network warm start (issue #13): features of a step's contact problem
//! ([`features`]), the f32 message-passing network ([`net`]), and the model file ([`ModelFile`]).
//! [`Predictor`] turns a problem into per-contact warm starts: builtin's impulse plus the
//! network's correction times the contact's effective masses.
//!
//! This crate is light (no burn) so that the simulator can run the model in-process; training
//! lives with the other learned model, and its networks must match [`net::Net`] weight for weight.

pub mod features;
pub mod net;

use msgs::{ProblemBody, ProblemContact};
use net::{Net, Scratch};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Why a model file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum GnnError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a contact-graph model file: {why}")]
    Format { path: String, why: String },
    #[error("{path}: weights checksum {found:016x} does not match {expected:016x}: the file is damaged")]
    Checksum { path: String, found: u64, expected: u64 },
    #[error("{path}: {why}")]
    Invalid { path: String, why: String },
}

/// What a `.dcg` file holds: the network, how it was made, and a checksum of its weights.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFile {
    /// `dc-gnn` model file format version.
    pub format: u32,
    pub net: Net,
    /// How the model was made (free text: data, loss, steps), shown by `dc-gnn info`.
    pub provenance: String,
    /// FNV-1a 64 of the weights' bytes, in layer order.
    pub checksum: u64,
}

/// The format [`ModelFile::save`] writes.
pub const FORMAT: u32 = 1;

/// FNV-1a 64 over every weight and bias, in layer order.
pub fn checksum(net: &Net) -> u64 {
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    for layer in [&net.encode_contact, &net.encode_body, &net.body, &net.contact, &net.decode] {
        for v in layer.weight.iter().chain(&layer.bias) {
            for byte in v.to_le_bytes() {
                h ^= byte as u64;
                h = h.wrapping_mul(0x0100_0000_01b3);
            }
        }
    }
    h
}

impl ModelFile {
    pub fn new(net: Net, provenance: &str) -> ModelFile {
        let checksum = checksum(&net);
        ModelFile { format: FORMAT, net, provenance: provenance.into(), checksum }
    }

    pub fn save(&self, path: &Path) -> Result<(), GnnError> {
        let io = |source| GnnError::Io { path: path.display().to_string(), source };
        let mut bytes = Vec::new();
        ciborium::into_writer(self, &mut bytes).expect("a model serialises to a Vec");
        std::fs::write(path, bytes).map_err(io)
    }

    /// Loads a model, refusing a damaged file (checksum), another format, wrong shapes or
    /// weights that are not finite.
    pub fn load(path: &Path) -> Result<ModelFile, GnnError> {
        let p = path.display().to_string();
        let bytes = std::fs::read(path).map_err(|source| GnnError::Io { path: p.clone(), source })?;
        let file: ModelFile = ciborium::from_reader(bytes.as_slice())
            .map_err(|e| GnnError::Format { path: p.clone(), why: e.to_string() })?;
        if file.format != FORMAT {
            return Err(GnnError::Format {
                path: p,
                why: format!("format {} (this build reads {FORMAT})", file.format),
            });
        }
        file.net.validate().map_err(|why| GnnError::Invalid { path: p.clone(), why })?;
        let found = checksum(&file.net);
        if found != file.checksum {
            return Err(GnnError::Checksum { path: p, found, expected: file.checksum });
        }
        Ok(file)
    }
}

/// Per-contact warm starts from a network, with its reusable buffers.
#[derive(Debug)]
pub struct Predictor {
    net: Net,
    scratch: Scratch,
    contact_features: Vec<f32>,
    body_features: Vec<f32>,
    masses: Vec<[f32; 2]>,
    pairs: Vec<(u32, u32)>,
    out: Vec<[f32; 2]>,
}

impl Predictor {
    pub fn new(net: Net) -> Predictor {
        Predictor {
            net,
            scratch: Scratch::default(),
            contact_features: Vec::new(),
            body_features: Vec::new(),
            masses: Vec::new(),
            pairs: Vec::new(),
            out: Vec::new(),
        }
    }

    pub fn net(&self) -> &Net {
        &self.net
    }

    /// Writes `(normal, tangent)` warm starts, one per contact: builtin's (`previous`) plus the
    /// network's correction times the contact's effective masses.
    pub fn warm_start(&mut self, bodies: &[ProblemBody], contacts: &[ProblemContact], out: &mut [[f32; 2]]) {
        features::features(bodies, contacts, &mut self.contact_features, &mut self.body_features, &mut self.masses);
        self.pairs.clear();
        self.pairs.extend(contacts.iter().map(|c| (c.body_a, c.body_b)));
        self.net.predict(&self.contact_features, &self.body_features, &self.pairs, &mut self.scratch, &mut self.out);
        for (((o, c), y), k) in out.iter_mut().zip(contacts).zip(&self.out).zip(&self.masses) {
            *o = [c.previous[0] + y[0] * k[0], c.previous[1] + y[1] * k[1]];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn model_files_round_trip_and_refuse_damage() {
        let dir = std::env::temp_dir().join(format!("dc-gnn-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("m.dcg");
        let file = ModelFile::new(Net::new(net::NetConfig::default(), 9), "test");
        file.save(&path).unwrap();
        assert_eq!(ModelFile::load(&path).unwrap(), file);
        // A changed weight that still parses: the checksum catches it.
        let mut damaged = file.clone();
        damaged.net.contact.weight[3] += 1e-3;
        damaged.save(&path).unwrap();
        assert!(matches!(ModelFile::load(&path), Err(GnnError::Checksum { .. })));
        // Bytes that do not parse, and a file that is not there, are named errors too.
        std::fs::write(&path, b"\x00\x01junk").unwrap();
        assert!(ModelFile::load(&path).unwrap_err().to_string().contains("not a contact-graph model file"));
        assert!(matches!(ModelFile::load(&dir.join("missing.dcg")), Err(GnnError::Io { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn an_untrained_predictor_is_builtin() {
        let bodies = [ProblemBody::default(), ProblemBody { v: [0.0, -0.1], w: 0.0, inv_mass: 1.0, inv_inertia: 2.0 }];
        let contacts = [ProblemContact {
            body_a: 0,
            body_b: 1,
            normal: [0.0, 1.0],
            rb: [0.0, -0.5],
            friction: 0.5,
            previous: [0.7, -0.1],
            age: 4,
            ..Default::default()
        }];
        let mut p = Predictor::new(Net::new(net::NetConfig::default(), 1));
        let mut out = [[0.0; 2]];
        p.warm_start(&bodies, &contacts, &mut out);
        assert_eq!(out, [[0.7, -0.1]]);
    }
}
