// The worker embeds Python for `gymnasium:` envs: find the libpython it was linked with.
include!("../gymnasium/python_rpath.rs");

fn main() {
    python_rpath();
}
