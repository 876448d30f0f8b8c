//! Puts the repository's root `memory.x` on the linker search path for cortex-m-rt's `link.x`.
use std::path::PathBuf;

fn main() {
    let out = PathBuf::from(std::env::var_os("OUT_DIR").unwrap_or_default());
    let root = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default())
        .join("../../memory.x");
    if let Err(e) = std::fs::copy(&root, out.join("memory.x")) {
        println!("cargo:warning=cannot copy {}: {e}", root.display());
    }
    println!("cargo:rustc-link-search={}", out.display());
    println!("cargo:rerun-if-changed={}", root.display());
    println!("cargo:rerun-if-changed=build.rs");
}
