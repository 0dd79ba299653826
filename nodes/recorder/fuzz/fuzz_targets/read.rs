//! Any bytes, as a recording, through every reader of the `recorder` crate (see
//! `../every_reader.rs` for the properties checked; `../README.md` for how to run it).
#![no_main]

#[path = "../every_reader.rs"]
mod every_reader;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    every_reader::every_reader(std::path::Path::new("fuzz-input.mcap"), data);
});
