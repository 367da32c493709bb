//! Builds the C shim that turns the FMU's variadic `fmi2CallbackLogger` calls into one formatted
//! string for Rust (Rust cannot define a C-variadic function on stable).

fn main() {
    println!("cargo:rerun-if-changed=src/logger_shim.c");
    cc::Build::new()
        .file("src/logger_shim.c")
        .warnings(true)
        .extra_warnings(true)
        .compile("kneebench_logger_shim");
}
