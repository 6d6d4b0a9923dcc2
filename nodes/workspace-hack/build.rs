// Cargo only resolves a package's build-dependencies when it has a build script: this one lets
// the crate unify the features of the proc-macro crates that build scripts and derives use.
fn main() {}
