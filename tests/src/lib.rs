//! Helpers shared by the end-to-end tests: where the built binaries are, how to export FMUs,
//! and how to reach the project's Python venv with the pinned fmpy.
