// Bakes libtorch's location into the binaries (so they run with no LD_LIBRARY_PATH), and links
// `torch_cuda` explicitly where the libtorch has it: with the default `--as-needed` linking it would
// otherwise be dropped, and `--device cuda` would find no CUDA.
use std::path::PathBuf;

include!("../gymnasium/python_rpath.rs");

fn main() {
    python_rpath();
    println!("cargo:rerun-if-env-changed=LIBTORCH");
    let Ok(libtorch) = std::env::var("LIBTORCH") else {
        return;
    };
    let lib = PathBuf::from(libtorch).join("lib");
    let lib = lib.canonicalize().unwrap_or(lib);
    println!("cargo:rustc-link-arg=-Wl,-rpath,{}", lib.display());
    if lib.join("libtorch_cuda.so").exists() {
        println!("cargo:rustc-link-arg=-Wl,--no-as-needed,-ltorch_cuda,--as-needed");
    }
}
