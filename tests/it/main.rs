//! The integration tests, as one test binary: each file was its own binary before, and each
//! linked the library and every dependency again; one binary builds in less time from a fresh
//! clone on two cores (`docs/benchmarks.md`, "Test build"). Run one group with its module
//! name as the filter, e.g. `cargo test --release --test it restore_reference`.

mod common;

mod bad_input;
mod bundler;
mod camera_reference;
mod formats;
mod kill;
mod mesh_io;
mod meshroom;
mod pages;
mod pyramid_reference;
mod render_eval;
mod restore_reference;
mod scene;
mod synth;
mod texture;
