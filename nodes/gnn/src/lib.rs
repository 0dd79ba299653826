//! The contact-graph network warm start (issue #13): features of a step's contact problem
//! ([`features`]), the f32 message-passing network ([`net`]), and the model file ([`ModelFile`]).
//! [`unroll`] is the solver in the loop a warm start for a sweep budget is trained against.
//! [`Predictor`] turns a problem into per-contact warm starts: builtin's impulse plus the
//! network's correction times the contact's effective masses.
//!
//! This crate is light (no burn) so that the simulator can run the model in-process; training
//! lives with the other learned model, and its networks must match [`net::Net`] weight for weight.

pub mod features;
pub mod net;
pub mod unroll;

use msgs::{ProblemBody, ProblemContact};
use net::{Net, Plan, Scratch};
use serde::{Deserialize, Serialize};
use std::path::Path;

/// Why a model file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum GnnError {
    #[error("{path}: {source}")]
    Io { path: String, source: std::io::Error },
    #[error("{path}: not a contact-graph model file: {why}")]
    Format { path: String, why: String },
    #[error("{path}: checksum {found:016x} does not match {expected:016x}: the file is damaged")]
    Checksum { path: String, found: u64, expected: u64 },
    #[error("{path}: {why}")]
    Invalid { path: String, why: String },
}

/// What a `.dcg` file holds: the network, how it was made, and a checksum of everything else.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelFile {
    /// `dc-gnn` model file format version.
    pub format: u32,
    pub net: Net,
    /// How the model was made (free text: data, loss, steps), shown by `dc-gnn info`.
    pub provenance: String,
    /// Format 2: FNV-1a 64 of the CBOR encoding of the format, the network (configuration and
    /// weights) and the provenance ([`content_checksum`]). Format 1: of the weights only.
    pub checksum: u64,
}

/// The format [`ModelFile::save`] writes.
pub const FORMAT: u32 = 2;

/// The format whose checksum covers the weights only: a changed configuration (`rounds`) went
/// unnoticed. Read only by [`ModelFile::upgrade`].
pub const FORMAT_WEIGHTS_ONLY: u32 = 1;

/// FNV-1a 64 of `bytes`, continuing from `h`.
fn fnv1a(mut h: u64, bytes: impl IntoIterator<Item = u8>) -> u64 {
    for byte in bytes {
        h ^= byte as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    }
    h
}

const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;

/// Format 1's checksum: FNV-1a 64 over every weight and bias, in layer order.
pub fn checksum(net: &Net) -> u64 {
    [&net.encode_contact, &net.encode_body, &net.body, &net.contact, &net.decode]
        .into_iter()
        .flat_map(|layer| layer.weight.iter().chain(&layer.bias))
        .fold(FNV_OFFSET, |h, v| fnv1a(h, v.to_le_bytes()))
}

/// Format 2's checksum: FNV-1a 64 over the CBOR encoding of everything the file holds but the
/// checksum itself.
pub fn content_checksum(format: u32, net: &Net, provenance: &str) -> u64 {
    let mut bytes = Vec::new();
    ciborium::into_writer(&(format, net, provenance), &mut bytes).expect("a model serialises to a Vec");
    fnv1a(FNV_OFFSET, bytes)
}

impl ModelFile {
    /// A format-2 file of `net`.
    pub fn new(net: Net, provenance: &str) -> ModelFile {
        let checksum = content_checksum(FORMAT, &net, provenance);
        ModelFile { format: FORMAT, net, provenance: provenance.into(), checksum }
    }

    /// Writes the file through a temporary beside it, renamed into place: a failed write never
    /// leaves a truncated model where a good one was.
    pub fn save(&self, path: &Path) -> Result<(), GnnError> {
        let mut bytes = Vec::new();
        ciborium::into_writer(self, &mut bytes).expect("a model serialises to a Vec");
        runtime::files::replace_file(path, &bytes)
            .map_err(|source| GnnError::Io { path: path.display().to_string(), source })
    }

    /// Loads a model, refusing a damaged file (checksum over everything it holds), bytes after
    /// the model, another format, wrong shapes or weights that are not finite.
    pub fn load(path: &Path) -> Result<ModelFile, GnnError> {
        let file = ModelFile::read(path)?;
        if file.format != FORMAT {
            let how = if file.format == FORMAT_WEIGHTS_ONLY {
                " whose checksum leaves the configuration unchecked: `dc-gnn upgrade FILE` rewrites it"
            } else {
                ""
            };
            let why = format!("format {}{how} (this build reads {FORMAT})", file.format);
            return Err(GnnError::Format { path: path.display().to_string(), why });
        }
        let found = content_checksum(file.format, &file.net, &file.provenance);
        file.checked(path, found)
    }

    /// Rewrites a format-1 file (checked by its weights' checksum and shapes) as format 2 at
    /// `out`; a format-2 file is checked and copied as it is.
    pub fn upgrade(path: &Path, out: &Path) -> Result<ModelFile, GnnError> {
        let file = ModelFile::read(path)?;
        let upgraded = match file.format {
            FORMAT => {
                let found = content_checksum(file.format, &file.net, &file.provenance);
                file.checked(path, found)?
            }
            FORMAT_WEIGHTS_ONLY => {
                let found = checksum(&file.net);
                let file = file.checked(path, found)?;
                ModelFile::new(file.net, &file.provenance)
            }
            other => {
                let why = format!("format {other} (this build reads {FORMAT})");
                return Err(GnnError::Format { path: path.display().to_string(), why });
            }
        };
        upgraded.save(out)?;
        Ok(upgraded)
    }

    /// The file if its stored checksum is `found` and its network is valid.
    fn checked(self, path: &Path, found: u64) -> Result<ModelFile, GnnError> {
        let p = path.display().to_string();
        if found != self.checksum {
            return Err(GnnError::Checksum { path: p, found, expected: self.checksum });
        }
        self.net.validate().map_err(|why| GnnError::Invalid { path: p, why })?;
        Ok(self)
    }

    /// The file's CBOR, all of it: bytes after the model are an error. Only a regular file of at
    /// most [`runtime::files::MAX_MODEL_BYTES`] is read (`/dev/zero`, a FIFO or a folder is
    /// refused by its kind, before reading).
    fn read(path: &Path) -> Result<ModelFile, GnnError> {
        let p = path.display().to_string();
        let bytes = runtime::files::read_bounded(path, "model file", runtime::files::MAX_MODEL_BYTES)
            .map_err(|e| GnnError::Io { path: p.clone(), source: e.into() })?;
        let mut rest = bytes.as_slice();
        let file: ModelFile =
            ciborium::from_reader(&mut rest).map_err(|e| GnnError::Format { path: p.clone(), why: e.to_string() })?;
        if !rest.is_empty() {
            return Err(GnnError::Format {
                path: p,
                why: format!("{} bytes after the model (of {})", rest.len(), bytes.len()),
            });
        }
        Ok(file)
    }
}

/// Per-contact warm starts from a network, with its reusable buffers.
#[derive(Debug)]
pub struct Predictor {
    plan: Plan,
    scratch: Scratch,
    contact_features: Vec<f32>,
    body_features: Vec<f32>,
    masses: Vec<[f32; 2]>,
    velocities: Vec<([f32; 2], f32)>,
    pairs: Vec<(u32, u32)>,
    out: Vec<[f32; 2]>,
}

impl Predictor {
    pub fn new(net: Net) -> Predictor {
        Predictor {
            plan: Plan::new(&net),
            scratch: Scratch::default(),
            contact_features: Vec::new(),
            body_features: Vec::new(),
            masses: Vec::new(),
            velocities: Vec::new(),
            pairs: Vec::new(),
            out: Vec::new(),
        }
    }

    /// Writes `(normal, tangent)` warm starts, one per contact: builtin's (`previous`) plus the
    /// network's correction times the contact's effective masses. A network whose weights are
    /// finite can still overflow on an input (a damaged or badly trained model): non-finite
    /// warm starts are an error, never handed to a solver.
    pub fn warm_start(
        &mut self,
        bodies: &[ProblemBody],
        contacts: &[ProblemContact],
        out: &mut [[f32; 2]],
    ) -> Result<(), NonFinite> {
        features::features_with(
            &mut self.velocities,
            bodies,
            contacts,
            &mut self.contact_features,
            &mut self.body_features,
            &mut self.masses,
        );
        self.pairs.clear();
        self.pairs.extend(contacts.iter().map(|c| (c.body_a, c.body_b)));
        self.plan.predict(&self.contact_features, &self.body_features, &self.pairs, &mut self.scratch, &mut self.out);
        for (((o, c), y), k) in out.iter_mut().zip(contacts).zip(&self.out).zip(&self.masses) {
            *o = [c.previous[0] + y[0] * k[0], c.previous[1] + y[1] * k[1]];
        }
        match out.iter().flatten().filter(|v| !v.is_finite()).count() {
            0 => Ok(()),
            values => Err(NonFinite { values, of: 2 * out.len() }),
        }
    }
}

/// A prediction with values that are not finite (overflow in the network).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("the network predicted {values} non-finite values of {of}")]
pub struct NonFinite {
    pub values: usize,
    pub of: usize,
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
        // A changed configuration that still parses and has valid shapes (rounds 4 -> 5: the
        // weights are shared across rounds): the checksum covers it too.
        let mut rounds = file.clone();
        rounds.net.config.rounds += 1;
        rounds.save(&path).unwrap();
        assert!(matches!(ModelFile::load(&path), Err(GnnError::Checksum { .. })), "a changed rounds loaded");
        // Trailing bytes after a good model are refused, naming them.
        file.save(&path).unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        bytes.extend_from_slice(b"trailing");
        std::fs::write(&path, &bytes).unwrap();
        assert!(ModelFile::load(&path).unwrap_err().to_string().contains("8 bytes after the model"));
        // Bytes that do not parse, and a file that is not there, are named errors too.
        std::fs::write(&path, b"\x00\x01junk").unwrap();
        assert!(ModelFile::load(&path).unwrap_err().to_string().contains("not a contact-graph model file"));
        assert!(matches!(ModelFile::load(&dir.join("missing.dcg")), Err(GnnError::Io { .. })));
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn devices_fifos_folders_and_oversized_files_are_refused_before_reading() {
        let dir = std::env::temp_dir().join(format!("dc-gnn-kinds-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("pipe.dcg");
        assert!(std::process::Command::new("mkfifo").arg(&fifo).status().unwrap().success());
        // Sparse: 1 GiB long, nothing written.
        let huge = dir.join("huge.dcg");
        std::fs::File::create(&huge).unwrap().set_len(1 << 30).unwrap();
        let started = std::time::Instant::now();
        for (path, why) in [
            (Path::new("/dev/zero"), "is a character device, not a model file"),
            (dir.as_path(), "is a directory, not a model file"),
            (fifo.as_path(), "is a FIFO (named pipe), not a model file"),
            (huge.as_path(), "is 1 GiB, larger than any model file (at most 256 MiB)"),
        ] {
            for e in [ModelFile::load(path).unwrap_err(), ModelFile::upgrade(path, &dir.join("out.dcg")).unwrap_err()] {
                assert!(matches!(e, GnnError::Io { .. }), "{e}");
                assert_eq!(e.to_string(), format!("{}: {why}", path.display()));
            }
        }
        assert!(started.elapsed() < std::time::Duration::from_secs(5), "{:?}", started.elapsed());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn format_1_files_are_refused_until_upgraded_and_upgrade_checks_their_weights() {
        let dir = std::env::temp_dir().join(format!("dc-gnn-v1-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (old, new) = (dir.join("old.dcg"), dir.join("new.dcg"));
        let net = Net::new(net::NetConfig::default(), 3);
        let v1 = ModelFile { format: FORMAT_WEIGHTS_ONLY, checksum: checksum(&net), net, provenance: "v1".into() };
        v1.save(&old).unwrap();
        let err = ModelFile::load(&old).unwrap_err().to_string();
        assert!(err.contains("format 1") && err.contains("dc-gnn upgrade"), "{err}");
        let upgraded = ModelFile::upgrade(&old, &new).unwrap();
        assert_eq!((upgraded.format, &upgraded.net, upgraded.provenance.as_str()), (FORMAT, &v1.net, "v1"));
        assert_eq!(ModelFile::load(&new).unwrap(), upgraded);
        // A damaged format-1 file is not laundered into a valid format-2 one.
        let mut damaged = v1.clone();
        damaged.net.decode.bias[0] += 1.0;
        damaged.save(&old).unwrap();
        assert!(matches!(ModelFile::upgrade(&old, &new), Err(GnnError::Checksum { .. })));
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
        p.warm_start(&bodies, &contacts, &mut out).unwrap();
        assert_eq!(out, [[0.7, -0.1]]);
        // A finite weight large enough to overflow: an error, not a NaN warm start.
        let mut huge = Net::new(net::NetConfig::default(), 1);
        huge.decode.weight.fill(f32::MAX);
        huge.encode_contact.weight.fill(f32::MAX);
        let mut p = Predictor::new(huge);
        assert_eq!(p.warm_start(&bodies, &contacts, &mut out), Err(NonFinite { values: 2, of: 2 }));
    }
}
