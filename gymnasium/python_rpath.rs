// Included by the build scripts of the binaries that embed Python (learner, selkd, actor-worker):
// bakes the directory of the libpython that PyO3 links (that of `PYO3_PYTHON`, else `python3`,
// the interpreter deploy/python.sh makes the venv from) into the binary, so the one found at run
// time is the one it was built against, not another 3.x on the loader's default path.
fn python_rpath() {
    println!("cargo:rerun-if-env-changed=PYO3_PYTHON");
    let python = std::env::var("PYO3_PYTHON").unwrap_or_else(|_| "python3".into());
    let Ok(out) = std::process::Command::new(&python)
        .args(["-c", "import sysconfig; print(sysconfig.get_config_var('LIBDIR') or '')"])
        .output()
    else {
        return;
    };
    let dir = String::from_utf8_lossy(&out.stdout).trim().to_string();
    if !dir.is_empty() {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{dir}");
    }
}
