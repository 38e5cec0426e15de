// `selkd` links libtorch through selkd-learner (for its benchmarks): same rpath and CUDA linking.
include!("../learner/build.rs");
