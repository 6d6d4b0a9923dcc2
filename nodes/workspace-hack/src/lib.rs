//! Nothing to use: this crate only unifies third-party features across the workspace (see its
//! `Cargo.toml`).
