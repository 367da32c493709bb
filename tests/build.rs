//! Builds the variadic test logger (C) that the end-to-end tests hand to FMUs.
fn main() {
    println!("cargo:rerun-if-changed=c/test_logger.c");
    cc::Build::new()
        .file("c/test_logger.c")
        .warnings(true)
        .compile("kneebench_test_logger");
}
